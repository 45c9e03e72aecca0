"""Deterministic tests of the failure classes the fuzzer (``test_fuzz.py``) found, next to
their fixes: each failed before its fix."""

from __future__ import annotations

import pytest
import torch

from sssbench.kernels import tap_positions
from sssbench.profiles import BurleyNormalized, Dipole, SumOfGaussians


@pytest.mark.parametrize("exponent", [0.25, 0.5, 1.0, 2.0, 3.0])
@pytest.mark.parametrize("samples", [3, 5, 7, 9, 33])
def test_power_placement_is_exactly_symmetric(samples, exponent):
    """An odd count puts the middle tap exactly on 0 and mirrors every other (the placement
    ``sign(t)|t|^p`` is odd); ``linspace``'s middle value is 1e-16, whose square root put the
    centre tap 1e-8 · extent off 0 for exponents below 1."""
    centres, edges = tap_positions(samples, "power", 1.0, exponent=exponent)
    assert float(centres[samples // 2]) == 0.0
    assert torch.equal(centres, -centres.flip(0))
    inner = edges[1:-1]
    assert torch.equal(inner, -inner.flip(0))


@pytest.mark.parametrize("bad", [None, "1", [None], object()])
def test_sum_of_gaussians_names_a_non_numeric_argument(bad):
    with pytest.raises(TypeError, match="^variances"):
        SumOfGaussians(bad, torch.ones(1, 3))
    with pytest.raises(TypeError, match="^weights"):
        SumOfGaussians(torch.ones(1), bad)


@pytest.mark.parametrize("make", [lambda v: BurleyNormalized(v, 0.5), lambda v: Dipole(v, 0.1)])
def test_a_bool_is_not_a_coefficient(make):
    """``True`` used to be taken as 1.0 mm (a silent wrong answer for a mistyped flag)."""
    with pytest.raises(TypeError, match="must be a number"):
        make(True)


@pytest.mark.parametrize("source", ["albedo", "diffuse"])
def test_lab_guide_does_not_depend_on_memory_layout(source):
    """kornia's Lab conversion rounds differently on a channels-last float32 tensor, so the
    halo weights (and every method using ``halo="lab"``) changed with the layout."""
    from sssbench import GBuffer
    from sssbench.ops import lab_guide

    gen = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 13, 8, generator=gen)

    def cl(t):
        return t.contiguous(memory_format=torch.channels_last)

    g = GBuffer(a * 0.5, torch.full((2, 1, 13, 8), 300.0), 0.5, albedo=a)
    g_cl = GBuffer(cl(a * 0.5), cl(g.depth), 0.5, albedo=cl(a))
    assert torch.equal(lab_guide(g, source=source), lab_guide(g_cl, source=source))

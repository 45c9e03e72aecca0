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


@pytest.mark.parametrize("name", ["thickness", "roulette_radius", "kill_radius"])
@pytest.mark.parametrize("value", [1e300, 1e20])
def test_walk_names_a_distance_beyond_float32(name, value):
    """Issue 29's ``long`` run: ``walk(thickness=1e300)`` passed the check (> 0) and died
    inside the float32 walk with torch's "cannot be converted to type float without
    overflow", naming nothing (a roulette radius of 1e300 overflowed when squared)."""
    from sssbench.mc.walk import walk

    with pytest.raises(ValueError, match=f"^{name} must be > 0 and at most"):
        walk(0.5, photons=4, progress=False, **{name: value})


@pytest.mark.parametrize("training", [float("nan"), 3, "face"])
def test_optimise_names_a_training_set_that_is_not_a_sequence(training):
    """Issue 29's fuzzer: ``optimise(training=nan)`` raised "'float' object is not iterable"."""
    from sssbench.tune.optimise import optimise

    with pytest.raises(TypeError, match="^training must be"):
        optimise(SumOfGaussians.from_table("skin_jg10"), training=training, cache=False)

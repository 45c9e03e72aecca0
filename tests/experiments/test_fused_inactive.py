"""experiments/fused_inactive.py: its earlier schedules are the fused method, bit for bit."""

from __future__ import annotations

import pytest
import torch

from experiments.fused_inactive import copying, serial_output, small_pages
from sssbench.ops import FusedSumOfGaussiansSSS, native
from sssbench.ops import sum_of_gaussians_fused as fused
from sssbench.profiles import SumOfGaussians
from tests.ops.test_sum_of_gaussians_fused import scene


@pytest.mark.parametrize("level", native.simd_levels() or ("scalar",))
def test_the_copying_schedule_is_the_method_bitwise(level):
    """The x sweep into every pixel of a workspace and the y sweep reading it there give the
    method's bits (which reads the inactive pixels from the diffuse image instead); NaN left
    in either's workspace changes nothing; so does the new result copied whole first
    (``serial_output``) instead of filled at its inactive pixels by the x sweep, nor a
    workspace in 4 KB pages (``small_pages``), which leaves the method's own in place."""
    g = scene(b=2, h=40, w=60, cover=0.5)
    op = FusedSumOfGaussiansSSS(SumOfGaussians.from_table("skin_deon6"), 7)
    scratch = torch.full((len(op.kernels), *g.diffuse.shape), float("nan"), dtype=g.dtype)
    with native.simd(level):
        first = op(g)
        fused._SCRATCH.tensor.fill_(float("nan"))  # the method's kept workspace
        assert torch.equal(op(g), first) and not bool(first.isnan().any())
        assert torch.equal(copying(op, g, scratch), first)
        scratch.fill_(float("nan"))
        assert torch.equal(serial_output(op, g, scratch), first)
        kept = fused._SCRATCH.tensor
        scratch.fill_(float("nan"))
        assert torch.equal(small_pages(op, g, scratch), first)
        assert fused._SCRATCH.tensor is kept

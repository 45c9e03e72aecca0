"""000 §4: the pre-integrated kernel reproduces the exact 2D convolution for additively
separable irradiance (a straight shadow edge). Measured against the reference that integrates
the irradiance the way the gather reads it (bilinear between pixel centres), it converges in
taps to below 1e-4; against the piecewise-constant (box) reference it stops at a floor that is
only the reconstruction convention (the budget's err_recon), not the taps."""

from __future__ import annotations

import os

import torch

from data_synth import make_scene
from sssbench import ops
from sssbench.profiles import SumOfGaussians
from sssbench.score.metrics import rel_rms

os.environ.setdefault("TQDM_DISABLE", "1")


def test_step_edge_converges_to_the_bilinear_reference():
    skin = SumOfGaussians.from_table("skin_deon6")
    g = make_scene("step_edge", (16, 128), fields=["mask"], dtype=torch.float64)
    with torch.inference_mode():
        box = ops.ReferenceSSS(skin)(g)
        bilinear = ops.ReferenceSSS(skin, reconstruction="bilinear")(g)
        errors = [
            rel_rms(ops.PreintegratedSSS(skin, n)(g), bilinear, g.mask) for n in (65, 257, 1025)
        ]
        floor = rel_rms(ops.PreintegratedSSS(skin, 1025)(g), box, g.mask)
    assert errors[0] > errors[1] > errors[2]  # converging in taps
    assert errors[2] < 1e-4
    # against the box reference the same kernel stops at the convention's floor
    convention = rel_rms(bilinear, box, g.mask)
    assert floor > 10 * errors[2] and abs(floor - convention) < 0.1 * convention

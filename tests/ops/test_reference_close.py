"""ReferenceSSS at the scale of a 1080p extreme close-up (0.07 mm of skin per pixel) against a
brute-force surface integral: skin_deon6's narrowest Gaussian (σ ≈ 0.08 mm, about a pixel)
is gathered cell by cell, the wider ones from block moments and Gauss–Legendre points on the
steep cells of the nose's side."""

import math

import numpy as np
import pytest
import torch
from oracles import brute_force_reference, rel_rms_np

from data_synth import make_scene
from sssbench.gbuffer import pixel_size_mm
from sssbench.ops import reference as reference
from sssbench.ops.reference import reference_radius_px, reference_sss
from sssbench.profiles import SumOfGaussians

#: skin_deon6's four narrowest Gaussians (σ 0.08–0.75 mm, 1–13 pixels): the two widest
#: (1.4 and 2.7 mm) would make the brute force too slow for a unit test; they take the same
#: moment path as the 0.22–0.75 mm ones here
_SKIN = SumOfGaussians.from_table("skin_deon6")
PROFILE = SumOfGaussians(_SKIN.variances[:4], _SKIN.weights[:4])


@pytest.fixture(scope="module")
def close_up():
    # the side of the nose turned 60° away: slopes up to ~3, a quarter of the cells steep
    g = make_scene("face", (24, 24), dtype=torch.float64, pixel_mm=0.07, aim="face", yaw=60.0)
    on = torch.nonzero(g.mask_or_ones()[0, 0] > 0).numpy()
    rng = np.random.default_rng(0)
    return g, on[rng.choice(len(on), 12, replace=False)]


def test_the_close_up_exercises_both_the_cell_gather_and_the_moments(close_up):
    # guards the test below: at this scale the narrowest Gaussian is narrower than
    # WIDE_PIXELS footprints (cell gather), the others wider (moments)
    g, _ = close_up
    z = g.depth[g.mask_or_ones() > 0]
    p_min, p_max = (float(pixel_size_mm(f(z), g.fov_y, 24)) for f in (torch.min, torch.max))
    sigma = PROFILE.variances.sqrt() / p_min
    wide = sigma >= reference.WIDE_PIXELS * p_max / p_min
    assert wide.tolist() == [False, True, True, True]
    assert p_min < 0.07 < p_max  # the focus at 0.07 mm per pixel


@pytest.mark.parametrize("threads", [1, 2])
def test_close_up_matches_the_brute_force_surface_integral(close_up, threads):
    g, targets = close_up
    k = reference_radius_px(g, PROFILE)
    want = brute_force_reference(g, PROFILE, targets, k, "box")
    out = reference_sss(g, PROFILE, threads=threads)  # auto: the multipole method
    got = out[0][:, targets[:, 0], targets[:, 1]].numpy().T
    assert math.isfinite(float(out.sum()))
    assert rel_rms_np(got, want) < 1e-4

"""Every scalar of the kernels, profiles and method constructors is validated on entry: NaN,
±inf, negative, zero where not allowed, and magnitudes that overflow or underflow float32 in
the passes raise a ValueError / TypeError naming the argument and the allowed range, before
any kernel is built (``sssbench._checks.MAGNITUDES``)."""

from __future__ import annotations

import math
import re

import pytest
import torch

from sssbench import GBuffer, ops
from sssbench._checks import MAGNITUDES, check_magnitude
from sssbench.kernels import (
    Kernel1D,
    artist,
    cell_centres,
    jimenez2012,
    preintegrated,
    tap_positions,
)
from sssbench.profiles import BurleyNormalized, Dipole, Layer, SumOfGaussians
from sssbench.profiles.empirical import empirical_pole_fit
from sssbench.profiles.layers import fit_powers_of_gaussian

SKIN = SumOfGaussians.from_table("skin_jg10")
NAN, INF = math.nan, math.inf


def _g() -> GBuffer:
    n = torch.zeros(1, 3, 4, 4)
    n[:, 2] = 1.0
    return GBuffer(
        torch.ones(1, 3, 4, 4), torch.full((1, 1, 4, 4), 100.0), 0.5, normal=n,
        thickness=torch.ones(1, 1, 4, 4), light_dir=torch.tensor([[0.0, 0.0, -1.0]]),
    )  # fmt: skip


def _sog(v: float = 1.0, w: float = 1.0) -> SumOfGaussians:
    return SumOfGaussians(
        torch.tensor([v], dtype=torch.float64), torch.full((1, 3), w, dtype=torch.float64)
    )


# (id, thunk, argument name that the message must contain)
CASES = [
    # ---- profiles
    ("sog_variance_huge", lambda: _sog(1e30), "variances"),
    ("sog_variance_tiny", lambda: _sog(1e-30), "variances"),
    ("sog_weight_huge", lambda: _sog(1.0, 1e300), "weights"),
    ("burley_d_tiny", lambda: BurleyNormalized(1e-300, 0.5), "d"),
    ("burley_d_huge", lambda: BurleyNormalized(1e300, 0.5), "d"),
    ("dipole_sigma_s_huge", lambda: Dipole(1e300, 0.01), "sigma_s_prime"),
    ("dipole_sigma_s_tiny", lambda: Dipole(1e-300, 0.01), "sigma_s_prime"),
    ("dipole_sigma_a_huge", lambda: Dipole(1.0, 1e300), "sigma_a"),
    ("pole_fit_z_huge", lambda: empirical_pole_fit(0.1, 1e300), "z"),
    ("pole_fit_sigma_huge", lambda: empirical_pole_fit(1e300, 1.0), "sigma_tr"),
    ("layer_v_huge", lambda: Layer(*[torch.zeros(2, 3)] * 4, 1e300), "v"),
    ("powers_v_tiny", lambda: fit_powers_of_gaussian(SKIN, 1e-300, 3), "v"),
    # ---- kernels
    ("artist_scale_huge", lambda: artist(0.1, 0.5, 0.5, 1e300, 7), "scale"),
    ("artist_scale_tiny", lambda: artist(0.1, 0.5, 0.5, 1e-300, 7), "scale"),
    (
        "artist_extent_huge",
        lambda: artist(0.1, 0.5, 0.5, 1.0, 7, "uniform", extent=1e300),
        "extent",
    ),
    ("jimenez_falloff_huge", lambda: jimenez2012(0.5, 1e300, 9), "falloff"),
    ("tap_extent_tiny", lambda: tap_positions(7, "uniform", 1e-300), "extent"),
    ("tap_exponent_huge", lambda: tap_positions(7, "power", 1.0, exponent=1e300), "exponent"),
    ("preintegrated_extent_huge", lambda: preintegrated(SKIN, 7, "uniform", 1e300), "extent"),
    ("cell_centres_extent_huge", lambda: cell_centres(1e300, 3), "extent"),
    ("kernel_scaled_nan", lambda: Kernel1D(torch.zeros(1), torch.ones(1, 3)).scaled(NAN), "factor"),
    ("kernel_scaled_inf", lambda: Kernel1D(torch.zeros(1), torch.ones(1, 3)).scaled(INF), "factor"),
    # ---- method constructors (before any kernel is built)
    ("jimenez_width_tiny", lambda: ops.Jimenez2012SSS(0.5, 0.5, 1e-300), "width"),
    ("jimenez_width_huge", lambda: ops.Jimenez2012SSS(0.5, 0.5, 1e300), "width"),
    (
        "jimenez_surface_scale",
        lambda: ops.Jimenez2012SSS(0.5, 0.5, 1.0, surface_scale=1e-300),
        "surface_scale",
    ),
    ("jimenez_seed", lambda: ops.Jimenez2012SSS(0.5, 0.5, 1.0, seed=2**70), "seed"),
    (
        "sog_surface_scale",
        lambda: ops.SumOfGaussiansSSS(SKIN, surface_scale=1e-300),
        "surface_scale",
    ),
    (
        "sog_extent_sigmas",
        lambda: ops.SumOfGaussiansSSS(SKIN, extent_sigmas=1e300),
        "extent_sigmas",
    ),
    (
        "sog_lod_threshold",
        lambda: ops.SumOfGaussiansSSS(SKIN, lod_threshold=1e300),
        "lod_threshold",
    ),
    ("sog_seed", lambda: ops.SumOfGaussiansSSS(SKIN, seed=-1), "seed"),
    ("low_rank_extent", lambda: ops.LowRankSSS(SKIN, 3, 9, extent=1e-300), "extent"),
    (
        "low_rank_surface_scale",
        lambda: ops.LowRankSSS(SKIN, 3, 9, surface_scale=INF),
        "surface_scale",
    ),
    (
        "preintegrated_halo_sigma",
        lambda: ops.PreintegratedSSS(SKIN, halo="lab", halo_sigma=1e-300),
        "halo_sigma",
    ),
    ("preintegrated_profile_none", lambda: ops.PreintegratedSSS(None), "profile"),
    ("preintegrated_seed", lambda: ops.PreintegratedSSS(SKIN, seed=1.5), "seed"),
    ("artist_op_scale", lambda: ops.ArtistSSS(0.1, 0.5, 0.5, 1e300), "scale"),
    ("artist_op_seed", lambda: ops.ArtistSSS(0.1, 0.5, 0.5, 1.0, seed=2**64), "seed"),
    ("jg10_ssslevel", lambda: ops.jg10_stretch(8, ssslevel=1e300), "ssslevel"),
    ("jg10_correction", lambda: ops.jg10_stretch(8, correction=1e300), "correction"),
    ("jg10_head", lambda: ops.jg10_stretch(8, head_mm=1e-300), "head_mm"),
    # ---- extensions
    ("range_weight_tiny", lambda: ops.range_weight(1e-300), "sigma"),
    ("halo_min_cos_tiny", lambda: ops.halo_guide(_g(), min_cos=1e-300), "min_cos"),
    (
        "curvature_gain_huge",
        lambda: ops.curvature_width(torch.ones(1, 1, 2, 2), "increase", gain=1e300),
        "gain",
    ),
    (
        "curvature_reference_tiny",
        lambda: ops.curvature_width(torch.ones(1, 1, 2, 2), reference=1e-300),
        "reference",
    ),
    ("curvature_smooth_huge", lambda: ops.CurvatureModulation(smooth=2 * 10**9 + 1), "smooth"),
    (
        "curvature_edge_ratio",
        lambda: ops.screen_space_curvature(_g(), edge_ratio=1e300),
        "edge_ratio",
    ),
    ("translucency_width_tiny", lambda: ops.translucency(_g(), "skin_deon6", 0.0, 1e-300), "width"),
    (
        "translucency_intensity_huge",
        lambda: ops.Translucency("skin_deon6", intensity=1e300),
        "intensity",
    ),
    ("rotation_seed_huge", lambda: ops.random_rotation(_g(), 0.1, 2**70), "seed"),
]


@pytest.mark.parametrize("thunk,name", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_absurd_scalar_raises_naming_the_argument(thunk, name):
    with pytest.raises((ValueError, TypeError)) as info:
        thunk()
    msg = str(info.value)
    assert msg.startswith(name) or f" {name} " in msg or f"{name} must" in msg, msg


@pytest.mark.parametrize("kind", sorted(MAGNITUDES))
def test_magnitude_bounds_are_inclusive_and_named(kind):
    lo, hi, unit = MAGNITUDES[kind]
    assert check_magnitude("x", lo, kind) == lo and check_magnitude("x", hi, kind) == hi
    for bad in (lo / 2, hi * 2, -lo, 0.0, NAN, INF, -INF):
        with pytest.raises(ValueError, match="^x must"):
            check_magnitude("x", bad, kind)
    # a quantity that may vanish is never divided by: all of [0, hi] is accepted
    assert check_magnitude("x", 0.0, kind, zero=True) == 0.0
    assert check_magnitude("x", lo / 2, kind, zero=True) == lo / 2
    for bad in (-lo, hi * 2, NAN):
        with pytest.raises(ValueError, match="^x must"):
            check_magnitude("x", bad, kind, zero=True)
    t = torch.tensor([lo, 1.0, hi], dtype=torch.float64)
    assert check_magnitude("x", t, kind) is t
    with pytest.raises(ValueError, match=re.escape(f"x must be in [{lo:g}, {hi:g}]")):
        check_magnitude("x", torch.tensor([1.0, hi * 10]), kind)
    with pytest.raises(TypeError, match="x must"):
        check_magnitude("x", "1.0", kind)


def test_a_smooth_window_larger_than_needed_is_refused_before_allocating():
    # the box filter of side `smooth` would allocate smooth² weights
    with pytest.raises(ValueError, match="smooth"):
        ops.CurvatureModulation(smooth=10**6 + 1)


def test_kernel_matrix_in_row_chunks_matches_the_closed_form(monkeypatch):
    """The matrix is integrated a few rows at a time (bounded memory at MAX_MATRIX_SIZE);
    the chunks must tile it exactly: one Gaussian's cell mass is a product of 1D normal CDF
    differences (scipy as the independent oracle)."""
    from scipy.stats import norm

    import sssbench.kernels.matrix as matrix

    monkeypatch.setattr(matrix, "_CELLS_PER_CHUNK", 10)  # 7 cells per row: one row per chunk
    v, extent, n = 0.7, 2.0, 7
    m = matrix.kernel_matrix(_sog(v), extent, n)
    edges = torch.linspace(-extent, extent, n + 1, dtype=torch.float64).numpy()
    mass = norm.cdf(edges[1:] / v**0.5) - norm.cdf(edges[:-1] / v**0.5)
    expected = torch.from_numpy(mass[:, None] * mass[None, :])
    for c in range(3):
        assert torch.allclose(m[c], expected, rtol=1e-10, atol=1e-15)

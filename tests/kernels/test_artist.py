"""artist(): 000 eq. 6 / Table 2 against closed-form Gaussian integrals."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.kernels import (
    ARTIST_PRESETS,
    ArtistParams,
    artist,
    artist_preset,
    artist_sigmas,
    tap_positions,
)


def _phi(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0))) if math.isfinite(x) else float(x > 0)


def test_presets_are_table_2() -> None:
    """000 Table 2, transcribed independently."""
    assert ARTIST_PRESETS["single_layer_close_fit"] == (
        10.34,
        (0.077, 0.034, 0.02),
        (1.0, 0.45, 0.25),
        0.5,
    )
    assert ARTIST_PRESETS["multi_layer_close_fit"] == (
        9.27,
        (0.055, 0.044, 0.038),
        (1.0, 0.2, 0.13),
        0.5,
    )
    assert ARTIST_PRESETS["production"] == (9.9, (0.22, 0.07, 0.07), (1.0, 0.3, 0.15), 0.65)


@pytest.mark.parametrize("sampling", ["uniform", "power", "importance"])
@pytest.mark.parametrize("name", sorted(ARTIST_PRESETS))
def test_weights_are_gaussian_cdf_differences(name: str, sampling: str) -> None:
    s, near, far, w = ARTIST_PRESETS[name]
    k = artist_preset(name, 9, sampling)
    assert len(k) == 9
    # edges: midpoints between centres for uniform/power, recomputed independently for importance
    _, edges = tap_positions(
        9,
        sampling,
        None if sampling == "importance" else 4.0 * s,
        cdf=lambda x: _mixture_cdf(x, near[0] * s, far[0] * s, w),
    )
    for c in range(3):
        sn, sf = near[c] * s, far[c] * s
        ref = []
        for a, b in zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True):
            ref.append(w * (_phi(b / sn) - _phi(a / sn)) + (1 - w) * (_phi(b / sf) - _phi(a / sf)))
        ref_t = torch.tensor(ref, dtype=torch.float64)
        torch.testing.assert_close(k.weights[:, c], ref_t / ref_t.sum(), rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(k.sum(), torch.ones(3, dtype=torch.float64), rtol=0, atol=1e-12)
    torch.testing.assert_close(k.offsets, -k.offsets.flip(0), rtol=0, atol=1e-12)
    torch.testing.assert_close(k.weights, k.weights.flip(0), rtol=0, atol=1e-12)


def _mixture_cdf(x: torch.Tensor, sn: float, sf: float, w: float) -> torch.Tensor:
    return w * torch.special.ndtr(x / sn) + (1 - w) * torch.special.ndtr(x / sf)


def test_importance_gives_equal_dominant_weights() -> None:
    """000 §7: taps at quantiles of the dominant (red) channel -> equal red weights."""
    k = artist_preset("multi_layer_close_fit", 7)
    torch.testing.assert_close(k.weights[:, 0], torch.full((7,), 1 / 7, dtype=torch.float64))


def test_sigmas_and_sigma_max_eq7() -> None:
    p = ArtistParams.preset("single_layer_close_fit")
    torch.testing.assert_close(
        p.sigma_near, torch.tensor([0.077, 0.034, 0.02], dtype=torch.float64) * 10.34
    )
    torch.testing.assert_close(
        p.sigma_far, torch.tensor([1.0, 0.45, 0.25], dtype=torch.float64) * 10.34
    )
    torch.testing.assert_close(p.sigma_max, p.sigma_far)  # 000 eq. 7: σ_max = σ_f
    sn, sf = artist_sigmas((0.1, 0.2, 0.3), 0.5, 2.0)
    torch.testing.assert_close(sn, torch.tensor([0.2, 0.4, 0.6], dtype=torch.float64))
    torch.testing.assert_close(sf, torch.full((3,), 1.0, dtype=torch.float64))


def test_eq6_normalisation_constant() -> None:
    """∫ a_m dx = 1/√(2π) for any parameters (000 eq. 6's 1/(2πσ)): the relation the taps'
    normalisation removes."""
    p = ArtistParams.make((0.1, 0.3, 0.02), (0.9, 0.5, 0.2), (0.3, 0.6, 0.9), 5.0)
    x = torch.linspace(-60, 60, 240001, dtype=torch.float64)
    integral = torch.trapezoid(p.evaluate(x), x, dim=0)
    torch.testing.assert_close(
        integral, torch.full((3,), 1 / math.sqrt(2 * math.pi), dtype=torch.float64)
    )
    assert float(p.evaluate(0.0)[0]) == pytest.approx(
        0.3 / (2 * math.pi * 0.5) + 0.7 / (2 * math.pi * 4.5)
    )


def test_delta_and_single_tap() -> None:
    k = artist(0.0, 0.0, 1.0, 1.0, 5, "uniform")  # both σ = 0: a delta at 0
    torch.testing.assert_close(k.weights[2], torch.ones(3, dtype=torch.float64))
    one = artist_preset("production", 1)
    torch.testing.assert_close(one.weights, torch.ones(1, 3, dtype=torch.float64))
    assert one.offsets.tolist() == [0.0]


def test_bad_inputs_name_argument() -> None:
    with pytest.raises(ValueError, match="near"):
        artist(1.5, 1.0, 0.5, 10.0, 7)
    with pytest.raises(ValueError, match="far"):
        artist(0.1, (1.0, -0.1, 0.2), 0.5, 10.0, 7)
    with pytest.raises(ValueError, match="far"):
        artist(0.1, (1.0, 0.2), 0.5, 10.0, 7)
    with pytest.raises(ValueError, match="weight"):
        artist(0.1, 1.0, 1.2, 10.0, 7)
    with pytest.raises(ValueError, match="scale"):
        artist(0.1, 1.0, 0.5, 0.0, 7)
    with pytest.raises(ValueError, match="near"):
        artist(float("nan"), 1.0, 0.5, 1.0, 7)
    with pytest.raises(TypeError, match="near"):
        artist("x", 1.0, 0.5, 1.0, 7)
    with pytest.raises(ValueError, match="samples"):
        artist(0.1, 1.0, 0.5, 1.0, 0)
    with pytest.raises(ValueError, match="sampling"):
        artist(0.1, 1.0, 0.5, 1.0, 7, "random")
    with pytest.raises(ValueError, match="name"):
        artist_preset("marble", 7)

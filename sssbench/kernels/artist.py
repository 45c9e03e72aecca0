"""The artist-friendly two-Gaussian separable kernel (000 §5 eq. 6, Table 2; §7 eq. 7).

``a_m(x) = w G(x, σ_n) + (1 − w) G(x, σ_f)``, ``A_m(x, y) = a_m(x) a_m(y)`` with
``G(x, σ) = exp(−x²/2σ²) / (2πσ)`` (000 eq. 6), ``σ_n = σ'_n s`` and ``σ_f = σ'_f s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from sssbench._checks import check_choice, check_int, check_magnitude, check_range, check_tensor
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.sampling import (
    MAX_SAMPLES,
    SAMPLINGS,
    gaussian_mixture_cdf,
    gaussian_mixture_interval,
    interval_weights,
    tap_positions,
)

__all__ = ["ArtistParams", "ARTIST_PRESETS", "artist", "artist_preset", "artist_sigmas"]

#: 000 Table 2: name -> (s mm, σ'_n (R, G, B), σ'_f (R, G, B), w)
ARTIST_PRESETS: dict[str, tuple[float, tuple[float, ...], tuple[float, ...], float]] = {
    "single_layer_close_fit": (10.34, (0.077, 0.034, 0.02), (1.0, 0.45, 0.25), 0.5),
    "multi_layer_close_fit": (9.27, (0.055, 0.044, 0.038), (1.0, 0.2, 0.13), 0.5),
    "production": (9.9, (0.22, 0.07, 0.07), (1.0, 0.3, 0.15), 0.65),
}

#: a σ of 0 is a delta; we clamp it to this (mm) so Gaussian CDF differences stay defined
_SIGMA_FLOOR = 1e-9
#: default half-width for uniform / power placement, in units of the widest σ
_EXTENT_SIGMAS = 4.0


def _per_channel(
    name: str, value: object, low: float | None = 0.0, high: float | None = 1.0
) -> torch.Tensor:
    """A scalar or a (3,) sequence/tensor in [low, high] -> (3,) float64."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        t = torch.full((3,), float(value), dtype=torch.float64)
    elif isinstance(value, torch.Tensor):
        t = value
    elif isinstance(value, (list, tuple)):
        try:
            t = torch.tensor(value, dtype=torch.float64)
        except (TypeError, ValueError) as err:
            raise TypeError(f"{name} must be 3 real numbers, got {value!r}") from err
    else:
        raise TypeError(
            f"{name} must be a number or 3 per-channel numbers (R, G, B), "
            f"got {type(value).__name__}"
        )
    if not t.is_floating_point():
        t = t.double()
    check_tensor(name, t)
    if t.ndim == 0:
        t = t.expand(3)
    if t.shape != (3,):
        raise ValueError(f"{name} must have shape (3,) (R, G, B), got {tuple(t.shape)}")
    check_range(name, t, low, high)
    return t.double()


@dataclass(frozen=True)
class ArtistParams:
    """Validated parameters of the artist-friendly model (000 §5, Table 2).

    Args:
        near: σ'_n per channel, ``(3,)`` in [0, 1] (a scalar is broadcast).
        far: σ'_f per channel, ``(3,)`` in [0, 1].
        weight: w, the near-Gaussian weight, in [0, 1] (scalar or per channel).
        scale: s, the global translucency scale in mm, in [1e-6, 1e6] (``_checks.MAGNITUDES``).

    Example:
        >>> p = ArtistParams.preset("production")
        >>> [round(v, 3) for v in p.sigma_max.tolist()]
        [9.9, 2.97, 1.485]
    """

    near: torch.Tensor
    far: torch.Tensor
    weight: torch.Tensor
    scale: float

    @classmethod
    def make(
        cls,
        near: object,
        far: object,
        weight: object,
        scale: float,
    ) -> ArtistParams:
        """Validate and build (scalars broadcast to the three channels)."""
        return cls(
            _per_channel("near", near),
            _per_channel("far", far),
            _per_channel("weight", weight),
            check_magnitude("scale", scale, "length"),
        )

    @classmethod
    def preset(cls, name: str) -> ArtistParams:
        """A row of 000 Table 2: one of :data:`ARTIST_PRESETS`."""
        check_choice("name", name, sorted(ARTIST_PRESETS))
        s, near, far, w = ARTIST_PRESETS[name]
        return cls.make(near, far, w, s)

    @property
    def sigma_near(self) -> torch.Tensor:
        """σ_n = σ'_n · s in mm, ``(3,)``."""
        return self.near * self.scale

    @property
    def sigma_far(self) -> torch.Tensor:
        """σ_f = σ'_f · s in mm, ``(3,)``."""
        return self.far * self.scale

    @property
    def sigma_max(self) -> torch.Tensor:
        """σ_max = max(σ_n, σ_f) per channel, mm: the depth falloff of 000 eq. 7.

        000 §7 writes σ_max = σ_f (the far Gaussian is the wider one in every Table 2 row); we
        take the maximum so a user swapping near and far still gets the wider one.
        """
        return torch.maximum(self.sigma_near, self.sigma_far)

    def _sigmas_masses(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(2, 3) standard deviations and (2, 3) unit-mass weights of the normalised kernel."""
        sig = torch.stack([self.sigma_near, self.sigma_far]).clamp_min(_SIGMA_FLOOR)
        mass = torch.stack([self.weight, 1.0 - self.weight])
        return sig, mass

    def dominant_channel(self) -> int:
        """The widest channel: largest variance ``w σ_n² + (1 − w) σ_f²`` of the normalised 1D
        kernel (000 §7 samples all channels at the dominant channel's positions)."""
        sig, mass = self._sigmas_masses()
        return int(torch.argmax((mass * sig**2).sum(0)))

    def evaluate(self, x: torch.Tensor | float) -> torch.Tensor:
        """``a_m(x)`` of 000 eq. 6 as printed, with the ``1/(2πσ)`` factor, ``(..., 3)``."""
        xt = torch.as_tensor(x, dtype=torch.float64)[..., None]
        sn, sf = self.sigma_near.clamp_min(_SIGMA_FLOOR), self.sigma_far.clamp_min(_SIGMA_FLOOR)
        g_n = torch.exp(-(xt**2) / (2 * sn**2)) / (2 * math.pi * sn)  # 000 eq. 6
        g_f = torch.exp(-(xt**2) / (2 * sf**2)) / (2 * math.pi * sf)
        return self.weight * g_n + (1.0 - self.weight) * g_f

    def kernel(
        self, samples: int, sampling: str = "importance", extent: float | None = None
    ) -> Kernel1D:
        """The taps; see :func:`artist`."""
        k = check_int("samples", samples, 1, MAX_SAMPLES)
        check_choice("sampling", sampling, SAMPLINGS)
        if extent is not None:
            extent = check_magnitude("extent", extent, "length")
        sig, mass = self._sigmas_masses()
        if extent is None and sampling != "importance":
            widest = float(sig.max())
            extent = _EXTENT_SIGMAS * widest if widest > _SIGMA_FLOOR else self.scale
        d = self.dominant_channel()

        def cdf(x: torch.Tensor) -> torch.Tensor:
            return gaussian_mixture_cdf(x, sig, mass)[..., d]

        centres, edges = tap_positions(k, sampling, extent, cdf=cdf)
        # 000 §7 area integration. Each 1D G of eq. 6 integrates to σ√(2π)/(2πσ) = 1/√(2π),
        # so a_m integrates to 1/√(2π) for every σ and w: the normalised taps are √(2π) times
        # the area integrals of a_m, i.e. unit-mass Gaussian CDF differences weighted w, 1 − w.
        w = interval_weights(edges, lambda a, b: gaussian_mixture_interval(a, b, sig, mass))
        return Kernel1D(centres, w / w.sum(0))


def artist_sigmas(near: object, far: object, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(σ_n, σ_f)`` in mm per channel, ``(3,)`` each (000 §5: σ = σ' · s).

    ``σ_f`` is the σ_max of the depth correction of 000 eq. 7 (see
    :attr:`ArtistParams.sigma_max`).

    Example:
        >>> sn, sf = artist_sigmas(0.1, 0.5, 10.0)
        >>> sn.tolist(), sf.tolist()
        ([1.0, 1.0, 1.0], [5.0, 5.0, 5.0])
    """
    p = ArtistParams.make(near, far, 0.5, scale)
    return p.sigma_near, p.sigma_far


def artist(
    near: object,
    far: object,
    weight: object,
    scale: float,
    samples: int,
    sampling: str = "importance",
    *,
    extent: float | None = None,
) -> Kernel1D:
    """Taps of the artist-friendly kernel ``a_m`` of 000 eq. 6, normalised to sum 1 per channel.

    000 eq. 6 normalises each 1D Gaussian by ``1/(2πσ)`` (not the 1D ``1/(√(2π)σ)``), so
    ``∫ a_m = 1/√(2π)`` and ``∬ A_m = 1/(2π)`` for any parameters: the factor is a constant
    that the paper's normalisation "to one" (000 §4) removes. We therefore divide the
    area-integrated taps by their sum; the normalised kernel is the mixture
    ``w N(0, σ_n²) + (1 − w) N(0, σ_f²)`` of unit-mass 1D Gaussians. A σ' of 0 is treated as a
    delta (σ clamped to 1e-9 mm).

    Taps are placed by :func:`~sssbench.kernels.tap_positions` (for ``importance``: the quantiles
    of the dominant, widest, channel's normalised kernel) and weighted by the integral of each
    channel's kernel over the tap's interval (Gaussian CDF differences, 000 §7), tails lumped
    into the end taps. Only the screen plane is discretised; the depth factor
    ``exp(−d_z²/2σ_max²)`` of 000 eq. 7 is applied by the pass with
    :attr:`ArtistParams.sigma_max` (= σ_f).

    Args:
        near: σ'_n, scalar or ``(3,)`` (R, G, B) in [0, 1].
        far: σ'_f, scalar or ``(3,)`` in [0, 1].
        weight: w in [0, 1] (scalar or per channel).
        scale: s in mm, > 0.
        samples: number of taps in [1, MAX_SAMPLES].
        sampling: ``"uniform"``, ``"power"`` or ``"importance"``.
        extent: half-width in mm; default ``4 · max σ`` for uniform / power (``s`` if every σ
            is 0), the whole line for importance.

    Returns:
        A :class:`Kernel1D` (offsets in mm), weights summing to 1 per channel.

    Shape:
        offsets ``(samples,)``, weights ``(samples, 3)``.

    Example:
        >>> k = artist((0.055, 0.044, 0.038), (1.0, 0.2, 0.13), 0.5, 9.27, 7)
        >>> len(k), [round(float(s), 6) for s in k.sum()]
        (7, [1.0, 1.0, 1.0])
    """
    return ArtistParams.make(near, far, weight, scale).kernel(samples, sampling, extent)


def artist_preset(
    name: str, samples: int, sampling: str = "importance", *, extent: float | None = None
) -> Kernel1D:
    """:func:`artist` with a row of 000 Table 2 (``"single_layer_close_fit"``,
    ``"multi_layer_close_fit"``, ``"production"``).

    Example:
        >>> len(artist_preset("production", 9))
        9
    """
    return ArtistParams.preset(name).kernel(samples, sampling, extent)

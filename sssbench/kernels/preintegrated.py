"""The pre-integrated separable kernel (000 §4, eq. 4–5) discretised into taps (000 §7)."""

from __future__ import annotations

import torch

from sssbench._checks import check_choice, check_int, check_magnitude
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.sampling import MAX_SAMPLES, SAMPLINGS, interval_weights, tap_positions
from sssbench.profiles.base import Profile

__all__ = ["preintegrated", "profile_taps"]


def profile_taps(
    profile: Profile,
    samples: int,
    sampling: str = "importance",
    extent: float | None = None,
) -> Kernel1D:
    """Taps of the normalised 1D kernel ``a_p(x) / ‖R‖₁`` of a radial profile.

    Positions follow ``sampling`` (for ``importance``: the quantiles of the dominant, i.e.
    widest, channel — 000 §7 samples all channels at the dominant channel's positions); every
    channel's weight is the integral of its own pre-integrated profile over the tap's interval
    (000 §7 "area integration"), divided by the channel total (000 eq. 5: ``A_p`` normalised to
    one). Weights therefore sum to 1 per channel.

    Args:
        profile: a radial profile with positive total in every channel.
        samples: number of taps K in [1, MAX_SAMPLES].
        sampling: one of ``"uniform"``, ``"power"``, ``"importance"``.
        extent: half-width in mm; default ``profile.radius()`` for uniform/power and the whole
            line for importance.

    Returns:
        A :class:`Kernel1D` in mm, float64.
    """
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
    check_int("samples", samples, 1, MAX_SAMPLES)
    check_choice("sampling", sampling, SAMPLINGS)
    if extent is not None:
        extent = check_magnitude("extent", extent, "length")
    total = profile.total()
    if bool((total <= 0).any()):
        raise ValueError(
            "profile total must be > 0 in every channel to normalise the kernel, "
            f"got {total.tolist()}"
        )
    if extent is None and sampling != "importance":
        extent = profile.radius()
    d = profile.dominant_channel()

    def cdf(x: torch.Tensor) -> torch.Tensor:
        return profile.preintegrated_cdf(x)[..., d] / total[d]

    centres, edges = tap_positions(samples, sampling, extent, cdf=cdf)
    weights = interval_weights(edges, profile.preintegrated_interval, total)  # 000 eq. 5
    return Kernel1D(centres, weights)


def preintegrated(
    profile: Profile,
    samples: int,
    sampling: str = "importance",
    extent: float | None = None,
) -> Kernel1D:
    """The pre-integrated kernel of 000 eq. 5 as ``samples`` taps; see :func:`profile_taps`.

    Example:
        >>> from sssbench.profiles import SumOfGaussians
        >>> k = preintegrated(SumOfGaussians.from_table("skin_deon6"), 7)
        >>> [round(float(s), 6) for s in k.sum()]
        [1.0, 1.0, 1.0]
    """
    return profile_taps(profile, samples, sampling, extent)

"""The pre-integrated separable kernel (000 §4, eq. 4–5) discretised into taps (000 §7)."""

from __future__ import annotations

import torch

from sssbench._checks import check_choice, check_int, check_magnitude
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.sampling import (
    MAX_SAMPLES,
    SAMPLINGS,
    gaussian_mixture_interval,
    interval_weights,
    tap_positions,
)
from sssbench.profiles.base import Profile
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = ["preintegrated", "profile_taps", "profile_cells", "shared_gaussian_taps"]


def profile_cells(
    profile: Profile,
    samples: int,
    sampling: str = "importance",
    extent: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The tap centres ``(K,)`` and cell edges ``(K+1,)`` (mm, float64, the ends ±inf) of
    :func:`profile_taps` (its arguments, checked the same way): where the pre-integrated
    kernel of ``profile`` samples and the interval each tap stands for (000 §7)."""
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

    return tap_positions(samples, sampling, extent, cdf=cdf)


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
    centres, edges = profile_cells(profile, samples, sampling, extent)
    total = profile.total()
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


def shared_gaussian_taps(
    profile: SumOfGaussians,
    samples: int,
    sampling: str = "importance",
    extent: float | None = None,
) -> tuple[tuple[Kernel1D, ...], torch.Tensor]:
    """Each Gaussian of a sum of Gaussians as taps at ONE shared set of offsets: the rank-S
    separable kernel ``R(x, y) = Σ_s c_s g_s(x) g_s(y)`` (003 §7.3 the sum; 000 §3 eq. 2 the
    rank-N separable sum), exact per Gaussian (a 2D Gaussian is the product of its 1D ones).

    The offsets are those of the pre-integrated kernel of the whole profile at the same
    ``samples`` and ``sampling`` (:func:`profile_cells`: equal taps, the same cells); Gaussian
    ``s``'s weight at tap ``t`` is its 1D mass over tap ``t``'s cell (000 §7 area integration,
    :func:`~sssbench.kernels.sampling.interval_weights`; the tails lumped into the end taps,
    so each set sums to 1). Why shared offsets: a sweep then fetches each sample and computes
    its follow-surface factor once for all Gaussians (:func:`~sssbench.ops.separable_sweep`).
    The cost: a Gaussian narrower than the tap spacing falls (nearly) entirely on the centre
    tap, i.e. is left unblurred, and a wide one is sampled as coarsely as the profile's tails.

    Args:
        profile: a :class:`SumOfGaussians` with weights >= 0 and total > 0 per channel.
        samples, sampling, extent: as :func:`profile_taps`.

    Returns:
        ``(kernels, coefficients)``: one :class:`Kernel1D` per Gaussian with some weight
        (narrowest first; its three channels equal), and ``(S, 3)`` float64 ``c_s = w_s /
        Σ_j w_j`` per channel (003 §7.3.3's normalisation: a constant image stays constant).

    Example:
        >>> ks, c = shared_gaussian_taps(SumOfGaussians.from_table("skin_deon6"), 7)
        >>> len(ks), [round(float(v), 6) for v in c.sum(0)]
        (6, [1.0, 1.0, 1.0])
    """
    if not isinstance(profile, SumOfGaussians):
        raise TypeError(f"profile must be a SumOfGaussians, got {type(profile).__name__}")
    if bool((profile.weights < 0).any()):
        raise ValueError("profile weights must be >= 0 (each Gaussian a blend coefficient)")
    centres, edges = profile_cells(profile, samples, sampling, extent)
    order = torch.argsort(profile.variances)
    var = profile.variances[order].to(torch.float64)
    wts = profile.weights[order].to(torch.float64)
    keep = (wts > 0).any(1)
    var, wts = var[keep], wts[keep]
    coefficients = wts / wts.sum(0)  # 003 §7.3.3: w_s / Σ_j w_j per channel
    ones = torch.ones(1, 3, dtype=torch.float64)
    kernels = []
    for v in var:
        sigma = v.sqrt().view(1)

        def mass(a: torch.Tensor, b: torch.Tensor, sigma: torch.Tensor = sigma) -> torch.Tensor:
            return gaussian_mixture_interval(a, b, sigma, ones)  # 000 §7 area integration

        kernels.append(Kernel1D(centres, interval_weights(edges, mass)))
    return tuple(kernels), coefficients

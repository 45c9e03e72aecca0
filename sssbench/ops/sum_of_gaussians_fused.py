"""The sum of Gaussians in one sweep per axis (003 §7.3 applied directly, 000 §3 eq. 2):
every Gaussian of the profile at one shared set of taps, two sweeps in all."""

from __future__ import annotations

import threading

import torch

from sssbench._checks import check_choice, check_int, check_method_options
from sssbench.gbuffer import GBuffer
from sssbench.kernels.preintegrated import shared_gaussian_taps
from sssbench.kernels.sampling import MAX_SAMPLES, SAMPLINGS
from sssbench.ops._pages import huge_page_empty
from sssbench.ops.functional import functional
from sssbench.ops.gather import MAX_SETS, separable_sweep
from sssbench.ops.method import SeparableMethod
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = ["FusedSumOfGaussiansSSS", "fused_sum_of_gaussians_sss"]

#: per thread, the x sweep's last workspace (one per thread: a call never shares it with
#: another running call, and the sweep overwrites all of it before the y sweep reads it)
_SCRATCH = threading.local()


def _workspace(shape: tuple[int, ...], like: torch.Tensor) -> torch.Tensor:
    """This thread's ``shape`` workspace of ``like``'s dtype and device, kept between calls
    (one at a time: a new shape replaces it). Measured at 1080p (skin_deon6, 6 Gaussians,
    1 thread): allocating and faulting in the 150 MB of six fresh images on every call cost
    about as much CPU time as the x sweep's taps. On the CPU in 2 MB pages
    (:func:`~sssbench.ops._pages.huge_page_empty`): the y sweep reads its 18 planes a strip row
    at a time, a 4 KB page per row and plane; measured (issue 30, 1080p close-up, 2 threads,
    alternated in one process, ``python -m experiments.fused_inactive --against small_pages``,
    three processes) 0.965× ± 0.005 the time of a workspace in 4 KB pages, the same bits."""
    ws = getattr(_SCRATCH, "tensor", None)
    if ws is None or ws.shape != shape or ws.dtype != like.dtype or ws.device != like.device:
        ws = None  # released before the new one is allocated
        _SCRATCH.tensor = None
        with torch.inference_mode(False):
            if like.device.type == "cpu":
                ws = huge_page_empty(shape, like.dtype)
            else:
                ws = torch.empty(shape, dtype=like.dtype, device=like.device)
            _SCRATCH.tensor = ws
    return ws


class FusedSumOfGaussiansSSS(SeparableMethod):
    """The sum of Gaussians as a rank-S separable kernel ``R(x, y) = Σ_s c_s g_s(x) g_s(y)``
    (003 §7.3: the profile is the sum; 000 §3 eq. 2: a rank-N sum of separable terms), each
    Gaussian applied *directly* (not blurred on top of the previous one as
    :class:`~sssbench.ops.SumOfGaussiansSSS` does, 003 §7.3.3), with ``c_s = w_s / Σ_j w_j``
    per channel: a constant image stays constant, and there is no separability error (a 2D
    Gaussian is the product of its 1D ones).

    Two sweeps (:func:`~sssbench.ops.separable_sweep`): the x sweep reads the diffuse image
    once and writes one image per Gaussian (its active pixels only) and, when the result is a
    new image, the diffuse image's inactive pixels into it; the y sweep reads those
    ``S`` images, and the diffuse image where they are inactive, and writes ``Σ_s c_s ·
    pass_s`` (the blend fused into the last pass). All Gaussians are sampled at
    ONE set of tap offsets (:func:`~sssbench.kernels.preintegrated.shared_gaussian_taps`): the
    offsets of the pre-integrated kernel of the whole profile at the same ``samples`` and
    ``sampling`` (so "equal taps" with :class:`~sssbench.ops.PreintegratedSSS` holds), each
    Gaussian's 1D weight at a tap its mass over the tap's cell (area integration, tails lumped
    into the end taps, every set summing to 1). The choice and why: shared offsets let a
    sweep fetch each sample and compute its follow-surface factor once per tap for all
    Gaussians (``S × 3`` multiply-adds per tap on top), where per-Gaussian offsets would need a
    fetch per Gaussian and tap. The cost: a Gaussian narrower than the tap spacing lands
    (almost) entirely on the centre tap, i.e. stays unblurred, and the widest one is sampled
    only as far as the profile's outermost cell centre (its tail lumped onto the end taps);
    there is no per-Gaussian level of detail (003 §7.3.2): a narrow Gaussian costs its
    multiply-adds anyway.

    Not the paper's method: 003 §7.3 is :class:`~sssbench.ops.SumOfGaussiansSSS` (12 passes
    for 6 Gaussians); this one is its fused counterpart for issue 30's speed target.

    Args:
        profile: a :class:`SumOfGaussians` (weights >= 0, total > 0 per channel), at most
            :data:`~sssbench.ops.gather.MAX_SETS` Gaussians with a non-zero weight.
        samples: taps per sweep (default 7).
        sampling: tap placement of the whole profile's pre-integrated kernel: ``importance``
            (default, as :class:`~sssbench.ops.PreintegratedSSS`), ``uniform`` or ``power``.
        follow_surface: ``"lerp"`` (default, as :class:`~sssbench.ops.SumOfGaussiansSSS`:
            004 §3.1.1 lerps every Gaussian pass across depth steps), ``"gaussian"`` or
            ``None``; one factor per tap shared by all Gaussians.
        surface_scale: mm; default the profile's widest length scale.

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``; ``width`` (curvature) is honoured,
          ``sample_weight`` (halo) refused.

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 30.0), 0.4)
        >>> op = FusedSumOfGaussiansSSS(SumOfGaussians.from_table("skin_deon6"))
        >>> len(op.kernels), bool(torch.allclose(op(g), g.diffuse))
        (6, True)
    """

    scatters_in_place = True

    needs = ("mask",)
    no_sample_weight = (
        "is not supported by FusedSumOfGaussiansSSS: its sweep has no per-sample bilateral "
        "weight; use preintegrated or sum_of_gaussians for halo reduction"
    )

    def __init__(
        self,
        profile: SumOfGaussians,
        samples: int = 7,
        sampling: str = "importance",
        follow_surface: str | None = "lerp",
        surface_scale: float | None = None,
    ) -> None:
        super().__init__()
        if not isinstance(profile, SumOfGaussians):
            raise TypeError(f"profile must be a SumOfGaussians, got {type(profile).__name__}")
        check_method_options(surface_scale, 0)
        check_int("samples", samples, 1, MAX_SAMPLES)
        check_choice("sampling", sampling, SAMPLINGS)
        if bool((profile.total() <= 0).any()):
            raise ValueError(f"profile total must be > 0 per channel, got {profile.total()}")
        self.set_options(
            follow_surface, surface_scale, None, 0, default_scale=profile.length_scales()[1]
        )
        kernels, coefficients = shared_gaussian_taps(profile, samples, sampling)
        if len(kernels) > MAX_SETS:
            raise ValueError(
                f"profile must have at most {MAX_SETS} Gaussians with a non-zero weight for "
                f"one sweep, got {len(kernels)}"
            )
        self.profile = profile
        self.samples = samples
        self.sampling = sampling
        #: one :class:`Kernel1D` per Gaussian (narrowest first), all at the same offsets
        self.kernels = kernels
        #: ``(S, 3)`` float64 ``c_s = w_s / Σ_j w_j`` per channel
        self.coefficients = coefficients

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        opts = {k: options[k] for k in ("width", "follow_surface", "surface_scale", "check_finite")}
        image = gbuffer.diffuse
        # x: one read of the image, one result per Gaussian, at the active pixels only (the
        # inactive ones of every result are the image's: the y sweep reads them there); a new
        # result gets the image's inactive pixels from the x sweep's threads, row by row
        # (1080p close-up, issue 30: in place of a copy of the whole image on one thread)
        scratch = _workspace((len(self.kernels), *image.shape), image)
        out = image
        if not options.get("inplace"):
            out = torch.empty_like(image, memory_format=torch.contiguous_format)
        per_gaussian = separable_sweep(image, self.kernels, "x", gbuffer, out=scratch,
                                       name="sog_fused.x", keep_inactive=False,
                                       inactive_into=None if out is image else out,
                                       **opts)  # fmt: skip
        # y: the S results in, Σ_s c_s · pass_s out at the active pixels (the blend fused)
        coefficients = self.coefficients.to(dtype=image.dtype, device=image.device)
        return separable_sweep(
            per_gaussian, self.kernels, "y", gbuffer, coefficients=coefficients, out=out,
            name="sog_fused.y", inactive_from=image, **opts,
        )  # fmt: skip


#: the functional twin: every argument of :class:`FusedSumOfGaussiansSSS`, kernels reused
fused_sum_of_gaussians_sss = functional(FusedSumOfGaussiansSSS, "fused_sum_of_gaussians_sss")

"""The pre-integrated separable method (000 §4, eq. 5): two 1D passes with one kernel."""

from __future__ import annotations

import torch

from sssbench._checks import check_choice, check_magnitude, check_method_options
from sssbench.gbuffer import GBuffer
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.preintegrated import preintegrated
from sssbench.kernels.sampling import METHOD_SAMPLINGS, OPTIMISED
from sssbench.kernels.sources import check_optimised_sampling, use_optimised
from sssbench.ops.functional import functional
from sssbench.ops.gather import separable_pass
from sssbench.ops.halo import HALO_KINDS, halo_weight
from sssbench.ops.method import SeparableMethod
from sssbench.profiles.base import Profile

__all__ = ["PreintegratedSSS", "preintegrated_sss", "two_pass"]


def two_pass(
    image: torch.Tensor,
    kernel: Kernel1D,
    gbuffer: GBuffer,
    *,
    name: str,
    **options: object,
) -> torch.Tensor:
    """Apply a rank-1 separable kernel: a horizontal then a vertical :func:`separable_pass`
    (000 eq. 2 with N = 1). ``options`` are forwarded to both passes; ``inplace`` among them
    makes the first pass overwrite ``image`` too (no full-image copy at all)."""
    inplace = bool(options.pop("inplace", False))
    tmp = separable_pass(image, kernel, "x", gbuffer, name=f"{name}.x", inplace=inplace, **options)
    # tmp is this function's own (or image, in place): the second pass overwrites it
    return separable_pass(tmp, kernel, "y", gbuffer, name=f"{name}.y", inplace=True, **options)


class PreintegratedSSS(SeparableMethod):
    """Pre-integrated separable SSS (000 §4): ``A_p(x, y) = a_p(x) a_p(y) / ‖R‖₁`` (eq. 5),
    discretised once at construction (importance-sampled by default, 000 §7) and applied as
    two depth-aware passes.

    Args:
        profile: radial diffusion profile (mm).
        samples: taps per pass (default 7, 000 §7).
        sampling: tap placement, one of ``uniform``, ``power``, ``importance`` (000 §7) or
            ``optimised``: taps fitted by gradient descent through these very passes (this
            method's options included) against the exact reference on training scenes at one
            pixel footprint (:func:`sssbench.tune.optimise.optimise`, disk-cached; fitted
            for 0.05–5 mm per pixel). The footprint is ``pixel_mm`` when given, else the
            footprint of the G-buffer of each call (:func:`sssbench.score.budget.footprint_mm`, the
            median over the mask) snapped to the nearest of
            :data:`~sssbench.tune.optimise.FOOTPRINTS` — a choice: the fit sees how taps fall
            on pixels of one size, and a log grid of ratio ≤ 1.7 keeps a run within ~30 % of
            the footprint its kernel was fitted at while reusing the cache. ``kernel`` then
            holds the kernel of the last call (``None`` before the first).
        follow_surface: ``"lerp"`` (default), ``"gaussian"`` or ``None``. The default is the
            depth-aware pass the method is published with: 000 §7 renders its kernel with
            the screen-space pass of [JSG09], whose shader follows the surface by lerping a
            sample back to the centre colour across a depth step (002 appendix
            ``SSSS_FOLLOW_SURFACE``; 004 §3.1.2 Fig. 3.6 runs the pre-integrated kernel through
            the same lerp). ``None`` blurs across silhouettes; measured on ``head_closeup``
            (skin_jg10, 7 taps, 128²) it is worse than no blur at all (rel RMS 0.047 against
            the unblurred input's 0.037), the lerp 0.016. ``"gaussian"`` (000 eq. 7's factor,
            derived for the artist model) is not renormalised, so silhouettes lose energy
            (0.046 there).
        rotation: stochastic rotation radius fraction (000 §6: 0.1; 0.3 close-ups), or
            ``None`` for none.
        seed: seed of the rotation angles.
        halo: ``None``, ``"bilateral"`` (halo reduction, 004 §3.3.1) or ``"lab"`` (skin /
            non-skin colour weights, 004 §3.3.2), see :func:`~sssbench.ops.halo.halo_weight`.
        halo_sigma: range σ of ``halo`` (``None``: its default).
        pixel_mm: footprint (mm per pixel) of an ``optimised`` kernel (see ``sampling``);
            ``None`` (default): the run's own. Only with ``sampling="optimised"``.

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.
        - forward(gbuffer, width=w, guide=g, sample_weight=f): a per-pixel width multiplier
          ``w (B, 1, H, W)`` (curvature modulation, 004 §3.3.3) and an explicit bilateral
          weight (overrides ``halo``).
    """

    scatters_in_place = True

    needs = ("mask",)

    def __init__(
        self,
        profile: Profile,
        samples: int = 7,
        sampling: str = "importance",
        follow_surface: str | None = "lerp",
        rotation: float | None = None,
        seed: int = 0,
        halo: str | None = None,
        halo_sigma: float | None = None,
        pixel_mm: float | None = None,
    ) -> None:
        super().__init__()
        if not isinstance(profile, Profile):
            raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
        check_method_options(None, seed)
        check_choice("sampling", sampling, METHOD_SAMPLINGS)
        pixel_mm = check_optimised_sampling(sampling, samples, pixel_mm)
        check_choice("halo", halo, (None, *HALO_KINDS))
        if halo_sigma is not None:
            halo_sigma = check_magnitude("halo_sigma", halo_sigma, "factor")
        #: σ_max of 000 eq. 7 / the lerp's full-replacement depth step: the profile's widest
        #: length scale (mm), a property of the material, not of where the taps sit
        self.set_options(
            follow_surface, None, rotation, seed, default_scale=profile.length_scales()[1]
        )
        self.profile = profile
        self.samples = samples
        self.sampling = sampling
        self.halo = halo
        self.halo_sigma = halo_sigma
        self.pixel_mm = pixel_mm
        #: the fits of ``sampling="optimised"`` per footprint, and the options they are fitted
        #: with (:func:`~sssbench.tune.optimise.use_optimised`)
        self.fitted: dict[float, object] = {}
        self.fit_options = dict(follow_surface=follow_surface, rotation=rotation, seed=seed,
                                halo=halo, halo_sigma=halo_sigma)  # fmt: skip
        self.kernel: Kernel1D | None = None
        if sampling != OPTIMISED:
            self.kernel = preintegrated(profile, samples, sampling)
        elif pixel_mm is not None:
            use_optimised(self)
        if halo == "bilateral":
            self.needs = ("mask", "normal")
        elif halo == "lab":
            self.needs = ("mask", "albedo")

    def pass_options(self, gbuffer, width=None, guide=None, sample_weight=None):
        """As :meth:`SeparableMethod.pass_options`, with the configured ``halo`` weights unless
        an explicit ``sample_weight`` is given."""
        if sample_weight is None and self.halo is not None:
            guide, sample_weight = halo_weight(gbuffer, self.halo, self.halo_sigma)
        return super().pass_options(gbuffer, width, guide, sample_weight)

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        if self.sampling == OPTIMISED and self.pixel_mm is None:
            use_optimised(self, gbuffer)
        return two_pass(gbuffer.diffuse, self.kernel, gbuffer, name="preintegrated", **options)


#: the functional twin: every argument of :class:`PreintegratedSSS`, kernels reused
preintegrated_sss = functional(PreintegratedSSS, "preintegrated_sss")

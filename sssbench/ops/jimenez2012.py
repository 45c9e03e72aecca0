"""The 2012 separable SSS (002 §3–4 and appendix shader): two passes of the width / strength /
falloff kernel with the shader's follow-surface lerp and per-pixel strength."""

from __future__ import annotations

import torch

from sssbench._checks import check_choice, check_magnitude, check_method_options
from sssbench.gbuffer import GBuffer
from sssbench.kernels.jimenez2012 import JIMENEZ2012_PRESETS, jimenez2012
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.sampling import OPTIMISED
from sssbench.kernels.sources import check_optimised_sampling, use_optimised
from sssbench.ops.functional import functional
from sssbench.ops.method import SeparableMethod
from sssbench.ops.preintegrated import two_pass
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = ["Jimenez2012SSS", "jimenez2012_sss", "SAMPLINGS"]

#: the ``sampling`` choices: the 2012 kernel builder's taps (power placement, 002 appendix) or
#: its parameters fitted through the passes
SAMPLINGS = ("power", OPTIMISED)


class Jimenez2012SSS(SeparableMethod):
    """Separable SSS of 002 (2012): ``s(w, t, f)`` (002 eq. 1) applied by the appendix shader.

    Mapping of ``SSSSBlurPS`` (002 appendix) onto :func:`~sssbench.ops.separable_pass`:

    - ``finalStep = sssWidth · distToProjWindow / depthM · dir / 3`` with ``kernel.a`` in
      [−3, 3]: the kernel builder returns offsets in widths
      (:func:`~sssbench.kernels.jimenez2012`), the pass ``width`` is ``width`` in mm and the
      pinhole mapping gives pixels per mm at each pixel's depth (DESIGN §2).
    - ``finalStep *= SSSS_STRENGTH_SOURCE``: the G-buffer ``mask`` scales each pixel's step
      (``separable_pass`` multiplies its pixels-per-offset scale by the mask) and a mask of 0
      is not computed (the shader's ``discard`` with ``initStencil``). So a mask of ½ blurs
      exactly like half the width (tested).
    - ``SSSS_FOLLOW_SURFACE``: ``s = saturate(300 · distToProjWindow · sssWidth · |Δz|)``,
      ``color = lerp(color, colorM, s)``: ``follow_surface="lerp"`` with ``s = |Δz| /
      surface_scale``. The shader's constant is not unit-consistent (``s`` grows with
      width × depth step); we keep its meaning, "a sample is replaced once the depth step
      reaches the order of the kernel's size", with ``surface_scale = width`` mm by default.

    Args:
        strength: ``t`` per channel, scalar or ``(3,)`` in [0, 1].
        falloff: ``f`` per channel, scalar or ``(3,)`` >= 0.
        width: the global width in mm, in [1e-6, 1e6] (``_checks.MAGNITUDES``).
        samples: taps per pass (002: 9, 17 or 33; an even count gets a centre tap added).
        follow_surface: apply the shader's depth lerp.
        surface_scale: depth step (mm) of full replacement; default ``width``.
        profile: base profile (its red channel), a table name or a :class:`SumOfGaussians`.
        quadrature: ``"shader"`` or ``"integrated"`` tap weights.
        rotation: stochastic rotation radius fraction (000 §6), or ``None``.
        seed: rotation seed (one :class:`Rotation` for both passes).
        sampling: ``"power"`` (default: the 2012 kernel builder's taps for the given
            ``strength``, ``falloff`` and ``width``, 002 appendix) or ``"optimised"``: the
            strength, falloff and width fitted by gradient descent through these very passes
            (this method's options included) against the exact reference of ``profile`` (all
            its channels) on training scenes at one pixel footprint
            (:func:`sssbench.tune.optimise.optimise`,
            :class:`~sssbench.kernels.parametrise.Jimenez2012Parameters`; disk-cached; fitted
            for 0.05–5 mm per pixel), starting from the given parameters and 002's presets at
            the given width, whichever is best on the training set. The taps stay the 2012
            kernel builder's. The footprint is ``pixel_mm`` when given, else the G-buffer's of
            each call snapped to the nearest of :data:`~sssbench.tune.optimise.FOOTPRINTS`
            (as :class:`~sssbench.ops.PreintegratedSSS`); ``kernel``, ``strength``,
            ``falloff`` and ``width`` then hold the fitted values of the last call (``kernel``
            is ``None`` before the first). ``surface_scale`` stays the given ``width`` (or the
            given ``surface_scale``): the fit runs with it.
        pixel_mm: footprint (mm per pixel) of an ``optimised`` fit; ``None`` (default): the
            run's own. Only with ``sampling="optimised"``.

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.

    Example:
        >>> op = Jimenez2012SSS.preset("shader_default", width=3.0)
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 200.0), 0.4)
        >>> bool(torch.allclose(op(g), g.diffuse)), len(op.kernel)
        (True, 17)
    """

    scatters_in_place = True

    needs = ("mask",)

    def __init__(
        self,
        strength: object,
        falloff: object,
        width: float,
        samples: int = 17,
        follow_surface: bool = True,
        surface_scale: float | None = None,
        profile: str | SumOfGaussians = "skin_deon6",
        quadrature: str = "shader",
        rotation: float | None = None,
        seed: int = 0,
        sampling: str = "power",
        pixel_mm: float | None = None,
    ) -> None:
        super().__init__()
        check_method_options(surface_scale, seed)
        check_choice("sampling", sampling, SAMPLINGS)
        self.sampling = sampling
        self.pixel_mm = check_optimised_sampling(sampling, samples, pixel_mm)
        self.width = check_magnitude("width", width, "length")
        if not isinstance(follow_surface, bool):
            raise TypeError(f"follow_surface must be a bool, got {type(follow_surface).__name__}")
        # the 2012 shader's follow-surface is its lerp; fully replaced at a `width` mm step
        self.set_options(
            "lerp" if follow_surface else None,
            surface_scale,
            rotation,
            seed,
            default_scale=self.width,
        )
        self.kernel: Kernel1D | None = jimenez2012(
            strength, falloff, samples, profile=profile, quadrature=quadrature
        )
        self.samples = samples
        #: the kernel's parameters, kept for its continuous form (sssbench.score.budget)
        self.strength, self.falloff, self.base_profile = strength, falloff, profile
        self.quadrature = quadrature
        #: the fits of ``sampling="optimised"`` per footprint and the options they start from
        #: (:func:`~sssbench.tune.optimise.use_optimised`)
        self.fitted: dict[float, object] = {}
        self.fit_options = dict(
            strength=strength, falloff=falloff, width=width, follow_surface=follow_surface,
            surface_scale=surface_scale, quadrature=quadrature, rotation=rotation, seed=seed,
        )  # fmt: skip
        if sampling == OPTIMISED:
            self.kernel = None
            if self.pixel_mm is not None:
                use_optimised(self)

    @classmethod
    def preset(
        cls, name: str, width: float | None = None, samples: int = 17, **options: object
    ) -> Jimenez2012SSS:
        """A preset of :data:`~sssbench.kernels.JIMENEZ2012_PRESETS`; ``width`` (mm) is
        required for ``"shader_default"`` (its width is a scene parameter) and for
        ``"table1"`` (002 Table 1's 0.014 is in the paper's unstated scene units)."""
        check_choice("name", name, sorted(JIMENEZ2012_PRESETS))
        if width is None:
            raise ValueError(f"width (mm, > 0) must be given for preset {name!r}")
        p = JIMENEZ2012_PRESETS[name]
        return cls(p["strength"], p["falloff"], width, samples, **options)

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        if self.sampling == OPTIMISED and self.pixel_mm is None:
            use_optimised(self, gbuffer)  # sets kernel, strength, falloff and width
        # the kernel offsets are in widths (002 appendix: ``sssWidth``), so the per-pixel
        # multiplier of the pass options scales ``self.width``
        options = dict(options, width=self.width * options["width"])
        return two_pass(gbuffer.diffuse, self.kernel, gbuffer, name="jimenez2012", **options)


#: the functional twin: every argument of :class:`Jimenez2012SSS`, kernels reused
jimenez2012_sss = functional(Jimenez2012SSS, "jimenez2012_sss")

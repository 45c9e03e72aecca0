"""The 2012 separable SSS (002 §3–4 and appendix shader): two passes of the width / strength /
falloff kernel with the shader's follow-surface lerp and per-pixel strength."""

from __future__ import annotations

import torch

from sssbench._checks import check_choice, check_magnitude, check_method_options
from sssbench.gbuffer import GBuffer
from sssbench.kernels.jimenez2012 import JIMENEZ2012_PRESETS, jimenez2012
from sssbench.ops.functional import functional
from sssbench.ops.method import SeparableMethod
from sssbench.ops.preintegrated import two_pass
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = ["Jimenez2012SSS", "jimenez2012_sss"]


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
    ) -> None:
        super().__init__()
        check_method_options(surface_scale, seed)
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
        self.kernel = jimenez2012(
            strength, falloff, samples, profile=profile, quadrature=quadrature
        )
        self.samples = samples
        #: the kernel's parameters, kept for its continuous form (sssbench.budget)
        self.strength, self.falloff, self.base_profile = strength, falloff, profile

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

    def pass_options(self, gbuffer, width=None, guide=None, sample_weight=None):
        """As :meth:`SeparableMethod.pass_options`; the kernel offsets are in widths (002
        appendix: ``sssWidth``), so the per-pixel multiplier scales ``self.width``."""
        options = super().pass_options(gbuffer, width, guide, sample_weight)
        options["width"] = self.width * options["width"]
        return options

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        return two_pass(gbuffer.diffuse, self.kernel, gbuffer, name="jimenez2012", **options)


#: the functional twin: every argument of :class:`Jimenez2012SSS`, kernels reused
jimenez2012_sss = functional(Jimenez2012SSS, "jimenez2012_sss")

"""The screen-space sum of Gaussians (003 §7.3): two 1D passes per Gaussian, each Gaussian
blurred on top of the previous one with the incremental variance and alpha-blended into the
result with the normalising weights ``w'`` (003 §7.3.3), with per-pixel level of detail
(003 §7.3.2) and the JG10 stretch factors (003 §7.3.1)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from sssbench._checks import (
    check_choice,
    check_int,
    check_magnitude,
    check_method_options,
    check_tensor,
)
from sssbench._memo import memoised
from sssbench.gbuffer import GBuffer
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.preintegrated import preintegrated
from sssbench.kernels.sampling import MAX_SAMPLES, METHOD_SAMPLINGS, OPTIMISED
from sssbench.kernels.sources import check_optimised_sampling, use_optimised
from sssbench.ops._gather_native import serial_copy
from sssbench.ops._stencil import image_spans
from sssbench.ops.functional import functional
from sssbench.ops.gather import Stretch, separable_pass
from sssbench.ops.method import SeparableMethod
from sssbench.ops.timing import PassRecord, add_record
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = [
    "SumOfGaussiansSSS",
    "sum_of_gaussians_sss",
    "blend_weights",
    "incremental_variances",
    "jg10_stretch",
    "SoGStep",
]

#: the default tap placement (003 Listing 7.1: uniform over ±3σ); also the schedule whose tap
#: sets ``sampling="optimised"`` replaces
DEFAULT_SAMPLING = "uniform"
#: 003 §7.3.2: a Gaussian narrower than half a pixel is not computed
DEFAULT_LOD_THRESHOLD = 0.5
#: the first Gaussian is replaced by the unblurred image when its σ is below this (mm); see
#: :class:`SumOfGaussiansSSS` (003 §7.3.3 does so for skin, σ 0.08 mm, not for marble, 0.19 mm)
UNBLURRED_FIRST_SIGMA = 0.1
#: Listing 7.1 (003): 7 taps over ±3σ with area-integrated weights 0.006 … 0.382
LISTING_EXTENT_SIGMAS = 3.0
#: 003 §7.3.1 calibration: a head 1.0 units tall, fov 20°, 720 px viewport
_JG10_FOV = math.radians(20.0)
_JG10_HEIGHT = 720
#: largest image height :func:`jg10_stretch` accepts (pixels)
MAX_HEIGHT = 1 << 20


def blend_weights(weights: torch.Tensor) -> torch.Tensor:
    """Blend factors ``w'_i = w_i / Σ_{j≤i} w_j`` of 003 §7.3.3, Gaussians ordered narrowest
    first.

    Blending ``out ← w'_i G_i + (1 − w'_i) out`` for ``i = 1 … n`` (003 Listing 7.2) leaves
    ``Σ_i w_i G_i / Σ_i w_i`` after the last step: each step's result is the normalised partial
    sum. The cumulative sum runs from the narrowest Gaussian (the order of 003 Table 7.1: it
    reproduces the printed ``w'``, e.g. skin R ``0.1158 / (0.2405 + 0.1158) = 0.3250``; the
    reverse order does not). Where nothing has been accumulated yet (``Σ_{j≤i} w_j = 0``)
    ``w'_i = 1``.

    Args:
        weights: ``(N, 3)`` per-channel weights ``w_i``, >= 0, rows narrowest first.

    Returns:
        ``(N, 3)`` float64 ``w'``; the first row is 1.

    Example:
        >>> w = torch.tensor([[0.2405, 0.4474, 0.6157], [0.1158, 0.3661, 0.3439]])
        >>> [round(v, 4) for v in blend_weights(w)[1].tolist()]
        [0.325, 0.45, 0.3584]
    """
    w = check_tensor("weights", weights, ndim=2).double()
    if w.shape[1] != 3:
        raise ValueError(f"weights must have shape (N, 3), got {tuple(w.shape)}")
    if bool((w < 0).any()):
        raise ValueError(f"weights must be >= 0, got min {float(w.min()):g}")
    cum = torch.cumsum(w, 0)  # 003 §7.3.3: Σ_{j=1}^{i} w_j
    return torch.where(cum > 0, w / torch.where(cum > 0, cum, 1.0), 1.0)


def incremental_variances(variances: torch.Tensor, unblurred_first: bool) -> torch.Tensor:
    """Variances each step adds on top of the previous Gaussian (003 §7.3.3).

    Gaussians convolve by adding variances, so blurring ``G_{i-1}`` with ``v_i − v_{i−1}``
    gives ``G_i`` (003: "2.0062 − 0.2719 = 1.7343"). With ``unblurred_first`` the first
    Gaussian is the unblurred image, which carries variance 0, so the second step adds all of
    ``v_2`` (a choice: 003 states the subtraction only for the widest skin Gaussian; adding
    ``v_2 − v_1`` would leave every later Gaussian ``v_1`` too narrow).

    Args:
        variances: ``(N,)`` mm², ascending.
        unblurred_first: whether step 1 is the unblurred image.

    Returns:
        ``(N,)`` mm²; entry 0 is ``v_1`` (or 0 when unblurred).

    Example:
        >>> v = torch.tensor([0.0064, 0.0516, 0.2719, 2.0062], dtype=torch.float64)
        >>> [round(x, 4) for x in incremental_variances(v, True).tolist()]
        [0.0, 0.0516, 0.2203, 1.7343]
    """
    v = check_tensor("variances", variances, ndim=1).double()
    if v.numel() > 1 and bool((v[1:] < v[:-1]).any()):
        raise ValueError(f"variances must be ascending, got {v.tolist()}")
    applied = v.clone()  # the variance RT1 carries after each step
    if unblurred_first:
        applied[0] = 0.0
    inc = v - torch.cat([v.new_zeros(1), applied[:-1]])  # 003 §7.3.3: v_i − v_{i−1}
    inc[0] = applied[0]
    return inc


def jg10_stretch(
    height: int = _JG10_HEIGHT,
    *,
    ssslevel: float = 31.5,
    correction: float = 800.0,
    maxdd: float = 0.001,
    head_mm: float = 230.0,
) -> Stretch:
    """003 §7.3.1's stretch parameters (head units, 720 px) as a mm :class:`Stretch`.

    003 chose ``ssslevel = 31.5``, ``correction = 800``, ``maxdd = 0.001`` "for a head 1.0
    units tall, a field-of-view of 20°, and a viewport height of 720 pixels", with Table 7.1's
    σ in mm. The mapping (``head_mm``: the head height we assume, 230 mm):

    - ``ssslevel``: Listing 7.1 spreads its 7 taps over ``±finalWidth = ±ssslevel·σ/d`` pixels
      with the weights of a ±3σ Gaussian, so the applied σ is ``ssslevel·σ/(3d)`` px with ``d``
      in head units; the physical σ is ``720 / (2 tan 10°) · σ / (d · head_mm)`` px. Their
      ratio, ``ssslevel · 2 tan 10° · head_mm / (3 · 720)``, is the multiplier of the physical
      width that :class:`Stretch` takes: 31.5 -> 1.18 (003's kernels are 18% wider than
      physical for a 230 mm head).
    - ``correction`` has the unit pixel (``d / |∂d/∂x|``) at 720 px; the depth derivative per
      pixel scales as ``1/height``, so the same geometric effect at ``height`` needs
      ``correction · height / 720``.
    - ``maxdd`` is head units per pixel at 720 px: ``maxdd · head_mm · 720 / height`` mm/px
      (0.23 mm/px at 720 px, :class:`Stretch`'s default).

    Args:
        height: image height H of the G-buffer the stretch is used on, pixels.
        ssslevel, correction, maxdd: 003's values (its defaults).
        head_mm: world size of 003's head unit, mm.

    Returns:
        A :class:`~sssbench.ops.gather.Stretch` in mm units.

    Example:
        >>> s = jg10_stretch(720)
        >>> round(s.ssslevel, 3), s.correction, round(s.maxdd, 3)
        (1.183, 800.0, 0.23)
    """
    height = check_int("height", height, 1, MAX_HEIGHT)
    check_magnitude("ssslevel", ssslevel, "factor")  # 0 would blur nothing: refused by Stretch
    check_magnitude("correction", correction, "factor", zero=True)
    check_magnitude("maxdd", maxdd, "factor")  # head units per pixel
    check_magnitude("head_mm", head_mm, "length")
    ratio = 2.0 * math.tan(_JG10_FOV / 2.0) * head_mm / (LISTING_EXTENT_SIGMAS * _JG10_HEIGHT)
    return Stretch(
        ssslevel=ssslevel * ratio,
        correction=correction * height / _JG10_HEIGHT,
        maxdd=maxdd * head_mm * _JG10_HEIGHT / height,
    )


@dataclass(frozen=True)
class SoGStep:
    """One Gaussian of the schedule.

    Attributes:
        variance: the Gaussian's variance v_i (mm²).
        increment: the variance this step adds on top of the previous one (mm²); 0 for the
            unblurred first step (no pass).
        blend: ``(3,)`` blend factor ``w'_i`` (003 §7.3.3).
        kernel: the 1D taps of the increment (mm), or ``None`` when no pass runs.
    """

    variance: float
    increment: float
    blend: torch.Tensor
    kernel: Kernel1D | None


class SumOfGaussiansSSS(SeparableMethod):
    """Screen-space sum of Gaussians (003 §7.3; DESIGN §4: 2N passes).

    Gaussians are sorted narrowest first. Step ``i`` blurs the previous Gaussian's image
    (RT1) with the increment ``v_i − v_{i−1}`` (two passes, 003 §7.3.3) and blends it into
    the result (RTF) with ``w'_i`` (:func:`blend_weights`), so the result is
    ``Σ w_i G_i / Σ w_i`` per channel: normalised like :class:`ReferenceSSS`; a constant
    image stays constant.

    Each step's taps come from :func:`~sssbench.kernels.preintegrated` of a one-Gaussian
    profile of the increment's variance (a 1D Gaussian; area-integrated weights, tails lumped
    into the end taps). The default ``sampling="uniform"`` over ``±3σ`` with 7 taps reproduces
    003 Listing 7.1's weights (0.006, 0.061, 0.242, 0.382, …) exactly.

    Level of detail (003 §7.3.2): at each pixel, a step whose increment σ is narrower than
    ``lod_threshold`` pixels there (σ · pixels-per-mm at the pixel's depth · ssslevel ·
    strength; 003's test ignores the depth derivative, so do we) is not computed: the passes
    see a G-buffer whose mask is zeroed there (stencil: the pass record's ``pixels`` drops),
    and RT1 and the result keep their values there (003 renders the step's quad with a depth
    test, so neither target is written). 003's inequality is 0.5 px; it notes that a 2 px
    threshold disables Gaussians "much faster without any noticeable popping". A step with no
    active pixel leaves a :class:`~sssbench.ops.PassRecord` with ``pixels = 0``.

    The first Gaussian is the unblurred image when ``unblurred_first`` (003 §7.3.3 for skin:
    "the original unblurred image is used instead"); ``None`` decides by its σ: unblurred
    below 0.1 mm (003's skin, σ 0.08 mm, but not its marble, σ 0.19 mm).

    Stretch (003 §7.3.1): ``stretch`` is a :class:`~sssbench.ops.Stretch` in mm units
    (``ssslevel`` multiplies the physical width, ``correction`` in pixels, ``maxdd`` in mm per
    pixel); :func:`jg10_stretch` converts 003's 31.5 / 800 / 0.001 (head units, 720 px) into
    it: 1.18 / 800·H/720 / 0.23·720/H mm per px for a 230 mm head. ``None``: physical width.

    Args:
        profile: a :class:`SumOfGaussians` (variances mm², weights (N, 3) >= 0).
        samples: taps per pass.
        sampling: ``"uniform"`` (default, over ±``extent_sigmas`` σ of each increment),
            ``"power"`` (same extent), ``"importance"`` (whole line) or ``"optimised"``: each
            Gaussian's tap set fitted by gradient descent through these very passes (this
            method's options included) against the exact reference on training scenes at one
            pixel footprint (:func:`sssbench.tune.optimise.optimise`,
            :class:`~sssbench.kernels.parametrise.PerGaussianTaps`: offsets and weights per
            Gaussian, each set normalised; variances and blend weights stay; disk-cached;
            fitted for 0.05–5 mm per pixel). The footprint is ``pixel_mm`` when given, else
            the G-buffer's of each call snapped to the nearest of
            :data:`~sssbench.tune.optimise.FOOTPRINTS` (as
            :class:`~sssbench.ops.PreintegratedSSS`); ``steps`` then holds the tap sets of
            the last call (``None`` before the first).
        stretch: JG10 stretch factors or ``None``.
        lod: per-pixel level of detail on/off.
        lod_threshold: LOD width in pixels (003: 0.5).
        unblurred_first: see above; ``None``: automatic (003 §7.3.3's rule). Default
            ``False``: every Gaussian is blurred where the level of detail (003 §7.3.2) finds
            it at least ``lod_threshold`` pixels wide, so the per-pixel footprint decides what
            003 §7.3.3 decided once for its viewing distances (skin's 0.08 mm Gaussian is far
            below a pixel there, but not on close-ups). Measured on ``light_dot`` (0.2 mm
            pixels at 128², skin_jg10): rel RMS 0.0996 with the unblurred first Gaussian,
            0.0102 without; the other benchmark scenes move by < 0.0005.
        follow_surface: ``"lerp"`` (default), ``"gaussian"`` or ``None``. 003 §7.3.1 makes its
            passes depth-aware with the stretch factors' derivative term only; 004 §3.1.1
            (Fig. 3.4), the test bed that runs this method beside the separable ones, adds the
            per-sample depth lerp ``mix(colorS, colorM, min(correction·|Δd|, 1))`` to every
            Gaussian pass, which is this default. Measured on the old ``head_close`` (skin_jg10,
            7 taps; now ``head_closeup`` at 128²): ``None`` scores rel RMS 0.034 at 128² and
            0.043 at 256², no better than
            the unblurred input (0.037, 0.043); the lerp 0.0135 and 0.0138; 003's stretch
            with physical width (``Stretch(1, correction, maxdd)`` of :func:`jg10_stretch`)
            0.026 and 0.032. The stretch needs the image height, so it cannot be a
            constructor default; pass it explicitly (it combines with the lerp).
        surface_scale: mm; default the profile's widest σ.
        rotation: stochastic rotation radius fraction (000 §6), or ``None``.
        seed: seed of the rotation angles (one :class:`Rotation` for every pass).
        extent_sigmas: half-width of uniform / power taps in units of the increment's σ.
        pixel_mm: footprint (mm per pixel) of an ``optimised`` fit (see ``sampling``);
            ``None`` (default): the run's own. Only with ``sampling="optimised"``.

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 30.0), 0.4)
        >>> op = SumOfGaussiansSSS(SumOfGaussians.from_table("skin_jg10"))
        >>> len(op.steps), bool(torch.allclose(op(g), g.diffuse))
        (4, True)
    """

    needs = ("mask",)

    def __init__(
        self,
        profile: SumOfGaussians,
        samples: int = 7,
        sampling: str = DEFAULT_SAMPLING,
        stretch: Stretch | None = None,
        lod: bool = True,
        lod_threshold: float = DEFAULT_LOD_THRESHOLD,
        unblurred_first: bool | None = False,
        follow_surface: str | None = "lerp",
        surface_scale: float | None = None,
        rotation: float | None = None,
        seed: int = 0,
        extent_sigmas: float = LISTING_EXTENT_SIGMAS,
        pixel_mm: float | None = None,
    ) -> None:
        super().__init__()
        if not isinstance(profile, SumOfGaussians):
            raise TypeError(f"profile must be a SumOfGaussians, got {type(profile).__name__}")
        check_method_options(surface_scale, seed)
        check_int("samples", samples, 1, MAX_SAMPLES)
        check_choice("sampling", sampling, METHOD_SAMPLINGS)
        self.pixel_mm = check_optimised_sampling(sampling, samples, pixel_mm)
        #: the fits of ``sampling="optimised"`` per footprint and the options they are fitted
        #: with, as given (:func:`~sssbench.tune.optimise.use_optimised`)
        self.fitted: dict[float, object] = {}
        self.fit_options = dict(
            stretch=stretch, lod=lod, lod_threshold=lod_threshold,
            unblurred_first=unblurred_first, follow_surface=follow_surface,
            surface_scale=surface_scale, rotation=rotation, seed=seed,
            extent_sigmas=extent_sigmas,
        )  # fmt: skip
        if not isinstance(lod, bool):  # a flag: nan or "no" must not read as True
            raise TypeError(f"lod must be True or False, got {type(lod).__name__} {lod!r}")
        if unblurred_first is not None and not isinstance(unblurred_first, bool):
            raise TypeError(
                "unblurred_first must be True, False or None, got "
                f"{type(unblurred_first).__name__} {unblurred_first!r}"
            )
        if stretch is not None and not isinstance(stretch, Stretch):
            raise TypeError(f"stretch must be a Stretch or None, got {type(stretch).__name__}")
        self.lod_threshold = check_magnitude("lod_threshold", lod_threshold, "factor", zero=True)
        extent_sigmas = check_magnitude("extent_sigmas", extent_sigmas, "factor")
        self.set_options(
            follow_surface, surface_scale, rotation, seed, default_scale=profile.length_scales()[1]
        )
        if bool((profile.weights < 0).any()):
            raise ValueError("profile weights must be >= 0 for alpha blending (003 §7.3.3)")
        if bool((profile.total() <= 0).any()):
            raise ValueError(f"profile total must be > 0 per channel, got {profile.total()}")
        order = torch.argsort(profile.variances)
        var = profile.variances[order]
        wts = profile.weights[order]
        if unblurred_first is None:
            unblurred_first = math.sqrt(float(var[0])) < UNBLURRED_FIRST_SIGMA
        inc = incremental_variances(var, bool(unblurred_first))
        blend = blend_weights(wts)
        rule = DEFAULT_SAMPLING if sampling == OPTIMISED else sampling
        steps = []
        for i in range(var.numel()):
            kernel = None
            if float(inc[i]) > 0:
                one = SumOfGaussians(inc[i : i + 1], torch.ones(1, 3, dtype=torch.float64))
                ext = None if rule == "importance" else extent_sigmas * math.sqrt(inc[i])
                kernel = preintegrated(one, samples, rule, ext)
            steps.append(SoGStep(float(var[i]), float(inc[i]), blend[i], kernel))
        self.profile = profile
        #: the Gaussian steps with the rule's taps (``sampling``'s; the default rule's for
        #: ``optimised``): the schedule whose tap sets a fit replaces
        self.schedule = steps
        #: the steps the passes run: ``schedule``, or with ``optimised`` the fitted tap sets
        #: (``None`` before the first call when the footprint comes from the G-buffer)
        self.steps: list[SoGStep] | None = steps if sampling != OPTIMISED else None
        self.samples = samples
        self.sampling = sampling
        self.stretch = stretch
        self.lod = bool(lod)
        self.unblurred_first = bool(unblurred_first)
        if sampling == OPTIMISED and self.pixel_mm is not None:
            use_optimised(self)

    def _lod_mask(self, gbuffer: GBuffer, sigma: float) -> torch.Tensor:
        """The G-buffer mask with pixels where ``sigma`` (mm) is under the LOD width zeroed.

        Memoised per G-buffer (:func:`~sssbench._memo.memoised`): like the stencil, a
        renderer derives it once from depth, not per call. Where no covered pixel is culled
        the result is the G-buffer's mask tensor itself (the same values): the steps then share
        one stencil per call (its runs, read once) and one mask in cache, not a copy each."""
        if not self.lod:
            return gbuffer.mask_or_ones()
        _, h, _ = gbuffer.shape
        focal_px = h / (2.0 * math.tan(gbuffer.fov_y / 2.0))  # DESIGN §2
        level = 1.0 if self.stretch is None else self.stretch.ssslevel

        def compute() -> torch.Tensor:
            # a normal tensor even in inference mode: its own stencil is then memoised across
            # calls too (an inference tensor's only within one call)
            with torch.inference_mode(False):
                mask = gbuffer.mask_or_ones()
                width_px = sigma * level * focal_px / gbuffer.depth * mask  # 003 §7.3.2, dd = 0
                keep = width_px >= self.lod_threshold
                if gbuffer.mask is not None and bool((keep | (mask == 0)).all()):
                    return gbuffer.mask  # nothing culled: where(keep, mask, 0) is mask
                return torch.where(keep, mask, torch.zeros_like(mask))

        tag = ("sog_lod", sigma, level, focal_px, self.lod_threshold)
        return memoised((gbuffer.depth, gbuffer.mask), tag, compute)

    def _axis_options(self, gbuffer: GBuffer, options: dict[str, object]) -> dict[str, dict]:
        """Per pass axis, the pass options with the stretch (003 §7.3.1).

        Small images: along an axis of length 1 (a 1×N, N×1 or 1×1 image) the depth
        derivative is 0 — there is no neighbour to difference with — so the stretch factor
        is just ``ssslevel``; and every tap of a pass along that axis clamps onto its one
        pixel whatever the scale, so the pass is exact without the stretch. It is run without
        it (the central difference, ``torch.gradient``, needs two samples per axis).
        """
        _, h, w = gbuffer.shape
        return {
            axis: dict(options, stretch=self.stretch if length > 1 else None)
            for axis, length in (("x", w), ("y", h))
        }

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        if self.sampling == OPTIMISED and self.pixel_mm is None:
            use_optimised(self, gbuffer)
        per_axis = self._axis_options(gbuffer, options)  # 003 §7.3.1
        dtype = gbuffer.dtype
        rt1 = gbuffer.diffuse  # the widest Gaussian so far (003 Fig. 7.6: RT1)
        rtf = gbuffer.diffuse  # the blended result (RTF)
        for i, step in enumerate(self.steps):
            blend = step.blend.to(dtype=dtype, device=gbuffer.device).view(1, 3, 1, 1)
            if step.kernel is None:  # the unblurred first Gaussian: w'_1 = 1, no pass
                continue
            mask = self._lod_mask(gbuffer, math.sqrt(step.increment))
            # the stencil's runs, shared with the passes within this call (one read of the
            # mask; image_stencils would compare the mask with a kept snapshot first)
            spans = image_spans(mask, (mask.shape[0], *mask.shape[2:]))
            name = f"sog{i}"
            if not any(s.shape[0] for s in spans):  # 003 §7.3.2: not computed anywhere
                for axis in ("x", "y"):
                    add_record(PassRecord(f"{name}.{axis}", len(step.kernel), 0, 0.0))
                continue
            g = gbuffer if mask is gbuffer.mask else gbuffer.replace(mask=mask)
            # render targets owned by this call are overwritten (no full-image copy per pass)
            owned = rt1 is not gbuffer.diffuse
            tmp = separable_pass(
                rt1, step.kernel, "x", g, name=f"{name}.x", inplace=owned, **per_axis["x"]
            )
            if rtf is gbuffer.diffuse:  # on this thread: see serial_copy
                rtf = serial_copy(rtf)
            # 003 §7.3.3, Listing 7.2: rtf ← blend · rt1 + (1 − blend) · rtf, as one lerp, on
            # the stencil's pixels only (blend_on_stencil), done by the y pass as it writes
            # each pixel of rt1 (the native loop; after it otherwise)
            rt1 = separable_pass(
                tmp, step.kernel, "y", g, name=f"{name}.y", inplace=True,
                blend_into=(rtf, blend.view(3)), **per_axis["y"],
            )  # fmt: skip
        return rtf


#: the functional twin: every argument of :class:`SumOfGaussiansSSS`, kernels reused
sum_of_gaussians_sss = functional(SumOfGaussiansSSS, "sum_of_gaussians_sss")

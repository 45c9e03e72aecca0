"""The one gather primitive: a depth-aware separable blur pass (DESIGN §4).

Every separable method of the papers (pre-integrated, artist, 2012, SVD rank-N, sum of
Gaussians) is a kernel builder plus a schedule of calls to :func:`separable_pass`; the papers'
variants are options of this function, not copies of its loop.

The loop is the CPU counterpart of the papers' blur shader (002 appendix, 003 Listing 7.1):
for each active pixel, step along the pass axis by ``offset × width × (pixels per mm at this
pixel's depth)``, fetch the neighbour with linear interpolation along the axis (bilinear when
stochastic rotation turns the axis), clamp at the image border, and accumulate
``weight × sample``.

Implementation: per image, pixels with ``mask > 0`` are compacted into one flat list (stencil:
masked-out pixels are never computed, 002 §4 / 003 §7.3.1; built once per mask and reused,
:func:`~sssbench.ops._stencil.image_stencils`), their index arithmetic is shared by all
channels, and samples are fetched straight from the ``(C, H·W)`` planes, so a pass touches
the full image only to copy it once (time follows covered pixels). The tap loop has one
specification, :func:`_accumulate` (torch, differentiable), and two faster backends chosen by
:func:`set_backend`: the same operations in C (``native/``, the default when no gradient is
needed) and the torch loop fused by ``torch.compile``.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from sssbench._checks import check_choice, check_scalar, check_tensor
from sssbench._memo import memoised
from sssbench.gbuffer import GBuffer
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.ops import native
from sssbench.ops._stencil import image_spans, image_stencils
from sssbench.ops.timing import PassRecord, add_record

__all__ = [
    "separable_pass",
    "blend_on_stencil",
    "set_backend",
    "get_backend",
    "BACKENDS",
    "Stretch",
    "Rotation",
    "FOLLOW_SURFACE",
]

FOLLOW_SURFACE = (None, "lerp", "gaussian")

#: ``sample_weight(centre_guide (N, G), sample_guide (N, G)) -> (N, 1) or (N, 3)``
SampleWeight = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class Stretch:
    """JG10 stretch factors (003 §7.3.1) in millimetre units.

    003 computes ``s_x = ssslevel / (d + correction · min(|ddx d|, maxdd))`` with depth in
    "units" of a head one unit tall, 20° fov and 720 px. Here the pinhole mapping already turns
    mm into pixels, so ``ssslevel`` is a dimensionless multiplier of the physical scale (1.0 =
    physically sized kernel); ``correction`` keeps its unit, pixels (003: 800), and ``maxdd`` is
    in mm of depth per pixel: 003's 0.001 head units per pixel × a 230 mm head = 0.23 mm/px.
    The resulting factor multiplies the pinhole pixels-per-mm:
    ``ssslevel · d / (d + correction · min(|∂d/∂axis|, maxdd))``.
    """

    ssslevel: float = 1.0
    correction: float = 800.0
    maxdd: float = 0.23


@dataclass(frozen=True)
class Rotation:
    """Stochastic kernel rotation (000 §6).

    Attributes:
        angles: per-pixel rotation of the sampling axis in radians, ``(B, 1, H, W)``.
        radius: fraction of the kernel extent within which taps are rotated (000 §6: 0.1;
            0.3 for extreme close-ups). Taps farther out stay on the axis (cache friendly in
            the paper; here it keeps their 1D interpolation).
    """

    angles: torch.Tensor
    radius: float = 0.1


@functools.lru_cache(maxsize=64)
def _constant(value: float, n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """A ``(n,)`` tensor of ``value``, made once (the passes only read it)."""
    return torch.full((n,), value, dtype=dtype, device=device)


def _axis_derivative(depth: torch.Tensor, axis: int) -> torch.Tensor:
    """|∂depth/∂axis| in mm per pixel by central differences (one-sided at the border).

    003 uses the shader's ``ddx``, a forward difference within a 2×2 quad; a central
    difference is its symmetric counterpart and does not shift silhouettes by half a pixel.
    """
    d = torch.gradient(depth, dim=axis)[0]
    return d.abs()


def _check_pass_inputs(
    image: torch.Tensor,
    kernel: Kernel1D,
    direction: str,
    gbuffer: GBuffer,
    width: float | torch.Tensor,
    follow_surface: str | None,
    surface_scale: float | torch.Tensor | None,
    check_finite: bool = True,
) -> None:
    check_tensor("image", image, ndim=4, channels=3, finite=check_finite)
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if not isinstance(kernel, Kernel1D):
        raise TypeError(f"kernel must be a Kernel1D, got {type(kernel).__name__}")
    if image.shape != gbuffer.diffuse.shape:
        raise ValueError(
            f"image must have the G-buffer's shape {tuple(gbuffer.diffuse.shape)}, "
            f"got {tuple(image.shape)}"
        )
    if image.dtype != gbuffer.dtype:
        raise TypeError(f"image dtype {image.dtype} must match the G-buffer's {gbuffer.dtype}")
    check_choice("direction", direction, ("x", "y"))
    check_choice("follow_surface", follow_surface, FOLLOW_SURFACE)
    if isinstance(width, torch.Tensor):
        check_tensor("width", width, ndim=4, channels=1)
        if width.shape != gbuffer.depth.shape:
            raise ValueError(
                f"width must be a scalar or have shape {tuple(gbuffer.depth.shape)}, "
                f"got {tuple(width.shape)}"
            )
        if bool((width < 0).any()):
            raise ValueError(f"width must be >= 0 mm, got min {float(width.min()):g}")
    else:
        check_scalar("width", width, 0.0, low_inclusive=False)
    if follow_surface is not None and surface_scale is None:
        raise ValueError(
            f"surface_scale (mm, > 0) must be given with follow_surface={follow_surface!r}"
        )
    if isinstance(surface_scale, torch.Tensor):
        check_tensor("surface_scale", surface_scale, ndim=1)
        if surface_scale.shape != (3,) or not bool((surface_scale > 0).all()):
            raise ValueError(
                "surface_scale must be a scalar > 0 or a (3,) tensor of per-channel mm > 0, "
                f"got {surface_scale.tolist()}"
            )
    elif surface_scale is not None:
        check_scalar("surface_scale", surface_scale, 0.0, low_inclusive=False)


def separable_pass(
    image: torch.Tensor,
    kernel: Kernel1D,
    direction: str,
    gbuffer: GBuffer,
    *,
    width: float | torch.Tensor = 1.0,
    follow_surface: str | None = None,
    surface_scale: float | torch.Tensor | None = None,
    stretch: Stretch | None = None,
    use_mask: bool = True,
    rotation: Rotation | None = None,
    guide: torch.Tensor | None = None,
    sample_weight: SampleWeight | None = None,
    name: str | None = None,
    check_finite: bool = True,
    inplace: bool = False,
) -> torch.Tensor:
    """One depth-aware 1D gather pass over the active pixels (DESIGN §4).

    Args:
        image: the image to blur, ``(B, 3, H, W)``, the G-buffer's dtype.
        kernel: taps; ``offsets`` in mm (times ``width``), ``weights (K, 3)``.
        direction: ``"x"`` (along rows) or ``"y"`` (along columns).
        gbuffer: supplies ``depth`` (mm), ``fov_y`` and ``mask``.
        width: multiplier of the kernel offsets (mm per offset unit): a scalar > 0 or a
            per-pixel ``(B, 1, H, W)`` tensor >= 0 (curvature modulation). Kernels built in mm
            use 1.0; the 2012 kernel is built in units of its ``width``.
        follow_surface: ``None``; ``"lerp"``: lerp each sample back to the centre colour by
            ``clamp(|Δz| / surface_scale, 0, 1)`` (002 appendix shader); ``"gaussian"``:
            multiply the tap weight by ``exp(-Δz² / 2 surface_scale²)`` with ``surface_scale =
            σ_max`` (000 eq. 7).
        surface_scale: mm, required with ``follow_surface``: the depth step at which a
            sample is fully replaced (lerp) or the σ_max of eq. 7 (gaussian); a scalar or a
            ``(3,)`` tensor of per-channel values (the artist model's σ_f). The methods
            pass their profile's widest length scale (the 2012 shader's constant
            ``300 · distToProjWindow · sssWidth`` likewise replaces a sample fully at a depth
            step of about the kernel's width).
        stretch: JG10 stretch factors (003 §7.3.1), see :class:`Stretch`.
        use_mask: use ``gbuffer.mask`` as stencil and strength: pixels with mask 0 are not
            computed (copied through), others have their step scaled by the mask (003 §7.3.1
            ``s' = s · alpha``; the 2012 shader's ``finalStep *= SSSS_STRENGTH_SOURCE``).
        rotation: stochastic rotation of the inner taps (000 §6), see :class:`Rotation`.
        guide: ``(B, G, H, W)`` auxiliary image fetched with the samples for ``sample_weight``.
        sample_weight: bilateral weight ``f(centre_guide (N, G), sample_guide (N, G))`` ->
            ``(N, 1)`` or ``(N, 3)`` (004 §3.3); the result is renormalised by the summed weights.
        name: name of the :class:`~sssbench.ops.timing.PassRecord` (default ``"pass.<dir>"``).
        check_finite: scan ``image`` for NaN / Inf (a full read of the image). The methods
            pass ``False``: their first image is ``gbuffer.diffuse``, validated when the
            G-buffer was built, and each later one is a pass output of finite inputs; on a
            far-away object the scan would otherwise cost more than the pass (measured).
        inplace: write the result into ``image`` and return it instead of a new tensor, for
            a caller that owns ``image`` (an intermediate of its own schedule): the pass then
            costs no full-image copy, only work on the active pixels. Honoured when no
            gradient is needed and ``image`` is contiguous; otherwise a new tensor is returned.

    Returns:
        ``(B, 3, H, W)``: blurred where active, ``image`` elsewhere.

    Shape:
        - image: ``(B, 3, H, W)``
        - output: ``(B, 3, H, W)``

    Example:
        >>> g = GBuffer(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 100.0), 0.5)
        >>> k = Kernel1D(torch.tensor([-1.0, 0.0, 1.0]), torch.full((3, 3), 1 / 3))
        >>> separable_pass(g.diffuse, k, "x", g).shape
        torch.Size([1, 3, 8, 8])
    """
    _check_pass_inputs(
        image, kernel, direction, gbuffer, width, follow_surface, surface_scale, check_finite
    )
    if (guide is None) != (sample_weight is None):
        raise ValueError("guide and sample_weight must be given together")
    if guide is not None:
        check_tensor("guide", guide, ndim=4)
        if guide.shape[0] != image.shape[0] or guide.shape[2:] != image.shape[2:]:
            raise ValueError(
                f"guide must have shape (B, G, H, W) = ({image.shape[0]}, G, "
                f"{image.shape[2]}, {image.shape[3]}), got {tuple(guide.shape)}"
            )
    if rotation is not None:
        check_tensor("rotation.angles", rotation.angles, ndim=4, channels=1)
        if rotation.angles.shape != gbuffer.depth.shape:
            raise ValueError(
                f"rotation.angles must have shape {tuple(gbuffer.depth.shape)}, "
                f"got {tuple(rotation.angles.shape)}"
            )
        check_scalar("rotation.radius", rotation.radius, 0.0, 1.0)

    b_, c_, h_, w_ = image.shape
    dtype = image.dtype
    strength = gbuffer.mask if (use_mask and gbuffer.mask is not None) else None
    focal_px = h_ / (2.0 * math.tan(gbuffer.fov_y / 2.0))  # pixels per mm at 1 mm depth
    axis = 3 if direction == "x" else 2
    follow = FOLLOW_SURFACE.index(follow_surface)
    if isinstance(surface_scale, torch.Tensor):  # per channel
        inv_scale = surface_scale.to(dtype=dtype, device=image.device).reciprocal()
    else:  # |Δz| / surface_scale; 0: unused
        inv = 0.0 if surface_scale is None else 1.0 / float(surface_scale)
        inv_scale = _constant(inv, c_, dtype, image.device)
    offsets, weights = memoised(
        (kernel.offsets, kernel.weights),
        ("taps", dtype),
        lambda: (kernel.offsets.to(dtype), kernel.weights.to(dtype)),
    )
    grads = _needs_grad(image, gbuffer, width)
    backend = _backend_for(image, grads, rotation, sample_weight)
    inplace = inplace and not grads and image.is_contiguous()

    start = time.perf_counter()
    if backend == "native":  # the stencil as runs of active pixels per row
        spans, stencils = image_spans(strength, (b_, h_, w_)), None
    else:  # as flat indices
        spans, stencils = None, None if strength is None else image_stencils(strength)
    f_px, ddepth = focal_px, None  # pixels per mm at 1 mm depth; |∂depth/∂axis| (mm / px)
    if stretch is not None:  # 003 §7.3.1
        f_px, ddepth = focal_px * stretch.ssslevel, _axis_derivative(gbuffer.depth, axis)
    # a new image is a copy of ``image`` with the active pixels replaced; the native loop
    # copies it line by line as it goes (no separate full-image pass, and no torch thread
    # pool left spinning against its threads)
    copy = not inplace and backend == "native"
    if inplace:
        out = image
    elif copy:
        out = torch.empty_like(image, memory_format=torch.contiguous_format)
    else:
        out = image.clone(memory_format=torch.contiguous_format)
    n_total = 0
    for bi in range(b_):  # per image: every tensor below is a view of one (C, H·W) plane set
        if backend == "native":
            if copy or spans[bi].shape[0]:
                n_total += _native_pass(
                    image[bi], out[bi], gbuffer.depth[bi], spans[bi],
                    None if strength is None else strength[bi],
                    width[bi] if isinstance(width, torch.Tensor) else width,
                    None if ddepth is None else ddepth[bi], stretch, axis, f_px, offsets,
                    weights, follow, inv_scale, copy,
                )  # fmt: skip
            continue
        lin = None if stencils is None else stencils[bi]
        if lin is not None and lin.numel() == 0:
            continue
        depth = gbuffer.depth[bi].reshape(-1)
        if lin is None:
            lin = torch.arange(h_ * w_, device=image.device)
        z = depth[lin]
        # ---- pixels per kernel-offset unit (DESIGN §2: a pixel covers 2 z tan(fov/2)/H mm)
        denom = z
        if ddepth is not None:  # 003 §7.3.1
            dd = ddepth[bi].reshape(-1)[lin]
            denom = z + stretch.correction * dd.clamp_max(stretch.maxdd)
        scale = f_px / denom
        if isinstance(width, torch.Tensor):
            scale = scale * width[bi].reshape(-1)[lin]
        else:
            scale = scale * width
        if strength is not None:
            scale = scale * strength[bi].reshape(-1)[lin]  # 003 §7.3.1 s' = s · alpha
        row, col = lin // w_, lin % w_
        if direction == "x":
            pos, fixed_lin, n_axis, stride_axis = col, row * w_, w_, 1
        else:
            pos, fixed_lin, n_axis, stride_axis = row, col, h_, w_
        rot = None
        if rotation is not None:
            ang = rotation.angles[bi].reshape(-1)[lin]
            # the x pass turns (1, 0) by the angle, the y pass turns (0, 1) by the same angle
            if direction == "x":
                dcol, drow = torch.cos(ang), torch.sin(ang)
            else:
                dcol, drow = -torch.sin(ang), torch.cos(ang)
            rot = (rotation.radius * kernel.extent, row.to(dtype), col.to(dtype), drow, dcol)
        planes = image[bi].reshape(c_, -1)
        guide_planes = None if guide is None else guide[bi].to(dtype).reshape(guide.shape[1], -1)
        fn = _compiled_accumulate() if backend == "compile" else _accumulate
        acc = fn(
            planes,
            depth,
            guide_planes,
            lin,
            fixed_lin,
            pos.to(dtype),
            scale,
            offsets,
            weights,
            n_axis,
            stride_axis,
            (h_, w_),
            follow,
            inv_scale,
            rot,
            sample_weight,
        )
        out[bi].view(c_, -1)[:, lin] = acc
        n_total += int(lin.numel())
    ms = (time.perf_counter() - start) * 1e3
    add_record(PassRecord(name or f"pass.{direction}", len(kernel), n_total, ms))
    return out


def _native_pass(
    image: torch.Tensor,
    out: torch.Tensor,
    depth: torch.Tensor,
    spans: torch.Tensor,
    strength: torch.Tensor | None,
    width: float | torch.Tensor,
    ddepth: torch.Tensor | None,
    stretch: Stretch | None,
    axis: int,
    f_px: float,
    offsets: torch.Tensor,
    weights: torch.Tensor,
    follow: int,
    inv_scale: torch.Tensor,
    copy: bool,
) -> int:
    """One image of a pass through the native loop (``native/gather_body.h``), which computes
    the per-pixel scale and the taps exactly as the torch code of :func:`separable_pass` and
    :func:`_accumulate` and writes ``out`` ``(3, H, W)`` (contiguous) at the active pixels,
    given as runs by ``spans`` ``(S, 3)`` (:func:`~sssbench.ops._stencil.image_spans`).
    Per-image tensors are ``(1, H, W)``; ``f_px`` includes the stretch's ``ssslevel``. ``out``
    may be ``image``: the loop reads every sample of a row (x) or column strip (y) into its
    own buffer before it writes any result there. ``copy``: ``out`` is uninitialised and
    gets ``image``'s pixels everywhere else (copied line by line as the loop goes).
    Returns the number of active pixels."""
    lib = native.library()
    _, h, w = image.shape
    keep = []  # contiguous copies must outlive the call

    def ptr(t: torch.Tensor | None) -> int | None:
        if t is None:
            return None
        if t.dtype != image.dtype and t.is_floating_point():
            t = t.to(image.dtype)
        if not t.is_contiguous():
            t = t.contiguous()
        keep.append(t)
        return t.data_ptr()

    correction, maxdd = (0.0, 0.0) if stretch is None else (stretch.correction, stretch.maxdd)
    per_pixel_width = width if isinstance(width, torch.Tensor) else None
    fn = lib.sss_gather_f32 if image.dtype == torch.float32 else lib.sss_gather_f64
    status = fn(
        ptr(image), ptr(depth), ptr(spans), ptr(strength), ptr(per_pixel_width), ptr(ddepth),
        ptr(offsets), ptr(weights), ptr(inv_scale), out.data_ptr(),
        f_px, 0.0 if per_pixel_width is not None else float(width), correction, maxdd,
        spans.shape[0], offsets.numel(), h, w, int(axis == 2), follow, int(copy),
        torch.get_num_threads(),
    )  # fmt: skip
    if status < 0:
        raise MemoryError(f"native gather: no memory for the line buffers of a {h}x{w} image")
    return status


def blend_on_stencil(
    out: torch.Tensor, end: torch.Tensor, weight: torch.Tensor, mask: torch.Tensor | None
) -> torch.Tensor:
    """``out ← lerp(out, end, weight)`` on the pixels with ``mask > 0`` (every pixel without a
    mask), in place: the sum-of-Gaussians blend of a blurred step into the result (003
    §7.3.3, Listing 7.2), on the stencil's pixels only.

    Args:
        out: ``(B, 3, H, W)`` contiguous, overwritten at the active pixels.
        end: ``(B, 3, H, W)`` the blurred step.
        weight: ``(3,)`` per-channel blend weight.
        mask: ``(B, 1, H, W)`` stencil or ``None``.

    Returns:
        ``out``. With the native backend (no gradient needed) a C loop over the stencil's
        runs; otherwise ``torch.lerp`` at the stencil's indices (the two agree to a rounding:
        torch fuses the multiply-add).
    """
    b_, c_, h_, w_ = out.shape
    weight = weight.to(dtype=out.dtype, device=out.device)
    grads = torch.is_grad_enabled() and any(t.requires_grad for t in (out, end, weight))
    if _backend_for(out, grads, None, None) == "native" and out.is_contiguous():
        lib = native.library()
        fn = lib.sss_blend_f32 if out.dtype == torch.float32 else lib.sss_blend_f64
        end = end.contiguous()
        weight = weight.contiguous()
        for bi, spans in enumerate(image_spans(mask, (b_, h_, w_))):
            if spans.shape[0]:
                fn(out[bi].data_ptr(), end[bi].data_ptr(), spans.data_ptr(), weight.data_ptr(),
                   spans.shape[0], h_, w_, torch.get_num_threads())  # fmt: skip
        return out
    stencils = [None] * b_ if mask is None else image_stencils(mask)
    for bi, lin in enumerate(stencils):
        flat, blurred = out[bi].view(c_, -1), end[bi].reshape(c_, -1)
        if lin is None:
            flat.copy_(torch.lerp(flat, blurred, weight.view(c_, 1)))
        else:
            flat[:, lin] = torch.lerp(flat[:, lin], blurred[:, lin], weight.view(c_, 1))
    return out


def _lerp_fetch(planes: torch.Tensor, a: torch.Tensor, b: torch.Tensor, f: torch.Tensor):
    """``planes[:, a] + f (planes[:, b] − planes[:, a])`` for ``(C, HW)`` planes."""
    pa = planes[:, a]
    return pa + f * (planes[:, b] - pa)


def _accumulate(
    planes: torch.Tensor,
    depth: torch.Tensor,
    guide: torch.Tensor | None,
    lin: torch.Tensor,
    fixed_lin: torch.Tensor,
    pos_f: torch.Tensor,
    scale: torch.Tensor,
    offsets: torch.Tensor,
    weights: torch.Tensor,
    n_axis: int,
    stride_axis: int,
    hw: tuple[int, int],
    follow: int,
    inv_scale: torch.Tensor,
    rot: tuple | None,
    sample_weight: SampleWeight | None,
) -> torch.Tensor:
    """The one accumulation loop over taps (DESIGN §4), ``(C, N)`` for the active pixels.

    ``planes`` ``(C, H·W)``, ``depth`` ``(H·W,)`` and ``guide`` ``(G, H·W)`` are views of one
    image; ``lin`` are the active pixels; ``fixed_lin + i·stride_axis`` addresses the i-th
    pixel along the pass axis. ``follow``: index into :data:`FOLLOW_SURFACE`. ``rot``:
    ``(radius_mm, row, col, drow, dcol)`` for rotated inner taps. Written with tensors only
    when ``rot`` and ``sample_weight`` are ``None`` so that ``torch.compile`` can fuse the
    whole loop (see :func:`set_backend`).
    """
    centre_rgb = planes[:, lin]
    centre_z = depth[lin]
    centre_guide = None if guide is None else guide[:, lin]
    acc = torch.zeros_like(centre_rgb)
    wsum = torch.zeros_like(acc) if sample_weight is not None else None
    for k in range(offsets.shape[0]):
        step = offsets[k] * scale
        if rot is not None and abs(float(offsets[k])) <= rot[0]:
            _, row_f, col_f, drow, dcol = rot
            idx, wts = _bilinear_corners(row_f + step * drow, col_f + step * dcol, *hw)
            rgb = sum(wt * planes[:, i] for i, wt in zip(idx, wts, strict=True))
            zs = sum(wt * depth[i] for i, wt in zip(idx, wts, strict=True))
            gs = None
            if guide is not None:
                gs = sum(wt * guide[:, i] for i, wt in zip(idx, wts, strict=True))
        else:
            p = (pos_f + step).clamp(0, n_axis - 1)  # border clamp
            p0 = p.floor()
            frac = p - p0
            i0 = p0.long()
            a = fixed_lin + i0 * stride_axis
            b = fixed_lin + (i0 + 1).clamp_max(n_axis - 1) * stride_axis
            rgb = _lerp_fetch(planes, a, b, frac)
            zs = depth[a] + frac * (depth[b] - depth[a])
            gs = None if guide is None else _lerp_fetch(guide, a, b, frac)
        weight = weights[k][:, None]
        if follow:
            dz = (zs - centre_z).abs()[None, :] * inv_scale[:, None]  # |Δz| / scale
            if follow == 1:  # 002 appendix shader: lerp back to the centre colour
                rgb = rgb + dz.clamp(0.0, 1.0) * (centre_rgb - rgb)
            else:  # 000 eq. 7: one exp with sigma_max
                weight = weight * torch.exp(-0.5 * dz * dz)
        if sample_weight is not None:
            weight = weight * sample_weight(centre_guide.T, gs.T).T
            wsum = wsum + weight
        acc = acc + weight * rgb
    if wsum is not None:
        acc = acc / wsum.clamp_min(torch.finfo(acc.dtype).tiny)
    return acc


BACKENDS = ("native", "torch", "compile")
_BACKEND: dict[str, object] = {"name": "native", "compiled": None}


def set_backend(name: str) -> None:
    """Choose how the tap loop runs (process-wide).

    - ``"native"`` (default): a C loop (``sssbench/ops/native``) built on first use with the
      system compiler (about a second) and cached; same float operations in the same order as
      the torch loop (tested equal). Used when no autograd graph is needed and the pass has no
      rotated taps or ``sample_weight``; otherwise, or without a C compiler, the torch loop runs.
    - ``"torch"``: the eager torch loop (:func:`_accumulate`), differentiable.
    - ``"compile"``: the torch loop through ``torch.compile`` (inductor; the first call per
      dtype, direction and follow-surface mode compiles for tens of seconds), differentiable.
    """
    _BACKEND["name"] = check_choice("backend", name, BACKENDS)


def get_backend() -> str:
    """The backend chosen by :func:`set_backend`."""
    return str(_BACKEND["name"])


def _needs_grad(image: torch.Tensor, gbuffer: GBuffer, width: float | torch.Tensor) -> bool:
    """Whether autograd records this pass."""
    return torch.is_grad_enabled() and any(
        isinstance(t, torch.Tensor) and t.requires_grad
        for t in (image, gbuffer.depth, gbuffer.mask, width)
    )


def _backend_for(
    image: torch.Tensor,
    grads: bool,
    rotation: Rotation | None,
    sample_weight: SampleWeight | None,
) -> str:
    """The backend this pass runs on (see :func:`set_backend`)."""
    name = get_backend()
    if rotation is not None or sample_weight is not None:
        return "torch"  # rotated taps and bilateral weights: torch loop only
    if name != "native":
        return name
    if grads or image.device.type != "cpu" or native.library() is None:
        return "torch"
    return "native"


def _compiled_accumulate():
    if _BACKEND["compiled"] is None:
        _BACKEND["compiled"] = torch.compile(_accumulate, dynamic=True)
    return _BACKEND["compiled"]


def _bilinear_corners(
    row: torch.Tensor, col: torch.Tensor, h: int, w: int
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Flat indices and weights of the four bilinear corners at fractional (row, col), clamped
    to the image (rotated taps)."""
    row = row.clamp(0, h - 1)
    col = col.clamp(0, w - 1)
    r0f, c0f = row.floor(), col.floor()
    fr, fc = row - r0f, col - c0f
    r0, c0 = r0f.long(), c0f.long()
    r1, c1 = (r0 + 1).clamp_max(h - 1), (c0 + 1).clamp_max(w - 1)
    idx = [r0 * w + c0, r0 * w + c1, r1 * w + c0, r1 * w + c1]
    wts = [(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc]
    return idx, wts

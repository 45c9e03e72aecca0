"""The tap loop of the gather primitive in torch: the specification, differentiable.

:func:`gather_torch` is one pass over a batch; :func:`pixel_scales` is the per-pixel step
(shared with nothing else: the native loop in ``native/gather_body.h`` performs the same float
operations in the same order and is tested bitwise equal to this code, see
:data:`sssbench.ops.gather.BACKEND_AGREEMENT`). Validation and the choice of backend live in
:mod:`sssbench.ops.gather`; this module trusts its arguments.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import torch

from sssbench.ops._stencil import image_stencils

__all__ = ["gather_torch", "sweep_torch", "pixel_scales", "compiled_accumulate"]

#: ``sample_weight(centre_guide (N, G), sample_guide (N, G)) -> (N, 1) or (N, 3)``
SampleWeight = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def pixel_scales(
    z: torch.Tensor,
    strength: torch.Tensor | None,
    width: torch.Tensor | None,
    ddepth: torch.Tensor | None,
    f_px: float,
    width_scalar: float,
    correction: float,
    maxdd: float,
) -> torch.Tensor:
    """Pixels per kernel-offset unit at the given pixels, ``(N,)`` in ``z``'s dtype.

    ``s = f_px / (z + correction · min(|∂z/∂axis|, maxdd)) · width · strength``: the pinhole
    mapping (DESIGN §2: a pixel covers 2 z tan(fov/2) / H mm), the JG10 stretch (003 §7.3.1)
    and ``s' = s · alpha`` (003 §7.3.1). Computed in float64 (every factor was validated finite
    and >= 0, so the product is finite or +inf, never NaN: no ``0 · inf``) and clamped to the
    dtype's largest finite value before the cast, so that ``offset · s`` is never NaN either
    (``0 · s = 0`` for the centre tap; a huge step clamps at the border). The native loop does
    the same operations in double.

    Args:
        z: ``(N,)`` linear depth of the pixels, mm.
        strength: ``(N,)`` mask strength in [0, 1], or ``None``.
        width: ``(N,)`` per-pixel width multiplier, or ``None`` for ``width_scalar``.
        ddepth: ``(N,)`` |∂z/∂axis| in mm per pixel (stretch), or ``None``.
        f_px: pixels per mm at 1 mm depth (times the stretch's ``ssslevel``), finite > 0.
        width_scalar: offset multiplier used when ``width`` is ``None``.
        correction, maxdd: the stretch's (pixels; mm per pixel), used with ``ddepth``.
    """
    f64 = torch.float64
    denom = z.to(f64)
    if ddepth is not None:  # 003 §7.3.1
        denom = denom + correction * ddepth.to(f64).clamp_max(maxdd)
    # a tensor divided by a tensor: torch turns ``scalar / tensor`` into reciprocal · scalar
    scale = torch.div(denom.new_tensor(f_px), denom)
    scale = scale * (width_scalar if width is None else width.to(f64))
    if strength is not None:
        scale = scale * strength.to(f64)  # 003 §7.3.1 s' = s · alpha
    big = torch.finfo(z.dtype).max
    return torch.where(scale <= big, scale, big).to(z.dtype)  # also NaN -> big (none expected)


def gather_torch(
    image: torch.Tensor,
    depth: torch.Tensor,
    strength: torch.Tensor | None,
    width: torch.Tensor | None,
    ddepth: torch.Tensor | None,
    offsets: torch.Tensor,
    weights: torch.Tensor,
    inv_scale: torch.Tensor,
    f_px: float,
    width_scalar: float,
    correction: float,
    maxdd: float,
    axis_y: bool,
    follow: int,
    *,
    rotation: tuple[torch.Tensor, float] | None = None,
    guide: torch.Tensor | None = None,
    sample_weight: SampleWeight | None = None,
    out: torch.Tensor | None = None,
    accumulate: Callable[..., torch.Tensor] | None = None,
) -> tuple[torch.Tensor, int]:
    """One pass over a batch with the torch tap loop; ``(out, active pixel count)``.

    Args:
        image: ``(B, 3, H, W)``.
        depth: ``(B, 1, H, W)`` linear depth, mm.
        strength: ``(B, 1, H, W)`` stencil / strength in [0, 1], or ``None`` (every pixel).
        width: ``(B, 1, H, W)`` per-pixel offset multiplier, or ``None`` for ``width_scalar``.
        ddepth: ``(B, 1, H, W)`` |∂depth/∂axis| mm per pixel for the stretch, or ``None``.
        offsets: ``(K,)`` tap offsets (mm per width unit), ``image``'s dtype.
        weights: ``(K, 3)`` tap weights, ``image``'s dtype.
        inv_scale: ``(3,)`` 1 / surface_scale per channel (1/mm; 0 when unused), finite.
        f_px, width_scalar, correction, maxdd: see :func:`pixel_scales`.
        axis_y: pass along columns (else rows).
        follow: index into :data:`~sssbench.ops.gather.FOLLOW_SURFACE`.
        rotation: ``(angles (B, 1, H, W) radians, radius mm)`` for rotated inner taps.
        guide: ``(B, G, H, W)`` fetched with the samples for ``sample_weight``.
        sample_weight: bilateral weight, see ``separable_pass``.
        out: where to write (may be ``image``: every tap of an image is read before its
            results are written); ``None``: a contiguous copy of ``image``.
        accumulate: the tap loop (default :func:`_accumulate`; the compiled one).
    """
    b_, c_, h_, w_ = image.shape
    if out is None:
        out = image.clone(memory_format=torch.contiguous_format)
    fn = accumulate or _accumulate
    stencils = None if strength is None else image_stencils(strength)
    n_total = 0
    for bi in range(b_):  # per image: every tensor below is a view of one (C, H·W) plane set
        lin = None if stencils is None else stencils[bi]
        if lin is not None and lin.numel() == 0:
            continue
        flat_depth = depth[bi].reshape(-1)
        if lin is None:
            lin = torch.arange(h_ * w_, device=image.device)

        def at(t: torch.Tensor | None, bi: int = bi, lin: torch.Tensor = lin):
            return None if t is None else t[bi].reshape(-1)[lin]

        scale = pixel_scales(
            flat_depth[lin], at(strength), at(width), at(ddepth), f_px, width_scalar,
            correction, maxdd,
        )  # fmt: skip
        row, col = lin // w_, lin % w_
        if axis_y:
            pos, fixed_lin, n_axis, stride_axis = row, col, h_, w_
        else:
            pos, fixed_lin, n_axis, stride_axis = col, row * w_, w_, 1
        rot = None
        if rotation is not None:
            ang = at(rotation[0])
            # the x pass turns (1, 0) by the angle, the y pass turns (0, 1) by the same angle
            if axis_y:
                dcol, drow = -torch.sin(ang), torch.cos(ang)
            else:
                dcol, drow = torch.cos(ang), torch.sin(ang)
            rot = (rotation[1], row.to(image.dtype), col.to(image.dtype), drow, dcol)
        planes = image[bi].reshape(c_, -1)
        guide_planes = None
        if guide is not None:
            guide_planes = guide[bi].to(image.dtype).reshape(guide.shape[1], -1)
        acc = fn(
            planes, flat_depth, guide_planes, lin, fixed_lin, pos.to(image.dtype), scale,
            offsets, weights, n_axis, stride_axis, (h_, w_), follow, inv_scale, rot,
            sample_weight,
        )  # fmt: skip
        out[bi].view(c_, -1)[:, lin] = acc
        n_total += int(lin.numel())
    return out, n_total


def sweep_torch(
    images: torch.Tensor,
    *args: object,
    coefficients: torch.Tensor | None = None,
    out: torch.Tensor | None = None,
    accumulate: Callable[..., torch.Tensor] | None = None,
) -> tuple[torch.Tensor, int]:
    """The sweep of ``S`` weight sets over the same taps: its specification, ``S`` passes of
    :func:`gather_torch` (the native loop shares each tap's position, fetch and follow-surface
    factor between the sets, with the same operations per set: bitwise these results but for
    the gaussian follow-surface's exp, see :data:`~sssbench.ops.gather.BACKEND_AGREEMENT`).

    Args:
        images: fan-out (``coefficients`` ``None``): one image ``(B, 3, H, W)``; fan-in:
            ``(S, B, 3, H, W)``, set ``s`` reads ``images[s]``.
        args: :func:`gather_torch`'s after ``image``, but ``weights`` (the sixth) ``(S, K, 3)``
            in ``images``' dtype.
        coefficients: ``(S, 3)`` per-set per-channel factors of the fan-in, ``images``' dtype.
        out: fan-in: ``(B, 3, H, W)`` written at the active pixels only (``None``: a new
            tensor holding ``Σ_s c_s · images[s]`` elsewhere, what ``S`` separate passes summed
            give there). Fan-out: ignored.

    Returns:
        ``(result, active pixels per set)``: fan-out ``(S, B, 3, H, W)``, set ``s``'s pass
        (``images`` at inactive pixels); fan-in ``(B, 3, H, W)``, ``0 + c_0 · r_0 + c_1 · r_1
        + …`` at the active pixels (``r_s`` set ``s``'s pass, summed in set order).
    """
    head, weights, tail = args[:5], args[5], args[6:]
    depth, strength = head[0], head[1]
    if coefficients is None:
        runs = [gather_torch(images, *head, wt, *tail, accumulate=accumulate) for wt in weights]
        return torch.stack([r for r, _ in runs]), runs[0][1]
    total = torch.zeros_like(images[0])
    n = 0
    for img, wt, c in zip(images, weights, coefficients, strict=True):
        r, n = gather_torch(img, *head, wt, *tail, accumulate=accumulate)
        total = total + c.view(1, 3, 1, 1) * r
    if out is None:
        return total, n  # inactive pixels: Σ_s c_s · images[s], as the summed passes
    active = torch.ones_like(depth, dtype=torch.bool) if strength is None else strength > 0
    out.copy_(torch.where(active, total, out))
    return out, n


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

    For each tap, step along the pass axis by ``offset × scale`` pixels, fetch the neighbour
    with linear interpolation (bilinear for rotated taps), clamp at the image border, and
    accumulate ``weight × sample`` (002 appendix, 003 Listing 7.1).

    ``planes`` ``(C, H·W)``, ``depth`` ``(H·W,)`` and ``guide`` ``(G, H·W)`` are views of one
    image; ``lin`` are the active pixels; ``fixed_lin + i·stride_axis`` addresses the i-th
    pixel along the pass axis; ``scale`` ``(N,)`` is finite (:func:`pixel_scales`), so a tap
    position is finite or ±inf and the clamp maps it into ``[0, n_axis − 1]`` before the
    integer conversion. ``follow``: index into ``FOLLOW_SURFACE``. ``rot``: ``(radius_mm, row,
    col, drow, dcol)`` for rotated inner taps. Written with tensors only when ``rot`` and
    ``sample_weight`` are ``None`` so that ``torch.compile`` can fuse the whole loop.
    """
    centre_rgb = planes[:, lin]
    centre_z = depth[lin]
    centre_guide = None if guide is None else guide[:, lin]
    acc = torch.zeros_like(centre_rgb)
    wsum = torch.zeros_like(acc) if sample_weight is not None else None
    big = torch.finfo(planes.dtype).max
    for k in range(offsets.shape[0]):
        step = offsets[k] * scale
        if rot is not None and abs(float(offsets[k])) <= rot[0]:
            _, row_f, col_f, drow, dcol = rot
            step = step.clamp(-big, big)  # finite: 0 · step = 0 for an axis-aligned direction
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


@functools.cache
def compiled_accumulate() -> Callable[..., torch.Tensor]:
    """:func:`_accumulate` through ``torch.compile`` (built once, on first use)."""
    return torch.compile(_accumulate, dynamic=True)


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

"""Shared geometry for the synthetic scenes: rays, convex primitives, compositing, lighting.

Frames. All tracing happens in the **camera frame** of :func:`sssbench.gbuffer.view_positions`:
``x`` right, ``y`` up, ``z`` forward (= linear depth, mm), camera at the origin. The G-buffer
stores normals and ``light_dir`` in **view space** (``GBuffer`` docstring: camera looks down
``-z``), i.e. the same ``x``, ``y`` with ``z`` flipped: a surface facing the camera has view-space
normal ``(0, 0, +1)``. :func:`to_view` converts between the two (it is its own inverse).

Rays. :func:`camera_rays` gives, per pixel, the direction ``d`` with ``d_z = 1`` through the pixel
centre defined by ``view_positions``; a hit at ray parameter ``t`` is at ``t d`` and has linear
depth exactly ``t``.

Primitives are convex solids. ``interval(o, d)`` returns the ray parameters ``t_in <= t_out`` where
the ray ``o + t d`` is inside the solid (``t_in > t_out`` when it misses), plus the outward normal
at the entry point. A scene is a list of primitives; the visible surface is the nearest entry
(:func:`trace`, compositing by nearest depth), which is exact for a union of convex solids seen
from outside all of them.

All tensors here are flattened: points and directions ``(N, 3)`` (or ``(3,)`` broadcast),
parameters ``(N,)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import kornia
import torch

from sssbench.gbuffer import view_positions

__all__ = [
    "bounding_sphere",
    "sphere_mask",
    "Box",
    "Ellipsoid",
    "EllipticSlab",
    "HalfSpace",
    "Hit",
    "Primitive",
    "blinn_phong",
    "camera_rays",
    "composite_nearest",
    "exit_distance",
    "lambert",
    "normals_from_depth",
    "occluded",
    "rotation",
    "to_view",
    "trace",
    "unit",
]

_INF = math.inf


def unit(v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """``v`` normalised to unit length along ``dim`` (zero vectors stay zero)."""
    if v.shape[dim] == 3 and v.stride(dim) != 1:
        # strided 3-vectors (e.g. a (3, N) layout): torch.norm is ~20x slower here
        x, y, z = v.unbind(dim)
        n = torch.addcmul(torch.addcmul(x * x, y, y), z, z).sqrt_()
        return v / n.clamp_min_(1e-30).unsqueeze(dim)
    return v / v.norm(dim=dim, keepdim=True).clamp_min(1e-30)


def to_view(v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Camera frame (``z`` forward) <-> G-buffer view space (``z`` toward the camera): flip z."""
    sign = torch.ones(3, dtype=v.dtype, device=v.device)
    sign[2] = -1.0
    shape = [1] * v.ndim
    shape[dim] = 3
    return v * sign.view(shape)


def rotation(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> torch.Tensor:
    """Rotation matrix ``(3, 3)`` float64 (camera frame): ``R_y(yaw) R_x(pitch) R_z(roll)``.

    Angles in degrees. ``yaw`` turns about the vertical ``y`` axis (positive turns ``+z`` toward
    ``+x``), ``pitch`` about ``x``, ``roll`` about the view axis ``z``.
    """
    a, b, c = (math.radians(v) for v in (yaw, pitch, roll))
    ry = torch.tensor(
        [[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]],
        dtype=torch.float64,
    )
    rx = torch.tensor(
        [[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]],
        dtype=torch.float64,
    )
    rz = torch.tensor(
        [[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]],
        dtype=torch.float64,
    )
    return ry @ rx @ rz


def camera_rays(height: int, width: int, fov_y: float, dtype=torch.float64) -> torch.Tensor:
    """Ray directions through pixel centres, ``(H*W, 3)`` in the camera frame, with ``d_z = 1``.

    Row-major pixel order (index ``i * W + j``). Built from :func:`view_positions` at depth 1, so
    a hit at parameter ``t`` lands exactly on ``view_positions`` of depth ``t``.
    """
    ones = torch.ones(1, 1, height, width, dtype=dtype)
    return view_positions(ones, fov_y)[0].reshape(3, -1).T.contiguous()


def mat_rows(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``m (3, 3) @ v (3, N)`` as row-wise multiply-adds.

    Avoids BLAS for these skinny products: with several threads on a busy machine a BLAS call
    per primitive cost ~50x more than the arithmetic.
    """
    rows = []
    for i in range(3):
        r = v[0] * m[i, 0]
        r = r.add(v[1], alpha=float(m[i, 1])).add_(v[2], alpha=float(m[i, 2]))
        rows.append(r)
    return torch.stack(rows)


# ---------------------------------------------------------------- primitives


class Primitive:
    """A convex solid placed by ``center`` (mm, camera frame) and ``rot`` (local -> camera).

    Attributes:
        casts_shadow: whether it blocks light in :func:`occluded` and :func:`exit_distance`.
    """

    def __init__(
        self,
        center: Sequence[float],
        rot: torch.Tensor | None = None,
        *,
        casts_shadow: bool = True,
    ) -> None:
        self.center = torch.as_tensor(center, dtype=torch.float64).reshape(3)
        self.rot = torch.eye(3, dtype=torch.float64) if rot is None else rot.to(torch.float64)
        self.casts_shadow = casts_shadow

    def interval(
        self, o: torch.Tensor, d: torch.Tensor, normals: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Inside interval of the ray ``o + t d``.

        Args:
            o: origins ``(N, 3)`` or ``(3,)`` in mm, camera frame.
            d: directions ``(N, 3)`` (any length).
            normals: also return the entry normals (skip them for shadow rays).

        Returns:
            ``t_in (N,)``, ``t_out (N,)`` (``t_in > t_out`` on a miss) and the unit outward
            normal at ``t_in``, ``(N, 3)`` in the camera frame (``None`` if not asked for).
        """
        dt = d.dtype
        rot = self.rot.to(dt)
        # local frame, one contiguous row per axis: R^T (o - c) and R^T d, shape (3, N)
        ol = mat_rows(rot.T, (o - self.center.to(dt)).reshape(-1, 3).T)
        dl = mat_rows(rot.T, d.T)
        ol = ol.expand_as(dl)
        t_in, t_out, n_local = self._local_interval(ol, dl, normals)
        if not normals:
            return t_in, t_out, None
        return t_in, t_out, unit(mat_rows(rot, n_local).T)

    def _local_interval(self, o, d, normals):  # pragma: no cover - abstract
        """``o, d``: local ``(3, N)``; returns ``t_in, t_out`` and local normals ``(3, N)``."""
        raise NotImplementedError

    def bound(self) -> tuple[torch.Tensor, float] | None:
        """A bounding sphere ``(center (3,), radius)`` in mm, or ``None`` if unbounded."""
        return None


def _slab(o: torch.Tensor, d: torch.Tensor, h: float):
    """Interval of ``|o + t d| <= h`` along one axis (``(N,)`` rows), and the entry normal sign."""
    zero = d == 0
    inv = 1.0 / torch.where(zero, torch.ones_like(d), d)
    ta = (-h - o) * inv
    tb = (h - o) * inv
    near = torch.minimum(ta, tb)
    far = torch.maximum(ta, tb)
    if bool(zero.any()):
        inside = o.abs() <= h
        near = torch.where(zero, torch.where(inside, -_INF, _INF), near)
        far = torch.where(zero, torch.where(inside, _INF, -_INF), far)
    return near, far, -torch.sign(d)


def _quadric(o: torch.Tensor, d: torch.Tensor, inv_r: Sequence[float], normals: bool):
    """Interval of ``sum_k ((o_k + t d_k) inv_r_k)^2 <= 1`` and the (unnormalised) entry normal.

    ``o, d`` are ``(3, N)``; ``inv_r_k = 0`` leaves axis ``k`` unconstrained (an elliptic
    cylinder).
    """
    axes = [k for k in range(3) if inv_r[k] != 0.0]
    a = b = c = None
    for k in axes:
        ok_, dk = o[k] * inv_r[k], d[k] * inv_r[k]
        a = dk * dk if a is None else a.addcmul_(dk, dk)
        b = ok_ * dk if b is None else b.addcmul_(ok_, dk)  # half of the usual b
        c = ok_ * ok_ if c is None else c.addcmul_(ok_, ok_)
    c = c - 1.0
    disc = b * b - a * c
    hit = (disc >= 0) & (a > 0)
    sq = disc.clamp_min(0).sqrt()
    inv_a = 1.0 / torch.where(a > 0, a, torch.ones_like(a))
    near = torch.where(hit, (-b - sq) * inv_a, _INF)
    far = torch.where(hit, (-b + sq) * inv_a, -_INF)
    par = a <= 0  # a ray parallel to the unconstrained axis: inside everywhere or nowhere
    if bool(par.any()):
        near = torch.where(par, torch.where(c <= 0, -_INF, _INF), near)
        far = torch.where(par, torch.where(c <= 0, _INF, -_INF), far)
    if not normals:
        return near, far, None
    tn = torch.where(torch.isfinite(near), near, torch.zeros_like(near))
    scale = torch.tensor([r * r for r in inv_r], dtype=d.dtype).unsqueeze(-1)
    normal = (o + tn * d) * scale  # gradient of the quadric
    return near, far, normal


class Ellipsoid(Primitive):
    """Ellipsoid with semi-axes ``radii`` (mm) along its local x, y, z. A sphere: equal radii."""

    def __init__(self, center, radii, rot=None, *, casts_shadow=True):
        super().__init__(center, rot, casts_shadow=casts_shadow)
        self.radii = torch.as_tensor(radii, dtype=torch.float64).reshape(3)

    def _local_interval(self, o, d, normals):
        return _quadric(o, d, [1.0 / float(r) for r in self.radii], normals)

    def bound(self):
        return self.center, float(self.radii.max())


class Box(Primitive):
    """Box with half extents ``half`` (mm) along its local axes."""

    def __init__(self, center, half, rot=None, *, casts_shadow=True):
        super().__init__(center, rot, casts_shadow=casts_shadow)
        self.half = [float(h) for h in half]

    def _local_interval(self, o, d, normals):
        nears, fars, signs = zip(*(_slab(o[k], d[k], self.half[k]) for k in range(3)), strict=True)
        near = torch.stack(nears)
        t_in, axis = near.max(0)
        t_out = torch.stack(fars).min(0).values
        if not normals:
            return t_in, t_out, None
        normal = torch.nn.functional.one_hot(axis, 3).T.to(d.dtype) * torch.stack(signs)
        return t_in, t_out, normal

    def bound(self):
        return self.center, math.hypot(*self.half)


class EllipticSlab(Primitive):
    """A slab of half thickness ``half_thickness`` (local z) with an elliptic outline.

    The outline has semi-axes ``radii_xy`` (local x, y), in mm: an elliptic cylinder cut by two
    parallel planes — the ear / thin-object primitive, exactly ``2 half_thickness`` thick.
    """

    def __init__(self, center, radii_xy, half_thickness, rot=None, *, casts_shadow=True):
        super().__init__(center, rot, casts_shadow=casts_shadow)
        self.radii_xy = tuple(float(r) for r in radii_xy)
        self.half_thickness = float(half_thickness)

    def _local_interval(self, o, d, normals):
        inv_r = [1.0 / self.radii_xy[0], 1.0 / self.radii_xy[1], 0.0]
        qn, qf, qnorm = _quadric(o, d, inv_r, normals)
        zn, zf, zs = _slab(o[2], d[2], self.half_thickness)
        t_in = torch.maximum(qn, zn)
        t_out = torch.minimum(qf, zf)
        if not normals:
            return t_in, t_out, None
        znorm = torch.zeros_like(d)
        znorm[2] = zs
        normal = torch.where(zn > qn, znorm, qnorm)
        return t_in, t_out, normal

    def bound(self):
        return self.center, math.hypot(max(self.radii_xy), self.half_thickness)


class HalfSpace(Primitive):
    """The solid behind an infinite plane through ``center`` with outward unit normal ``normal``.

    ``normal`` is in the camera frame; ``(0, 0, -1)`` is a wall facing the camera.
    """

    def __init__(self, center, normal, *, casts_shadow=True):
        super().__init__(center, None, casts_shadow=casts_shadow)
        self.normal = unit(torch.as_tensor(normal, dtype=torch.float64).reshape(3))

    def _local_interval(self, o, d, normals):
        m = self.normal.to(d.dtype)
        md = _dot3(m.view(3, 1), d)
        om = _dot3(m.view(3, 1), o)
        s = -om / torch.where(md == 0, torch.ones_like(md), md)
        outside = om > 0
        t_in = torch.where(md < 0, s, torch.where((md == 0) & outside, _INF, -_INF))
        t_out = torch.where(md > 0, s, torch.where((md == 0) & outside, -_INF, _INF))
        return t_in, t_out, (m.unsqueeze(-1).expand_as(d) if normals else None)


# ---------------------------------------------------------------- tracing


def _dot3(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Row-wise dot of ``(3, N)`` component arrays (faster than ``(N, 3).sum(-1)``)."""
    return torch.addcmul(torch.addcmul(u[0] * v[0], u[1], v[1]), u[2], v[2])


def bounding_sphere(prims: Sequence[Primitive]) -> tuple[torch.Tensor, float] | None:
    """A sphere enclosing every primitive (``None`` if one is unbounded)."""
    bounds = [p.bound() for p in prims]
    if not bounds or any(b is None for b in bounds):
        return None
    center = torch.stack([c for c, _ in bounds]).mean(0)
    radius = max(float((c - center).norm()) + r for c, r in bounds)
    return center, radius


def sphere_mask(
    o: torch.Tensor, d: torch.Tensor, center: torch.Tensor, radius: float, t_min=0.0
) -> torch.Tensor:
    """Which rays ``o + t d`` meet the sphere for some ``t > t_min``; ``(N,)`` bool.

    A cheap conservative cull before testing the primitives inside a bounding sphere.
    """
    m = (o - center.to(d.dtype)).reshape(-1, 3).T
    dt = d.T
    a = _dot3(dt, dt)
    b = _dot3(m.expand_as(dt), dt)
    c = _dot3(m, m) - radius * radius
    disc = b * b - a * c
    t_far = (-b + disc.clamp_min(0).sqrt()) / a
    return (disc >= 0) & (t_far > t_min)


@dataclass
class Hit:
    """Nearest surface along each ray: ``t (N,)`` (inf on a miss), unit ``normal (N, 3)``
    (camera frame) and ``index (N,)`` of the primitive hit (-1 on a miss)."""

    t: torch.Tensor
    normal: torch.Tensor
    index: torch.Tensor


def composite_nearest(t: torch.Tensor, *values: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Composite K layers by nearest depth.

    Args:
        t: ``(K, N)`` depth (or ray parameter) of each layer, ``inf`` where the layer is empty.
        values: ``(K, N, ...)`` per-layer attributes.

    Returns:
        ``t_min (N,)``, ``index (N,)`` (-1 where every layer is empty) and each value taken from
        the nearest layer ``(N, ...)``.
    """
    t_min, index = t.min(0)
    out = []
    for v in values:
        idx = index.view(1, -1, *([1] * (v.ndim - 2))).expand(1, *v.shape[1:])
        out.append(v.gather(0, idx)[0])
    index = torch.where(torch.isfinite(t_min), index, -1)
    return (t_min, index, *out)


def trace(prims: Sequence[Primitive], o: torch.Tensor, d: torch.Tensor, t_min: float = 0.0) -> Hit:
    """Nearest entry ``t > t_min`` into any primitive along ``o + t d``."""
    ts, ns = [], []
    for p in prims:
        t_in, t_out, n = p.interval(o, d)
        ts.append(torch.where((t_in <= t_out) & (t_in > t_min), t_in, _INF))
        ns.append(n)
    t, index, normal = composite_nearest(torch.stack(ts), torch.stack(ns))
    return Hit(t, normal, index)


def occluded(
    prims: Sequence[Primitive],
    o: torch.Tensor,
    d: torch.Tensor,
    eps: float | torch.Tensor = 1e-6,
) -> torch.Tensor:
    """Whether the ray ``o + t d`` (``t > eps``) enters any shadow-casting primitive; ``(N,)``.

    ``eps`` (mm, scalar or ``(N,)``) keeps a point from shadowing itself through rounding.

    Meant for shadow rays from visible surface points toward a directional light: a point's own
    convex primitive is not an occluder (its entry is at ``t <= 0``), so self-shadowing of a
    single primitive is left to the ``n·l`` clamp of :func:`lambert`.
    """
    hit = torch.zeros(d.shape[0], dtype=torch.bool, device=d.device)
    for p in prims:
        if not p.casts_shadow:
            continue
        t_in, t_out, _ = p.interval(o, d, normals=False)
        hit |= (t_in <= t_out) & (t_in > eps)
    return hit


def exit_distance(prims: Sequence[Primitive], o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Largest exit parameter ``t_out > 0`` of the ray ``o + t d`` from any shadow-casting
    primitive, 0 when it exits none; ``(N,)``.

    With ``o`` a visible surface point and ``d`` the unit direction toward the light, this is the
    distance from the point to where the light enters the object (the last surface toward the
    light), i.e. the distance ``m`` through the object that a translucent shadow map measures
    (001 §5.2).
    Gaps between primitives along the ray are counted, as a shadow map would.
    """
    out = torch.zeros(d.shape[0], dtype=d.dtype, device=d.device)
    for p in prims:
        if not p.casts_shadow:
            continue
        t_in, t_out, _ = p.interval(o, d, normals=False)
        valid = (t_in <= t_out) & torch.isfinite(t_out)
        out = torch.maximum(out, torch.where(valid, t_out, 0.0).clamp_min(0.0))
    return out


# ---------------------------------------------------------------- lighting


def lambert(normal: torch.Tensor, light: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Lambert cosine ``max(n·l, 0)``; ``light`` is the unit direction toward the light."""
    return (normal * light).sum(dim).clamp_min(0.0)


def blinn_phong(
    normal: torch.Tensor,
    light: torch.Tensor,
    view: torch.Tensor,
    shininess: torch.Tensor | float,
    dim: int = -1,
) -> torch.Tensor:
    """Blinn–Phong lobe ``max(n·h, 0)^s`` with ``h = normalize(l + v)``, zero where ``n·l <= 0``.

    Args:
        normal, light, view: unit vectors (``view`` points from the surface to the camera).
        shininess: exponent ``s`` (scalar or broadcastable tensor).
    """
    h = unit(light + view, dim)
    nh = (normal * h).sum(dim).clamp_min(0.0)
    lit = (normal * light).sum(dim) > 0
    return torch.where(lit, nh.pow(shininess), 0.0)


def normals_from_depth(depth: torch.Tensor, fov_y: float) -> torch.Tensor:
    """View-space unit normals ``(B, 3, H, W)`` from a linear depth map ``(B, 1, H, W)`` (mm).

    Positions come from :func:`view_positions`; their screen derivatives from
    ``kornia.filters.spatial_gradient`` (central differences; one-sided at the image border,
    undoing kornia's replicate-border halving). The normal is ``dP/dcol × dP/drow`` oriented
    toward the camera, returned in G-buffer view space (``+z`` toward the camera).
    """
    pos = view_positions(depth, fov_y)
    g = kornia.filters.spatial_gradient(pos, mode="diff", order=1, normalized=True)
    dx, dy = g[:, :, 0].clone(), g[:, :, 1].clone()
    if dx.shape[-1] > 1:
        dx[..., 0] *= 2.0
        dx[..., -1] *= 2.0
    if dy.shape[-2] > 1:
        dy[..., 0, :] *= 2.0
        dy[..., -1, :] *= 2.0
    n = torch.cross(dx, dy, dim=1)  # camera frame; rows go down, so this faces the camera
    return to_view(unit(n, dim=1), dim=1)

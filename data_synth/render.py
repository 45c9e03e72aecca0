"""The renderer of the ray-traced scenes: primary visibility, shading, shadows, thickness.

A scene is a list of objects (:class:`Surface`: a union of convex primitives,
:class:`SceneObject`, or the implicit face of :mod:`data_synth.face`) seen by a pinhole camera at
the origin, lit by directional lights. :func:`render` traces every pixel's ray through every
object (culled by the object's bounding sphere), composites by nearest depth, shades and writes a
:class:`~sssbench.gbuffer.GBuffer`:

- ``diffuse`` = ``Σ_k I_k · max(n·l_k, 0) · V_k + ambient`` (Lambert; ``V_k`` = 0 where an object
  blocks light ``k``), the same in R, G, B.
- ``specular`` = ``Σ_k I_k · ks · max(n·h_k, 0)^shininess · V_k`` (Blinn–Phong).
- ``thickness`` = the distance from the visible point along the *first* light to where that light
  enters the object (the last exit toward the light), as a translucent shadow map measures
  (001 §5.2); 0 on lit points of convex parts, on the background and on opaque objects.
- ``light_dir`` = the first light's direction (unit, view space, toward the light).

Frames: tracing happens in the camera frame of :mod:`data_synth.geometry` (``z`` forward); light
directions are given, and normals stored, in G-buffer view space (``+z`` toward the camera).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from data_synth.geometry import (
    HalfSpace,
    Hit,
    Primitive,
    blinn_phong,
    bounding_sphere,
    camera_rays,
    composite_nearest,
    exit_distance,
    lambert,
    occluded,
    sphere_mask,
    to_view,
    trace,
    unit,
)
from sssbench.gbuffer import GBuffer

__all__ = [
    "OPTIONAL_FIELDS",
    "SKIN_ALBEDO",
    "Ctx",
    "CulledUnion",
    "Light",
    "Material",
    "SceneObject",
    "Surface",
    "axis_depth",
    "backdrop",
    "constant_material",
    "flat_plane",
    "gbuffer",
    "image",
    "render",
    "render_labelled",
    "ParamsChecked",
]

#: optional G-buffer fields a scene may build (``diffuse`` and ``depth`` are always built)
OPTIONAL_FIELDS = ("albedo", "specular", "normal", "mask", "thickness")
SKIN_ALBEDO = (0.78, 0.52, 0.42)
_BACKDROP_ALBEDO = (0.5, 0.5, 0.5)


class ParamsChecked(Exception):
    """Raised by :meth:`Ctx.images_next` under ``check_only``: the builder has checked every
    parameter and is about to compute its first image (:func:`data_synth.scenes.check_scene`)."""


@dataclass(frozen=True)
class Ctx:
    """What every builder gets: image size, random generator, fields to build, output dtype.

    ``check_only``: check the parameters, build no image — the builder runs as usual up to its
    first image computation, where :meth:`images_next` raises :class:`ParamsChecked` (the same
    checks as a build, so a check and a build never disagree)."""

    height: int
    width: int
    gen: torch.Generator
    want: frozenset[str]
    dtype: torch.dtype
    check_only: bool = False

    def images_next(self) -> None:
        """Called by every builder (and by :func:`flat_plane`, :func:`render` and
        :func:`render_labelled`) right before its first ``(H, W)`` image work: every
        parameter has been checked by then. Under ``check_only`` it stops the build there."""
        if self.check_only:
            raise ParamsChecked


@dataclass(frozen=True)
class Light:
    """A directional light: ``direction`` toward the light (view space, any length > 0)."""

    direction: torch.Tensor
    intensity: float


@dataclass
class Material:
    """Per-point surface attributes, ``(n, 3)`` albedo and ``(n,)`` the rest.

    ``normal`` (optional, ``(n, 3)`` unit, camera frame) replaces the geometric normal for
    shading and in the G-buffer (a normal map); ``None`` keeps the geometric one. ``labels``
    (optional, ``(n,)`` long) names the part at each point (:func:`render_labelled`).
    """

    albedo: torch.Tensor
    mask: torch.Tensor
    ks: torch.Tensor
    shininess: torch.Tensor
    normal: torch.Tensor | None = None
    labels: torch.Tensor | None = None


def constant_material(albedo, mask: float, ks: float = 0.0, shininess: float = 1.0):
    """A material function giving the same attributes at every point."""

    def material(p: torch.Tensor, part: torch.Tensor, normal: torch.Tensor) -> Material:
        n = p.shape[0]
        return Material(
            torch.tensor(albedo, dtype=p.dtype).expand(n, 3),
            torch.full((n,), mask, dtype=p.dtype),
            torch.full((n,), ks, dtype=p.dtype),
            torch.full((n,), shininess, dtype=p.dtype),
        )

    return material


class Surface:
    """What :func:`render` needs of an object (camera frame, mm; ``o``, ``d`` are ``(N, 3)``).

    Attributes:
        translucent: whether the object gets a ``thickness``.
    """

    translucent: bool = True

    def bound(self) -> tuple[torch.Tensor, float] | None:
        """A bounding sphere ``(center (3,), radius)``, or ``None`` if unbounded."""
        raise NotImplementedError

    def hit(self, o: torch.Tensor, d: torch.Tensor) -> Hit:
        """Nearest entry ``t > 0`` along ``o + t d`` (``d_z = 1`` camera rays)."""
        raise NotImplementedError

    def occluded(self, o: torch.Tensor, d: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
        """Whether the ray from the surface point ``o`` along the unit ``d`` meets the object."""
        raise NotImplementedError

    def exit_distance(self, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Distance from ``o`` along the unit ``d`` to the last exit from the object (0 if none)."""
        raise NotImplementedError

    def material(self, p: torch.Tensor, part: torch.Tensor, normal: torch.Tensor) -> Material:
        """Attributes at the hit points ``p (n, 3)`` with part index and unit normal."""
        raise NotImplementedError


class SceneObject(Surface):
    """A union of convex primitives (:mod:`data_synth.geometry`) with a material.

    ``material(p, part, normal)`` gets the camera-frame hit points ``(n, 3)`` on this object, the
    index of the part hit ``(n,)`` and the geometric normal ``(n, 3)``. ``translucent`` objects
    get a ``thickness``.
    """

    def __init__(
        self,
        parts: list[Primitive],
        material: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], Material],
        translucent: bool = True,
    ) -> None:
        self.parts = parts
        self._material = material
        self.translucent = translucent

    def bound(self):
        return bounding_sphere(self.parts)

    def hit(self, o, d):
        return trace(self.parts, o, d)

    def occluded(self, o, d, eps):
        return occluded(self.parts, o, d, eps)

    def exit_distance(self, o, d):
        return exit_distance(self.parts, o, d)

    def material(self, p, part, normal):
        return self._material(p, part, normal)


class CulledUnion(SceneObject):
    """A :class:`SceneObject` whose rays meet each part only inside that part's bounding sphere.

    Same results as :class:`SceneObject`; for unions of many small parts (a face) most rays skip
    most parts. Every part must be bounded.
    """

    def __init__(self, parts, material, translucent: bool = True) -> None:
        super().__init__(parts, material, translucent)
        self._bounds = [p.bound() for p in parts]
        if any(b is None for b in self._bounds):
            raise ValueError("CulledUnion needs bounded parts")

    def _each(self, o: torch.Tensor, d: torch.Tensor, t_min: torch.Tensor | float, normals):
        """Per part: the selected rays ``sel`` and their ``(t_in, t_out, normal)``."""
        if o.ndim == 1:
            select = self._cone_select(o, d)
        elif d.shape[0] and bool((d == d[0]).all()):
            select = self._parallel_select(o, d[0], t_min)
        else:
            select = self._ray_select(o, d, t_min)
        for k, part in enumerate(self.parts):
            if not (normals or part.casts_shadow):
                continue
            sel = select(k)
            if sel.numel():  # one origin (3,) broadcasts in Primitive.interval
                yield k, sel, part.interval(o if o.ndim == 1 else o[sel], d[sel], normals)

    def _cone_select(self, origin: torch.Tensor, d: torch.Tensor):
        """Rays from one ``origin``: per part, those whose direction ``(x/z, y/z)`` falls in the
        box holding the projection of the part's bounding sphere (all rays if it is not wholly
        in front); rays sorted by ``x/z`` once, each part's range found by binary search."""
        dz = d[:, 2]
        px, py = d[:, 0] / dz, d[:, 1] / dz
        forward = bool((dz > 0).all())
        px_sorted, order = px.sort()
        py_sorted = py[order]
        everything = torch.arange(d.shape[0])

        def select(k):
            c, r = self._bounds[k]
            c = c - origin
            cz = float(c[2])
            if not forward or cz - r <= 0:
                return everything
            near, far = cz - r, cz + r
            lo = [(float(c[a]) - r) / (near if float(c[a]) - r < 0 else far) for a in (0, 1)]
            hi = [(float(c[a]) + r) / (far if float(c[a]) + r < 0 else near) for a in (0, 1)]
            ends = torch.tensor([lo[0], hi[0]], dtype=px_sorted.dtype)  # x range, then filter y
            a, b = torch.searchsorted(px_sorted, ends).tolist()
            yc = py_sorted[a:b]
            return order[a:b][(yc >= lo[1]) & (yc <= hi[1])]

        return select

    def _parallel_select(self, o: torch.Tensor, d: torch.Tensor, t_min):
        """Rays of one direction ``d`` (a directional light): per part, those whose origin
        projects, along ``d``, into the disc of the part's bounding sphere and that reach it
        beyond ``t_min``; origins sorted along one axis of the disc's plane once."""
        u = unit(d)
        e1 = unit(torch.linalg.cross(u, torch.tensor([1.0, 0.0, 0.0], dtype=d.dtype)))
        if float(e1.norm()) < 0.5 or abs(float(u[0])) > 0.9:
            e1 = unit(torch.linalg.cross(u, torch.tensor([0.0, 1.0, 0.0], dtype=d.dtype)))
        e2 = torch.linalg.cross(u, e1)
        basis = torch.stack([e1, e2, u])  # rows
        proj = (o @ basis.T).T.contiguous()  # (3, N): along e1, e2 and the ray
        a_sorted, order = proj[0].sort()
        b_sorted, s_sorted = proj[1][order], proj[2][order]
        t_min = torch.as_tensor(t_min, dtype=d.dtype).expand(o.shape[0]) * float(d.norm())
        t_sorted = t_min[order]

        def select(k):
            c, r = self._bounds[k]
            pc = (basis @ c.to(d.dtype)).tolist()
            ends = torch.tensor([pc[0] - r, pc[0] + r], dtype=a_sorted.dtype)
            lo, hi = torch.searchsorted(a_sorted, ends).tolist()
            da = a_sorted[lo:hi] - pc[0]
            db = b_sorted[lo:hi] - pc[1]
            near = torch.addcmul(da * da, db, db) <= r * r
            # the far side of the sphere along the ray lies beyond t_min
            near &= (pc[2] + r) - s_sorted[lo:hi] > t_sorted[lo:hi]
            return order[lo:hi][near]

        return select

    def _ray_select(self, o: torch.Tensor, d: torch.Tensor, t_min):
        """Rays with their own origins: per part, those meeting its bounding sphere beyond
        ``t_min`` (components taken once, so each test is a few contiguous operations)."""
        oc = o.T.contiguous()
        dc = d.T.contiguous()
        a = (dc * dc).sum(0)
        t_min = torch.as_tensor(t_min, dtype=d.dtype)

        def select(k):
            c, r = self._bounds[k]
            m = oc - c.to(d.dtype).view(3, 1)
            b = (m * dc).sum(0)
            cc = (m * m).sum(0) - r * r
            disc = b * b - a * cc
            t_far = (disc.clamp_min(0.0).sqrt() - b) / a
            return ((disc >= 0) & (t_far > t_min)).nonzero().squeeze(-1)

        return select

    def hit(self, o, d):
        n = d.shape[0]
        t = torch.full((n,), math.inf, dtype=d.dtype)
        normal = torch.zeros(n, 3, dtype=d.dtype)
        index = torch.full((n,), -1, dtype=torch.long)
        for k, sel, (t_in, t_out, nrm) in self._each(o, d, 0.0, True):
            better = (t_in <= t_out) & (t_in > 0) & (t_in < t[sel])
            s = sel[better]
            t[s], normal[s], index[s] = t_in[better], nrm[better], k
        return Hit(t, normal, index)

    def occluded(self, o, d, eps):
        out = torch.zeros(d.shape[0], dtype=torch.bool)
        eps = torch.as_tensor(eps, dtype=d.dtype).expand(d.shape[0])
        for _, sel, (t_in, t_out, _) in self._each(o, d, eps, False):
            out[sel] |= (t_in <= t_out) & (t_in > eps[sel])
        return out

    def exit_distance(self, o, d):
        out = torch.zeros(d.shape[0], dtype=d.dtype)
        for _, sel, (t_in, t_out, _) in self._each(o, d, 0.0, False):
            valid = (t_in <= t_out) & torch.isfinite(t_out)
            out[sel] = torch.maximum(out[sel], torch.where(valid, t_out, 0.0).clamp_min(0.0))
        return out


def backdrop(depth: float, *, casts_shadow: bool = True) -> SceneObject:
    """A grey camera-facing wall at ``depth`` mm, outside the SSS mask."""
    wall = HalfSpace([0.0, 0.0, depth], [0.0, 0.0, -1.0], casts_shadow=casts_shadow)
    return SceneObject([wall], constant_material(_BACKDROP_ALBEDO, 0.0), translucent=False)


_AXIS = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
_ORIGIN = torch.zeros(3, dtype=torch.float64)


def axis_depth(objects: Sequence[Surface]) -> float:
    """Depth (mm) of the nearest surface on the view axis (the focus of a scene).

    Raises:
        ValueError: if the axis meets none of ``objects``.
    """
    t = min(float(obj.hit(_ORIGIN, _AXIS).t[0]) for obj in objects)
    if not math.isfinite(t):
        raise ValueError("the view axis meets no surface: the scene has no focus point")
    return t


# ---------------------------------------------------------------- output assembly


def image(x: torch.Tensor, ctx: Ctx) -> torch.Tensor:
    """``(N,)`` or ``(N, C)`` row-major pixels -> ``(1, C, H, W)``."""
    if x.ndim == 1:
        x = x.unsqueeze(-1)
    return x.T.reshape(1, -1, ctx.height, ctx.width)


def gbuffer(ctx: Ctx, fov_y: float, light: torch.Tensor | None = None, **images) -> GBuffer:
    """Cast to ``ctx.dtype`` and keep only the requested optional fields."""
    out = {}
    for key, value in images.items():
        if value is None or (key in OPTIONAL_FIELDS and key not in ctx.want):
            continue
        out[key] = value.to(ctx.dtype).contiguous()
    if light is not None:
        out["light_dir"] = unit(light).reshape(1, 3).to(ctx.dtype)
    return GBuffer(fov_y=fov_y, **out)


def flat_plane(ctx: Ctx, fov_y: float, z: float, irradiance: torch.Tensor) -> GBuffer:
    """A camera-facing plane at depth ``z`` with painted irradiance ``(1, 1, H, W)``."""
    ctx.images_next()
    h, w = ctx.height, ctx.width
    depth = torch.full((1, 1, h, w), z, dtype=torch.float64)
    normal = torch.zeros(1, 3, h, w, dtype=torch.float64)
    normal[:, 2] = 1.0
    albedo = torch.tensor(SKIN_ALBEDO, dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, h, w)
    return gbuffer(
        ctx,
        fov_y,
        diffuse=irradiance.expand(1, 3, h, w),
        depth=depth,
        albedo=albedo,
        normal=normal,
        mask=torch.ones_like(depth),
    )


# ---------------------------------------------------------------- rendering


def _primary(ctx: Ctx, fov_y: float, objects: Sequence[Surface], bounds):
    """Nearest hit over ``objects`` for every pixel: ``t, object, normal, part, rays``."""
    rays = camera_rays(ctx.height, ctx.width, fov_y)
    npx = rays.shape[0]
    ts, ns, parts_hit = [], [], []
    for obj, b in zip(objects, bounds, strict=True):
        sel = None if b is None else sphere_mask(_ORIGIN, rays, b[0], b[1]).nonzero().squeeze(-1)
        t_k = torch.full((npx,), math.inf, dtype=torch.float64)
        n_k = torch.zeros(npx, 3, dtype=torch.float64)
        i_k = torch.full((npx,), -1, dtype=torch.long)
        if sel is None or sel.numel():
            hit = obj.hit(_ORIGIN, rays if sel is None else rays[sel])
            idx = slice(None) if sel is None else sel
            t_k[idx], n_k[idx], i_k[idx] = hit.t, hit.normal, hit.index
        ts.append(t_k)
        ns.append(n_k)
        parts_hit.append(i_k)
    t, obj_id, n, part_id = composite_nearest(
        torch.stack(ts), torch.stack(ns), torch.stack(parts_hit)
    )
    missed = int((obj_id < 0).sum())
    if missed:
        raise ValueError(
            f"the scene leaves {missed} pixels empty (no surface in front of the camera); "
            "reduce fov_y or the tilt / move the geometry"
        )
    return t, obj_id, n, part_id, rays


def _visible(objects, bounds, p, light, eps, todo) -> torch.Tensor:
    """``(N,)`` 1 where no object blocks ``light`` from ``p``; only rays in ``todo`` are cast."""
    blocked = torch.zeros(p.shape[0], dtype=torch.bool)
    cand = todo.nonzero().squeeze(-1)
    lights = light.expand_as(p)
    for obj, b in zip(objects, bounds, strict=True):
        sel = cand
        if b is not None and sel.numel():
            sel = sel[sphere_mask(p[sel], lights[sel], b[0], b[1], eps[sel])]
        if sel.numel():
            blocked[sel] |= obj.occluded(p[sel], lights[sel], eps[sel])
    return (~blocked).to(p.dtype)


def render(
    ctx: Ctx,
    fov_y: float,
    objects: Sequence[Surface],
    lights: Sequence[Light],
    ambient: float,
) -> GBuffer:
    """Trace ``objects`` and shade them with directional ``lights`` (module docstring).

    Args:
        ctx: image size, fields to build, dtype.
        fov_y: vertical field of view, radians.
        objects: the scene, camera frame (mm).
        lights: at least one; the first is stored as ``light_dir`` and defines ``thickness``.
        ambient: irradiance added everywhere, >= 0.
    """
    ctx.images_next()
    return render_labelled(ctx, fov_y, objects, lights, ambient)[0]


def render_labelled(
    ctx: Ctx,
    fov_y: float,
    objects: Sequence[Surface],
    lights: Sequence[Light],
    ambient: float,
) -> tuple[GBuffer, torch.Tensor]:
    """:func:`render` and the part label of each pixel ``(1, 1, H, W)`` long (the materials'
    ``labels``; 0 where a material gives none)."""
    ctx.images_next()
    bounds = [obj.bound() for obj in objects]
    t, obj_id, n, part_id, rays = _primary(ctx, fov_y, objects, bounds)
    npx = t.shape[0]
    p = t.unsqueeze(-1) * rays
    eps = 1e-7 * t + 1e-9  # mm; keeps a point from shadowing itself through rounding

    albedo = torch.zeros(npx, 3, dtype=t.dtype)
    mask = torch.zeros(npx, dtype=t.dtype)
    ks = torch.zeros(npx, dtype=t.dtype)
    shin = torch.ones(npx, dtype=t.dtype)
    thickness = torch.zeros(npx, dtype=t.dtype) if "thickness" in ctx.want else None
    first = unit(to_view(lights[0].direction))  # camera frame
    shading_n = n.clone()
    labels = torch.zeros(npx, dtype=torch.long)
    for k, obj in enumerate(objects):
        sel = (obj_id == k).nonzero().squeeze(-1)
        if not sel.numel():
            continue
        m = obj.material(p[sel], part_id[sel], n[sel])
        albedo[sel], mask[sel], ks[sel], shin[sel] = m.albedo, m.mask, m.ks, m.shininess
        if m.normal is not None:
            shading_n[sel] = m.normal
        if m.labels is not None:
            labels[sel] = m.labels
        if thickness is not None and obj.translucent:
            th = obj.exit_distance(p[sel], first.expand(sel.numel(), 3))
            thickness[sel] = torch.where(th > 1e-6 * (1.0 + t[sel]), th, 0.0)

    irr = torch.full((npx,), float(ambient), dtype=t.dtype)
    spec = torch.zeros(npx, dtype=t.dtype) if "specular" in ctx.want else None
    view = -unit(p)
    for light in lights:
        l_cam = unit(to_view(light.direction))
        cos = lambert(shading_n, l_cam)
        # shadow rays only where the light can matter; a point whose geometric normal faces
        # away is in its own shadow whatever its (normal-mapped) shading normal says
        faces = lambert(n, l_cam) > 0
        vis = _visible(objects, bounds, p, l_cam, eps, (cos > 0) & faces) * faces
        irr = irr + light.intensity * cos * vis  # Lambert n·l, directional light
        if spec is not None:
            spec = spec + light.intensity * ks * blinn_phong(shading_n, l_cam, view, shin) * vis

    h, w = ctx.height, ctx.width
    g = gbuffer(
        ctx,
        fov_y,
        lights[0].direction,
        diffuse=image(irr, ctx).expand(1, 3, h, w),
        depth=image(t, ctx),
        albedo=image(albedo.clamp(0.0, 1.0), ctx),
        specular=None if spec is None else image(spec, ctx).expand(1, 3, h, w),
        normal=image(to_view(shading_n), ctx),
        mask=image(mask, ctx),
        thickness=None if thickness is None else image(thickness, ctx),
    )
    return g, labels.view(1, 1, h, w)

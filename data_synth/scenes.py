"""Synthetic scenes: procedural G-buffers in millimetres (DESIGN §2, §3, §5).

Every scene is a builder registered in :data:`SCENES` and built by :func:`make_scene`. Shared
conventions:

- B = 1, square pixels, pinhole camera at the origin with vertical field of view ``fov_y``
  (radians, default 25°), linear depth in mm (DESIGN §2).
- ``diffuse`` is the irradiance of one white directional light: ``intensity · max(n·l, 0) · V +
  ambient`` (Lambert; ``V`` = 0 where another primitive blocks the light), the same in R, G, B.
  ``step_edge`` and ``light_dot`` paint their irradiance instead (a projected light pattern).
- Normals and ``light_dir`` (unit, *toward* the light) are in G-buffer view space: ``+z`` points
  toward the camera (see :mod:`data_synth.geometry`). A ``light_dir`` parameter uses the same
  convention and need not be normalised.
- ``specular`` is Blinn–Phong, ``ks · max(n·h, 0)^shininess · V``.
- ``thickness`` is the distance from the visible point along ``light_dir`` to where the light
  enters the object, as a translucent shadow map measures (001 §5.2); 0 on lit points of convex
  parts, on the background, and wherever the scene has no translucent object.
- Scenes whose pixel size is fixed in mm (``step_edge``, ``light_dot``, ``pores``) place the
  plane at ``z = pixel_mm · H / (2 tan(fov_y / 2))`` unless ``z`` is given; the others fix the
  geometry and let the pixel size follow the resolution.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import skimage.data
import torch

from data_synth.geometry import (
    Ellipsoid,
    EllipticSlab,
    HalfSpace,
    Primitive,
    blinn_phong,
    bounding_sphere,
    camera_rays,
    composite_nearest,
    exit_distance,
    lambert,
    mat_rows,
    normals_from_depth,
    occluded,
    rotation,
    sphere_mask,
    to_view,
    trace,
    unit,
)
from sssbench._checks import check_choice, check_int, check_scalar
from sssbench.gbuffer import GBuffer, view_positions

__all__ = [
    "DEFAULT_FOV_Y",
    "DEFAULT_RESOLUTION",
    "HEAD_HEIGHT_MM",
    "OPTIONAL_FIELDS",
    "SCENES",
    "SceneSpec",
    "make_scene",
]

#: optional G-buffer fields a scene may build (``diffuse`` and ``depth`` are always built)
OPTIONAL_FIELDS = ("albedo", "specular", "normal", "mask", "thickness")
DEFAULT_RESOLUTION = (256, 256)
DEFAULT_FOV_Y = math.radians(25.0)
#: chin-to-crown height of the procedural head
HEAD_HEIGHT_MM = 230.0
#: semi-axes of the head ellipsoid (width, height, depth), mm
HEAD_RADII = (75.0, HEAD_HEIGHT_MM / 2, 95.0)
#: head height / screen height for the distance presets
HEAD_FRAMING = {"close": 3.0, "mid": 0.8, "far": 0.15}

SKIN_ALBEDO = (0.78, 0.52, 0.42)
_BACKDROP_ALBEDO = (0.5, 0.5, 0.5)
_MAX_SIDE = 8192


# ---------------------------------------------------------------- registry and entry point


@dataclass(frozen=True)
class SceneSpec:
    """A registered scene.

    Attributes:
        name: registry key.
        builder: ``builder(ctx, **params) -> GBuffer``.
        fields: optional G-buffer fields the scene can build.
        defaults: parameter defaults (every accepted parameter appears here).
    """

    name: str
    builder: Callable[..., GBuffer]
    fields: frozenset[str]
    defaults: Mapping[str, object] = field(default_factory=dict)

    @property
    def doc(self) -> str:
        return self.builder.__doc__ or ""


@dataclass(frozen=True)
class _Ctx:
    height: int
    width: int
    gen: torch.Generator
    want: frozenset[str]
    dtype: torch.dtype


SCENES: dict[str, SceneSpec] = {}


def _register(name: str, fields: Iterable[str], **defaults: object):
    def deco(fn):
        SCENES[name] = SceneSpec(name, fn, frozenset(fields), MappingProxyType(dict(defaults)))
        return fn

    return deco


def make_scene(
    name: str,
    resolution: Sequence[int] = DEFAULT_RESOLUTION,
    seed: int = 0,
    *,
    fields: Iterable[str] | None = None,
    dtype: torch.dtype = torch.float32,
    **params: object,
) -> GBuffer:
    """Build a synthetic scene's G-buffer.

    Args:
        name: a key of :data:`SCENES`.
        resolution: ``(H, W)`` in pixels, each in [1, 8192].
        seed: seed of the ``torch.Generator`` used for the scene's randomness (same seed, same
            output; scenes without randomness ignore it).
        fields: optional fields to build, a subset of :data:`OPTIONAL_FIELDS`; ``None`` builds
            every field the scene has (``SCENES[name].fields``). Requested fields the scene does
            not have stay ``None`` (DESIGN §3), like the ones not requested.
        dtype: ``torch.float32`` or ``torch.float64`` (geometry is computed in float64).
        **params: scene parameters; see ``SCENES[name].defaults`` and the builder docstring.

    Returns:
        A validated :class:`~sssbench.gbuffer.GBuffer` with B = 1.

    Example:
        >>> g = make_scene("step_edge", (8, 8), fields=["mask"])
        >>> g.shape, g.albedo is None
        ((1, 8, 8), True)
    """
    if not isinstance(name, str) or name not in SCENES:
        raise ValueError(f"name must be one of {sorted(SCENES)}, got {name!r}")
    spec = SCENES[name]
    if (
        isinstance(resolution, (str, bytes))
        or not isinstance(resolution, Sequence)
        or len(resolution) != 2
    ):
        raise ValueError(f"resolution must be a pair (H, W) of integers, got {resolution!r}")
    h = check_int("resolution[0] (H)", resolution[0], 1, _MAX_SIDE)
    w = check_int("resolution[1] (W)", resolution[1], 1, _MAX_SIDE)
    seed = check_int("seed", seed, 0)
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    if fields is None:
        want = spec.fields
    else:
        if isinstance(fields, str):
            raise TypeError(
                f"fields must be a collection of field names, got the string {fields!r}"
            )
        requested = list(fields)
        for f in requested:
            check_choice("fields", f, OPTIONAL_FIELDS)
        want = frozenset(requested) & spec.fields
    unknown = sorted(set(params) - set(spec.defaults))
    if unknown:
        raise ValueError(
            f"unknown parameter(s) {unknown} for scene {name!r}; valid parameters are "
            f"{sorted(spec.defaults)}"
        )
    gen = torch.Generator().manual_seed(seed)
    merged = {**spec.defaults, **params}
    return spec.builder(_Ctx(h, w, gen, want, dtype), **merged)


# ---------------------------------------------------------------- parameter helpers


def _fov(value: object) -> float:
    return check_scalar("fov_y", value, 0.0, math.radians(170.0), low_inclusive=False)


def _positive(name: str, value: object) -> float:
    return check_scalar(name, value, 0.0, low_inclusive=False)


def _vec(name: str, value: object, n: int = 3, *, nonzero: bool = True) -> torch.Tensor:
    if isinstance(value, torch.Tensor):
        value = value.tolist()
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != n:
        raise ValueError(f"{name} must be a sequence of {n} real numbers, got {value!r}")
    out = torch.tensor(
        [check_scalar(f"{name}[{i}]", v) for i, v in enumerate(value)], dtype=torch.float64
    )
    if nonzero and float(out.norm()) == 0.0:
        raise ValueError(f"{name} must be a non-zero vector, got {value!r}")
    return out


def _f64(x: float) -> torch.Tensor:
    return torch.tensor(x, dtype=torch.float64)


def _plane_depth(ctx: _Ctx, fov_y: float, z: object, pixel_mm: object, default_px: float) -> float:
    """Depth of a camera-facing plane: ``z`` if given, else the one giving ``pixel_mm``."""
    if z is not None and pixel_mm is not None:
        raise ValueError(
            f"give either z or pixel_mm, not both (got z={z!r}, pixel_mm={pixel_mm!r})"
        )
    if z is not None:
        return _positive("z", z)
    px = default_px if pixel_mm is None else _positive("pixel_mm", pixel_mm)
    return px * ctx.height / (2.0 * math.tan(fov_y / 2.0))


# ---------------------------------------------------------------- output assembly


def _image(x: torch.Tensor, ctx: _Ctx) -> torch.Tensor:
    """``(N,)`` or ``(N, C)`` row-major pixels -> ``(1, C, H, W)``."""
    if x.ndim == 1:
        x = x.unsqueeze(-1)
    return x.T.reshape(1, -1, ctx.height, ctx.width)


def _gbuffer(ctx: _Ctx, fov_y: float, light: torch.Tensor | None = None, **images) -> GBuffer:
    """Cast to ``ctx.dtype`` and keep only the requested optional fields."""
    out = {}
    for key, value in images.items():
        if value is None or (key in OPTIONAL_FIELDS and key not in ctx.want):
            continue
        out[key] = value.to(ctx.dtype).contiguous()
    if light is not None:
        out["light_dir"] = unit(light).reshape(1, 3).to(ctx.dtype)
    return GBuffer(fov_y=fov_y, **out)


def _flat_plane(ctx: _Ctx, fov_y: float, z: float, irradiance: torch.Tensor) -> GBuffer:
    """A camera-facing plane at depth ``z`` with painted irradiance ``(1, 1, H, W)``."""
    h, w = ctx.height, ctx.width
    depth = torch.full((1, 1, h, w), z, dtype=torch.float64)
    normal = torch.zeros(1, 3, h, w, dtype=torch.float64)
    normal[:, 2] = 1.0
    albedo = torch.tensor(SKIN_ALBEDO, dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, h, w)
    return _gbuffer(
        ctx,
        fov_y,
        diffuse=irradiance.expand(1, 3, h, w),
        depth=depth,
        albedo=albedo,
        normal=normal,
        mask=torch.ones_like(depth),
    )


# ---------------------------------------------------------------- ray-traced scenes


@dataclass
class Material:
    """Per-point surface attributes, ``(n, 3)`` albedo and ``(n,)`` the rest."""

    albedo: torch.Tensor
    mask: torch.Tensor
    ks: torch.Tensor
    shininess: torch.Tensor


def _constant_material(albedo, mask: float, ks: float = 0.0, shininess: float = 1.0):
    def material(p: torch.Tensor, part: torch.Tensor) -> Material:
        n = p.shape[0]
        return Material(
            torch.tensor(albedo, dtype=p.dtype).expand(n, 3),
            torch.full((n,), mask, dtype=p.dtype),
            torch.full((n,), ks, dtype=p.dtype),
            torch.full((n,), shininess, dtype=p.dtype),
        )

    return material


@dataclass
class SceneObject:
    """One object: convex parts (unioned) and a material.

    ``material(p, part)`` gets the camera-frame hit points ``(n, 3)`` on this object and the
    index of the part hit ``(n,)``. ``translucent`` objects get a ``thickness``.
    """

    parts: list[Primitive]
    material: Callable[[torch.Tensor, torch.Tensor], Material]
    translucent: bool = True


def _backdrop(depth: float, *, casts_shadow: bool = True) -> SceneObject:
    """A grey camera-facing wall at ``depth`` mm, outside the SSS mask."""
    wall = HalfSpace([0.0, 0.0, depth], [0.0, 0.0, -1.0], casts_shadow=casts_shadow)
    return SceneObject([wall], _constant_material(_BACKDROP_ALBEDO, 0.0), translucent=False)


def _render(
    ctx: _Ctx,
    fov_y: float,
    objects: Sequence[SceneObject],
    light_view: torch.Tensor,
    intensity: float,
    ambient: float,
) -> GBuffer:
    """Ray-trace ``objects`` and shade them with one directional light (see module docstring).

    Each object is culled by its bounding sphere, traced, then composited by nearest depth.
    """
    rays = camera_rays(ctx.height, ctx.width, fov_y)
    npx = rays.shape[0]
    origin = torch.zeros(3, dtype=torch.float64)
    bounds = [bounding_sphere(obj.parts) for obj in objects]
    sels = [
        None if b is None else sphere_mask(origin, rays, b[0], b[1]).nonzero().squeeze(-1)
        for b in bounds
    ]

    # primary visibility: nearest entry over objects (each a union of convex parts)
    ts, ns, parts_hit = [], [], []
    for obj, sel in zip(objects, sels, strict=True):
        t_k = torch.full((npx,), math.inf, dtype=torch.float64)
        n_k = torch.zeros(npx, 3, dtype=torch.float64)
        i_k = torch.full((npx,), -1, dtype=torch.long)
        hit = trace(obj.parts, origin, rays if sel is None else rays[sel])
        idx = slice(None) if sel is None else sel
        t_k[idx], n_k[idx], i_k[idx] = hit.t, hit.normal, hit.index
        ts.append(t_k)
        ns.append(n_k)
        parts_hit.append(i_k)
    t, obj_id, n, part_id = composite_nearest(
        torch.stack(ts), torch.stack(ns), torch.stack(parts_hit)
    )
    del ts, ns, parts_hit
    missed = int((obj_id < 0).sum())
    if missed:
        raise ValueError(
            f"the scene leaves {missed} pixels empty (no surface in front of the camera); "
            "reduce fov_y or the tilt / move the geometry"
        )
    p = t.unsqueeze(-1) * rays
    light = unit(to_view(light_view))  # camera frame
    lights = light.expand_as(p)
    eps = 1e-7 * t + 1e-9  # mm; keeps a point from shadowing itself through rounding

    # shadow rays toward the light
    blocked = torch.zeros(npx, dtype=torch.bool)
    for obj, b in zip(objects, bounds, strict=True):
        if b is None:
            blocked |= occluded(obj.parts, p, lights, eps)
            continue
        sel = sphere_mask(p, lights, b[0], b[1], eps).nonzero().squeeze(-1)
        if sel.numel():
            blocked[sel] |= occluded(obj.parts, p[sel], lights[sel], eps[sel])
    vis = (~blocked).to(t.dtype)
    irr = intensity * lambert(n, light) * vis + ambient  # Lambert n·l, directional light

    albedo = torch.zeros(npx, 3, dtype=t.dtype)
    mask = torch.zeros(npx, dtype=t.dtype)
    ks = torch.zeros(npx, dtype=t.dtype)
    shin = torch.ones(npx, dtype=t.dtype)
    thickness = torch.zeros(npx, dtype=t.dtype) if "thickness" in ctx.want else None
    for k, obj in enumerate(objects):
        sel = (obj_id == k).nonzero().squeeze(-1)
        if not sel.numel():
            continue
        m = obj.material(p[sel], part_id[sel])
        albedo[sel], mask[sel], ks[sel], shin[sel] = m.albedo, m.mask, m.ks, m.shininess
        if thickness is not None and obj.translucent:
            th = exit_distance(obj.parts, p[sel], lights[sel])
            thickness[sel] = torch.where(th > 1e-6 * (1.0 + t[sel]), th, 0.0)

    specular = None
    if "specular" in ctx.want:
        lobe = blinn_phong(n, light, -unit(p), shin)
        specular = (intensity * ks * lobe * vis).unsqueeze(-1).expand(npx, 3)
    return _gbuffer(
        ctx,
        fov_y,
        light_view,
        diffuse=_image(irr, ctx).expand(1, 3, ctx.height, ctx.width),
        depth=_image(t, ctx),
        albedo=_image(albedo.clamp(0.0, 1.0), ctx),
        specular=None if specular is None else _image(specular, ctx),
        normal=_image(to_view(n), ctx),
        mask=_image(mask, ctx),
        thickness=None if thickness is None else _image(thickness, ctx),
    )


def _light_params(light_dir, intensity, ambient):
    return (
        unit(_vec("light_dir", light_dir)),
        check_scalar("intensity", intensity, 0.0),
        check_scalar("ambient", ambient, 0.0),
    )


# ---------------------------------------------------------------- flat-plane scenes


@_register(
    "step_edge",
    ("albedo", "normal", "mask"),
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    z=None,
    edge=None,
    low=0.1,
    high=1.0,
)
def step_edge(ctx: _Ctx, *, fov_y, pixel_mm, z, edge, low, high) -> GBuffer:
    """A camera-facing plane with a vertical shadow boundary (an analytic oracle).

    Geometry: the plane ``z = const`` (mm), normal ``(0, 0, 1)``, mask 1, skin albedo. Default
    ``z`` makes one pixel ``pixel_mm = 0.2`` mm (``z = 0.2 H / (2 tan(fov_y/2))``; 115.5 mm at
    H = 256 and 25°); give ``z`` *or* ``pixel_mm``.

    Irradiance (R = G = B): columns ``j < edge`` get ``low``, columns ``j >= edge`` get ``high``
    (default ``edge = W // 2``, an int in [0, W]). With ``p = 2 z tan(fov_y/2) / H`` mm the pixel
    size, column ``j``'s centre is at ``x_j = (j + 0.5 - W/2) p`` (``view_positions``), so the
    boundary is the line ``x = x_edge = (edge - W/2) p`` mm, halfway between the centres of
    columns ``edge - 1`` and ``edge``: ``E(x, y) = low + (high - low) H(x - x_edge)``.
    For the default ``edge = W // 2`` and even ``W`` it is ``x = 0``.
    """
    fov_y = _fov(fov_y)
    z = _plane_depth(ctx, fov_y, z, pixel_mm, 0.2)
    edge = ctx.width // 2 if edge is None else check_int("edge", edge, 0, ctx.width)
    low = check_scalar("low", low, 0.0)
    high = check_scalar("high", high, 0.0)
    cols = torch.arange(ctx.width)
    irr = torch.where(cols < edge, _f64(low), _f64(high))
    return _flat_plane(ctx, fov_y, z, irr.view(1, 1, 1, -1).expand(1, 1, ctx.height, ctx.width))


@_register(
    "light_dot",
    ("albedo", "normal", "mask"),
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    z=None,
    radius=1.0,
    center=(0.0, 0.0),
    low=0.05,
    high=1.0,
)
def light_dot(ctx: _Ctx, *, fov_y, pixel_mm, z, radius, center, low, high) -> GBuffer:
    """A small bright disc of light on a dim camera-facing plane (non-separable, high frequency).

    Same plane as ``step_edge`` but default ``pixel_mm = 0.1`` (57.7 mm at H = 256, 25°). A pixel
    gets ``high`` when its centre ``(x, y)`` (``view_positions``) satisfies
    ``(x - cx)^2 + (y - cy)^2 <= radius^2`` (mm; ``center = (cx, cy)``, default the image centre,
    ``radius`` default 1 mm, i.e. 20 pixels across by default), else ``low``. No anti-aliasing.
    """
    fov_y = _fov(fov_y)
    z = _plane_depth(ctx, fov_y, z, pixel_mm, 0.1)
    radius = _positive("radius", radius)
    c = _vec("center", center, 2, nonzero=False)
    low = check_scalar("low", low, 0.0)
    high = check_scalar("high", high, 0.0)
    depth = torch.full((1, 1, ctx.height, ctx.width), z, dtype=torch.float64)
    pos = view_positions(depth, fov_y)
    r2 = (pos[:, 0:1] - c[0]) ** 2 + (pos[:, 1:2] - c[1]) ** 2
    irr = torch.where(r2 <= radius * radius, _f64(high), _f64(low))
    return _flat_plane(ctx, fov_y, z, irr)


# ---------------------------------------------------------------- sphere


@_register(
    "sphere",
    OPTIONAL_FIELDS,
    fov_y=DEFAULT_FOV_Y,
    radius=70.0,
    distance=500.0,
    background=700.0,
    light_dir=(-0.5, 0.5, 0.7),
    intensity=1.0,
    ambient=0.03,
    ks=0.15,
    shininess=40.0,
)
def sphere(
    ctx: _Ctx,
    *,
    fov_y,
    radius,
    distance,
    background,
    light_dir,
    intensity,
    ambient,
    ks,
    shininess,
) -> GBuffer:
    """A lit skin-coloured sphere in front of a grey wall.

    The sphere (``radius`` mm, default 70) is centred on the view axis at depth ``distance``
    (default 500 mm); the wall is the plane ``z = background`` (default 700 mm, mask 0). Its
    silhouette is the circle of NDC radius ``tan(asin(radius/distance)) / tan(fov_y/2)``
    (81.7 px radius at H = 256). Mask 1 on the sphere. The default light (from upper left, in
    front) gives a Lambert terminator on the sphere and a cast shadow on the wall. Pixel size at
    the sphere's front: ``2 (distance - radius) tan(fov_y/2) / H`` (0.74 mm at H = 256).
    """
    fov_y = _fov(fov_y)
    radius = _positive("radius", radius)
    distance = check_scalar("distance", distance, radius, low_inclusive=False)
    background = check_scalar("background", background, distance + radius, low_inclusive=False)
    light, intensity, ambient = _light_params(light_dir, intensity, ambient)
    ks = check_scalar("ks", ks, 0.0)
    shininess = _positive("shininess", shininess)
    ball = SceneObject(
        [Ellipsoid([0.0, 0.0, distance], [radius] * 3)],
        _constant_material(SKIN_ALBEDO, 1.0, ks, shininess),
    )
    return _render(ctx, fov_y, [ball, _backdrop(background)], light, intensity, ambient)


# ---------------------------------------------------------------- heads


def _smooth_noise(gen: torch.Generator, waves: int = 12, wavelength=(15.0, 60.0)):
    """A smooth random field of 3D position (mm), values roughly in [-1, 1].

    A sum of ``waves`` plane waves with random directions, wavelengths and phases drawn from
    ``gen``: resolution independent, so the same seed gives the same surface at any resolution.
    """
    dirs = unit(torch.randn(waves, 3, generator=gen, dtype=torch.float64))
    lam = wavelength[0] + (wavelength[1] - wavelength[0]) * torch.rand(
        waves, generator=gen, dtype=torch.float64
    )
    phase = 2 * math.pi * torch.rand(waves, generator=gen, dtype=torch.float64)
    k = dirs * (2 * math.pi / lam).unsqueeze(-1)

    def field_(q: torch.Tensor) -> torch.Tensor:
        arg = q[:, 0:1] * k[:, 0] + q[:, 1:2] * k[:, 1] + q[:, 2:3] * k[:, 2] + phase
        return torch.sin(arg).sum(-1) * math.sqrt(2.0 / waves)

    return field_


def _in_ellipse(x, y, cx, cy, rx, ry):
    return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1.0


def head_object(center: Sequence[float], yaw: float, gen: torch.Generator) -> SceneObject:
    """The procedural head as a :class:`SceneObject` (shared by ``head*`` and ``crowd``).

    Head frame (mm, before the ``yaw`` turn in degrees about the vertical axis): ``x`` to the
    viewer's right, ``y`` up, ``z`` away from the face (the face looks toward ``-z``, at the
    camera when ``yaw = 0``), origin at ``center`` (camera frame).

    Parts: the head ellipsoid (semi-axes :data:`HEAD_RADII` = 75 × 115 × 95, 230 mm tall), a nose
    ellipsoid (26 × 48 × 48 mm, ~20 mm proud of the face) and two ears as 5 mm thick elliptic
    slabs (36 × 62 mm outline) on the sides, turned 20° out from the head.

    Material: skin albedo with smooth mottling (from ``gen``), red lips; eyes (sclera, iris),
    brows and hair have their own albedo and mask 0; skin and ears mask 1. Specular: skin
    ``ks = 0.12, s = 25``, eyes ``ks = 0.6, s = 300`` (wet), hair and brows ``ks = 0.05``.
    """
    c = torch.as_tensor(center, dtype=torch.float64)
    rot = rotation(yaw=yaw)
    rx, ry, rz = HEAD_RADII

    def place(q):
        return c + rot @ torch.tensor(q, dtype=torch.float64)

    parts: list[Primitive] = [
        Ellipsoid(c, HEAD_RADII, rot),
        Ellipsoid(place([0.0, -22.0, -90.0]), [13.0, 24.0, 24.0], rot),
    ]
    for side in (-1.0, 1.0):
        # slab local z (thickness) ~ along head x; turned 20° more so the back edge stands out
        ear_rot = rot @ rotation(yaw=side * (90.0 + 20.0))
        parts.append(EllipticSlab(place([side * 78.0, -10.0, 12.0]), [18.0, 31.0], 2.5, ear_rot))

    mottle = _smooth_noise(gen)
    skin = torch.tensor(SKIN_ALBEDO, dtype=torch.float64)

    def material(p: torch.Tensor, part: torch.Tensor) -> Material:
        q = mat_rows(rot.T, (p - c).T).T  # head frame
        x, y, z = q.unbind(-1)
        n = p.shape[0]
        albedo = skin * (1.0 + 0.08 * mottle(q)).unsqueeze(-1)
        mask = torch.ones(n, dtype=p.dtype)
        ks = torch.full((n,), 0.12, dtype=p.dtype)
        shin = torch.full((n,), 25.0, dtype=p.dtype)
        front = (z < -40.0) & (part == 0)
        lips = front & _in_ellipse(x, y, 0.0, -65.0, 22.0, 7.0)
        albedo[lips] = torch.tensor([0.70, 0.33, 0.33], dtype=p.dtype)
        hairline = 70.0 - 0.4 * (z + 90.0)
        dark = ((y > hairline) & (part == 0)) | (
            front
            & (_in_ellipse(x, y, -32.0, 15.0, 18.0, 4.0) | _in_ellipse(x, y, 32.0, 15.0, 18.0, 4.0))
        )
        albedo[dark] = torch.tensor([0.10, 0.07, 0.05], dtype=p.dtype)
        mask[dark] = 0.0
        ks[dark] = 0.05
        shin[dark] = 10.0
        for ex in (-32.0, 32.0):
            eye = front & _in_ellipse(x, y, ex, 0.0, 14.0, 7.0)
            iris = eye & _in_ellipse(x, y, ex, 0.0, 5.5, 5.5)
            albedo[eye] = torch.tensor([0.85, 0.82, 0.78], dtype=p.dtype)
            albedo[iris] = torch.tensor([0.25, 0.15, 0.08], dtype=p.dtype)
            mask[eye] = 0.0
            ks[eye] = 0.6
            shin[eye] = 300.0
        return Material(albedo, mask, ks, shin)

    return SceneObject(parts, material)


def _head_distance(distance: object, fov_y: float) -> float:
    """Camera-to-head-centre distance (mm) for a preset name or a number."""
    if isinstance(distance, str):
        check_choice("distance", distance, list(HEAD_FRAMING))
        screen = HEAD_HEIGHT_MM / HEAD_FRAMING[distance]  # screen height at the face, mm
        return screen / (2.0 * math.tan(fov_y / 2.0)) + HEAD_RADII[2]
    return check_scalar("distance", distance, 150.0, low_inclusive=False)


_HEAD_DEFAULTS = dict(
    fov_y=DEFAULT_FOV_Y,
    distance="mid",
    aim=None,
    yaw=0.0,
    light_dir=(-0.4, 0.35, 0.85),
    intensity=1.0,
    ambient=0.03,
)


def head(ctx: _Ctx, *, fov_y, distance, aim, yaw, light_dir, intensity, ambient) -> GBuffer:
    """A procedural head (see :func:`head_object`) in front of a grey wall 600 mm behind it.

    ``distance``: camera to head centre in mm (> 150), or a preset giving the head height as a
    multiple of the screen height at the face: ``"close"`` ≈ 3× (close-up on the cheek),
    ``"mid"`` ≈ 0.8×, ``"far"`` ≈ 0.15×. At 25° fov the head centre is then at 268 mm,
    743 mm and 3553 mm, and a pixel at the face (H = 256) is ≈ 0.30, 1.1 and 6.0 mm.
    ``aim``: ``"face"`` (the face centre on the view axis) or ``"cheek"`` (the right cheek on
    the axis); default ``"cheek"`` for ``"close"`` and ``"face"`` otherwise. ``yaw``: head turn
    in degrees about the vertical axis (positive turns the face toward the viewer's left).
    Mask covers skin (face, ears, neck-less head); eyes, brows, hair and wall are 0.
    Variants ``head_close``, ``head_mid``, ``head_far`` preset ``distance``.
    """
    fov_y = _fov(fov_y)
    light, intensity, ambient = _light_params(light_dir, intensity, ambient)
    preset = distance if isinstance(distance, str) else None
    dist = _head_distance(distance, fov_y)
    yaw = check_scalar("yaw", yaw, -180.0, 180.0)
    if aim is None:
        aim = "cheek" if preset == "close" else "face"
    check_choice("aim", aim, ["face", "cheek"])
    offset = torch.tensor([-40.0, 20.0, 0.0]) if aim == "cheek" else torch.zeros(3)
    center = offset.to(torch.float64) + torch.tensor([0.0, 0.0, dist], dtype=torch.float64)
    obj = head_object(center, yaw, ctx.gen)
    return _render(ctx, fov_y, [obj, _backdrop(dist + 600.0)], light, intensity, ambient)


_HEAD_FIELDS = OPTIONAL_FIELDS
_register("head", _HEAD_FIELDS, **_HEAD_DEFAULTS)(head)
for _preset in HEAD_FRAMING:
    SCENES[f"head_{_preset}"] = SceneSpec(
        f"head_{_preset}",
        head,
        frozenset(_HEAD_FIELDS),
        MappingProxyType({**_HEAD_DEFAULTS, "distance": _preset}),
    )


@_register(
    "crowd",
    OPTIONAL_FIELDS,
    fov_y=DEFAULT_FOV_Y,
    n_heads=5,
    near=800.0,
    far=4000.0,
    light_dir=(-0.4, 0.35, 0.85),
    intensity=1.0,
    ambient=0.03,
)
def crowd(ctx: _Ctx, *, fov_y, n_heads, near, far, light_dir, intensity, ambient) -> GBuffer:
    """Several heads (:func:`head_object`) at different depths in front of a wall.

    Head centres are at depths evenly spaced from ``near`` to ``far`` (mm; at least 300 mm
    apart, jittered by ±10 % of the spacing, so heads never interpenetrate), at shuffled lateral
    slots across the view, with random yaw in ±35° and each its own skin mottling — all from the
    seed. The wall is 800 mm behind ``far``. Heads are composited by nearest depth; nearer heads
    cast shadows on farther ones and on the wall where the light allows.
    """
    fov_y = _fov(fov_y)
    light, intensity, ambient = _light_params(light_dir, intensity, ambient)
    n_heads = check_int("n_heads", n_heads, 1, 20)
    near = check_scalar("near", near, 300.0)
    far = check_scalar("far", far, near)
    spacing = (far - near) / max(n_heads - 1, 1)
    if n_heads > 1 and spacing < 300.0:
        raise ValueError(
            f"far - near must leave >= 300 mm between the {n_heads} heads, got "
            f"near={near}, far={far} ({spacing:.0f} mm apart)"
        )
    g = ctx.gen
    tan = math.tan(fov_y / 2.0)
    aspect = ctx.width / ctx.height
    # lateral slots spread across the view, shuffled, so that far heads are not all hidden
    slots = torch.linspace(-0.7, 0.7, n_heads, dtype=torch.float64) if n_heads > 1 else [0.0]
    order = torch.randperm(n_heads, generator=g).tolist()
    objects = []
    for i in range(n_heads):
        u = torch.rand(4, generator=g, dtype=torch.float64).tolist()
        z = near + i * spacing + (u[0] - 0.5) * 0.2 * spacing * (n_heads > 1)
        x = (float(slots[order[i]]) + 0.1 * (u[1] - 0.5)) * z * tan * aspect
        y = (2 * u[2] - 1) * 0.3 * z * tan
        objects.append(head_object([x, y, z], 70.0 * (u[3] - 0.5), g))
    objects.append(_backdrop(far + 800.0))
    return _render(ctx, fov_y, objects, light, intensity, ambient)


# ---------------------------------------------------------------- skin details


@_register(
    "pores",
    ("albedo", "specular", "normal", "mask"),
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    z=None,
    texel_mm=0.05,
    pore_depth=0.03,
    light_dir=(0.75, 0.25, 0.6),
    intensity=1.0,
    ambient=0.03,
    ks=0.12,
    shininess=25.0,
)
def pores(
    ctx: _Ctx,
    *,
    fov_y,
    pixel_mm,
    z,
    texel_mm,
    pore_depth,
    light_dir,
    intensity,
    ambient,
    ks,
    shininess,
) -> GBuffer:
    """A close-up skin patch whose relief comes from a real photograph.

    Texture: ``skimage.data.gravel()`` (512², bundled with scikit-image, no download), tiled,
    one texel = ``texel_mm`` (0.05 mm), randomly shifted and turned by a multiple of 90° per
    seed. Height ``h = pore_depth · (g - mean) / std`` mm (bilinear at each pixel centre's
    ``(x, y)`` on the base plane); depth ``z - h`` (the plane at ``z``, default giving
    ``pixel_mm = 0.05``: 28.9 mm at H = 256, 25°). Normals from the depth map
    (:func:`~data_synth.geometry.normals_from_depth`), so the grazing default light gives
    pore-scale Lambert shading; no cast shadows at pore scale. Mask 1; albedo skin, slightly
    darker in the crevices; Blinn–Phong specular.
    """
    fov_y = _fov(fov_y)
    z = _plane_depth(ctx, fov_y, z, pixel_mm, 0.05)
    texel = _positive("texel_mm", texel_mm)
    amp = check_scalar("pore_depth", pore_depth, 0.0)
    if amp >= 0.5 * z:
        raise ValueError(f"pore_depth must be < z / 2 = {0.5 * z:g} mm, got {amp:g}")
    light, intensity, ambient = _light_params(light_dir, intensity, ambient)
    ks = check_scalar("ks", ks, 0.0)
    shininess = _positive("shininess", shininess)

    tex = torch.from_numpy(skimage.data.gravel()).to(torch.float64)
    turns = int(torch.randint(4, (1,), generator=ctx.gen))
    tex = torch.rot90(tex, turns)
    tex = (tex - tex.mean()) / tex.std()
    shift = torch.rand(2, generator=ctx.gen, dtype=torch.float64) * torch.tensor(tex.shape)
    base = torch.full((1, 1, ctx.height, ctx.width), z, dtype=torch.float64)
    pos = view_positions(base, fov_y)[0]
    g = _bilinear_wrap(tex, -pos[1] / texel + shift[0], pos[0] / texel + shift[1])
    depth = (base - amp * g).clamp_min(1e-3 * z)
    normal = normals_from_depth(depth, fov_y)

    n = to_view(normal[0].reshape(3, -1).T)  # camera frame, (N, 3)
    lcam = unit(to_view(light))
    irr = intensity * lambert(n, lcam) + ambient
    skin = torch.tensor(SKIN_ALBEDO, dtype=torch.float64).view(1, 3, 1, 1)
    albedo = skin * (1.0 + 0.06 * g.clamp(-2.0, 2.0)).view(1, 1, ctx.height, ctx.width)
    specular = None
    if "specular" in ctx.want:
        p = view_positions(depth, fov_y)[0].reshape(3, -1).T
        spec = intensity * ks * blinn_phong(n, lcam, -unit(p), shininess)
        specular = _image(spec, ctx).expand(1, 3, ctx.height, ctx.width)
    return _gbuffer(
        ctx,
        fov_y,
        light,
        diffuse=_image(irr, ctx).expand(1, 3, ctx.height, ctx.width),
        depth=depth,
        albedo=albedo.clamp(0.0, 1.0),
        specular=specular,
        normal=normal,
        mask=torch.ones_like(depth),
    )


def _bilinear_wrap(tex: torch.Tensor, r: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of ``tex (h, w)`` at fractional texel (row, col), tiling the texture."""
    h, w = tex.shape
    r0, c0 = r.floor(), c.floor()
    fr, fc = r - r0, c - c0
    r0, c0 = r0.long() % h, c0.long() % w
    r1, c1 = (r0 + 1) % h, (c0 + 1) % w
    top = tex[r0, c0] * (1 - fc) + tex[r0, c1] * fc
    bottom = tex[r1, c0] * (1 - fc) + tex[r1, c1] * fc
    return top * (1 - fr) + bottom * fr


@_register(
    "halo",
    OPTIONAL_FIELDS,
    fov_y=DEFAULT_FOV_Y,
    distance=250.0,
    tilt=45.0,
    protrusion=20.0,
    light_dir=(0.35, 0.15, 0.92),
    intensity=1.0,
    ambient=0.03,
)
def halo(ctx: _Ctx, *, fov_y, distance, tilt, protrusion, light_dir, intensity, ambient) -> GBuffer:
    """A nose-like bump on a cheek seen obliquely: a depth discontinuity over skin.

    The cheek is the plane through ``(0, 0, distance)`` (mm, default 250) turned by ``tilt``
    degrees (default 45) about the vertical axis, its normal toward the viewer's left; it fills
    the view (``tilt`` up to ~75° at 25° fov). The nose is an ellipsoid (semi-axes 14 × 24 mm in
    the cheek plane, 24 mm along its normal) standing ``protrusion`` mm (default 20) proud of
    the cheek at the axis point. Seen from the camera, its left silhouette lies over cheek
    ~30 mm deeper. The default light (upper right, in front) lights the nose's front and right
    (irradiance rising from ambient at the silhouette to ~0.6 within ~2 mm) and the nose casts
    its shadow onto the cheek beyond the silhouette (ambient only for tens of mm): a bright bump
    over a dark cheek behind it, with the terminator on the nose's flank at the silhouette,
    where screen-space blurs bleed (halos). All skin: mask 1.
    """
    fov_y = _fov(fov_y)
    distance = _positive("distance", distance)
    tilt = check_scalar("tilt", tilt, 0.0, 80.0)
    protrusion = check_scalar("protrusion", protrusion, 0.0, 48.0)
    light, intensity, ambient = _light_params(light_dir, intensity, ambient)
    rot = rotation(yaw=tilt)
    normal = rot @ torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    q = torch.tensor([0.0, 0.0, distance], dtype=torch.float64)
    nose_r = 24.0
    nose = Ellipsoid(q + normal * (protrusion - nose_r), [14.0, 24.0, nose_r], rot)
    face = SceneObject(
        [HalfSpace(q, normal), nose], _constant_material(SKIN_ALBEDO, 1.0, 0.12, 25.0)
    )
    return _render(ctx, fov_y, [face], light, intensity, ambient)


@_register(
    "backlit_ear",
    OPTIONAL_FIELDS,
    fov_y=DEFAULT_FOV_Y,
    distance=200.0,
    size=(34.0, 60.0),
    thickness=4.0,
    turn=0.0,
    light_dir=(0.25, 0.3, -0.92),
    intensity=1.0,
    ambient=0.05,
)
def backlit_ear(
    ctx: _Ctx, *, fov_y, distance, size, thickness, turn, light_dir, intensity, ambient
) -> GBuffer:
    """A thin ear-like slab lit from behind, for translucency.

    The slab is an elliptic slab (outline ``size = (width, height)`` mm, default 34 × 60;
    ``thickness`` mm, default 4, constant) centred on the view axis at ``distance`` mm
    (default 200; ≈ 0.35 mm per pixel at H = 256), facing the camera, turned ``turn`` degrees
    about the vertical axis. The default ``light_dir`` points away from the camera side
    (``z < 0``): the face toward the camera is unlit (``diffuse = ambient``) except the rim,
    and ``thickness`` on the front face is the chord along the light,
    ``thickness / |l_z|`` (slab frame) where the light ray leaves through the back face, less
    near the rim. A grey wall 400 mm behind has mask 0 and thickness 0; it stands for distant
    surroundings and does not block the back light. Mask 1 on the slab.
    """
    fov_y = _fov(fov_y)
    distance = _positive("distance", distance)
    w, h = (float(v) for v in _vec("size", size, 2))
    if w <= 0 or h <= 0:
        raise ValueError(f"size must be two positive lengths (width, height) in mm, got {size!r}")
    thickness = _positive("thickness", thickness)
    if distance <= thickness:
        raise ValueError(f"distance must exceed thickness ({thickness:g} mm), got {distance:g}")
    turn = check_scalar("turn", turn, -80.0, 80.0)
    light, intensity, ambient = _light_params(light_dir, intensity, ambient)
    ear = SceneObject(
        [EllipticSlab([0.0, 0.0, distance], [w / 2, h / 2], thickness / 2, rotation(yaw=turn))],
        _constant_material(SKIN_ALBEDO, 1.0, 0.12, 25.0),
    )
    objects = [ear, _backdrop(distance + 400.0, casts_shadow=False)]
    return _render(ctx, fov_y, objects, light, intensity, ambient)

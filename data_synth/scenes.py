"""The scene catalogue: :data:`SCENES`, :func:`make_scene` and the builders (DESIGN §2, §3, §5).

One module because it is the catalogue: each builder is a short function registered next to
its defaults and documented scale; splitting it would scatter the registry.

Every scene is a builder registered in :data:`SCENES` and built by :func:`make_scene`. Shared
conventions:

- B = 1, square pixels, pinhole camera at the origin with vertical field of view ``fov_y``
  (radians, default 25°), linear depth in mm (DESIGN §2).
- **Scale** (:mod:`data_synth.scale`): a scene's *focus* is the surface point on the view axis;
  ``pixel_mm`` is the skin footprint of one pixel there, independent of the resolution (the
  camera is placed at ``z_f = pixel_mm · H / (2 tan(fov_y/2))`` from the focus, so a larger image
  shows more, at the same mm per pixel). A name of :data:`~data_synth.scale.SCALES` is accepted
  too. Scale of each scene (default ``pixel_mm``): ``step_edge`` 0.2, ``light_dot`` 0.1,
  ``pores`` 0.05, ``face`` 0.3 (portrait), ``head`` / ``head_mid`` 1.0 (medium),
  ``head_closeup`` 0.6 (the head close-up: cheek, nose and eye), ``head_cheek`` 0.3 (a smooth
  cheek at small resolutions), ``head_far`` 6.0, ``crowd`` 3.0 (far). The analytic oracles
  ``sphere``, ``halo`` and ``backlit_ear`` keep a fixed object at a fixed ``distance`` by default
  (the whole object in view at any resolution, which their tests need; scale follows the
  resolution) and take ``pixel_mm`` to be built at a physical scale instead.
- Lighting, shading and ``thickness``: :mod:`data_synth.render` (Lambert + Blinn–Phong,
  directional lights with cast shadows; ``thickness`` toward the first light, 001 §5.2).
  ``step_edge`` and ``light_dot`` paint their irradiance instead (a projected light pattern).
- Checks first, images after: a builder checks every parameter before its first ``(H, W)``
  image work, which starts in :func:`~data_synth.render.render`,
  :func:`~data_synth.render.render_labelled`, :func:`~data_synth.render.flat_plane` or at an
  explicit ``ctx.images_next()``; :func:`check_scene` stops the builder there (the app's check
  of every job's scene parameters before its first run).
- Normals and ``light_dir`` (unit, *toward* the light) are in G-buffer view space: ``+z`` points
  toward the camera. A ``light_dir`` parameter uses the same convention and need not be unit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType

import torch

from data_synth import face as face_model
from data_synth.geometry import (
    Ellipsoid,
    EllipticSlab,
    HalfSpace,
    blinn_phong,
    lambert,
    normals_from_depth,
    rotation,
    to_view,
    unit,
)
from data_synth.head import HEAD_RADII, head_object
from data_synth.render import (
    OPTIONAL_FIELDS,
    SKIN_ALBEDO,
    Ctx,
    Light,
    ParamsChecked,
    SceneObject,
    Surface,
    axis_depth,
    backdrop,
    constant_material,
    flat_plane,
    gbuffer,
    image,
    render,
    render_labelled,
)
from data_synth.scale import focus_depth, resolve_pixel_mm
from data_synth.textures import bilinear_wrap, texture
from sssbench._checks import check_choice, check_int, check_scalar, check_seed
from sssbench.gbuffer import GBuffer, view_positions

__all__ = [
    "DEFAULT_FOV_Y",
    "DEFAULT_RESOLUTION",
    "FaceBuild",
    "HEAD_PIXEL_MM",
    "RETIRED_SCENES",
    "SCENES",
    "SceneSpec",
    "check_scene",
    "face_parts",
    "make_scene",
]

DEFAULT_RESOLUTION = (256, 256)
DEFAULT_FOV_Y = math.radians(25.0)
#: mm per pixel at the face of the head presets (``head_<preset>``, ``distance="<preset>"``):
#: close = a portrait (SSS clearly visible), mid = a medium shot, far = a distant figure where
#: every skin Gaussian (σ ≤ 2.7 mm) is below half a pixel. At H = 256 these are the framings the
#: presets had when they were fractions of the screen (head 3×, 0.8×, 0.15× the screen height).
HEAD_PIXEL_MM = {"close": 0.3, "mid": 1.0, "far": 6.0}
#: the head scenes at a fixed scale, ``name: (pixel_mm, aim)``. ``head_closeup`` is the head
#: close-up the name ``head_close`` meant until 0d65624 (a head framed 268 mm from the camera,
#: about 0.6 mm/px at 128², the cheek on the axis with nose and eye in frame: SSS plainly
#: visible at 128² and 256²; at 64² the frame holds only the cheek); ``head_cheek`` is what
#: ``head_close`` meant after it (0.3 mm/px on the cheek: a smooth cheek where SSS is not
#: visible at 64² and 128², visible from 256²). Measured in docs/error_budget.md, tested.
HEAD_SCENES = {
    "head_closeup": (0.6, "cheek"),
    "head_cheek": (HEAD_PIXEL_MM["close"], "cheek"),
    "head_mid": (HEAD_PIXEL_MM["mid"], None),
    "head_far": (HEAD_PIXEL_MM["far"], None),
}
#: scene names whose content changed, refused (by :func:`make_scene` and the app) with the
#: names that now hold each of their meanings: a name never silently means something else
RETIRED_SCENES = MappingProxyType(
    {
        "head_close": (
            "scene 'head_close' is retired because its content changed: until 0d65624 "
            "(2026-11-30) it was a head close-up framed 268 mm from the camera (about 0.6 mm/px "
            "at 128², SSS plainly visible), then a smooth cheek at 0.3 mm/px (SSS not visible at "
            "128²). Use 'head_closeup' for the close-up (0.6 mm/px) or 'head_cheek' for the "
            "smooth cheek (0.3 mm/px)"
        ),
    }
)
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
        pixel_mm: the scale built when no scale parameter is given: mm per pixel at the focus
            (module docstring), or ``None`` for the oracles framed by a fixed ``distance``.
    """

    name: str
    builder: Callable[..., GBuffer]
    fields: frozenset[str]
    defaults: Mapping[str, object] = field(default_factory=dict)
    pixel_mm: float | None = None

    @property
    def doc(self) -> str:
        return self.builder.__doc__ or ""


SCENES: dict[str, SceneSpec] = {}


def _register(name: str, fields: Iterable[str], scale: float | None, **defaults: object):
    def deco(fn):
        SCENES[name] = SceneSpec(
            name, fn, frozenset(fields), MappingProxyType(dict(defaults)), scale
        )
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
            ``pixel_mm`` (mm per pixel at the focus, or a name of ``SCALES``) sets the scale.

    Returns:
        A validated :class:`~sssbench.gbuffer.GBuffer` with B = 1.

    Example:
        >>> g = make_scene("step_edge", (8, 8), fields=["mask"])
        >>> g.shape, g.albedo is None
        ((1, 8, 8), True)
    """
    spec, ctx = _context(name, resolution, seed, fields, dtype, params)
    return spec.builder(ctx, **{**spec.defaults, **params})


def check_scene(
    name: str,
    resolution: Sequence[int] = DEFAULT_RESOLUTION,
    seed: int = 0,
    *,
    fields: Iterable[str] | None = None,
    dtype: torch.dtype = torch.float32,
    **params: object,
) -> bool:
    """Check :func:`make_scene`'s arguments without building an image (a run's pre-check).

    The scene's own builder runs exactly as :func:`make_scene` runs it, with a context that
    stops it right before its first image computation (:meth:`~data_synth.render.Ctx.
    images_next`): every parameter check of the build runs, and only those — the check and the
    build share one set of rules. What only the images can show (e.g. geometry that leaves
    pixels empty) is found by the build.

    Returns:
        ``True`` when the builder stopped before its first image (the usual case), ``False``
        when it built the whole scene (a builder that never calls ``images_next``).

    Raises:
        ValueError, TypeError: as :func:`make_scene` would, naming the parameter.

    Example:
        >>> check_scene("step_edge", (4096, 4096), pixel_mm=0.1)
        True
    """
    spec, ctx = _context(name, resolution, seed, fields, dtype, params)
    try:
        spec.builder(replace(ctx, check_only=True), **{**spec.defaults, **params})
    except ParamsChecked:
        return True
    return False


def _context(name, resolution, seed, fields, dtype, params) -> tuple[SceneSpec, Ctx]:
    """Check :func:`make_scene`'s arguments; the scene's spec and the builder context."""
    if isinstance(name, str) and name in RETIRED_SCENES:
        raise ValueError(RETIRED_SCENES[name])
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
    seed = check_seed("seed", seed)
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
    return spec, Ctx(h, w, gen, want, dtype)


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


def _light(light_dir, intensity, name: str = "light_dir", iname: str = "intensity") -> Light:
    return Light(unit(_vec(name, light_dir)), check_scalar(iname, intensity, 0.0))


def _ambient(value: object) -> float:
    return check_scalar("ambient", value, 0.0)


def _one_of(a: str, va: object, b: str, vb: object) -> None:
    if va is not None and vb is not None:
        raise ValueError(f"give either {a} or {b}, not both (got {a}={va!r}, {b}={vb!r})")


def _plane_depth(ctx: Ctx, fov_y: float, z: object, pixel_mm: object, default: float) -> float:
    """Depth of a camera-facing plane: ``z`` if given, else the one giving ``pixel_mm``."""
    _one_of("z", z, "pixel_mm", pixel_mm)
    if z is not None:
        return _positive("z", z)
    px = default if pixel_mm is None else resolve_pixel_mm(pixel_mm)
    return focus_depth(px, ctx.height, fov_y)


def _at_scale(
    ctx: Ctx,
    fov_y: float,
    pixel_mm: object,
    nominal: float,
    build: Callable[[float], tuple[list[Surface], list[Surface]]],
) -> list[Surface]:
    """Objects ``build(dist)`` moved along the view axis so the focus is at ``pixel_mm`` scale.

    ``build(dist)`` returns ``(objects, focus_objects)``, every position offset by ``dist`` along
    the axis; ``pixel_mm = None`` keeps ``dist = nominal``. Otherwise the axis hit on
    ``focus_objects`` at ``nominal`` is moved to :func:`~data_synth.scale.focus_depth`.
    """
    objects, focus = build(nominal)
    if pixel_mm is None:
        return objects
    z_f = focus_depth(resolve_pixel_mm(pixel_mm), ctx.height, fov_y)
    return build(nominal + z_f - axis_depth(focus))[0]


# ---------------------------------------------------------------- flat-plane scenes


@_register(
    "step_edge",
    ("albedo", "normal", "mask"),
    0.2,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    z=None,
    edge=None,
    low=0.1,
    high=1.0,
)
def step_edge(ctx: Ctx, *, fov_y, pixel_mm, z, edge, low, high) -> GBuffer:
    """A camera-facing plane with a vertical shadow boundary (an analytic oracle).

    Scale: ``pixel_mm = 0.2`` mm per pixel (``z = 0.2 H / (2 tan(fov_y/2))``; 115.5 mm at
    H = 256 and 25°); or give the plane's depth ``z`` instead (then ``pixel_mm`` is ignored).
    Geometry: the plane ``z = const`` (mm), normal ``(0, 0, 1)``, mask 1, skin albedo.

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
    ctx.images_next()
    cols = torch.arange(ctx.width)
    irr = torch.where(cols < edge, _f64(low), _f64(high))
    return flat_plane(ctx, fov_y, z, irr.view(1, 1, 1, -1).expand(1, 1, ctx.height, ctx.width))


@_register(
    "light_dot",
    ("albedo", "normal", "mask"),
    0.1,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    z=None,
    radius=1.0,
    center=(0.0, 0.0),
    low=0.05,
    high=1.0,
)
def light_dot(ctx: Ctx, *, fov_y, pixel_mm, z, radius, center, low, high) -> GBuffer:
    """A small bright disc of light on a dim camera-facing plane (non-separable, high frequency).

    Same plane as ``step_edge``; scale ``pixel_mm = 0.1`` (57.7 mm at H = 256, 25°) unless ``z``
    is given. A pixel gets ``high`` when its centre ``(x, y)`` (``view_positions``) satisfies
    ``(x - cx)^2 + (y - cy)^2 <= radius^2`` (mm; ``center = (cx, cy)``, default the image centre,
    ``radius`` default 1 mm, i.e. 20 pixels across by default), else ``low``. No anti-aliasing.
    """
    fov_y = _fov(fov_y)
    z = _plane_depth(ctx, fov_y, z, pixel_mm, 0.1)
    radius = _positive("radius", radius)
    c = _vec("center", center, 2, nonzero=False)
    low = check_scalar("low", low, 0.0)
    high = check_scalar("high", high, 0.0)
    ctx.images_next()
    depth = torch.full((1, 1, ctx.height, ctx.width), z, dtype=torch.float64)
    pos = view_positions(depth, fov_y)
    r2 = (pos[:, 0:1] - c[0]) ** 2 + (pos[:, 1:2] - c[1]) ** 2
    irr = torch.where(r2 <= radius * radius, _f64(high), _f64(low))
    return flat_plane(ctx, fov_y, z, irr)


# ---------------------------------------------------------------- sphere


@_register(
    "sphere",
    OPTIONAL_FIELDS,
    None,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    radius=70.0,
    distance=None,
    background=None,
    light_dir=(-0.5, 0.5, 0.7),
    intensity=1.0,
    ambient=0.03,
    ks=0.15,
    shininess=40.0,
)
def sphere(
    ctx: Ctx,
    *,
    fov_y,
    pixel_mm,
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
    (default 500 mm); the wall is the plane ``z = background`` (default ``distance + 200``,
    mask 0). Scale: an oracle framing by default (the whole sphere in view; its silhouette is the
    circle of NDC radius ``tan(asin(radius/distance)) / tan(fov_y/2)``, 81.7 px radius at H = 256,
    and a pixel at the sphere's front is ``2 (distance - radius) tan(fov_y/2) / H``, 0.74 mm at
    H = 256); give ``pixel_mm`` instead of ``distance`` to put the front (the focus) at that scale.
    Mask 1 on the sphere. The default light (from upper left, in front) gives a Lambert
    terminator on the sphere and a cast shadow on the wall.
    """
    fov_y = _fov(fov_y)
    _one_of("distance", distance, "pixel_mm", pixel_mm)
    radius = _positive("radius", radius)
    if distance is not None:
        distance = check_scalar("distance", distance, radius, low_inclusive=False)
    light = _light(light_dir, intensity)
    ks = check_scalar("ks", ks, 0.0)
    shininess = _positive("shininess", shininess)
    if background is not None and pixel_mm is not None:
        raise ValueError("background is a depth; give it with distance, not with pixel_mm")
    material = constant_material(SKIN_ALBEDO, 1.0, ks, shininess)

    def build(dist):
        ball = SceneObject([Ellipsoid([0.0, 0.0, dist], [radius] * 3)], material)
        wall = dist + 200.0 if background is None else background
        return [ball, backdrop(wall)], [ball]

    if background is not None:
        check_scalar("background", background, (distance or 500.0) + radius, low_inclusive=False)
    nominal = 500.0 if distance is None else distance
    objects = _at_scale(ctx, fov_y, pixel_mm, nominal, build)
    return render(ctx, fov_y, objects, [light], _ambient(ambient))


# ---------------------------------------------------------------- heads


def _head_scale(distance: object, pixel_mm: object) -> tuple[str | None, float | None, object]:
    """``(preset, camera-to-head-centre distance, pixel_mm)`` from the two scale parameters."""
    _one_of("distance", distance, "pixel_mm", pixel_mm)
    if isinstance(distance, str):
        check_choice("distance", distance, list(HEAD_PIXEL_MM))
        return distance, None, HEAD_PIXEL_MM[distance]
    if distance is not None:
        return None, check_scalar("distance", distance, 150.0, low_inclusive=False), None
    return None, None, HEAD_PIXEL_MM["mid"] if pixel_mm is None else pixel_mm


_HEAD_DEFAULTS = dict(
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    distance=None,
    aim=None,
    yaw=0.0,
    light_dir=(-0.4, 0.35, 0.85),
    intensity=1.0,
    ambient=0.03,
)


def head(ctx: Ctx, *, fov_y, pixel_mm, distance, aim, yaw, light_dir, intensity, ambient):
    """A procedural head (:func:`~data_synth.head.head_object`) before a wall 600 mm behind it.

    Scale: ``pixel_mm`` mm per pixel at the focus (the head surface on the view axis); default
    (``None``) 1.0 (a medium shot: the 230 mm head spans ~200 px at any resolution).
    ``head_closeup``, ``head_cheek``, ``head_mid``, ``head_far`` preset 0.6, 0.3, 1.0 and 6.0
    mm per pixel (:data:`HEAD_SCENES`; ``head_close`` is retired, :data:`RETIRED_SCENES`).
    ``distance`` replaces ``pixel_mm``: a preset name (``"close"``, ``"mid"``, ``"far"``, the
    same scales) or a number, the camera-to-head-centre distance in mm (> 150; then the scale
    follows the resolution: ``distance=268`` with ``aim="cheek"``, 743 and 3553 are the
    screen-relative close / mid / far framings these presets had before they had a scale).
    ``aim``: ``"face"`` (the face centre on the view axis) or
    ``"cheek"`` (the right cheek on the axis); default ``"cheek"`` for ``"close"`` and
    ``"face"`` otherwise. ``yaw``: head turn in degrees about the vertical axis (positive turns
    the face toward the viewer's left). Mask covers skin (face, ears, neck-less head); eyes,
    brows, hair and wall are 0.
    """
    fov_y = _fov(fov_y)
    light = _light(light_dir, intensity)
    preset, dist, pixel_mm = _head_scale(distance, pixel_mm)
    yaw = check_scalar("yaw", yaw, -180.0, 180.0)
    if aim is None:
        aim = "cheek" if preset == "close" else "face"
    check_choice("aim", aim, ["face", "cheek"])
    offset = torch.tensor([-40.0, 20.0, 0.0]) if aim == "cheek" else torch.zeros(3)
    offset = offset.to(torch.float64)

    def build(d):
        obj = head_object(offset + torch.tensor([0.0, 0.0, d], dtype=torch.float64), yaw, ctx.gen)
        return [obj, backdrop(d + 600.0)], [obj]

    state = ctx.gen.get_state()

    def build_same(d):  # every build draws the same mottling
        ctx.gen.set_state(state)
        return build(d)

    if dist is not None:
        objects = build(dist)[0]
    else:
        objects = _at_scale(ctx, fov_y, pixel_mm, 3.0 * HEAD_RADII[2], build_same)
    return render(ctx, fov_y, objects, [light], _ambient(ambient))


_register("head", OPTIONAL_FIELDS, HEAD_PIXEL_MM["mid"], **_HEAD_DEFAULTS)(head)
for _name, (_px, _aim) in HEAD_SCENES.items():
    SCENES[_name] = SceneSpec(
        _name,
        head,
        frozenset(OPTIONAL_FIELDS),
        MappingProxyType({**_HEAD_DEFAULTS, "pixel_mm": _px, "aim": _aim}),
        _px,
    )


@_register(
    "crowd",
    OPTIONAL_FIELDS,
    3.0,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=3.0,
    n_heads=5,
    spread=3200.0,
    light_dir=(-0.4, 0.35, 0.85),
    intensity=1.0,
    ambient=0.03,
)
def crowd(ctx: Ctx, *, fov_y, pixel_mm, n_heads, spread, light_dir, intensity, ambient):
    """Several heads (:func:`~data_synth.head.head_object`) at different depths before a wall.

    Scale: ``pixel_mm`` (default 3.0, ``SCALES["far"]``) at the focus, the face of the nearest
    head, which faces the camera on the view axis. The other head centres are at depths evenly
    spaced up to ``spread`` mm (default 3200) behind the nearest one (at least 300 mm apart,
    jittered by ±10 % of the spacing, so heads never interpenetrate), at shuffled lateral slots
    across the view, with random yaw in ±35° and each its own skin mottling — all from the seed.
    The wall is 800 mm behind the farthest head. Heads are composited by nearest depth; nearer
    heads cast shadows on farther ones and on the wall where the light allows.
    """
    fov_y = _fov(fov_y)
    light = _light(light_dir, intensity)
    z_f = focus_depth(resolve_pixel_mm(pixel_mm), ctx.height, fov_y)
    n_heads = check_int("n_heads", n_heads, 1, 20)
    spread = check_scalar("spread", spread, 0.0)
    spacing = spread / max(n_heads - 1, 1)
    if n_heads > 1 and spacing < 300.0:
        raise ValueError(
            f"spread must leave >= 300 mm between the {n_heads} heads, got spread={spread} "
            f"({spacing:.0f} mm apart)"
        )
    g = ctx.gen
    tan = math.tan(fov_y / 2.0)
    aspect = ctx.width / ctx.height
    near = z_f + HEAD_RADII[2]  # the nearest head's centre; the face is refined below
    # lateral slots spread across the view, shuffled, so that far heads are not all hidden
    slots = torch.linspace(-0.7, 0.7, n_heads, dtype=torch.float64) if n_heads > 1 else [0.0]
    order = torch.randperm(n_heads, generator=g).tolist()
    state = g.get_state()

    def build(z0):
        g.set_state(state)
        objects = []
        for i in range(n_heads):
            u = torch.rand(4, generator=g, dtype=torch.float64).tolist()
            if i == 0:
                objects.append(head_object([0.0, 0.0, z0], 0.0, g))
                continue
            z = z0 + i * spacing + (u[0] - 0.5) * 0.2 * spacing
            x = (float(slots[order[i]]) + 0.1 * (u[1] - 0.5)) * z * tan * aspect
            y = (2 * u[2] - 1) * 0.3 * z * tan
            objects.append(head_object([x, y, z], 70.0 * (u[3] - 0.5), g))
        objects.append(backdrop(z0 + spread + 800.0))
        return objects, objects[:1]

    objects, focus = build(near)
    objects = build(near + z_f - axis_depth(focus))[0]
    return render(ctx, fov_y, objects, [light], _ambient(ambient))


# ---------------------------------------------------------------- skin details


@_register(
    "pores",
    ("albedo", "specular", "normal", "mask"),
    0.05,
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
    ctx: Ctx,
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

    Scale: ``pixel_mm = 0.05`` at the base plane (28.9 mm deep at H = 256, 25°), or give the
    plane's depth ``z`` instead. Texture: ``skimage.data.gravel()`` (512², bundled with
    scikit-image, no download), tiled, one texel = ``texel_mm`` (0.05 mm), randomly shifted and
    turned by a multiple of 90° per seed. Height ``h = pore_depth · (g - mean) / std`` mm
    (bilinear at each pixel centre's ``(x, y)`` on the base plane); depth ``z - h``. Normals from
    the depth map (:func:`~data_synth.geometry.normals_from_depth`), so the grazing default light
    gives pore-scale Lambert shading; no cast shadows at pore scale. Mask 1; albedo skin,
    slightly darker in the crevices; Blinn–Phong specular.
    """
    fov_y = _fov(fov_y)
    z = _plane_depth(ctx, fov_y, z, pixel_mm, 0.05)
    texel = _positive("texel_mm", texel_mm)
    amp = check_scalar("pore_depth", pore_depth, 0.0)
    if amp >= 0.5 * z:
        raise ValueError(f"pore_depth must be < z / 2 = {0.5 * z:g} mm, got {amp:g}")
    light = _light(light_dir, intensity)
    ambient = _ambient(ambient)
    ks = check_scalar("ks", ks, 0.0)
    shininess = _positive("shininess", shininess)
    ctx.images_next()

    tex = texture("gravel")
    turns = int(torch.randint(4, (1,), generator=ctx.gen))
    tex = torch.rot90(tex, turns)
    shift = torch.rand(2, generator=ctx.gen, dtype=torch.float64) * torch.tensor(tex.shape)
    base = torch.full((1, 1, ctx.height, ctx.width), z, dtype=torch.float64)
    pos = view_positions(base, fov_y)[0]
    g = bilinear_wrap(tex, -pos[1] / texel + shift[0], pos[0] / texel + shift[1])
    depth = (base - amp * g).clamp_min(1e-3 * z)
    normal = normals_from_depth(depth, fov_y)

    n = to_view(normal[0].reshape(3, -1).T)  # camera frame, (N, 3)
    lcam = unit(to_view(light.direction))
    irr = light.intensity * lambert(n, lcam) + ambient
    skin = torch.tensor(SKIN_ALBEDO, dtype=torch.float64).view(1, 3, 1, 1)
    albedo = skin * (1.0 + 0.06 * g.clamp(-2.0, 2.0)).view(1, 1, ctx.height, ctx.width)
    specular = None
    if "specular" in ctx.want:
        p = view_positions(depth, fov_y)[0].reshape(3, -1).T
        spec = light.intensity * ks * blinn_phong(n, lcam, -unit(p), shininess)
        specular = image(spec, ctx).expand(1, 3, ctx.height, ctx.width)
    return gbuffer(
        ctx,
        fov_y,
        light.direction,
        diffuse=image(irr, ctx).expand(1, 3, ctx.height, ctx.width),
        depth=depth,
        albedo=albedo.clamp(0.0, 1.0),
        specular=specular,
        normal=normal,
        mask=torch.ones_like(depth),
    )


@_register(
    "halo",
    OPTIONAL_FIELDS,
    None,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    distance=None,
    tilt=45.0,
    protrusion=20.0,
    light_dir=(0.35, 0.15, 0.92),
    intensity=1.0,
    ambient=0.03,
)
def halo(ctx: Ctx, *, fov_y, pixel_mm, distance, tilt, protrusion, light_dir, intensity, ambient):
    """A nose-like bump on a cheek seen obliquely: a depth discontinuity over skin.

    The cheek is the plane through ``(0, 0, distance)`` (mm, default 250) turned by ``tilt``
    degrees (default 45) about the vertical axis, its normal toward the viewer's left; it fills
    the view (``tilt`` up to ~75° at 25° fov). The nose is an ellipsoid (semi-axes 14 × 24 mm in
    the cheek plane, 24 mm along its normal) standing ``protrusion`` mm (default 20) proud of
    the cheek at the axis point. Scale: an oracle framing by default (``distance``; ≈ 0.3 mm per
    pixel on the nose at H = 256); give ``pixel_mm`` instead to put the focus (the nose on the
    axis) at that scale. Seen from the camera, the nose's left silhouette lies over cheek
    ~30 mm deeper. The default light (upper right, in front) lights the nose's front and right
    (irradiance rising from ambient at the silhouette to ~0.6 within ~2 mm) and the nose casts
    its shadow onto the cheek beyond the silhouette (ambient only for tens of mm): a bright bump
    over a dark cheek behind it, with the terminator on the nose's flank at the silhouette,
    where screen-space blurs bleed (halos). All skin: mask 1.
    """
    fov_y = _fov(fov_y)
    _one_of("distance", distance, "pixel_mm", pixel_mm)
    distance = 250.0 if distance is None else _positive("distance", distance)
    tilt = check_scalar("tilt", tilt, 0.0, 80.0)
    protrusion = check_scalar("protrusion", protrusion, 0.0, 48.0)
    light = _light(light_dir, intensity)
    rot = rotation(yaw=tilt)
    normal = rot @ torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    nose_r = 24.0
    material = constant_material(SKIN_ALBEDO, 1.0, 0.12, 25.0)

    def build(dist):
        q = torch.tensor([0.0, 0.0, dist], dtype=torch.float64)
        nose = Ellipsoid(q + normal * (protrusion - nose_r), [14.0, 24.0, nose_r], rot)
        face = SceneObject([HalfSpace(q, normal), nose], material)
        return [face], [face]

    objects = _at_scale(ctx, fov_y, pixel_mm, distance, build)
    return render(ctx, fov_y, objects, [light], _ambient(ambient))


@_register(
    "backlit_ear",
    OPTIONAL_FIELDS,
    None,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    distance=None,
    size=(34.0, 60.0),
    thickness=4.0,
    turn=0.0,
    light_dir=(0.25, 0.3, -0.92),
    intensity=1.0,
    ambient=0.05,
)
def backlit_ear(
    ctx: Ctx, *, fov_y, pixel_mm, distance, size, thickness, turn, light_dir, intensity, ambient
) -> GBuffer:
    """A thin ear-like slab lit from behind, for translucency.

    The slab is an elliptic slab (outline ``size = (width, height)`` mm, default 34 × 60;
    ``thickness`` mm, default 4, constant) centred on the view axis at ``distance`` mm
    (default 200), facing the camera, turned ``turn`` degrees about the vertical axis. Scale: an
    oracle framing by default (≈ 0.35 mm per pixel at H = 256); give ``pixel_mm`` instead of
    ``distance`` to put the focus (the slab's front on the axis) at that scale. The default
    ``light_dir`` points away from the camera side (``z < 0``): the face toward the camera is
    unlit (``diffuse = ambient``) except the rim, and ``thickness`` on the front face is the
    chord along the light, ``thickness / |l_z|`` (slab frame) where the light ray leaves through
    the back face, less near the rim. A grey wall 400 mm behind has mask 0 and thickness 0; it
    stands for distant surroundings and does not block the back light. Mask 1 on the slab.
    """
    fov_y = _fov(fov_y)
    _one_of("distance", distance, "pixel_mm", pixel_mm)
    w, h = (float(v) for v in _vec("size", size, 2))
    if w <= 0 or h <= 0:
        raise ValueError(f"size must be two positive lengths (width, height) in mm, got {size!r}")
    thickness = _positive("thickness", thickness)
    distance = 200.0 if distance is None else _positive("distance", distance)
    if distance <= thickness:
        raise ValueError(f"distance must exceed thickness ({thickness:g} mm), got {distance:g}")
    turn = check_scalar("turn", turn, -80.0, 80.0)
    light = _light(light_dir, intensity)
    material = constant_material(SKIN_ALBEDO, 1.0, 0.12, 25.0)

    def build(dist):
        slab = EllipticSlab([0.0, 0.0, dist], [w / 2, h / 2], thickness / 2, rotation(yaw=turn))
        ear = SceneObject([slab], material)
        return [ear, backdrop(dist + 400.0, casts_shadow=False)], [ear]

    objects = _at_scale(ctx, fov_y, pixel_mm, distance, build)
    return render(ctx, fov_y, objects, [light], _ambient(ambient))


# ---------------------------------------------------------------- the implicit face


@dataclass(frozen=True)
class FaceBuild:
    """What :func:`face_parts` returns.

    Attributes:
        gbuffer: the ``face`` scene's G-buffer (the same as :func:`make_scene` builds).
        parts: ``(1, 1, H, W)`` long label map, values of :data:`~data_synth.face.FACE_PARTS`.
        ears: the two ears' slabs (camera frame), :class:`~data_synth.face.EarFrame`.
    """

    gbuffer: GBuffer
    parts: torch.Tensor
    ears: list[face_model.EarFrame]


def _face(ctx: Ctx, **params) -> FaceBuild:
    p = dict(params)
    fov_y = _fov(p["fov_y"])
    yaw = check_scalar("yaw", p["yaw"], -90.0, 90.0)
    pitch = check_scalar("pitch", p["pitch"], -45.0, 45.0)
    check_choice("aim", p["aim"], list(face_model.AIMS))
    lights = [
        _light(p["back_dir"], p["back_intensity"], "back_dir", "back_intensity"),
        _light(p["key_dir"], p["key_intensity"], "key_dir", "key_intensity"),
        _light(p["rim_dir"], p["rim_intensity"], "rim_dir", "rim_intensity"),
    ]
    ambient = _ambient(p["ambient"])
    rot = rotation(yaw, pitch)
    aim = rot @ torch.tensor(face_model.AIMS[p["aim"]], dtype=torch.float64)
    scale = 2.0 * math.tan(fov_y / 2.0) / ctx.height
    material = face_model.face_material(ctx.gen, lambda q: q[:, 2] * scale)

    def build(d):
        center = torch.tensor([-float(aim[0]), -float(aim[1]), d], dtype=torch.float64)
        obj = face_model.FaceObject(center, rot, material)
        return [obj, backdrop(d + 600.0)], [obj]

    objects = _at_scale(ctx, fov_y, p["pixel_mm"], 400.0, build)
    g, labels = render_labelled(ctx, fov_y, objects, lights, ambient)
    return FaceBuild(g, labels, face_model.ear_frames(objects[0]))


@_register(
    "face",
    OPTIONAL_FIELDS,
    0.3,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=0.3,
    aim="face",
    yaw=20.0,
    pitch=0.0,
    back_dir=(0.4, 0.3, -0.87),
    back_intensity=0.8,
    key_dir=(-0.55, 0.45, 0.70),
    key_intensity=1.0,
    rim_dir=(0.85, 0.2, -0.5),
    rim_intensity=0.5,
    ambient=0.03,
)
def face(ctx: Ctx, **params) -> GBuffer:
    """A procedural face (:mod:`data_synth.face`): an implicit head with nose, lips, eye sockets,
    brow, ears 3 mm thick and a neck on shoulders, before a grey wall 600 mm behind the focus.

    Scale: ``pixel_mm`` mm per pixel at the focus (default 0.3, ``SCALES["portrait"]``: at
    512² the whole face with both ears; ``"close"`` 0.07 is a cheek close-up with ``aim="cheek"``,
    ``"medium"`` 1.0 a head-and-shoulders shot, ``"far"`` 3.0 a bust in a room). The focus is the
    surface on the view axis through the ``aim`` point (``"face"``: the nose, ``"cheek"``: the
    right cheek) of the head turned ``yaw`` degrees (default 20: the face toward the viewer's
    left, the right ear in view) and ``pitch`` degrees.

    Lights (view space, toward the light; the first is the G-buffer's ``light_dir`` and defines
    ``thickness``): ``back_dir`` behind the head, to the right and slightly up (through the
    right ear: its ``thickness`` is the chord of the 3 mm slab, ~7 mm), ``key_dir`` from the
    upper left in front (the nose casts its shadow on the right cheek and lip), ``rim_dir``
    from behind on the right (a bright edge along the right silhouette); ``ambient`` everywhere.

    Randomness (``seed``): the textures' offsets and turns and the skin's tint field. Mask 1 on
    skin (face, nose, lips, ears, neck); hair, brows, eyes, clothes and wall 0. Part labels:
    :func:`face_parts`.
    """
    return _face(ctx, **params).gbuffer


def face_parts(
    resolution: Sequence[int] = DEFAULT_RESOLUTION,
    seed: int = 0,
    *,
    fields: Iterable[str] | None = None,
    dtype: torch.dtype = torch.float32,
    **params: object,
) -> FaceBuild:
    """The ``face`` scene with its part labels and ear geometry (arguments of :func:`make_scene`).

    Example:
        >>> b = face_parts((32, 32), pixel_mm="medium", fields=[])
        >>> tuple(b.parts.shape), int(b.parts.max()) <= max(face_model.FACE_PARTS.values())
        ((1, 1, 32, 32), True)
    """
    spec, ctx = _context("face", resolution, seed, fields, dtype, params)
    return _face(ctx, **{**spec.defaults, **params})

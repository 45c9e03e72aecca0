"""Analytic descriptions of scenes for the whole-scene Monte Carlo reference, and ``backlit_slab``.

:func:`mc_model` describes a scene of :data:`MC_SCENES` by its *analytic* shape and the
irradiance over its whole surface (including the parts the camera does not see: the back of a
slab, the far side of a sphere), which :mod:`sssbench.mc.scene` turns into photon sources.
The camera is the scene's own (the frame of :func:`sssbench.gbuffer.view_positions`: camera at
the origin looking along ``+z``, ``y`` up, depth ``z`` in mm).

* ``step_edge``, ``light_dot``: the camera-facing plane ``z = depth`` over an infinite
  half-space; the painted irradiance is constant over each pixel (the box reconstruction the
  exact reference also uses) and extended beyond the frame by the border pixels (the
  reference's clamp-to-edge, which for these patterns is their analytic extension); light at
  normal incidence (a projector on the view axis).
* ``backlit_slab`` (built here): a camera-facing slab ``depth < z < depth + thickness`` lit
  from behind along the view axis through a round window in an opaque card ``gap`` mm behind
  it; the camera side gets ``ambient`` at normal incidence.
* ``sphere``: the ball of the ``sphere`` scene under its directional light (``n·l`` on the lit
  half) plus ``ambient`` from every direction (uniform diffuse sky) on the whole surface; the
  ball is convex and the wall is behind it, so nothing shadows it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from data_synth.geometry import to_view, unit
from data_synth.render import Ctx, flat_plane
from data_synth.scale import focus_depth, resolve_pixel_mm
from data_synth.scenes import (
    DEFAULT_FOV_Y,
    SCENES,
    _ambient,
    _fov,
    _light,
    _plane_depth,
    _positive,
    _register,
)
from sssbench.gbuffer import GBuffer, view_positions

__all__ = ["MC_SCENES", "FlatMC", "SphereMC", "mc_model", "backlit_slab"]

#: scenes with an analytic Monte Carlo model
MC_SCENES = ("step_edge", "light_dot", "backlit_slab", "sphere")


@dataclass(frozen=True)
class FlatMC:
    """A camera-facing plane (``thickness = inf``) or slab, lit at normal incidence.

    Attributes:
        depth: depth of the camera-facing face, mm.
        fov_y: the camera's vertical field of view, radians.
        thickness: mm (``inf``: a half-space).
        front: ``(H, W)`` irradiance on the camera-facing face per pixel (constant over it).
        back: ``(H, W)`` irradiance on the back face behind each pixel, or None.
    """

    depth: float
    fov_y: float
    thickness: float
    front: torch.Tensor
    back: torch.Tensor | None = None

    @property
    def pixel_mm(self) -> float:
        """Pixel footprint on the plane, ``2 z tan(fov_y/2) / H`` (sssbench.gbuffer)."""
        return 2.0 * self.depth * math.tan(self.fov_y / 2.0) / self.front.shape[0]


@dataclass(frozen=True)
class SphereMC:
    """A ball under a directional light and a uniform diffuse ambient light.

    Attributes:
        center: camera-frame centre, mm.
        radius: mm.
        fov_y: radians.
        resolution: ``(H, W)``.
        light: unit camera-frame direction *toward* the light.
        intensity: irradiance of the directional light on a surface facing it.
        ambient: irradiance of the ambient light on any surface.
    """

    center: tuple[float, float, float]
    radius: float
    fov_y: float
    resolution: tuple[int, int]
    light: tuple[float, float, float]
    intensity: float
    ambient: float

    def irradiance(self, points: torch.Tensor) -> torch.Tensor:
        """``E = intensity · max(0, n·l) + ambient`` at surface points ``(N, 3)`` -> ``(N,)``."""
        c = torch.tensor(self.center, dtype=points.dtype)
        n = (points - c) / self.radius
        cos = (n @ torch.tensor(self.light, dtype=points.dtype)).clamp_min(0.0)
        return self.intensity * cos + self.ambient


def mc_model(name: str, gbuffer: GBuffer, params: dict | None = None) -> FlatMC | SphereMC:
    """The analytic model of scene ``name`` built with ``params`` (its G-buffer ``gbuffer``,
    B = 1, gives the painted irradiance of the flat scenes and their depth).

    Raises:
        ValueError: ``name`` has no Monte Carlo model (not in :data:`MC_SCENES`).
    """
    if name not in MC_SCENES:
        raise ValueError(
            f"scene {name!r} has no Monte Carlo model (reference=mc); scenes with one: "
            f"{', '.join(MC_SCENES)}"
        )
    p = {**SCENES[name].defaults, **(params or {})}
    fov_y = float(gbuffer.fov_y)
    h, w = gbuffer.shape[1:]
    if name == "sphere":
        radius = float(p["radius"])
        if p["distance"] is not None:
            dist = float(p["distance"])
        elif p["pixel_mm"] is not None:  # the front of the ball at the focus (_at_scale)
            dist = focus_depth(resolve_pixel_mm(p["pixel_mm"]), h, fov_y) + radius
        else:
            dist = 500.0
        light = _light(p["light_dir"], p["intensity"])
        lcam = unit(to_view(light.direction))
        return SphereMC(
            (0.0, 0.0, dist),
            radius,
            fov_y,
            (h, w),
            tuple(float(v) for v in lcam),
            float(light.intensity),
            float(p["ambient"]),
        )
    depth = float(gbuffer.depth[0, 0, 0, 0])
    front = gbuffer.diffuse[0, 0].double()
    if name != "backlit_slab":
        return FlatMC(depth, fov_y, math.inf, front)
    thickness = _positive("thickness", p["thickness"])
    return FlatMC(depth, fov_y, thickness, front, _window(gbuffer.depth.double(), fov_y, p)[0, 0])


def _window(depth: torch.Tensor, fov_y: float, p: dict) -> torch.Tensor:
    """Back-face irradiance ``(1, 1, H, W)``: ``intensity`` behind pixels whose centre is
    within ``window`` mm of the axis, else 0 (the card's shadow)."""
    pos = view_positions(depth, fov_y)
    r2 = pos[:, 0:1] ** 2 + pos[:, 1:2] ** 2
    radius = _positive("window", p["window"])
    inside = r2 <= radius * radius
    return torch.where(inside, float(p["intensity"]), 0.0).to(torch.float64)


@_register(
    "backlit_slab",
    ("albedo", "normal", "mask", "thickness"),
    0.2,
    fov_y=DEFAULT_FOV_Y,
    pixel_mm=None,
    z=None,
    thickness=3.0,
    window=4.0,
    gap=20.0,
    intensity=1.0,
    ambient=0.05,
)
def backlit_slab(
    ctx: Ctx, *, fov_y, pixel_mm, z, thickness, window, gap, intensity, ambient
) -> GBuffer:
    """A thin camera-facing slab lit from behind through a round window (translucency oracle).

    The slab's front face is the plane of ``step_edge`` (scale ``pixel_mm = 0.2`` unless ``z``
    is given), ``thickness`` mm thick (default 3), laterally unbounded, skin albedo, mask 1.
    A directional light behind it shines along the view axis (``light_dir = (0, 0, −1)``,
    view space) through a round hole of radius ``window`` mm (default 4) on the axis in an
    opaque card ``gap`` mm (default 20) behind the slab: the back face gets ``intensity``
    behind pixels whose centre is within ``window`` of the axis and nothing elsewhere. The
    camera side gets ``ambient`` (default 0.05): ``diffuse = ambient``. ``thickness`` (the
    shadow-map distance of 001 §5.2, from the first surface the back light reaches to the
    shaded point) is the slab's thickness behind the window and ``thickness + gap`` behind
    the card.
    """
    fov_y = _fov(fov_y)
    z = _plane_depth(ctx, fov_y, z, pixel_mm, 0.2)
    thickness = _positive("thickness", thickness)
    gap = _positive("gap", gap)
    _positive("window", window)  # read again by _window (thickness): checked before any image
    ambient = _ambient(ambient)
    light = _light((0.0, 0.0, -1.0), intensity)
    h, w = ctx.height, ctx.width
    g = flat_plane(ctx, fov_y, z, torch.full((1, 1, h, w), ambient, dtype=torch.float64))
    changes = {"light_dir": unit(light.direction).reshape(1, 3).to(ctx.dtype)}
    if "thickness" in ctx.want:
        lit = _window(g.depth.double(), fov_y, {"window": window, "intensity": 1.0}) > 0
        changes["thickness"] = torch.where(lit, thickness, thickness + gap).to(ctx.dtype)
    return g.replace(**changes)

"""The procedural head of the ``head*`` and ``crowd`` scenes: ellipsoids and slabs, textured.

Head frame (mm): ``x`` to the viewer's right, ``y`` up, ``z`` away from the face (the face looks
toward ``-z``, at the camera when ``yaw = 0``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from data_synth.geometry import Ellipsoid, EllipticSlab, Primitive, mat_rows, rotation, unit
from data_synth.render import SKIN_ALBEDO, Material, SceneObject

__all__ = ["HEAD_HEIGHT_MM", "HEAD_RADII", "head_object", "in_ellipse", "smooth_noise"]

#: chin-to-crown height of the procedural head
HEAD_HEIGHT_MM = 230.0
#: semi-axes of the head ellipsoid (width, height, depth), mm
HEAD_RADII = (75.0, HEAD_HEIGHT_MM / 2, 95.0)


def smooth_noise(gen: torch.Generator, waves: int = 12, wavelength=(15.0, 60.0)):
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


def in_ellipse(x, y, cx, cy, rx, ry):
    """Whether ``(x, y)`` lies in the axis-aligned ellipse at ``(cx, cy)``, radii ``rx, ry``."""
    return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1.0


def head_object(center: Sequence[float], yaw: float, gen: torch.Generator) -> SceneObject:
    """The procedural head as a :class:`~data_synth.render.SceneObject` (``head*``, ``crowd``).

    Head frame (module docstring) turned by ``yaw`` degrees about the vertical axis, origin at
    ``center`` (camera frame, mm).

    Parts: the head ellipsoid (semi-axes :data:`HEAD_RADII` = 75 × 115 × 95, 230 mm tall), a nose
    ellipsoid (26 × 48 × 48 mm, ~20 mm proud of the face) and two ears as 5 mm thick elliptic
    slabs (36 × 62 mm outline) on the sides, turned 20° out from the head.

    Material: skin albedo with smooth mottling (from ``gen``), red lips; eyes (sclera, iris),
    brows and hair have their own albedo and mask 0; skin and ears mask 1. Specular: skin
    ``ks = 0.12, s = 25``, eyes ``ks = 0.6, s = 300`` (wet), hair and brows ``ks = 0.05``.
    """
    c = torch.as_tensor(center, dtype=torch.float64)
    rot = rotation(yaw=yaw)

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

    mottle = smooth_noise(gen)
    skin = torch.tensor(SKIN_ALBEDO, dtype=torch.float64)

    def material(p: torch.Tensor, part: torch.Tensor, normal: torch.Tensor) -> Material:
        q = mat_rows(rot.T, (p - c).T).T  # head frame
        x, y, z = q.unbind(-1)
        n = p.shape[0]
        albedo = skin * (1.0 + 0.08 * mottle(q)).unsqueeze(-1)
        mask = torch.ones(n, dtype=p.dtype)
        ks = torch.full((n,), 0.12, dtype=p.dtype)
        shin = torch.full((n,), 25.0, dtype=p.dtype)
        front = (z < -40.0) & (part == 0)
        lips = front & in_ellipse(x, y, 0.0, -65.0, 22.0, 7.0)
        albedo[lips] = torch.tensor([0.70, 0.33, 0.33], dtype=p.dtype)
        hairline = 70.0 - 0.4 * (z + 90.0)
        dark = ((y > hairline) & (part == 0)) | (
            front
            & (in_ellipse(x, y, -32.0, 15.0, 18.0, 4.0) | in_ellipse(x, y, 32.0, 15.0, 18.0, 4.0))
        )
        albedo[dark] = torch.tensor([0.10, 0.07, 0.05], dtype=p.dtype)
        mask[dark] = 0.0
        ks[dark] = 0.05
        shin[dark] = 10.0
        for ex in (-32.0, 32.0):
            eye = front & in_ellipse(x, y, ex, 0.0, 14.0, 7.0)
            iris = eye & in_ellipse(x, y, ex, 0.0, 5.5, 5.5)
            albedo[eye] = torch.tensor([0.85, 0.82, 0.78], dtype=p.dtype)
            albedo[iris] = torch.tensor([0.25, 0.15, 0.08], dtype=p.dtype)
            mask[eye] = 0.0
            ks[eye] = 0.6
            shin[eye] = 300.0
        return Material(albedo, mask, ks, shin)

    return SceneObject(parts, material)

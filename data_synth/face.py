"""The procedural face: a head built from many convex parts, traced exactly.

Head frame (mm, as :mod:`data_synth.head`): ``x`` to the viewer's right, ``y`` up, ``z`` away
from the face (the face looks toward ``-z``). The solid is the union of ellipsoids and two
elliptic slabs (:mod:`data_synth.geometry`), intersected analytically — exact depth, normals,
shadows and ``thickness`` (the last exit toward the light over the parts, 001 §5.2), and as fast
per part as the ellipsoid head (each ray meets only the parts whose bounding sphere it crosses,
:class:`~data_synth.render.CulledUnion`):

- masses: cranium, face, jaw, a neck and shoulders;
- features: chin, cheekbones, a brow ridge over eye sockets (the recess left between the brow,
  the nose bridge and the cheekbones, with the eyeballs set in it), a nose ~25 mm proud of the
  face (pitched bridge, tip, two alae), upper and lower lips (the mouth line is their seam);
- two ears, elliptic slabs 3 mm thick (outline 29 × 59 mm) standing out 30° from the head's
  side with their back edge ~15 mm proud: thin enough for a back light to pass; their
  ``thickness`` toward a light is the chord ``3 / |l·w|`` (``w`` the slab's normal) wherever the
  light enters and leaves through the flat faces.

Parts meet in creases (no fillets): the surface is a union, not a smooth blend. Choice: a smooth
union (signed distance + sphere tracing) was built first and was ~30× slower than the ellipsoid
head in eager torch (3.1 s against 0.1 s at 128², one thread); the exact union keeps the face
within a small factor of ``head`` and its thickness in closed form.

Material (:func:`face_material`): skin albedo modulated by ``skimage.data.moon()`` (blotches,
0.4 mm texels; offset and turn from the seed), flushed cheeks and nose tip, redder lips;
hair, brows, eyes (sclera, iris, pupil) and clothes with their own albedo and mask 0. The
shading normal is the geometric one perturbed by pores (``skimage.data.gravel()`` relief,
0.05 mm texels, 0.03 mm deep, triplanar, box-filtered to the pixel footprint) and wrinkles
(forehead, under the eyes): a normal map.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from data_synth.geometry import Ellipsoid, EllipticSlab, Primitive, mat_rows, rotation, unit
from data_synth.head import in_ellipse
from data_synth.render import SKIN_ALBEDO, CulledUnion, Material
from data_synth.textures import bilinear_wrap, mip_level, texture

__all__ = [
    "AIMS",
    "EAR_HALF_THICKNESS",
    "FACE_PARTS",
    "EarFrame",
    "FaceObject",
    "ear_frames",
    "face_material",
]

#: label of each part in :func:`data_synth.face_parts`'s map (0 = no face: background)
FACE_PARTS = {
    "background": 0,
    "skin": 1,
    "nose": 2,
    "lips": 3,
    "ear": 4,
    "eye": 5,
    "neck": 6,
    "clothes": 7,
    "hair": 8,
    "brow": 9,
}
#: head-frame point put on the view axis for each ``aim``
AIMS = {"face": (34.0, -12.0, -74.0), "cheek": (40.0, -22.0, -75.0)}
#: half thickness of the ears' slabs, mm (3 mm thick)
EAR_HALF_THICKNESS = 1.5
_EAR_OUTLINE = (14.5, 29.5)  # semi-axes of the ear's outline (back-to-front, height), mm
_EAR_FLARE = 30.0  # degrees the ear plane turns out from the head's side
_EAR_CENTRES = ((-76.0, -2.0, 10.0), (76.0, -2.0, 10.0))

# (label, centre, semi-axes, pitch in degrees or None), head frame, mm
_ELLIPSOIDS = [
    ("skin", (0.0, 30.0, 12.0), (74.0, 92.0, 98.0), None),  # cranium
    ("skin", (0.0, -25.0, -20.0), (60.0, 68.0, 66.0), None),  # face
    ("skin", (0.0, -60.0, -12.0), (54.0, 40.0, 58.0), None),  # jaw
    ("neck", (0.0, -135.0, 18.0), (46.0, 75.0, 48.0), None),
    ("clothes", (0.0, -250.0, 25.0), (170.0, 60.0, 95.0), None),  # shoulders
    ("skin", (0.0, -78.0, -58.0), (24.0, 16.0, 22.0), None),  # chin
    ("skin", (-38.0, -12.0, -52.0), (24.0, 18.0, 22.0), None),  # cheekbones
    ("skin", (38.0, -12.0, -52.0), (24.0, 18.0, 22.0), None),
    ("skin", (0.0, 28.0, -72.0), (50.0, 11.0, 15.0), None),  # brow ridge
    ("nose", (0.0, 4.0, -88.0), (7.5, 24.0, 11.0), 22.0),  # bridge, bottom forward
    ("nose", (0.0, -17.0, -102.0), (10.0, 9.0, 10.0), None),  # tip
    ("nose", (-11.0, -21.0, -94.0), (7.0, 6.0, 7.0), None),  # alae
    ("nose", (11.0, -21.0, -94.0), (7.0, 6.0, 7.0), None),
    ("lips", (0.0, -37.0, -84.0), (20.0, 5.5, 7.0), None),  # upper lip
    ("lips", (0.0, -48.0, -82.0), (18.0, 5.5, 7.0), None),  # lower lip
    ("eye", (-32.0, 10.0, -64.0), (12.0, 12.0, 12.0), None),
    ("eye", (32.0, 10.0, -64.0), (12.0, 12.0, 12.0), None),
]
_PARTS_ORDER = [lbl for lbl, *_ in _ELLIPSOIDS] + ["ear", "ear"]


def _ear_axes(side: float) -> tuple[list[float], list[float], list[float]]:
    """Head-frame ``u`` (toward the back edge, outward), ``v`` (up), ``w`` = ``u × v``."""
    f = math.radians(_EAR_FLARE)
    u = [side * math.sin(f), 0.0, math.cos(f)]
    return u, [0.0, 1.0, 0.0], [-math.cos(f), 0.0, side * math.sin(f)]


@dataclass(frozen=True)
class EarFrame:
    """An ear's slab in the camera frame: ``center`` (3,), unit axes ``u`` (in the ear plane,
    toward the back edge), ``v`` (up) and ``w`` (the slab normal), outline semi-axes ``radii``
    (along ``u``, ``v``) and ``half_thickness`` (mm)."""

    center: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor
    w: torch.Tensor
    radii: tuple[float, float]
    half_thickness: float


class FaceObject(CulledUnion):
    """The face at ``center`` (camera frame, mm), head frame turned by ``rot`` (3, 3)."""

    def __init__(self, center: torch.Tensor, rot: torch.Tensor, material: Callable) -> None:
        self.center = center.to(torch.float64)
        self.rot = rot.to(torch.float64)

        def place(q):
            return self.center + self.rot @ torch.tensor(q, dtype=torch.float64)

        parts: list[Primitive] = []
        for _, c, r, pitch in _ELLIPSOIDS:
            local = self.rot if pitch is None else self.rot @ rotation(pitch=pitch)
            parts.append(Ellipsoid(place(c), r, local))
        self.ears = []
        for c, side in zip(_EAR_CENTRES, (-1.0, 1.0), strict=True):
            axes = [self.rot @ torch.tensor(a, dtype=torch.float64) for a in _ear_axes(side)]
            frame = EarFrame(place(c), *axes, _EAR_OUTLINE, EAR_HALF_THICKNESS)
            self.ears.append(frame)
            parts.append(
                EllipticSlab(frame.center, _EAR_OUTLINE, EAR_HALF_THICKNESS, torch.stack(axes, 1))
            )
        super().__init__(parts, lambda p, part, n: material(self, p, part, n))

    def to_head(self, p: torch.Tensor) -> torch.Tensor:
        """Camera-frame points ``(N, 3)`` -> head frame ``(3, N)``."""
        return mat_rows(self.rot.T, (p - self.center).T)


def ear_frames(obj: FaceObject) -> list[EarFrame]:
    """The two ears' slabs of ``obj`` in the camera frame (left, right)."""
    return list(obj.ears)


# ---------------------------------------------------------------- material

_PORE_TEXEL = 0.05  # mm
_PORE_DEPTH = 0.03  # mm
_MOTTLE_TEXEL = 0.4  # mm
_LABEL_OF = torch.tensor([FACE_PARTS[lbl] for lbl in _PARTS_ORDER])
_SKIN_LABELS = (FACE_PARTS["skin"], FACE_PARTS["nose"], FACE_PARTS["lips"], FACE_PARTS["ear"])


def face_material(gen: torch.Generator, footprint: Callable[[torch.Tensor], torch.Tensor]):
    """The face's material (module docstring), random parts drawn from ``gen``.

    ``footprint(p)`` gives the pixel footprint (mm) at camera-frame points ``(n, 3)``; it picks
    the pores' mip level. ``material(obj, p, part, normal)`` returns a
    :class:`~data_synth.render.Material` whose ``labels`` are :data:`FACE_PARTS` values.
    """
    moon = torch.rot90(texture("moon"), int(torch.randint(4, (1,), generator=gen)))
    gravel = torch.rot90(texture("gravel"), int(torch.randint(4, (1,), generator=gen)))
    shift = torch.rand(4, generator=gen, dtype=torch.float64) * 512.0
    levels = {}

    def pore_level(level: int):
        if level not in levels:
            tex = mip_level(gravel, level)
            gy, gx = torch.gradient(tex)  # per texel of this level
            levels[level] = (tex, gx, gy)
        return levels[level]

    def material(obj: FaceObject, p, part, normal) -> Material:
        q = obj.to_head(p)  # (3, n)
        x, y, z = q
        n_geo = mat_rows(obj.rot.T, normal.T)  # head frame (3, n)
        lab = _LABEL_OF[part.clamp_min(0)]
        n = p.shape[0]
        hair = (lab == FACE_PARTS["skin"]) & (y > 58.0 - 0.55 * (z + 85.0))
        brow = (lab == FACE_PARTS["skin"]) & (z < -55.0)
        brow &= in_ellipse(x, y, -30.0, 27.5, 17.0, 4.0) | in_ellipse(x, y, 30.0, 27.5, 17.0, 4.0)
        lab = torch.where(hair, FACE_PARTS["hair"], torch.where(brow, FACE_PARTS["brow"], lab))

        blotch = bilinear_wrap(
            mip_level(moon, 1), -y / _MOTTLE_TEXEL + shift[0], x / _MOTTLE_TEXEL + shift[1]
        ).clamp(-2.5, 2.5)
        skin = torch.tensor(SKIN_ALBEDO, dtype=p.dtype)
        red = torch.tensor([0.80, 0.45, 0.40], dtype=p.dtype)
        flush = (
            torch.exp(-(((x.abs() - 38.0) / 18.0) ** 2 + ((y + 15.0) / 14.0) ** 2))  # cheeks
            + torch.exp(-((x / 9.0) ** 2 + ((y + 17.0) / 9.0) ** 2))  # nose tip
        ).clamp(max=1.0) * 0.6
        albedo = torch.lerp(skin.expand(n, 3), red.expand(n, 3), flush.unsqueeze(-1))
        albedo = albedo * (1.0 + 0.07 * blotch).unsqueeze(-1)
        mask = torch.ones(n, dtype=p.dtype)
        ks = torch.full((n,), 0.12, dtype=p.dtype)
        shin = torch.full((n,), 25.0, dtype=p.dtype)

        def paint(sel, rgb, m, k, s):
            albedo[sel] = torch.tensor(rgb, dtype=p.dtype)
            mask[sel], ks[sel], shin[sel] = m, k, s

        lips = lab == FACE_PARTS["lips"]
        albedo[lips] = torch.tensor([0.66, 0.30, 0.30], dtype=p.dtype) * (
            1.0 + 0.05 * blotch[lips].unsqueeze(-1)
        )
        ks[lips] = 0.25
        paint((lab == FACE_PARTS["hair"]) | (lab == FACE_PARTS["brow"]), (0.09, 0.06, 0.04), 0.0,
              0.05, 10.0)  # fmt: skip
        paint(lab == FACE_PARTS["clothes"], (0.12, 0.16, 0.30), 0.0, 0.04, 8.0)
        eye = lab == FACE_PARTS["eye"]
        if bool(eye.any()):
            r_eye = torch.minimum((x + 32.0) ** 2, (x - 32.0) ** 2) + (y - 10.0) ** 2
            paint(eye, (0.85, 0.82, 0.78), 0.0, 0.6, 300.0)
            paint(eye & (r_eye < 5.5**2), (0.30, 0.20, 0.10), 0.0, 0.6, 300.0)
            paint(eye & (r_eye < 2.3**2), (0.02, 0.02, 0.02), 0.0, 0.6, 300.0)

        bumped = torch.zeros(n, dtype=torch.bool)
        for label in _SKIN_LABELS + (FACE_PARTS["neck"],):
            bumped |= lab == label
        grad = torch.zeros(3, n, dtype=p.dtype)
        sel = bumped.nonzero().squeeze(-1)
        if sel.numel():
            grad[:, sel] = _relief_gradient(
                q[:, sel], n_geo[:, sel], footprint(p[sel]), pore_level, shift[2:]
            )
        # normal map: n' = normalize(n - (∇h - (∇h·n) n)), the surface gradient of the relief
        tangential = grad - (grad * n_geo).sum(0) * n_geo
        shading = unit(mat_rows(obj.rot, n_geo - tangential).T)
        return Material(albedo.clamp(0.0, 1.0), mask, ks, shin, shading, lab)

    return material


def _relief_gradient(q, n_geo, footprint, pore_level, shift) -> torch.Tensor:
    """Head-frame gradient ``∇h (3, n)`` of the relief: pores (triplanar) and wrinkles."""
    x, y, z = q
    level = (footprint / _PORE_TEXEL).clamp_min(1.0).log2().floor().clamp_max(8).long()
    w = n_geo.abs() ** 4
    w = w / w.sum(0).clamp_min(1e-12)
    grad = torch.zeros_like(q)
    # projections along x (on z, y), y (on x, z) and z (on x, y): (axis, row coord, col coord)
    planes = ((0, (1, -1.0), (2, 1.0)), (1, (2, 1.0), (0, 1.0)), (2, (1, -1.0), (0, 1.0)))
    for lv in level.unique().tolist():
        on = level == lv
        tex, gx, gy = pore_level(lv)
        texel = _PORE_TEXEL * 2**lv
        for axis, (ra, rs), (ca, cs) in planes:
            r = rs * q[ra, on] / texel + shift[0]
            c = cs * q[ca, on] / texel + shift[1]
            amp = _PORE_DEPTH * w[axis, on] / texel  # mm of height per texel of slope
            grad[ra, on] += rs * amp * bilinear_wrap(gy, r, c)
            grad[ca, on] += cs * amp * bilinear_wrap(gx, r, c)
    # wrinkles: horizontal creases, h = A sin(2π y / λ) under a smooth window (0.06 mm deep)
    for yc, half, lam, amp, xs in ((48.0, 13.0, 7.0, 0.06, 40.0), (-3.0, 4.0, 2.5, 0.03, 14.0)):
        win = torch.exp(-(((y - yc) / half) ** 2)) * (z < -50.0)
        if xs < 30.0:  # under the eyes: two windows at x = ±32
            side = torch.exp(-(((x - 32.0) / xs) ** 2)) + torch.exp(-(((x + 32.0) / xs) ** 2))
            win = win * side
        else:
            win = win * torch.exp(-((x / xs) ** 2))
        grad[1] += amp * (2 * math.pi / lam) * torch.cos(2 * math.pi * y / lam) * win
    return grad

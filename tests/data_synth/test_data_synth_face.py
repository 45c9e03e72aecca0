"""The procedural face: parts in view, thickness of the ears against the slab's closed form,
cast shadows, determinism."""

from __future__ import annotations

import math

import pytest
import torch

from data_synth import FACE_PARTS, SCENES, face_parts, make_scene
from sssbench.gbuffer import view_positions


@pytest.fixture(scope="module")
def portrait():
    return face_parts((512, 512), dtype=torch.float64, pixel_mm=0.3)


def _cam(v: torch.Tensor) -> torch.Tensor:
    """View space (z toward the camera) -> camera frame (z forward)."""
    out = v.clone()
    out[..., 2] = -out[..., 2]
    return out


def test_nose_lips_and_ears_are_in_view_and_in_the_mask(portrait):
    g, parts = portrait.gbuffer, portrait.parts
    for name in ("nose", "lips", "ear"):
        on = parts == FACE_PARTS[name]
        assert int(on.sum()) > 1000, name  # > 1000 px of each at 0.3 mm per pixel
        assert bool((g.mask[on] == 1).all()), name
    for name in ("eye", "hair", "brow"):  # not skin: outside the SSS mask
        on = parts == FACE_PARTS[name]
        assert int(on.sum()) > 0 and bool((g.mask[on] == 0).all()), name
    assert bool((g.mask[parts == FACE_PARTS["background"]] == 0).all())


def test_ear_thickness_is_the_chord_of_the_3_mm_slab(portrait):
    g, parts = portrait.gbuffer, portrait.parts
    light = _cam(g.light_dir[0])  # the back light, toward the light
    assert float(g.light_dir[0, 2]) < 0  # behind the head
    ear = (parts == FACE_PARTS["ear"]).reshape(-1)
    pos = view_positions(g.depth, g.fov_y)[0].reshape(3, -1).T[ear]  # camera frame, mm
    th = g.thickness.reshape(-1)[ear]
    assert bool(((th > 0) & (th < 10.0)).float().mean() > 0.9)  # measured: 98 %
    checked = 0
    for e in portrait.ears:
        q = pos - e.center
        a, b, c = q @ e.u, q @ e.v, q @ e.w
        lu, lv, lw = float(light @ e.u), float(light @ e.v), float(light @ e.w)
        on_face = (c.abs() - e.half_thickness).abs() < 1e-6  # on a flat face of the slab
        into = torch.sign(c) * lw < 0  # the light ray goes into the slab
        chord = 2 * e.half_thickness / abs(lw)
        ra, rb = e.radii

        def inside(u, v, ra=ra, rb=rb, margin=2.0):
            return ((u / (ra - margin)) ** 2 + (v / (rb - margin)) ** 2) < 1

        # back half of the ear (>= 7 mm proud of the head), entry and exit inside the outline
        sel = on_face & into & (a > 0) & inside(a, b) & inside(a + chord * lu, b + chord * lv)
        if bool(sel.any()):
            torch.testing.assert_close(th[sel], torch.full_like(th[sel], chord), rtol=1e-6, atol=0)
            checked += int(sel.sum())
    assert checked > 300  # the visible ear's back half, lit through


def test_the_key_light_casts_shadows_across_the_face():
    spec = SCENES["face"]
    g = make_scene("face", (128, 128), dtype=torch.float64, pixel_mm=1.2, back_intensity=0.0,
                   rim_intensity=0.0)  # fmt: skip
    key = torch.tensor(spec.defaults["key_dir"], dtype=torch.float64)
    key = key / key.norm()
    cos = (g.normal[0] * key.view(3, 1, 1)).sum(0)
    skin = g.mask[0, 0] > 0
    ambient = spec.defaults["ambient"]
    lit_side = skin & (cos > 0.3)
    shadowed = lit_side & (g.diffuse[0, 0] - ambient).abs().lt(1e-12)
    unshadowed = lit_side & ((g.diffuse[0, 0] - ambient - cos).abs() < 1e-9)
    assert int(shadowed.sum()) > 20  # e.g. the nose's shadow on the cheek
    assert int(unshadowed.sum()) > 4 * int(shadowed.sum())  # most of the lit side is lit
    assert int(lit_side.sum()) == int(shadowed.sum()) + int(unshadowed.sum())


def test_same_seed_same_face_other_seed_other_skin():
    a = make_scene("face", (40, 48), seed=5, pixel_mm=2.0)
    b = make_scene("face", (40, 48), seed=5, pixel_mm=2.0)
    c = make_scene("face", (40, 48), seed=6, pixel_mm=2.0)
    for f in ("diffuse", "depth", "albedo", "normal", "mask", "thickness", "specular"):
        assert torch.equal(getattr(a, f), getattr(b, f)), f
    assert torch.equal(a.depth, c.depth)  # the geometry is fixed
    assert not torch.equal(a.albedo, c.albedo)  # textures move with the seed


def test_face_scales_and_framings():
    # the same camera at half the resolution and twice the pixel_mm: same depth at the focus
    a = make_scene("face", (33, 33), dtype=torch.float64, fields=[], pixel_mm=0.6)
    b = make_scene("face", (99, 99), dtype=torch.float64, fields=[], pixel_mm=0.2)
    assert float(a.depth[0, 0, 16, 16]) == pytest.approx(float(b.depth[0, 0, 49, 49]), rel=1e-9)
    z = float(b.depth[0, 0, 49, 49])
    assert z == pytest.approx(0.2 * 99 / (2 * math.tan(b.fov_y / 2)), rel=1e-9)
    close = face_parts((33, 33), pixel_mm="close", aim="cheek", fields=["mask"])
    assert bool((close.parts == FACE_PARTS["skin"]).all())  # a cheek fills the close-up
    with pytest.raises(ValueError, match="aim"):
        make_scene("face", (9, 9), aim="ear")

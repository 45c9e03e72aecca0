"""Physical scale of the scenes: mm per pixel at the focus, independent of the resolution."""

from __future__ import annotations

import math

import pytest
import torch

from data_synth import SCALES, SCENES, make_scene, pixel_footprint_mm
from sssbench.gbuffer import GBuffer

ODD = [(33, 33), (65, 49)]  # odd sizes: a pixel centre lies on the view axis


def _axis_footprint(g: GBuffer) -> float:
    """2 z tan(fov_y / 2) / H at the pixel on the view axis (closed form, odd H and W)."""
    _, h, w = g.shape
    z = float(g.depth[0, 0, h // 2, w // 2])
    return 2.0 * z * math.tan(g.fov_y / 2.0) / h


@pytest.mark.parametrize("name", sorted(SCENES))
def test_given_pixel_mm_is_the_footprint_at_the_focus_at_every_resolution(name):
    p = 0.45
    for res in ODD:
        g = make_scene(name, res, dtype=torch.float64, fields=[], pixel_mm=p)
        # pores: the focus is its pore relief (±0.1 mm) on a plane ~10 mm away
        tol = 2e-2 if name == "pores" else 1e-9
        assert _axis_footprint(g) == pytest.approx(p, rel=tol), res


@pytest.mark.parametrize("name", sorted(n for n, s in SCENES.items() if s.pixel_mm is not None))
def test_default_scale_is_the_documented_one_at_every_resolution(name):
    spec = SCENES[name]
    for res in ODD:
        g = make_scene(name, res, dtype=torch.float64, fields=[])
        tol = 2e-2 if name == "pores" else 1e-9
        assert _axis_footprint(g) == pytest.approx(spec.pixel_mm, rel=tol), res


def test_oracles_framed_by_distance_keep_their_distance():
    # without pixel_mm, the sphere's front is at distance - radius whatever the resolution
    for res in ODD:
        g = make_scene("sphere", res, dtype=torch.float64, fields=[])
        assert float(g.depth[0, 0, res[0] // 2, res[1] // 2]) == pytest.approx(430.0, abs=1e-9)
    assert SCENES["sphere"].pixel_mm is None


def test_scale_names_and_bad_values():
    assert SCALES == {"close": 0.07, "portrait": 0.3, "medium": 1.0, "far": 3.0}
    a = make_scene("step_edge", (9, 9), dtype=torch.float64, pixel_mm="portrait")
    b = make_scene("step_edge", (9, 9), dtype=torch.float64, pixel_mm=0.3)
    assert torch.equal(a.depth, b.depth)
    with pytest.raises(ValueError, match="pixel_mm must be one of"):
        make_scene("step_edge", (9, 9), pixel_mm="huge")
    with pytest.raises(ValueError, match="pixel_mm"):
        make_scene("face", (9, 9), pixel_mm=-1.0)
    with pytest.raises(ValueError, match="either distance or pixel_mm"):
        make_scene("sphere", (9, 9), distance=500.0, pixel_mm=0.3)


def test_doubling_the_resolution_doubles_the_field_of_view():
    # at fixed pixel_mm the object keeps its size in pixels (more of the scene around it)
    small = make_scene("sphere", (65, 65), dtype=torch.float64, pixel_mm=3.0, fields=["mask"])
    large = make_scene("sphere", (129, 129), dtype=torch.float64, pixel_mm=3.0, fields=["mask"])
    for g in (small, large):
        h = g.shape[1]
        rows = float((g.mask[0, 0] > 0).any(1).sum())
        # silhouette of the 70 mm sphere whose front is at z_f: NDC radius tan(asin(r/D)) / t
        t = math.tan(g.fov_y / 2)
        dist = 3.0 * h / (2 * t) + 70.0
        expected = 2 * math.tan(math.asin(70.0 / dist)) / t * h / 2
        assert abs(rows - expected) <= 2.0, (h, rows, expected)
        assert expected == pytest.approx(140.0 / 3.0, rel=0.15)  # ~140 / 3 rows at any size


def test_pixel_footprint_mm_is_the_closed_form_at_the_image_centre():
    fov = math.radians(30.0)
    h, w = 6, 8
    # depth linear across the image: the centre (between the 4 central pixels) is the mean
    cols = torch.arange(w, dtype=torch.float64).view(1, 1, 1, w)
    rows = torch.arange(h, dtype=torch.float64).view(1, 1, h, 1)
    depth = (400.0 + 3.0 * cols + 5.0 * rows).expand(2, 1, h, w).clone()
    depth[1] *= 2.0
    g = GBuffer(torch.ones(2, 3, h, w, dtype=torch.float64), depth, fov)
    z = torch.tensor([400.0 + 3.0 * 3.5 + 5.0 * 2.5, 2 * (400.0 + 3.0 * 3.5 + 5.0 * 2.5)])
    expected = 2.0 * z * math.tan(fov / 2.0) / h
    torch.testing.assert_close(pixel_footprint_mm(g), expected.to(torch.float64))
    with pytest.raises(TypeError, match="gbuffer"):
        pixel_footprint_mm(depth)

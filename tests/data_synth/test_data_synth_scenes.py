"""Scenes of data_synth against analytic oracles (pinhole camera of sssbench.gbuffer)."""

from __future__ import annotations

import math

import pytest
import torch

from data_synth import HEAD_HEIGHT_MM, OPTIONAL_FIELDS, SCENES, make_scene, pixel_footprint_mm
from sssbench.gbuffer import GBuffer, pixel_size_mm, view_positions

SMALL = (48, 64)  # non-square: catches H/W mix-ups


def _light_cam(g: GBuffer) -> torch.Tensor:
    """light_dir in the camera frame of view_positions (z forward)."""
    l = g.light_dir[0].clone()
    l[2] = -l[2]
    return l


# ---------------------------------------------------------------- every scene


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_scene_is_a_valid_plausible_gbuffer(name):
    g = make_scene(name, SMALL)
    assert isinstance(g, GBuffer)
    assert g.shape == (1, *SMALL)
    assert g.dtype == torch.float32
    assert float(g.diffuse.min()) >= 0 and float(g.depth.min()) > 0
    assert math.radians(20) <= g.fov_y <= math.radians(30)
    for f in SCENES[name].fields:
        assert getattr(g, f) is not None, f
    for f in set(OPTIONAL_FIELDS) - SCENES[name].fields:
        assert getattr(g, f) is None, f
    if g.normal is not None:
        assert torch.allclose(g.normal.norm(dim=1), torch.ones(1), atol=1e-5)
    if g.light_dir is not None:
        assert torch.allclose(g.light_dir.norm(dim=1), torch.ones(1), atol=1e-6)


@pytest.mark.parametrize("name", ["sphere", "head", "crowd", "pores", "backlit_ear"])
def test_float64_matches_float32(name):
    g64 = make_scene(name, (24, 32), dtype=torch.float64)
    g32 = make_scene(name, (24, 32))
    assert g64.dtype == torch.float64
    assert torch.allclose(g64.depth.float(), g32.depth)
    assert torch.allclose(g64.diffuse.float(), g32.diffuse)


@pytest.mark.parametrize("name", ["head", "crowd", "pores"])
def test_same_seed_same_scene_other_seed_other_scene(name):
    a = make_scene(name, SMALL, seed=3)
    b = make_scene(name, SMALL, seed=3)
    c = make_scene(name, SMALL, seed=4)
    for f in ("diffuse", "depth", "albedo", "normal", "mask"):
        assert torch.equal(getattr(a, f), getattr(b, f)), f
    assert not torch.equal(a.albedo, c.albedo)


def test_scenes_without_randomness_ignore_the_seed():
    a = make_scene("sphere", SMALL, seed=0)
    b = make_scene("sphere", SMALL, seed=9)
    assert torch.equal(a.diffuse, b.diffuse) and torch.equal(a.depth, b.depth)


# ---------------------------------------------------------------- fields


def test_fields_subset_leaves_the_others_none():
    g = make_scene("sphere", SMALL, fields=["mask", "normal"])
    assert g.mask is not None and g.normal is not None
    assert g.albedo is None and g.specular is None and g.thickness is None
    full = make_scene("sphere", SMALL)
    assert torch.equal(g.mask, full.mask) and torch.equal(g.diffuse, full.diffuse)


def test_no_fields_and_fields_a_scene_does_not_have():
    g = make_scene("head", SMALL, fields=[])
    assert all(getattr(g, f) is None for f in OPTIONAL_FIELDS)
    g = make_scene("step_edge", SMALL, fields=["thickness", "mask"])
    assert g.thickness is None and g.mask is not None


def test_bad_fields():
    with pytest.raises(ValueError, match="fields must be one of"):
        make_scene("sphere", SMALL, fields=["normals"])
    with pytest.raises(TypeError, match="fields"):
        make_scene("sphere", SMALL, fields="mask")


# ---------------------------------------------------------------- errors


def test_unknown_scene_lists_the_valid_names():
    with pytest.raises(ValueError, match="name must be one of .*step_edge"):
        make_scene("teapot")


def test_unknown_param_lists_the_valid_ones():
    with pytest.raises(ValueError, match=r"unknown parameter.*'radius'.*valid.*'edge'"):
        make_scene("step_edge", SMALL, radius=3.0)


@pytest.mark.parametrize("res", [(0, 8), (8,), (8, 8, 8), (8.0, 8), "88", (8, 10_000)])
def test_bad_resolution(res):
    with pytest.raises((ValueError, TypeError), match="resolution"):
        make_scene("sphere", res)


def test_bad_seed_dtype_and_params():
    with pytest.raises(ValueError, match="seed"):
        make_scene("sphere", SMALL, seed=-1)
    with pytest.raises(TypeError, match="dtype"):
        make_scene("sphere", SMALL, dtype=torch.float16)
    with pytest.raises(ValueError, match="distance must be one of"):
        make_scene("head", SMALL, distance="medium")
    with pytest.raises(ValueError, match="radius"):
        make_scene("sphere", SMALL, radius=-1.0)
    with pytest.raises(ValueError, match="light_dir"):
        make_scene("sphere", SMALL, light_dir=(0, 0, 0))
    with pytest.raises(ValueError, match="either z or pixel_mm"):
        make_scene("step_edge", SMALL, z=100.0, pixel_mm=0.1)
    with pytest.raises(ValueError, match="edge"):
        make_scene("step_edge", SMALL, edge=SMALL[1] + 1)
    with pytest.raises(ValueError, match="empty"):
        make_scene("halo", SMALL, tilt=80.0, fov_y=math.radians(60))


# ---------------------------------------------------------------- step_edge, light_dot


@pytest.mark.parametrize("edge", [None, 0, 13, 64])
def test_step_edge_boundary_and_values(edge):
    h, w = SMALL
    kw = {} if edge is None else {"edge": edge}
    g = make_scene("step_edge", SMALL, dtype=torch.float64, low=0.25, high=2.0, **kw)
    e = w // 2 if edge is None else edge
    d = g.diffuse
    assert torch.all(d[..., :e] == 0.25) and torch.all(d[..., e:] == 2.0)
    p = float(pixel_size_mm(g.depth, g.fov_y, h)[0, 0, 0, 0])
    assert p == pytest.approx(0.2)  # default pixel size
    x = view_positions(g.depth, g.fov_y)[0, 0, 0]  # column centres, mm
    x_edge = (e - w / 2) * p  # documented boundary
    if 0 < e < w:
        assert float(x[e - 1]) < x_edge < float(x[e])
        assert 0.5 * float(x[e - 1] + x[e]) == pytest.approx(x_edge, abs=1e-12)
    assert torch.all(g.normal[:, 2] == 1) and torch.all(g.mask == 1)
    assert g.depth.unique().numel() == 1


def test_step_edge_depth_parameters():
    g = make_scene("step_edge", SMALL, z=300.0)
    assert torch.all(g.depth == 300.0)
    g = make_scene("step_edge", SMALL, dtype=torch.float64, pixel_mm=0.15)
    assert float(pixel_size_mm(g.depth, g.fov_y, SMALL[0]).max()) == pytest.approx(0.15)


def test_light_dot_disc_is_the_set_of_pixel_centres_within_the_radius():
    h, w = SMALL
    g = make_scene("light_dot", SMALL, dtype=torch.float64, center=(0.3, -0.2))
    p = 0.1  # default pixel size
    assert float(pixel_size_mm(g.depth, g.fov_y, h)[0, 0, 0, 0]) == pytest.approx(p)
    x = (torch.arange(w, dtype=torch.float64) + 0.5 - w / 2) * p
    y = (h / 2 - torch.arange(h, dtype=torch.float64) - 0.5) * p
    inside = (x.view(1, -1) - 0.3) ** 2 + (y.view(-1, 1) + 0.2) ** 2 <= 1.0
    assert torch.equal(g.diffuse[0, 0] == 1.0, inside)
    assert torch.all(g.diffuse[0, 0][~inside] == 0.05)
    assert 250 < int(inside.sum()) < 380  # pi r^2 / p^2 = 314
    assert torch.linalg.matrix_rank(g.diffuse[0, 0]) > 1  # not separable


# ---------------------------------------------------------------- sphere


def _sphere(res=(65, 65), **kw):
    return make_scene("sphere", res, dtype=torch.float64, **kw)


def test_sphere_centre_depth_is_the_ray_sphere_intersection():
    r, dist = 70.0, 500.0
    g = _sphere()
    assert float(g.depth[0, 0, 32, 32]) == pytest.approx(dist - r, abs=1e-9)  # on the axis
    # even size: no pixel on the axis; intersect the pixel's ray directly
    g = _sphere((64, 64))
    d = view_positions(torch.ones(1, 1, 64, 64, dtype=torch.float64), g.fov_y)[0, :, 32, 32]
    a, b, c = d @ d, -2 * dist * d[2], dist**2 - r**2
    t = (-b - math.sqrt(b * b - 4 * a * c)) / (2 * a)
    assert float(g.depth[0, 0, 32, 32]) == pytest.approx(float(t), abs=1e-9)


@pytest.mark.parametrize("res", [(65, 65), (64, 96)])
def test_sphere_silhouette_is_the_pinhole_projection(res):
    r, dist = 70.0, 500.0
    h, w = res
    g = _sphere(res)
    t = math.tan(g.fov_y / 2)
    # NDC radius of the silhouette cone, and each pixel centre's NDC radius
    rho = math.tan(math.asin(r / dist)) / t
    u = (torch.arange(w, dtype=torch.float64) + 0.5 - w / 2) / (h / 2)
    v = (h / 2 - torch.arange(h, dtype=torch.float64) - 0.5) / (h / 2)
    ndc = (u.view(1, -1) ** 2 + v.view(-1, 1) ** 2).sqrt()
    mask = g.mask[0, 0] > 0
    near_edge = (ndc - rho).abs() < 1e-9
    assert torch.equal(mask[~near_edge], (ndc < rho)[~near_edge])
    radius_px = rho * h / 2
    area = float(mask.sum())
    assert area == pytest.approx(math.pi * radius_px**2, rel=0.05)


def test_sphere_positions_normals_and_lambert():
    r, dist = 70.0, 500.0
    g = _sphere()
    on = g.mask[0, 0] > 0
    pos = view_positions(g.depth, g.fov_y)[0]
    centre = torch.tensor([0.0, 0.0, dist], dtype=torch.float64).view(3, 1, 1)
    radial = (pos - centre) / r  # camera frame
    assert torch.allclose(radial.norm(dim=0)[on], torch.ones(1, dtype=torch.float64), atol=1e-9)
    expected = radial.clone()
    expected[2] = -expected[2]  # view space: +z toward the camera
    assert torch.allclose(g.normal[0][:, on], expected[:, on], atol=1e-9)
    assert torch.allclose(g.normal.norm(dim=1), torch.ones(1, dtype=torch.float64))
    # the wall: depth 700, normal toward the camera, mask 0
    assert torch.all(g.depth[0, 0][~on] == 700.0) and torch.all(g.normal[0, 2][~on] == 1.0)
    # Lambert with the terminator (nothing else shadows the sphere)
    ndl = (radial * _light_cam(g).view(3, 1, 1)).sum(0).clamp_min(0)
    assert torch.allclose(g.diffuse[0, 0][on], (ndl + 0.03)[on], atol=1e-9)
    assert float(ndl[on].min()) == 0.0 and float(ndl[on].max()) > 0.9


def test_sphere_casts_a_shadow_on_the_wall():
    g = _sphere((96, 96), light_dir=(-0.3, 0.3, 0.9))
    wall = g.mask[0, 0] == 0
    # wall irradiance is either lit (n·l + ambient) or shadowed (ambient only)
    lit = float(_light_cam(g)[2].neg()) + 0.03
    vals = g.diffuse[0, 0][wall]
    assert torch.all(((vals - lit).abs() < 1e-9) | ((vals - 0.03).abs() < 1e-9))
    assert int(((vals - 0.03).abs() < 1e-9).sum()) > 20


def test_sphere_thickness_is_the_chord_toward_the_light():
    r = 70.0
    g = _sphere()
    on = g.mask[0, 0] > 0
    n_cam = g.normal[0].clone()
    n_cam[2] = -n_cam[2]
    chord = (-2 * r * (n_cam * _light_cam(g).view(3, 1, 1)).sum(0)).clamp_min(0)
    assert torch.allclose(g.thickness[0, 0][on], chord[on], atol=1e-6)
    assert torch.all(g.thickness[0, 0][~on] == 0)


# ---------------------------------------------------------------- heads


def _rows_covered(g: GBuffer) -> float:
    """Fraction of image rows containing head pixels (anything nearer than the wall)."""
    head = g.depth[0, 0] < g.depth.max()
    return float(head.any(dim=1).float().mean())


def test_head_presets_keep_the_physical_scale_at_any_resolution():
    # head_far is 6 mm per pixel at the face: the 230 mm head spans ~230 / 6 rows at the depth
    # of its centre whatever the image height (it was a fixed fraction of the screen before)
    rows = {}
    for h in (80, 160):
        g = make_scene("head_far", (h, h), dtype=torch.float64, fields=[])
        rows[h] = _rows_covered(g) * h
        z_f = float(pixel_footprint_mm(g)[0]) * h / (2 * math.tan(g.fov_y / 2))
        z_c = z_f + 114.0  # the head centre: the nose tip stands 114 mm in front of it
        assert rows[h] * 6.0 * z_c / z_f == pytest.approx(HEAD_HEIGHT_MM, rel=0.06)
    assert rows[160] == pytest.approx(rows[80], rel=0.1)  # not twice as many
    assert torch.equal(
        make_scene("head", (32, 32), distance="far").depth, make_scene("head_far", (32, 32)).depth
    )
    # a numeric distance keeps the head at that distance: rows x screen height at its centre
    dist = 700.0
    g = make_scene("head", (128, 128), distance=dist, fields=[])
    screen = 2 * dist * math.tan(g.fov_y / 2)
    assert _rows_covered(g) * screen == pytest.approx(HEAD_HEIGHT_MM, rel=0.1)
    with pytest.raises(ValueError, match="either distance or pixel_mm"):
        make_scene("head_cheek", (8, 8), distance=500.0)


def test_head_mask_excludes_eyes_brows_hair_and_background():
    g = make_scene("head_mid", (96, 96))
    head = g.depth[0, 0] < g.depth.max()
    skin = g.mask[0, 0] > 0
    assert torch.all(~skin[~head])  # background mask 0
    assert 0.4 < float(skin[head].float().mean()) < 0.95  # some head pixels are not skin
    assert g.specular is not None and float(g.specular.max()) > 0
    assert float(g.thickness.max()) > 0 and g.light_dir is not None


def test_crowd_has_heads_at_several_depths():
    g = make_scene("crowd", (96, 128), seed=1)
    skin_depths = g.depth[g.mask > 0]
    assert float(skin_depths.max() - skin_depths.min()) > 1000.0
    with pytest.raises(ValueError, match="300 mm"):
        make_scene("crowd", SMALL, n_heads=10, spread=200.0)


# ---------------------------------------------------------------- details


def test_pores_normals_vary_at_pixel_scale():
    g = make_scene("pores", (64, 64), dtype=torch.float64)
    assert float(pixel_size_mm(g.depth, g.fov_y, 64).mean()) == pytest.approx(0.05, rel=1e-3)
    assert float(g.normal[0, 0].std()) > 0.05 and float(g.normal[0, 2].min()) > 0
    assert float(g.diffuse[0, 0].std()) > 0.05  # pore-scale shading
    assert torch.all(g.mask == 1)


def test_halo_has_a_depth_discontinuity_with_a_bright_bump_over_a_dark_cheek():
    g = make_scene("halo", (128, 128), dtype=torch.float64)
    z = g.depth[0, 0]
    jump = (z[:, 1:] - z[:, :-1]).abs()
    assert float(jump.max()) > 15.0  # mm between neighbouring pixels
    i, j = divmod(int(jump.argmax()), jump.shape[1])
    assert float(z[i, j + 1]) < float(z[i, j])  # bump (right) in front of the cheek (left)
    e = g.diffuse[0, 0, i]
    assert float(e[j + 1 : j + 9].mean()) > 5 * float(e[j - 8 : j + 1].mean())
    assert torch.all(g.mask == 1)


def test_backlit_ear_thickness_inside_the_slab_and_zero_outside():
    thick = 4.0
    g = make_scene("backlit_ear", (97, 97), dtype=torch.float64, thickness=thick)
    assert float(g.light_dir[0, 2]) < 0  # toward the light = away from the camera side
    slab = g.mask[0, 0] > 0
    inner = slab.clone()  # erode by 3 px: away from the rim
    for s in (1, 2, 3):
        inner[s:] &= slab[:-s]
        inner[:-s] &= slab[s:]
        inner[:, s:] &= slab[:, :-s]
        inner[:, :-s] &= slab[:, s:]
    th = g.thickness[0, 0]
    assert torch.all(th[inner] > 0) and torch.all(th[~slab] == 0)
    # the centre pixel looks straight at the front face; light exits through the back face
    l_z = abs(float(g.light_dir[0, 2]))
    assert float(th[48, 48]) == pytest.approx(thick / l_z, rel=1e-9)
    assert torch.allclose(g.diffuse[0, 0][inner], torch.tensor(0.05, dtype=torch.float64))

"""GBuffer validation: every bad input names its argument."""

import math

import pytest
import torch

from sssbench.gbuffer import GBuffer, pixel_size_mm, view_positions


def good(**kw):
    args = dict(diffuse=torch.ones(1, 3, 4, 5), depth=torch.full((1, 1, 4, 5), 100.0), fov_y=0.5)
    args.update(kw)
    return args


@pytest.mark.parametrize(
    "kw, exc, match",
    [
        (dict(diffuse=torch.full((1, 3, 4, 5), float("nan"))), ValueError, "diffuse"),
        (dict(depth=torch.zeros(1, 1, 4, 5)), ValueError, "depth"),
        (dict(depth=torch.full((1, 1, 4, 5), -1.0)), ValueError, "depth"),
        (dict(depth=torch.full((1, 1, 4, 5), float("inf"))), ValueError, "depth"),
        (dict(depth=torch.ones(1, 1, 4, 6)), ValueError, "depth"),
        (dict(mask=torch.full((1, 1, 4, 5), 1.5)), ValueError, "mask"),
        (dict(fov_y=math.pi), ValueError, "fov_y"),
        (dict(fov_y=0.0), ValueError, "fov_y"),
        (dict(diffuse=torch.ones(1, 3, 4, 5, dtype=torch.int32)), TypeError, "diffuse"),
        (dict(diffuse=torch.ones(1, 4, 4, 5)), ValueError, "diffuse"),
        (dict(albedo=torch.ones(2, 3, 4, 5)), ValueError, "albedo"),
        (dict(thickness=torch.ones(1, 1, 4, 5, dtype=torch.float64)), TypeError, "thickness"),
        (dict(diffuse=torch.ones(1, 3, 4, 5, dtype=torch.float16)), TypeError, "diffuse"),
    ],
)
def test_bad_inputs(kw, exc, match):
    with pytest.raises(exc, match=match):
        GBuffer(**good(**kw))


def test_pixel_size_and_positions_follow_the_pinhole_model():
    depth = torch.full((1, 1, 4, 6), 200.0, dtype=torch.float64)
    fov = math.radians(40)
    p = 2 * 200 * math.tan(fov / 2) / 4
    assert float(pixel_size_mm(torch.tensor(200.0), fov, 4)) == pytest.approx(p)
    pos = view_positions(depth, fov)
    # neighbouring pixel centres are one pixel footprint apart; the image centre is on axis
    assert float(pos[0, 0, 0, 1] - pos[0, 0, 0, 0]) == pytest.approx(p)
    assert float(pos[0, 1, 0, 0] - pos[0, 1, 1, 0]) == pytest.approx(p)
    assert float(pos[0, 0, 0, 2] + pos[0, 0, 0, 3]) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    "field, value, exc, match",
    [
        ("mask", torch.full((1, 1, 4, 5), 1.5), ValueError, "mask"),
        ("mask", torch.ones(1, 1, 3, 5), ValueError, "mask must have shape"),
        ("depth", torch.zeros(1, 1, 4, 5), ValueError, "depth"),
        ("albedo", torch.ones(1, 3, 4, 5, dtype=torch.float64), TypeError, "albedo has dtype"),
        ("light_dir", torch.ones(2, 3), ValueError, "light_dir"),
        ("colour", torch.ones(1), TypeError, "no field"),
    ],
)
def test_replace_validates_the_replaced_fields(field, value, exc, match):
    g = GBuffer(torch.ones(1, 3, 4, 5), torch.full((1, 1, 4, 5), 100.0), 0.5)
    with pytest.raises(exc, match=match):
        g.replace(**{field: value})


def test_replace_equals_building_anew():
    g = GBuffer(torch.ones(1, 3, 4, 5), torch.full((1, 1, 4, 5), 100.0), 0.5)
    mask = torch.rand(1, 1, 4, 5)
    new = g.replace(mask=mask)
    assert new.mask is mask and new.depth is g.depth and g.mask is None
    fresh = GBuffer(g.diffuse, g.depth, g.fov_y, mask=mask)
    assert all(getattr(new, f) is getattr(fresh, f) for f in ("diffuse", "depth", "mask"))
    assert new.fov_y == fresh.fov_y
    with pytest.raises(ValueError, match="fov_y"):
        g.replace(fov_y=4.0)  # fov_y / diffuse: everything is validated again


def test_replace_checks_a_reused_tensor_again_after_an_in_place_change():
    """The field check is memoised on the tensor's identity and version: reusing a checked
    mask costs nothing, but writing into it in place (a new version) is checked again, and a
    bad tensor is refused every time."""
    g = GBuffer(torch.rand(1, 3, 4, 5), torch.full((1, 1, 4, 5), 100.0), 0.5)
    mask = torch.ones(1, 1, 4, 5)
    assert g.replace(mask=mask).mask is mask
    assert g.replace(mask=mask).mask is mask
    mask[0, 0, 0, 0] = 2.0  # in place: out of [0, 1]
    for _ in range(2):
        with pytest.raises(ValueError, match="mask must lie"):
            g.replace(mask=mask)


def test_a_cast_to_the_own_dtype_is_the_same_g_buffer_and_a_real_cast_copies_every_float():
    """``GBuffer.to``: casting to the dtype every float field already has changes nothing
    (the same G-buffer); any other dtype casts every float field and keeps ``profile_id``."""
    g = GBuffer(**good())
    assert g.to(g.dtype) is g
    g64 = g.to(torch.float64)
    assert g64 is not g
    for name, value in vars(g64).items():
        if isinstance(value, torch.Tensor):
            old = getattr(g, name)
            if old.is_floating_point():
                assert value.dtype == torch.float64 and torch.equal(value, old.double())
            else:
                assert value.dtype == old.dtype
    assert g64.to(torch.float64) is g64

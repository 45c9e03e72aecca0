"""Geometry helpers of data_synth: primitives, compositing, normals from depth."""

from __future__ import annotations

import math

import pytest
import torch

from data_synth.geometry import (
    Box,
    Ellipsoid,
    EllipticSlab,
    HalfSpace,
    camera_rays,
    composite_nearest,
    exit_distance,
    normals_from_depth,
    rotation,
    trace,
)

O = torch.zeros(3, dtype=torch.float64)
Z = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)


def test_primitive_intervals_on_the_axis():
    t_in, t_out, n = Ellipsoid([0, 0, 100], [5, 6, 10]).interval(O, Z)
    assert (float(t_in), float(t_out)) == pytest.approx((90.0, 110.0), abs=1e-9)
    assert torch.allclose(n, torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64))
    t_in, t_out, _ = Box([0, 0, 50], [1, 1, 2]).interval(O, Z)
    assert (float(t_in), float(t_out)) == (48.0, 52.0)
    t_in, t_out, _ = EllipticSlab([0, 0, 50], [3, 4], 1.5).interval(O, Z)
    assert (float(t_in), float(t_out)) == (48.5, 51.5)
    t_in, t_out, _ = HalfSpace([0, 0, 70], [0, 0, -1]).interval(O, Z)
    assert float(t_in) == 70.0 and math.isinf(float(t_out))
    # a miss
    t_in, t_out, _ = Ellipsoid([20, 0, 100], [5, 5, 5]).interval(O, Z)
    assert float(t_in) > float(t_out)


def test_rotated_slab_chord_is_thickness_over_cosine():
    turn = 30.0
    slab = EllipticSlab([0, 0, 100], [20, 20], 2.0, rotation(yaw=turn))
    t_in, t_out, n = slab.interval(O, Z)
    assert math.isclose(float(t_out - t_in), 4.0 / math.cos(math.radians(turn)), rel_tol=1e-12)
    # from the entry point along the axis the exit distance is the same chord
    p = t_in.unsqueeze(-1) * Z
    assert math.isclose(float(exit_distance([slab], p, Z)), float(t_out - t_in), rel_tol=1e-9)
    assert math.isclose(abs(float(n[0, 2])), math.cos(math.radians(turn)), rel_tol=1e-12)


def test_composite_nearest_and_trace():
    t = torch.tensor([[1.0, math.inf, 5.0], [2.0, math.inf, 3.0]])
    v = torch.tensor([[10.0, 11.0, 12.0], [20.0, 21.0, 22.0]])
    t_min, idx, val = composite_nearest(t, v)
    assert t_min.tolist()[0] == 1.0 and idx.tolist() == [0, -1, 1]
    assert val.tolist() == [10.0, 11.0, 22.0]
    hit = trace([HalfSpace([0, 0, 70], [0, 0, -1]), Ellipsoid([0, 0, 50], [5, 5, 5])], O, Z)
    assert float(hit.t) == pytest.approx(45.0, abs=1e-9) and int(hit.index) == 1


def test_normals_from_depth_of_a_tilted_plane_are_exact():
    h, w, fov = 24, 32, math.radians(25)
    m = rotation(yaw=35.0, pitch=-20.0) @ torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    hit = trace([HalfSpace([0, 0, 300], m)], O, camera_rays(h, w, fov))
    depth = hit.t.reshape(1, 1, h, w)
    n = normals_from_depth(depth, fov)
    expected = m.clone()
    expected[2] = -expected[2]  # view space
    assert torch.allclose(n, expected.view(1, 3, 1, 1).expand_as(n), atol=1e-9)

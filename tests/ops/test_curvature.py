"""Screen-space curvature and curvature modulation (004 §3.3.3)."""

import math

import pytest
import torch

from data_synth import make_scene
from sssbench.gbuffer import GBuffer
from sssbench.ops import CurvatureModulation, curvature_width, screen_space_curvature
from sssbench.ops.timing import record_passes

RADIUS = 70.0
DISTANCE = 500.0


def _silhouette_radius_px(h: int, fov_y: float) -> float:
    return math.tan(math.asin(RADIUS / DISTANCE)) / math.tan(fov_y / 2) * h / 2


@pytest.mark.parametrize("res", [64, 96])
def test_sphere_curvature_is_one_over_radius(res):
    g = make_scene("sphere", (res, res), dtype=torch.float64, radius=RADIUS, distance=DISTANCE)
    k = screen_space_curvature(g)[0, 0] * RADIUS  # κ R
    c = torch.arange(res, dtype=torch.float64) + 0.5 - res / 2
    rr = (c[:, None] ** 2 + c[None, :] ** 2).sqrt()
    inner = rr < 0.8 * _silhouette_radius_px(res, g.fov_y)
    # measured: κR in [1.000, 1.079] (64²) and [1.000, 1.072] (96²) within 0.8 of the
    # silhouette radius; the excess is perspective (the footprint is taken at the pixel's
    # depth, the surface recedes toward the rim). Tolerance: 10 %.
    assert float((k[inner] - 1.0).abs().max()) < 0.10
    # 004: the magnitude reading grows toward the contour
    m = screen_space_curvature(g, mode="magnitude")[0, 0] * RADIUS
    assert float(m[inner].max()) > float(k[inner].max())
    # the wall behind (mask 0) carries no curvature
    assert float(k[g.mask[0, 0] == 0].abs().max()) == 0.0


def test_plane_has_zero_curvature():
    # a tilted plane: constant normal, linear depth
    n = 32
    normal = torch.tensor([0.3, -0.2, (1 - 0.13) ** 0.5], dtype=torch.float64)
    rows = torch.arange(n, dtype=torch.float64)
    depth = (300.0 + 2.0 * rows[:, None] + 1.0 * rows[None, :]).view(1, 1, n, n)
    g = GBuffer(
        torch.ones(1, 3, n, n, dtype=torch.float64),
        depth,
        0.5,
        normal=normal.view(1, 3, 1, 1).expand(1, 3, n, n).contiguous(),
    )
    for mode in ("divergence", "magnitude"):
        assert float(screen_space_curvature(g, mode=mode).abs().max()) < 1e-12
    flat = make_scene("step_edge", (16, 16), dtype=torch.float64)
    assert float(screen_space_curvature(flat).abs().max()) == 0.0


def test_strategies():
    k = torch.tensor([0.0, 0.01, 0.05, 0.5], dtype=torch.float64).view(1, 1, 1, 4)
    inc = curvature_width(k, "increase", reference=0.05, gain=1.0).flatten().tolist()
    red = curvature_width(k, "reduce", reference=0.05).flatten().tolist()
    rmin = curvature_width(k, "reduce_min", reference=0.05, minimum=0.4).flatten().tolist()
    assert inc == pytest.approx([1.0, 1.2, 2.0, 2.0])
    assert red == pytest.approx([0.0, 0.2, 1.0, 1.0])
    assert rmin == pytest.approx([0.4, 0.52, 1.0, 1.0])


def test_module_records_and_checks():
    g = make_scene("sphere", (32, 32), dtype=torch.float64)
    with record_passes() as rec:
        w = CurvatureModulation("reduce_min", minimum=0.5)(g)
    assert w.shape == (1, 1, 32, 32)
    assert float(w.min()) >= 0.5 and float(w.max()) <= 1.0
    assert [r.name for r in rec] == ["curvature"]
    with pytest.raises(ValueError, match="normal"):
        screen_space_curvature(g.replace(normal=None))
    with pytest.raises(ValueError, match="strategy"):
        CurvatureModulation("flatten")

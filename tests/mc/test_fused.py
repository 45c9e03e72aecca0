"""The fused (torch.compile) photon step against the same function run eagerly, the geometry
of its boundary hits, and its clean fallback (sssbench.mc.fused)."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.mc import fused
from sssbench.mc.fused import Fused, torch_threads
from sssbench.mc.transport import SUBSTEPS, Ball, Slab, _fly_and_collide, _uniforms, exit_distance

N = 4096


def _state(geo_kind: str, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    dirn = torch.randn(3, N, generator=gen)
    dirn /= dirn.norm(dim=0)
    if geo_kind == "ball":
        geometry = Ball((1.0, -2.0, 30.0), 5.0)
        u = torch.randn(3, N, generator=gen)
        pos = u / u.norm(dim=0) * 5.0 * torch.rand(N, generator=gen) ** (1 / 3)
        pos += torch.tensor(geometry.center).view(3, 1)
    else:
        geometry = Slab(10.0, 12.0)
        pos = torch.rand(3, N, generator=gen) * torch.tensor([4.0, 4.0, 2.0]).view(3, 1)
        pos[2] += 10.0
    w = torch.rand(N, generator=gen) + 0.5
    inv_st = torch.rand(N, generator=gen) * 2  # mean free paths up to 2 mm: many hits
    alb = torch.rand(N, generator=gen)
    x = torch.empty(SUBSTEPS, N, dtype=torch.int64).random_(generator=gen)
    return geometry, (pos, dirn, w, inv_st, alb, x)


@pytest.mark.parametrize("geo_kind", ["ball", "slab"])
def test_compiled_step_equals_eager_step(geo_kind):
    # the compiled step is the same function: identical decisions and float32-close states
    # (the eager run is the reference; compilation may only reorder float32 arithmetic)
    if not fused.compile_enabled():
        pytest.skip("SSSBENCH_MC_COMPILE=0")
    geometry, state = _state(geo_kind)
    step = Fused(_fly_and_collide)
    eager = [t.clone() for t in state[:3]]
    comp = [t.clone() for t in state[:3]]
    with torch_threads(1):
        hit_e, coll_e = _fly_and_collide(*eager, *state[3:], geometry.params())
        hit_c, coll_c = step(*comp, *state[3:], geometry.params())
    assert step.failed is None, step.failed
    assert int((hit_e != hit_c).sum()) <= 2  # a tie s = db may round either way
    same = (hit_e == hit_c) & (coll_e == coll_c)
    assert int((~same).sum()) <= 2
    for a, b in zip(eager, comp, strict=True):
        assert torch.allclose(a[..., same], b[..., same], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("geo_kind", ["ball", "slab"])
def test_steps_stop_on_the_boundary_and_capture_weight(geo_kind):
    # the geometry's own definition: a photon that hit stands on the surface (|p − c| = R, or
    # z on a face); implicit capture leaves w·α^c after c collisions; a photon that did not
    # hit collided in every step; directions stay unit vectors
    geometry, (pos, dirn, w, inv_st, alb, x) = _state(geo_kind, seed=1)
    p, d, ww = pos.clone(), dirn.clone(), w.clone()
    with torch_threads(1):
        hit, coll = Fused(_fly_and_collide)(p, d, ww, inv_st, alb, x, geometry.params())
    assert 0.05 < float(hit.float().mean()) < 0.95
    if geo_kind == "ball":
        c = torch.tensor(geometry.center).view(3, 1)
        r = (p[:, hit] - c).norm(dim=0)
        assert torch.allclose(r, torch.full_like(r, geometry.radius), rtol=1e-5)
    else:
        z = p[2, hit]
        assert bool(((z - 10.0).abs().lt(1e-5) | (z - 12.0).abs().lt(1e-5)).all())
    assert bool((coll[~hit] == SUBSTEPS).all()) and bool((coll[hit] < SUBSTEPS).all())
    assert torch.allclose(ww, w * alb.double().pow(coll).float(), rtol=1e-5)
    assert torch.allclose(d.norm(dim=0), torch.ones(N), atol=1e-5)


def test_three_uniforms_from_one_draw_are_independent_uniforms():
    # moments of U(0, 1): mean 1/2, variance 1/12, no correlation between the three
    r = torch.empty(200_000, dtype=torch.int64).random_(generator=torch.Generator().manual_seed(5))
    u = torch.stack(_uniforms(r)).double()
    assert float(u.min()) > 0 and float(u.max()) < 1
    se_mean = math.sqrt(1 / 12 / u.shape[1])
    assert torch.allclose(u.mean(1), torch.full((3,), 0.5, dtype=torch.float64), atol=4 * se_mean)
    assert torch.allclose(u.var(1), torch.full((3,), 1 / 12, dtype=torch.float64), atol=1e-3)
    corr = torch.corrcoef(u)
    assert float((corr - torch.eye(3, dtype=torch.float64)).abs().max()) < 4 / math.sqrt(u.shape[1])


def test_exit_distance_of_a_ball_from_its_centre_is_the_radius():
    d = torch.randn(3, 50)
    d /= d.norm(dim=0)
    ball = Ball((3.0, 0.0, -1.0), 2.5)
    pos = torch.tensor(ball.center).view(3, 1).expand(3, 50)
    t = exit_distance(pos, d, ball.params())
    assert torch.allclose(t, torch.full((50,), 2.5))
    slab = Slab(0.0, math.inf)  # half-space: only downward... upward directions reach z = 0
    t = exit_distance(torch.zeros(3, 50) + torch.tensor([[0.0], [0.0], [1.0]]), d, slab.params())
    up = d[2] < 0
    assert torch.allclose(t[up], -1.0 / d[2, up]) and bool(torch.isinf(t[~up]).all())


def test_failed_compilation_falls_back_to_the_eager_result(monkeypatch):
    def broken(fn, **kwargs):
        def call(*args):
            raise RuntimeError("no C++ compiler")

        return call

    monkeypatch.setattr(torch, "compile", broken)
    monkeypatch.delenv("SSSBENCH_MC_COMPILE", raising=False)
    step = Fused(lambda a: a * 2)
    a = torch.arange(100.0)
    with torch_threads(1), pytest.warns(RuntimeWarning, match="no C\\+\\+ compiler"):
        out = step(a)
    assert torch.equal(out, a * 2) and step.failed and not step.active
    assert torch.equal(step(a), a * 2)  # stays eager, no second warning needed


def test_disabled_compilation_never_compiles(monkeypatch):
    def forbidden(fn, **kwargs):
        raise AssertionError("torch.compile must not be called")

    monkeypatch.setattr(torch, "compile", forbidden)
    monkeypatch.setenv("SSSBENCH_MC_COMPILE", "0")
    step = Fused(lambda a: a + 1)
    assert not step.active
    assert torch.equal(step(torch.ones(1000)), torch.full((1000,), 2.0))

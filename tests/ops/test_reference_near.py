"""The bilinear reconstruction's near field (sssbench.ops._reference_near): its 1D hat masses
against numerical quadrature, its nine weights against the box rule they split, and the
bilinear reference against the brute-force surface integral with Gaussians narrower than a
pixel (the closed-form "flat" and "narrow" rules and the per-quadrant Gauss–Legendre rule)."""

import math

import numpy as np
import pytest
import torch
from oracles import brute_force_reference
from scipy.integrate import quad

from sssbench.ops import _reference_near as near
from sssbench.ops import _reference_quad as _quad
from sssbench.ops._reference_near import (
    HAT_OFFSETS,
    hat_cell_sums,
    hat_cell_weights,
    hat_masses,
)
from sssbench.ops.reference import _sog_cell_weights, reference_radius_px, reference_sss
from sssbench.profiles import SumOfGaussians
from sssbench.profiles.sum_of_gaussians import cell_rules
from tests.ops.test_reference_far import _rel_rms, _targets, scene


def _hat(a: int, s: float, h: float) -> float:
    return 1 - abs(s) / (2 * h) if a == 0 else max(0.0, a * s / (2 * h))


@pytest.mark.parametrize("mu, sigma, h", [(0.0, 0.3, 1.0), (0.7, 0.2, 0.5), (-3.0, 0.5, 0.4)])
def test_hat_masses_equal_numerical_quadrature(mu, sigma, h):
    got = hat_masses(*(torch.tensor(x, dtype=torch.float64) for x in (mu, sigma, h)))
    for a, m in zip((-1, 0, 1), got, strict=True):

        def f(s, a=a):
            return _hat(a, s, h) * math.exp(-0.5 * ((s - mu) / sigma) ** 2) / (sigma * 2.5066283)

        want = quad(f, -h, 0, epsabs=0, epsrel=1e-13)[0] + quad(f, 0, h, epsabs=0)[0]
        assert float(m) == pytest.approx(want, rel=1e-7, abs=1e-300)


def test_nine_weights_add_up_to_the_box_rules_weight():
    # the hats sum to 1 at every point: the nine integrals split the box rule's cell integral
    rng = np.random.default_rng(0)
    prof = SumOfGaussians(
        torch.tensor([0.01, 0.2, 0.6]) ** 2, torch.tensor([[0.5, 0.3, 0.2]] * 3).t()
    )
    n = 64
    dx, dy, dz = (torch.from_numpy(rng.uniform(-0.8, 0.8, n)) for _ in range(3))
    hh = torch.full((n,), 0.25, dtype=torch.float64)
    v = prof.variances.tolist()
    for tilted in (False, True):
        sx = torch.from_numpy(rng.uniform(-2, 2, n)) if tilted else torch.zeros(n).double()
        sy = torch.from_numpy(rng.uniform(-2, 2, n)) if tilted else torch.zeros(n).double()
        rule = cell_rules(v, 0.0, 0.25, tilted)
        assert ("narrow" in rule) == tilted and ("flat" in rule) != tilted
        nine = hat_cell_weights(prof, rule, dx, dy, dz, hh, sx, sy)
        assert nine.shape == (3, len(HAT_OFFSETS), n) and bool((nine >= -1e-15).all())
        box = _sog_cell_weights(prof, rule, dx, dy, dz, hh, sx, sy)
        # quadrature rules differ (a rule per quadrant): to their accuracy
        torch.testing.assert_close(nine.sum(1), box, rtol=1e-6, atol=1e-12)


#: σ = 0.01 mm (a fifth of a pixel: the narrow closed form on tilted cells), 0.03 mm (the
#: per-quadrant Gauss–Legendre rule), 0.2 mm (moments)
NARROW = SumOfGaussians(
    torch.tensor([0.01, 0.03, 0.2]) ** 2,
    torch.tensor([[0.4, 0.2, 0.1], [0.3, 0.4, 0.3], [0.3, 0.4, 0.6]]),
)


@pytest.fixture(scope="module")
def narrow_setup():
    g = scene()
    return g, reference_radius_px(g, NARROW), _targets(g, 24)


@pytest.mark.parametrize("reconstruction", ["box", "bilinear"])
def test_narrow_gaussians_match_the_brute_force_surface_integral(narrow_setup, reconstruction):
    # curved, masked, a depth step and a shadow edge; float64. The bound is the box rule's
    # own: the narrow closed form completes the square as if the tangents were orthogonal
    # (measured: 4.8e-5 box, 9.7e-5 bilinear; the σ = 0.03 mm Gaussian alone 2.4e-9 / 2.5e-9)
    g, k, tg = narrow_setup
    want = brute_force_reference(g, NARROW, tg, k, reconstruction)
    out = reference_sss(g, NARROW, reconstruction=reconstruction)
    assert _rel_rms(out[0][:, tg[:, 0], tg[:, 1]].numpy().T, want) < 2e-4


def test_bilinear_float32_matches_float64(narrow_setup):
    g = narrow_setup[0]
    o64 = reference_sss(g, NARROW, reconstruction="bilinear")
    o32 = reference_sss(g.to(torch.float32), NARROW, reconstruction="bilinear")
    assert o32.dtype == torch.float32
    assert float((o32.double() - o64).norm() / o64.norm()) < 1e-6  # measured 4.3e-8


def _unfused_hat_cell_sums(profile, rule, dx, dy, dz, hh, sx, sy, values, cells, hat):
    """The old near field, kept as the oracle of ``hat_cell_sums``: the nine weights of
    ``hat_cell_weights`` (one (27, nodes) product per quadrature Gaussian) contracted with
    the gathered neighbours, all cells at once."""
    wgt = hat_cell_weights(profile, rule, dx, dy, dz, hh, sx, sy)  # (3, 9, M)
    q = values[cells[None, :] + hat[:, None]]  # (9, M, 4)
    num = torch.einsum("cjm,jmc->cm", wgt, q[..., 1:])
    den = torch.einsum("cjm,jm->cm", wgt, q[..., 0])
    return torch.cat([num, den])


@pytest.mark.parametrize("native", [False, True])
@pytest.mark.parametrize("tilted", [False, True])
def test_hat_cell_sums_equal_the_contracted_nine_weights(tilted, native, monkeypatch):
    # native: the Gauss–Legendre sums and the contraction in native/quad.c (issue 30)
    if native and not _quad.available():
        pytest.skip("the native reference quadrature is not available (no C compiler)")
    # several blocks and node sub-blocks, every rule: flat or narrow (σ = 0.01 mm) and
    # Gauss–Legendre orders 3..10
    monkeypatch.setattr(near, "_CELL_BLOCK", 40)
    monkeypatch.setattr(near, "_NODE_ELEMS", 3000)
    rng = np.random.default_rng(3)
    prof = SumOfGaussians(
        torch.tensor([0.01, 0.1, 0.2, 0.3, 0.6]) ** 2,
        torch.from_numpy(rng.uniform(0.05, 0.5, (5, 3))),
    )
    n, size = 150, 400
    dx, dy, dz = (torch.from_numpy(rng.uniform(-0.8, 0.8, n)) for _ in range(3))
    hh = torch.from_numpy(rng.uniform(0.1, 0.25, n))
    hh[::7] = 0.0  # cells off the surface
    sx = torch.from_numpy(rng.uniform(-2, 2, n)) if tilted else torch.zeros(n).double()
    sy = torch.from_numpy(rng.uniform(-2, 2, n)) if tilted else torch.zeros(n).double()
    values = torch.from_numpy(rng.uniform(0, 1, (size, 4)))
    cells = torch.from_numpy(rng.integers(30, size - 30, n))
    hat = torch.tensor([a - 20 * b for a, b in HAT_OFFSETS])
    v = prof.variances.tolist()
    rules = [cell_rules(v, near2, 0.25, tilted) for near2 in (0.0, 0.05, 0.5)]
    rules.append(tuple(r if isinstance(r, int) else None for r in rules[0]))
    if tilted:
        assert {r for rule in rules for r in rule} >= {"narrow", 3, 4, 6, 7, 8, 10}
    for rule in rules:
        args = (prof, rule, dx, dy, dz, hh, sx, sy, values, cells, hat)
        got, want = hat_cell_sums(*args, native=native), _unfused_hat_cell_sums(*args)
        assert got.shape == (6, n)
        # the same terms summed in another order: rounding
        torch.testing.assert_close(got, want, rtol=1e-13, atol=1e-15 * float(want.abs().max()))


def _old_sog_chunk(profile, v, fields, centre, shift, radius_mm, hat=None, values=None):
    """The bilinear branch of ``reference._sog_chunk`` before issue 30 (every cell of an
    offset, on the surface or not, through ``hat_cell_weights``, nine gathers per batch),
    kept as the oracle of the reference's near field."""
    import math

    from sssbench.ops.reference import _BATCH_ELEMS, _SOG_SKIP

    e = centre.numel()
    acc = torch.zeros(e, 3, dtype=torch.float64)
    wsum = torch.zeros_like(acc)
    xc, yc, zc = fields[0, centre], fields[1, centre], fields[2, centre]
    per = max(1, _BATCH_ELEMS // e)
    for a in range(0, shift.numel(), per):
        sh = shift[a : a + per]
        c = sh.numel()
        idx = (centre[None, :] + sh[:, None]).reshape(1, -1).expand(fields.shape[0], -1)
        nb = torch.gather(fields, 1, idx).view(-1, c, e)
        dx, dy, dz = nb[0] - xc, nb[1] - yc, nb[2] - zc
        hh, sx, sy = nb[3], nb[4], nb[5]
        near2 = (dx.abs() - hh).clamp_min(0) ** 2 + (dy.abs() - hh).clamp_min(0) ** 2
        near2_min = near2.amin(1).tolist()
        near_on = near2.masked_fill(hh <= 0, math.inf).amin(1).tolist()
        h_max = hh.amax(1).tolist()
        tilted = (torch.count_nonzero(sx, 1) + torch.count_nonzero(sy, 1)).tolist()
        groups = {}
        for j in range(c):
            if near_on[j] > radius_mm**2:
                continue
            rule = cell_rules(v, near2_min[j], h_max[j], tilted[j] > 0, 2.0 * _SOG_SKIP)
            if any(r is not None for r in rule):
                groups.setdefault(rule, []).append(j)
        for rule, rows in groups.items():
            sel = torch.tensor(rows)
            sub = [t.index_select(0, sel) for t in (dx, dy, dz, hh, sx, sy)]
            cells = idx[0].view(c, e).index_select(0, sel)
            wgt = hat_cell_weights(profile, rule, *(t.reshape(-1) for t in sub))
            wgt = wgt.view(3, 9, -1, e)
            for j, off in enumerate(hat.tolist()):
                qn = fields[6:10, cells + off]
                acc += (wgt[:, j] * qn[1:]).sum(1).t()
                wsum += (wgt[:, j] * qn[0]).sum(1).t()
    return acc, wsum


def test_reference_equals_the_unfused_near_field(monkeypatch):
    # the whole bilinear reference (curved, masked, a depth step and a shadow edge; and the
    # face at three scales with the six-Gaussian skin) with the old near field as the oracle
    import sssbench.ops.reference as ref
    from data_synth import make_scene

    cases = [(scene(), NARROW)]
    skin = SumOfGaussians.from_table("skin_deon6")
    for pmm in (0.1, 0.3, 1.0):
        cases.append((make_scene("face", (24, 24), dtype=torch.float64, pixel_mm=pmm), skin))
    for g, prof in cases:
        new = reference_sss(g, prof, reconstruction="bilinear")
        with monkeypatch.context() as m:
            m.setattr(ref, "_sog_chunk", _old_sog_chunk)
            old = reference_sss(g, prof, reconstruction="bilinear")
        assert float((new - old).abs().max()) < 1e-13 * float(old.abs().max())

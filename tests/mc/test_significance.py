"""The one significance rule of MC-based verdicts (sssbench.mc.significance), the walk's
per-group tallies it feeds on, and the cut-off energy that closes a lossless half-space."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.mc import searchlight_result
from sssbench.mc.significance import compare, jackknife, paired, scene_errors
from sssbench.mc.walk import walk

RADII = torch.tensor([0.0, 0.5, 1.0, 2.0, 5.0])


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SSSBENCH_CACHE_DIR", str(tmp_path))


def test_compare_rule():
    assert compare(-0.5, 0.1).verdict == "closer"
    assert compare(0.5, 0.1).verdict == "worse"
    assert compare(0.25, 0.1).verdict == "not resolved"
    assert compare(0.25, 0.1, photons=1_000_000).verdict == "not resolved at 1e+06 photons"
    assert compare(0.25, 0.1, k=2).verdict == "worse"
    assert compare(0.0, 0.0).verdict == "no difference"  # a tie is never a ranking
    assert compare(1e-9, 0.0).verdict == "worse"  # noiseless and different
    assert not compare(0.5, math.nan).resolved  # unknown noise resolves nothing
    with pytest.raises(ValueError, match="k must be"):
        compare(1.0, 0.1, k=0)


def _band(res):
    return res.groups[:, 1]  # the 0.5-1 mm annulus, (G, 3)


def test_two_models_below_the_noise_are_not_resolved():
    # two synthetic "models" of the band energy: the MC estimate ± 0.3 s.e. and ± 0.5 s.e.
    # (known truth up to the MC noise): their difference against transport is far below the
    # noise of the MC, so the rule must not rank them
    res = searchlight_result("skin1", RADII, photons=40_000)
    mc = res.fraction[1]
    se = res.fraction_stderr[1]
    model_a = mc + 0.3 * se
    model_b = mc - 0.5 * se

    def err(model):
        return lambda m, n: ((model - m[1]) / m[1]).abs()  # m: (K + 2, 3) pooled means

    diff, dse = paired(err(model_a), err(model_b), res.groups, res.group_photons)
    for c in range(3):
        v = compare(float(diff[c]), float(dse[c]), photons=res.photons)
        assert v.verdict == "not resolved at 4e+04 photons", (c, v)


def test_two_models_above_the_noise_are_resolved():
    res = searchlight_result("skin1", RADII, photons=40_000)
    mc = res.fraction[1]
    se = res.fraction_stderr[1]
    close, far = mc * (1 + 0.5 * se / mc), mc + 30 * se

    def err(model):
        return lambda m, n: ((model - m[1]) / m[1]).abs()

    diff, dse = paired(err(close), err(far), res.groups, res.group_photons)
    for c in range(3):
        assert compare(float(diff[c]), float(dse[c])).verdict == "closer"
    diff, dse = paired(err(far), err(close), res.groups, res.group_photons)
    assert all(
        compare(float(d), float(s)).verdict == "worse" for d, s in zip(diff, dse, strict=True)
    )


def test_jackknife_of_a_mean_is_the_binomial_standard_error():
    # the jackknife over groups of a linear statistic reproduces the per-photon s.e. (~within
    # its own sampling error with 16 groups)
    res = searchlight_result("skin1", RADII, photons=60_000)
    v, se = jackknife(lambda m, n: m[:4], res.groups, res.group_photons)
    assert torch.allclose(v, res.fraction, rtol=1e-12)
    ratio = se / res.fraction_stderr
    assert bool(((ratio > 0.5) & (ratio < 1.6)).all()), ratio


def test_groups_do_not_change_the_estimates():
    edges = torch.linspace(0.0, 8.0, 5)
    one = walk(0.95, photons=30_000, seed=3, radial_edges=edges, progress=False)
    many = walk(0.95, photons=30_000, seed=3, radial_edges=edges, progress=False, groups=7)
    assert torch.equal(one.top, many.top) and torch.equal(one.radial, many.radial)
    assert int(many.group_photons.sum()) == 30_000 and many.by_group.shape == (7, 5 + 4)
    assert torch.allclose(
        many.by_group.sum(0)[:5],
        torch.stack([one.top[0], one.bottom[0], one.absorbed[0], one.roulette[0], one.escaped[0]]),
    )
    assert torch.allclose(many.by_group.sum(0)[5:], one.radial[0])


def test_lossless_halfspace_reflects_everything_once_the_cut_off_is_added():
    # albedo 1, dielectric boundary: every photon eventually leaves through the top. The walk
    # cuts photons beyond kill_radius (roulette beyond roulette_radius, unbiased): the top exits
    # alone fall short of 1 by the cut-off energy, and top + cut-off is 1 within its s.e.
    t = walk(1.0, photons=40_000, eta=1.3, seed=2, roulette_radius=10.0, kill_radius=20.0,
             progress=False)  # fmt: skip
    top, top_se = t.estimate("top")
    esc, _ = t.estimate("escaped")
    both, se = t.estimate("top+escaped")
    assert esc > 10 * top_se  # the cut-off is a visible bias of the top exits alone
    assert abs(1.0 - top) > 3 * top_se
    assert abs(1.0 - both) <= 3 * se, (both, se)
    # the same through the searchlight (mm, per channel): lossless coefficients
    res = searchlight_result(((10.0, 20.0, 15.0), (0.0, 0.0, 0.0)), [0.0, 0.5, 1.0],
                             photons=20_000)  # fmt: skip
    assert bool((res.escaped > 3 * res.escaped_stderr).all())
    assert bool(((res.reflected - 1).abs() <= 3 * res.reflected_stderr).all()), res.reflected


def test_scene_errors_pair_the_same_batches():
    gen = torch.Generator().manual_seed(0)
    truth = torch.ones(3, 8, 8, dtype=torch.float64)
    batches = truth + 0.05 * torch.randn(8, 3, 8, 8, generator=gen, dtype=torch.float64)
    a = truth * 1.001  # 0.1 % off, under the noise of the mean (~0.6 %/pixel, 0.04 % overall)
    b = truth * 0.999
    c = truth * 1.2
    errors, diff = scene_errors({"a": a, "b": b, "c": c}, batches)
    assert errors["c"][0] == pytest.approx(0.2, rel=0.05)
    d, s = diff("a", "b")
    assert not compare(d, s).resolved
    d, s = diff("a", "c")
    assert compare(d, s).verdict == "closer"


def test_band_stderr_is_the_per_photon_one():
    # a band of several annuli: its exact s.e. (second moments add: one annulus per photon)
    # against the jackknife over 16 groups (which has ~18 % sampling error of its own)
    res = searchlight_result("skin1", RADII, photons=60_000)
    m, se = res.band(0.0, 2.0)
    assert torch.allclose(m, res.fraction[:3].sum(0), rtol=1e-12)
    _, jse = jackknife(lambda x, n: x[:3].sum(0), res.groups, res.group_photons)
    assert bool(((se / jse > 0.5) & (se / jse < 2.0)).all()), (se, jse)
    # roulette beyond the last radius (5 mm ≈ 4 mfp in red) gives weights 4, 16, ...: the
    # s.e. is at least the binomial one of the photon count
    assert bool((se >= torch.sqrt(m * (1 - m) / 60_000) * 0.99).all())
    with pytest.raises(ValueError, match="union of annuli"):
        res.band(0.0, 1.5)


def test_bootstrap_sees_the_kink_the_jackknife_misses():
    # two fixed models 1.18 and 1.116 against an MC value 1 ± 0.16: the truth may lie between
    # them, so which is closer is not resolved, although |e_a| − |e_b| = 0.064 has a small
    # linearised (jackknife-like) error 0.064 × 0.16
    from sssbench.mc.significance import bootstrap

    mean, se = torch.tensor([1.0]), torch.tensor([0.16])
    d, s = bootstrap(lambda t: (1.18 - t).abs() / t - (1.116 - t).abs() / t, mean, se)
    assert float(d) == pytest.approx(0.064)
    assert not compare(float(d), float(s)).resolved
    d, s = bootstrap(lambda t: (1.18 - t).abs() / t - (1.116 - t).abs() / t, mean, se / 100)
    assert compare(float(d), float(s)).verdict == "worse"
    assert compare(1e-9, 0.0, tol=1e-6).verdict == "no difference"

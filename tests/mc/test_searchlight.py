"""Searchlight profiles: the H-function oracle through the mm/channel plumbing, the scaling
law of homogeneous media, and a disk cache that cannot go stale."""

from __future__ import annotations

import importlib

import pytest
import torch

from sssbench.mc import halfspace_reflectance, searchlight, searchlight_result

#: the module (the package exports a function of the same name)
searchlight_module = importlib.import_module("sssbench.mc.searchlight")

RADII = torch.tensor([0.0, 0.5, 1.0, 2.0, 4.0])


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SSSBENCH_CACHE_DIR", str(tmp_path))


def test_index_matched_total_matches_h_function():
    # per channel albedo 0.5, 0.9, 0.99 with η = 1: total = 1 − H(1)√(1 − a) (Chandrasekhar)
    ss = torch.tensor([0.5, 0.9, 0.99])
    # radii to 40 mfp: the walk stops photons beyond 80 mfp, ~14 diffusion lengths at a = 0.99
    radii = torch.tensor([0.0, 1.0, 5.0, 40.0])
    res = searchlight_result((ss, 1 - ss, 1.0), radii, photons=30_000, cache=False)
    assert bool((res.escaped < 1e-4).all())
    for c, a in enumerate(ss.tolist()):
        exact = halfspace_reflectance(a)
        assert abs(float(res.total[c]) - exact) <= 3 * float(res.total_stderr[c]), (c, exact)
    # the annuli partition the exitance inside the last radius
    assert bool((res.fraction.sum(0) <= res.total + 1e-12).all())


def test_similarity_scaling_of_lengths():
    # homogeneous medium: scaling every coefficient by k scales lengths by 1/k, so the energy
    # through the annulus [r0, r1]/k at kσ equals that through [r0, r1] at σ (same seed: the
    # walks in mean free paths are the same draws)
    mat = ((0.8, 1.2, 2.0), (0.02, 0.05, 0.1), 1.3)
    k = 2.0
    scaled = (tuple(k * v for v in mat[0]), tuple(k * v for v in mat[1]), 1.3)
    a = searchlight_result(mat, RADII, photons=3000, cache=False)
    b = searchlight_result(scaled, RADII / k, photons=3000, cache=False)
    assert torch.allclose(a.fraction, b.fraction, atol=1e-12)
    assert torch.allclose(b.R, a.R * k * k, rtol=1e-9)


def test_cache_hits_and_never_goes_stale(tmp_path, monkeypatch):
    r1, e1 = searchlight("skin1", RADII, photons=500)
    files = list((tmp_path / "mc").glob("*.pt"))
    assert len(files) == 1
    r2, _ = searchlight("skin1", RADII, photons=500)
    assert torch.equal(r1, r2) and len(list((tmp_path / "mc").glob("*.pt"))) == 1
    # any change of the inputs or of the walk's source is a different entry
    searchlight("skin1", RADII, photons=501)
    searchlight("skin1", RADII, photons=500, seed=1)
    monkeypatch.setattr(searchlight_module, "mc_digest", lambda: "edited-source")
    searchlight("skin1", RADII, photons=500)
    assert len(list((tmp_path / "mc").glob("*.pt"))) == 4
    assert bool((e1 >= 0).all()) and r1.shape == (len(RADII) - 1, 3)


@pytest.mark.parametrize(
    ("material", "radii", "exc"),
    [
        ("unobtainium", RADII, ValueError),
        ("skin1", torch.tensor([0.0, 2.0, 1.0]), ValueError),
        ("skin1", torch.tensor([1.0]), ValueError),
        (42, RADII, TypeError),
        (((1.0, 1.0, 1.0), (-0.1, 0.0, 0.0)), RADII, ValueError),
    ],
)
def test_bad_inputs(material, radii, exc):
    with pytest.raises(exc):
        searchlight_result(material, radii, photons=10, cache=False)

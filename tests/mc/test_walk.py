"""The random walk against outside oracles: Chandrasekhar's half-space reflectance, energy
conservation, the thick conservative slab, HG's mean cosine and the Fresnel equations."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.mc import fresnel_dielectric, h_function, halfspace_reflectance, slab, walk
from sssbench.mc.walk import _new_directions

#: photons per albedo: chosen for run time (~2–4 M collisions each), not for the tolerance
HALFSPACE = {0.5: 1_500_000, 0.9: 400_000, 0.99: 150_000}


@pytest.mark.parametrize("a", sorted(HALFSPACE))
def test_halfspace_reflectance_matches_chandrasekhar(a):
    # index-matched isotropic half-space, normal incidence: R = 1 − H(1)√(1 − a)
    # (Chandrasekhar, Radiative Transfer 1950, the albedo problem; H from our quadrature,
    # itself checked against his table in test_hfunction.py)
    t = walk(a, photons=HALFSPACE[a], seed=1, progress=False)
    r, se = t.estimate("top")
    exact = halfspace_reflectance(a)
    assert abs(r - exact) <= 3 * se, (r, se, exact)
    assert abs(r - exact) <= 0.005 * exact, (r, exact)
    assert t.counts["bottom"] == 0 and t.counts["roulette"] == 0


def test_two_worker_processes_sum_independent_walks():
    # the shares are walked with their own generators in 2 processes: the total still counts
    # every photon once (R + T + A = 1 per photon in an analog slab) and the half-space
    # reflectance is Chandrasekhar's; were both shares seeded alike, the total would be exactly
    # twice one share
    t = walk(0.9, photons=200_000, thickness=3.0, eta=1.0, seed=5, workers=2, progress=False)
    assert t.photons == 200_000 and sum(t.counts.values()) == 200_000
    r, t_, a = (t.estimate(f)[0] for f in ("top", "bottom", "absorbed"))
    assert r + t_ + a == pytest.approx(1.0, abs=1e-12)
    half = walk(0.9, photons=100_000, thickness=3.0, eta=1.0, seed=5, progress=False)
    assert float(t.top[0]) != 2 * float(half.top[0])
    h = walk(0.9, photons=400_000, seed=1, workers=2, progress=False)
    r, se = h.estimate("top")
    assert abs(r - halfspace_reflectance(0.9)) <= 3 * se, (r, se)


@pytest.mark.parametrize(
    ("a", "thickness", "eta", "g"),
    [(0.7, 2.0, 1.0, 0.0), (0.95, 5.0, 1.3, 0.0), (0.9, 1.0, 1.5, 0.8), (1.0, 3.0, 1.4, -0.3)],
)
def test_slab_conserves_energy_per_photon(a, thickness, eta, g):
    out = slab(a, thickness, eta=eta, g=g, photons=20_000, seed=2)
    assert out["counts_sum"] == out["photons"]  # every photon ends in exactly one fate
    assert out["R"] + out["T"] + out["A"] == pytest.approx(1.0, abs=1e-12)
    if a == 1.0:
        assert out["A"] == 0.0
    assert out["specular"] == pytest.approx(((eta - 1) / (eta + 1)) ** 2)


def test_thick_conservative_slab_transmission():
    # Thick conservative isotropic slab, optical thickness b, normal incidence:
    # T = 4 K(1) / (3 (b + 2 q0)) + O(e^{-b}) (van de Hulst, Multiple Light Scattering 1980,
    # vol. 2 ch. 13, asymptotic thick-layer formulas), with the escape function
    # K(μ) = (√3/4) H(μ) (normalised 2∫K μ dμ = 1) and the Milne extrapolation length
    # q0 = 0.7104461 (Chandrasekhar 1950, ch. III).
    b = 10.0
    expected = 4 * (math.sqrt(3) / 4 * float(h_function(1.0, 1.0))) / (3 * (b + 2 * 0.7104461))
    out = slab(1.0, b, photons=150_000, seed=3)
    assert abs(out["T"] - expected) <= 3 * out["T_stderr"], (out["T"], out["T_stderr"], expected)
    assert out["T"] == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("g", [-0.5, 0.3, 0.9])
def test_henyey_greenstein_mean_cosine_is_g(g):
    # the defining moment of HG: <cos θ> = g (Henyey & Greenstein 1941)
    gen = torch.Generator().manual_seed(4)
    n = 200_000
    d = torch.randn(3, n, generator=gen, dtype=torch.float64)
    d = d / d.norm(dim=0, keepdim=True)
    xi = torch.rand(2, n, generator=gen, dtype=torch.float64)
    new = _new_directions(d, xi[0], xi[1], g)
    cos = (new * d).sum(0)
    assert torch.allclose(new.norm(dim=0), torch.ones(n, dtype=torch.float64), atol=1e-9)
    assert abs(float(cos.mean()) - g) <= 4 * float(cos.std()) / math.sqrt(n)


def test_fresnel_normal_incidence_and_total_internal_reflection():
    eta = 1.3
    c = torch.tensor([1.0], dtype=torch.float64)
    # normal incidence: ((n1 − n2)/(n1 + n2))², from either side
    assert float(fresnel_dielectric(c, eta)) == pytest.approx(((eta - 1) / (eta + 1)) ** 2)
    assert float(fresnel_dielectric(c, 1 / eta)) == pytest.approx(((eta - 1) / (eta + 1)) ** 2)
    crit = math.sqrt(1 - 1 / eta**2)  # cos of the critical angle seen from inside
    below = torch.tensor([crit - 1e-6, 0.0], dtype=torch.float64)
    assert torch.all(fresnel_dielectric(below, eta) == 1.0)
    assert float(fresnel_dielectric(c, 1.0)) == 0.0


def test_fresnel_reciprocity_between_sides():
    # Stokes relations: the reflectance is the same for the two directions of one ray path,
    # F_inside(θ_i) = F_outside(θ_t) with η sin θ_i = sin θ_t
    eta = 1.4
    cos_out = torch.linspace(0.05, 1.0, 50, dtype=torch.float64)  # angle in air
    sin_in = torch.sqrt(1 - cos_out**2) / eta
    cos_in = torch.sqrt(1 - sin_in**2)
    assert torch.allclose(fresnel_dielectric(cos_in, eta), fresnel_dielectric(cos_out, 1 / eta))


def test_roulette_is_unbiased_in_a_lossless_dielectric_slab():
    # conservation in expectation: a = 1 slab with roulette must still return R + T = 1
    t = walk(1.0, photons=20_000, eta=1.3, thickness=12.0, roulette_radius=3.0, seed=5,
             progress=False)  # fmt: skip
    both = t.top + t.bottom  # per photon only one of the two is non-zero: sums of squares add
    r = float(both[0]) / t.photons
    se = math.sqrt((float(both[1]) / t.photons - r * r) / t.photons)
    assert abs(r - 1.0) <= 3 * se, (r, se)
    assert t.counts["roulette"] > 0  # the roulette was exercised


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"albedo": 1.2, "photons": 10}, "albedo"),
        ({"albedo": 0.5, "photons": 1}, "photons"),
        ({"albedo": 0.5, "photons": 10, "g": 1.0}, "g"),
        ({"albedo": 0.5, "photons": 10, "eta": 0.5}, "eta"),
        ({"albedo": 0.5, "photons": 10, "thickness": 0.0}, "thickness"),
        ({"albedo": 1.0, "photons": 10}, "kill_radius"),
        ({"albedo": 0.5, "photons": 10, "radial_edges": torch.tensor([1.0, 0.5])}, "radial"),
    ],
)
def test_bad_inputs(kwargs, match):
    a = kwargs.pop("albedo")
    with pytest.raises(ValueError, match=match):
        walk(a, **kwargs)


def test_walk_restores_the_callers_thread_count():
    saved = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        walk(0.5, photons=100, threads=1, progress=False)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)

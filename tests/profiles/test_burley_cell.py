"""Cell integrals of Burley's profile, whose ``1/r`` singularity at r = 0 the exact reference
integrates over each pixel's centre cell: against scipy's adaptive quadrature (split at the
singular point) and energy conservation over a plane."""

from __future__ import annotations

import math

import pytest
import torch
from scipy import integrate

from sssbench.profiles import BurleyNormalized, Profile

DT = torch.float64


def t(v: float) -> torch.Tensor:
    return torch.tensor([v], dtype=DT)


def burley_r(d: float, a: float):
    """Burley's R(r) (Christensen & Burley 2015) in plain floats, the exact 1/r included."""

    def f(r: float) -> float:
        return a * (math.exp(-r / d) + math.exp(-r / (3 * d))) / (8 * math.pi * d * r)

    return f


def dblquad_patch(f, dx, dy, dz, h, sx=0.0, sy=0.0, split=None):
    """∫∫ f(|p(s,t)|) √(1+sx²+sy²) over [−h, h]², p = (dx+s, dy+t, dz+sx s+sy t); the domain
    is split at ``split`` (the singular point) so the singularity sits at sub-domain corners."""
    area = math.sqrt(1 + sx * sx + sy * sy)

    def g(b, a):
        return f(math.sqrt((dx + a) ** 2 + (dy + b) ** 2 + (dz + sx * a + sy * b) ** 2)) * area

    xs, ys = [-h, h], [-h, h]
    if split is not None:
        xs = sorted({*xs, split[0]})
        ys = sorted({*ys, split[1]})
    return sum(
        integrate.dblquad(g, xa, xb, ya, yb, epsabs=1e-14, epsrel=1e-12)[0]
        for xa, xb in zip(xs[:-1], xs[1:], strict=True)
        for ya, yb in zip(ys[:-1], ys[1:], strict=True)
    )


@pytest.mark.parametrize("h", [0.02, 0.3, 1.0, 4.0])
def test_centre_cell_matches_split_dblquad(h):
    # the singular point at the cell centre, cells from 1/50 to 4 shape lengths d
    p = BurleyNormalized([1.0, 0.5, 2.0], [0.8, 0.6, 0.4])
    got = p.cell_integral(t(0.0), t(0.0), t(0.0), t(h), t(h))[0]
    for c in range(3):
        want = dblquad_patch(burley_r(float(p.d[c]), float(p.albedo[c])), 0, 0, 0, h, split=(0, 0))
        assert got[c].item() == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize(
    "dx, dy, dz",
    [(0.2, -0.1, 0.0), (0.6, 0.0, 0.0), (1.0, 1.0, 0.0), (0.3, 0.2, 0.05), (0.9, -0.4, 0.3)],
)
def test_off_centre_and_neighbour_cells_match_dblquad(dx, dy, dz):
    # singular point inside the cell off-centre, on the plane's extension next to the cell,
    # diagonal neighbour, and slightly off the plane (h0 > 0: smooth but sharply peaked)
    p = BurleyNormalized(0.4, 0.7)
    h = 0.5
    got = p.cell_integral(t(dx), t(dy), t(dz), t(h), t(h))[0, 0].item()
    inside = abs(dx) < h and abs(dy) < h
    want = dblquad_patch(burley_r(0.4, 0.7), dx, dy, dz, h, split=(-dx, -dy) if inside else None)
    assert got == pytest.approx(want, rel=1e-8)


@pytest.mark.parametrize("sx, sy", [(0.5, -0.3), (3.0, 1.0), (-8.0, 0.2)])
def test_tilted_cell_through_the_singular_point_matches_dblquad(sx, sy):
    # the planar patch p = (dx+s, dy+t, dz + sx s + sy t) passes through the origin at
    # (s, t) = (−dx, −dy), inside the cell: the reference's centre cell on a slope, and the
    # same patch shifted off the origin's foot
    p = BurleyNormalized(0.7, 0.9)
    h, dx, dy = 0.5, 0.15, -0.2
    dz = sx * dx + sy * dy  # p(−dx, −dy) = 0
    got = p.cell_integral(t(dx), t(dy), t(dz), t(h), t(h), t(sx), t(sy))[0, 0].item()
    want = dblquad_patch(burley_r(0.7, 0.9), dx, dy, dz, h, sx, sy, split=(-dx, -dy))
    assert got == pytest.approx(want, rel=1e-8)
    centre = p.cell_integral(t(0.0), t(0.0), t(0.0), t(h), t(h), t(sx), t(sy))[0, 0].item()
    want0 = dblquad_patch(burley_r(0.7, 0.9), 0, 0, 0, h, sx, sy, split=(0, 0))
    assert centre == pytest.approx(want0, rel=1e-8)


@pytest.mark.parametrize("pix", [0.05, 2.0])
def test_cells_of_a_plane_conserve_the_total(pix):
    # Σ over a plane's cells of ∫∫ R dA = ∫ 2πr R dr = A (the closed form), up to the energy
    # beyond the grid's inscribed circle (< 1e-10 here); shape lengths from a tenth of a pixel
    # to 1.5 pixels. An 8×8 rule alone loses 7–15% of the centre cell
    p = BurleyNormalized([0.1 * pix, 0.5 * pix, 1.5 * pix], [0.8, 0.6, 0.4])
    k = int(p.radius(1e-10) / pix) + 1
    assert float(p.energy_beyond(k * pix).max()) < 1e-10
    o = torch.arange(-k, k + 1, dtype=DT) * pix
    dx, dy = o[None, :].expand(2 * k + 1, -1), o[:, None].expand(-1, 2 * k + 1)
    half = torch.full_like(dx, pix / 2)
    total = p.cell_integral(dx, dy, torch.zeros_like(dx), half, half).sum((0, 1))
    assert torch.allclose(total, p.albedo, rtol=0, atol=1e-10)


def test_float32_cells_match_float64():
    p = BurleyNormalized([1.0, 0.5, 2.0], [0.8, 0.6, 0.4])
    args = [torch.tensor([0.0, 0.5, 1.0, 0.1]), torch.tensor([0.0, 0.0, 1.0, -0.2])]
    z = torch.zeros(4)
    h = torch.full((4,), 0.25)
    f32 = p.cell_integral(*args, z, h, h)
    f64 = p.cell_integral(*(a.double() for a in args), z.double(), h.double(), h.double())
    assert f32.dtype == torch.float32
    assert torch.allclose(f32.double(), f64, rtol=1e-6)


class _NumericBurley(Profile):
    """Burley's R(r) with only evaluate/length_scales and the singular flag: the base class's
    numeric ``radial_mass`` (Gauss–Legendre over r R(r)) instead of the closed form."""

    singular_at_origin = True

    def __init__(self, p: BurleyNormalized) -> None:
        self.p = p

    def evaluate(self, r):
        return self.p.evaluate(r)

    def length_scales(self):
        return self.p.length_scales()


def test_generic_singular_profile_uses_the_polar_rule():
    # any profile declaring the singularity gets the polar cell integral; its numeric radial
    # mass agrees with Burley's closed form on the cells near the singular point
    p = BurleyNormalized([1.0, 0.5, 2.0], [0.8, 0.6, 0.4])
    num = _NumericBurley(p)
    dx = torch.tensor([0.0, 0.1, 1.0, 0.0])
    dy = torch.tensor([0.0, -0.3, 0.0, 0.0])
    dz = torch.tensor([0.0, 0.0, 0.0, 0.2])
    h = torch.full((4,), 0.5)
    args = [v.double() for v in (dx, dy, dz, h, h)]
    assert torch.allclose(num.cell_integral(*args), p.cell_integral(*args), rtol=1e-9)
    a, b = torch.tensor([0.0, 0.3, 2.0], dtype=DT), torch.tensor([0.4, 1.0, 2.5], dtype=DT)
    assert torch.allclose(Profile.radial_mass(p, a, b), p.radial_mass(a, b), rtol=1e-9)

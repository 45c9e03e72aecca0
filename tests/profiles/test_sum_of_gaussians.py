"""SumOfGaussians closed forms against scipy quadrature and the papers' tables."""

import math

import numpy as np
import pytest
import torch
from scipy import integrate

from sssbench.profiles import SOG_TABLES, SumOfGaussians


def radial(profile: SumOfGaussians, r: float) -> np.ndarray:
    """Independent evaluation of 001 eq. 6–7 in numpy."""
    v = profile.variances.numpy()
    w = profile.weights.numpy()
    g = np.exp(-(r**2) / (2 * v)) / (2 * np.pi * v)
    return g @ w


@pytest.mark.parametrize("name", sorted(SOG_TABLES))
def test_preintegrated_matches_quadrature_of_radial_profile(name):
    p = SumOfGaussians.from_table(name)
    xs = [0.0, 0.05, 0.3, 1.0, 2.5]
    got = p.preintegrated(torch.tensor(xs, dtype=torch.float64)).numpy()
    for i, x in enumerate(xs):
        for c in range(3):
            # 000 eq. 4: a_p(x) = ∫ R(√(x²+y²)) dy, split at the scales of the Gaussians
            pts = np.sqrt(p.variances.numpy())
            f = lambda y, c=c, x=x: radial(p, math.hypot(x, y))[c]  # noqa: E731
            val = (
                2 * integrate.quad(f, 0, np.inf, points=None, epsabs=0, epsrel=1e-12, limit=400)[0]
            )
            if val == 0:
                assert got[i, c] == 0
                continue
            # the integrand's scales span decades: check also a split integral
            edges = np.concatenate([[0.0], np.sort(pts) * 8, [np.inf]])
            val2 = 2 * sum(
                integrate.quad(f, a, b, epsabs=0, epsrel=1e-12, limit=400)[0]
                for a, b in zip(edges[:-1], edges[1:], strict=True)
            )
            assert got[i, c] == pytest.approx(val2, rel=1e-8)


def test_tables_are_normalised_and_match_paper_values():
    # 004 Table 3.1 (blue first weight 0.649, see the module docstring), 003 Table 7.1
    skin = SumOfGaussians.from_table("skin_deon6")
    assert skin.total().tolist() == pytest.approx([1.0, 1.0, 1.0], abs=1e-12)
    assert skin.variances.tolist() == [0.0064, 0.0484, 0.187, 0.567, 1.99, 7.41]
    jg = SumOfGaussians.from_table("skin_jg10")
    # 003 Table 7.1 weights sum: R 0.9999, G 0.9999, B 0.9998
    assert jg.total().tolist() == pytest.approx([0.9999, 0.9999, 0.9998], abs=1e-12)


def test_total_and_cdf_match_quadrature():
    p = SumOfGaussians.from_table("marble_jg10")
    for c in range(3):
        tot = integrate.quad(lambda r, c=c: 2 * np.pi * r * radial(p, r)[c], 0, 60, limit=400)[0]
        assert float(p.total()[c]) == pytest.approx(tot, rel=1e-9)
    x = 0.7
    cdf = p.preintegrated_cdf(torch.tensor(x, dtype=torch.float64))
    a = lambda t, c: float(p.preintegrated(torch.tensor(t, dtype=torch.float64))[c])  # noqa: E731
    for c in range(3):
        ref = integrate.quad(lambda t, c=c: a(t, c), -np.inf, x, limit=400)[0]
        assert float(cdf[c]) == pytest.approx(ref, rel=1e-9)


def test_cell_integral_matches_dblquad_including_subpixel_gaussian():
    p = SumOfGaussians.from_table("skin_deon6")  # narrowest sigma 0.08 mm
    cells = [(0.0, 0.0, 0.0, 0.5), (0.6, -0.3, 0.2, 0.25), (2.0, 1.0, 0.5, 0.5)]
    for dx, dy, dz, h in cells:
        got = p.cell_integral(*(torch.tensor([v], dtype=torch.float64) for v in (dx, dy, dz, h, h)))
        for c in range(3):
            f = lambda y, x, c=c, dz=dz: radial(p, math.sqrt(x * x + y * y + dz * dz))[c]  # noqa: E731
            ref = integrate.dblquad(f, dx - h, dx + h, dy - h, dy + h, epsabs=1e-13, epsrel=1e-10)[
                0
            ]
            assert float(got[0, c]) == pytest.approx(ref, rel=1e-7, abs=1e-14)


def test_interval_mass_has_no_cancellation_in_the_tail():
    from sssbench.profiles.sum_of_gaussians import interval_mass

    a = torch.tensor([9.0], dtype=torch.float32)
    b = torch.tensor([10.0], dtype=torch.float32)
    # Φ(10) − Φ(9) = 0.5 (erfc(9/√2) − erfc(10/√2)) = 1.1285884e-19 (scipy.special.ndtr(-9) - ...)
    from scipy.special import ndtr

    ref = ndtr(-9.0) - ndtr(-10.0)
    assert float(interval_mass(a, b)) == pytest.approx(ref, rel=1e-5)


@pytest.mark.parametrize(
    "variances, weights, match",
    [
        (torch.tensor([1.0, -1.0]), torch.ones(2, 3), "variances"),
        (torch.tensor([1.0]), torch.ones(2, 3), "weights"),
        (torch.tensor([float("nan")]), torch.ones(1, 3), "variances"),
        (torch.tensor([1.0]), torch.tensor([[1.0, float("inf"), 0.0]]), "weights"),
    ],
)
def test_bad_inputs_name_the_argument(variances, weights, match):
    with pytest.raises(ValueError, match=match):
        SumOfGaussians(variances, weights)


def test_unknown_table_name():
    with pytest.raises(ValueError, match="name must be one of"):
        SumOfGaussians.from_table("skin_unknown")


def test_narrow_tilted_cell_is_capped_on_steep_silhouette_cells():
    """A Gaussian narrower than the cell on a patch sloping along both axes: the orthogonal-
    tangent closed form can overstate a far cell by orders of magnitude (uncapped: 0.99 of
    the mass below); the result must stay within the exact area × peak-density bound, which
    scipy's dblquad of the patch integral (independent) also respects."""
    from sssbench.profiles.sum_of_gaussians import narrow_tilted_cell_mass

    v, h = 0.01, 0.25  # σ = 0.1 mm on a 0.5 mm cell
    f64 = lambda x: torch.tensor([x], dtype=torch.float64)  # noqa: E731
    for dx, dy, dz, sx, sy in [
        (0.1792, -0.6356, -0.5354, -3.9745, 3.5970),  # steep both ways, 3.9σ away
        (0.9, 0.0, 0.0, -3.97, -2.92),
        (-0.6, 0.7, 0.4, 2.0, -1.5),
    ]:
        got = float(narrow_tilted_cell_mass(*map(f64, (dx, dy, dz, h, h, sx, sy)), v))

        def density(t, s, dx=dx, dy=dy, dz=dz, sx=sx, sy=sy):
            r2 = (dx + s) ** 2 + (dy + t) ** 2 + (dz + sx * s + sy * t) ** 2
            return math.exp(-r2 / (2 * v)) / (2 * math.pi * v) * math.sqrt(1 + sx * sx + sy * sy)

        ref = integrate.dblquad(density, -h, h, -h, h, epsabs=1e-15, epsrel=1e-9)[0]
        near2 = max(abs(dx) - h, 0) ** 2 + max(abs(dy) - h, 0) ** 2
        area = 4 * h * h * math.sqrt(1 + sx * sx + sy * sy)
        cap = area * math.exp(-near2 / (2 * v)) / (2 * math.pi * v)
        assert ref <= cap and got <= cap * (1 + 1e-12)
        assert abs(got - ref) <= cap

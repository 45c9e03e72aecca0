"""The cost-as-the-work-grows section (issue 30): its log-log fit and its stencil discs. The
section's quick run is ``tests/experiments/test_experiments.py`` (every registered section)."""

from __future__ import annotations

import math

import pytest

from experiments.common import scene
from experiments.scaling import _disc_mask, fit_exponent


def test_fit_exponent_recovers_a_power_law_exactly():
    xs = [256.0, 1024.0, 4096.0, 65536.0]
    k, se = fit_exponent(xs, [3e-4 * x**1.5 for x in xs])
    assert k == pytest.approx(1.5, abs=1e-12) and se == pytest.approx(0.0, abs=1e-12)


def test_fit_exponent_standard_error_by_hand():
    # ln x = 0, 1, 2 and ln t = 0, 1, 3: slope Σ(dx dy)/Σ dx² = (4/3 + 5/3) / 2 = 3/2; residuals
    # 1/6, −1/3, 1/6 -> s² = (1/36 + 1/9 + 1/36) / (3 − 2) = 1/6; se = √(s² / Σ dx²) = √(1/12)
    k, se = fit_exponent([1.0, math.e, math.e**2], [1.0, math.e, math.e**3])
    assert k == pytest.approx(1.5, rel=1e-12)
    assert se == pytest.approx(math.sqrt(1 / 12), rel=1e-12)
    k, se = fit_exponent([1.0, 2.0], [1.0, 4.0])  # two points: a slope, no error estimate
    assert k == pytest.approx(2.0) and math.isnan(se)


@pytest.mark.parametrize(
    "bad", [([1.0], [1.0]), ([1.0, 0.0], [1.0, 2.0]), ([2.0, 2.0], [1.0, 3.0])]
)
def test_fit_exponent_refuses_what_it_cannot_fit(bad):
    with pytest.raises(ValueError, match="x"):
        fit_exponent(*bad)


@pytest.mark.parametrize("fraction", [1 / 16, 1 / 4, 1.0])
def test_disc_stencil_covers_the_fraction_asked(fraction):
    # the covered-pixels axis: a disc of area f·H·W (π r² = f H W) holds f of the pixels, to
    # within its perimeter's pixels (2 π r)
    h = w = 128
    g = _disc_mask(scene("step_edge", (h, w)), fraction)
    covered = float((g.mask > 0).sum())
    r = math.sqrt(fraction * h * w / math.pi)
    assert abs(covered - fraction * h * w) <= (2 * math.pi * r if fraction < 1 else 0)

"""Stiff and extreme parameters (issue 8): no NaN or Inf, normalised kernels preserve constants
(1e-5 float32, 1e-12 float64), non-negative kernels stay within the input's range, float32
within the documented tolerance of float64 (``docs/numerics.md``).

The cases are the quick grid of ``experiments/stability.py`` (the experiment sweeps more and
writes ``experiments/sections/stability.md``); every case is one parametrised test here.
"""

from __future__ import annotations

import importlib
import math
import sys
from pathlib import Path

import pytest
import torch

_ROOT = Path(__file__).resolve().parents[2]
if str(_ROOT) not in sys.path:  # the experiments package lives beside sssbench, not installed
    sys.path.insert(0, str(_ROOT))
stability = importlib.import_module("experiments.stability")

CASES = stability.cases(quick=True)
_IDS: dict[str, int] = {}


def _id(group: str, i: int) -> str:
    _IDS[group] = _IDS.get(group, -1) + 1
    return f"{group}-{_IDS[group]}"


def test_at_least_200_combinations():
    assert len(CASES) >= 200
    assert {g for g, _ in CASES} == set(stability.GROUPS)


@pytest.mark.parametrize("case", [pytest.param(c, id=_id(g, i)) for i, (g, c) in enumerate(CASES)])
def test_extreme_case(case):
    out = case()
    detail = (
        f"{out.group}: {out.label}: finite={out.finite}, const32={out.const_err32:.2e}, "
        f"const64={out.const_err64:.2e}, range={out.range_excess:.2e}, "
        f"f32={out.f32_err:.2e} (allowed {out.f32_allow:.2e}), "
        f"error={out.error!r}, extra={out.extra}"
    )
    assert out.ok, detail


def test_tolerances_are_the_documented_ones():
    assert stability.CONST_TOL == {torch.float32: 1e-5, torch.float64: 1e-12}
    doc = (Path(__file__).resolve().parents[2] / "docs" / "numerics.md").read_text()
    assert "| 1e-5 | 1e-12 |" in doc and stability.F32_TOL == 1e-5
    assert "`max(1e-5, K · 2⁻²⁴)`" in doc
    assert f"{stability.F32_DEPTH_FACTOR:g} · ulp32(max depth) / surface_scale" in doc


def test_c_curves_continuous_at_zero():
    c0 = stability.c_curves(0.0)
    for x in (1e-300, 1e-16, 1e-9):
        assert torch.allclose(stability.c_curves(x), c0, rtol=0, atol=10 * x + 1e-15)
    # the limits are the printed curves' values at 0 (expm1 form): C1(0) = −0.3454 + 1.2422·0.7452
    assert math.isclose(float(c0[0]), -0.3454 + 1.2422 * 0.7452, rel_tol=1e-12)

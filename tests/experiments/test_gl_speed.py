"""The gl_speed section's per-sample comparison (the disk's cost per sample over the
two-pass's cost per tap, from one round's times: a closed form; its paragraph's counts) and
its verdict's reading of a ratio against its standard error."""

from __future__ import annotations

import math

import pytest

from experiments.gl_speed import (
    DISK_SAMPLES,
    PER_SAMPLE_BOUND,
    TAP_CONFIG,
    gl_verdict,
    per_sample_over_per_tap,
    per_sample_text,
)


def test_per_sample_over_per_tap_closed_form():
    taps = 2 * TAP_CONFIG[2]["samples"]
    # 1 ms a sample against 1 ms a tap on the CPU; GL: 0.5 ms a sample against 2 ms a tap
    times = {"cpu": 1.0 * DISK_SAMPLES, "tap_cpu": 1.0 * taps, "float64": 0.5 * DISK_SAMPLES,
             "float32": 0.25 * DISK_SAMPLES, "tap_gl": 2.0 * taps}  # fmt: skip
    assert per_sample_over_per_tap(times, "cpu") == pytest.approx(1.0)
    assert per_sample_over_per_tap(times, "float64") == pytest.approx(0.25)
    assert per_sample_over_per_tap(times, "float32") == pytest.approx(0.125)
    # the GL columns divide by the GL two-pass, the CPU column by the CPU one
    assert per_sample_over_per_tap({**times, "tap_cpu": 2.0 * taps}, "float64") == (
        pytest.approx(0.25)
    )
    assert per_sample_over_per_tap({**times, "tap_gl": 1.0 * taps}, "cpu") == pytest.approx(1.0)


def test_per_sample_text_counts_rows_within_the_bound():
    rows = [
        {"estimator": "sssbench", "profile": "burley", "tap_cpu": 0.4, "tap_gl": 5.0,
         "per_tap": {"cpu": 20.0, "float64": PER_SAMPLE_BOUND, "float32": 0.5}},
        {"estimator": "hdrp", "profile": "burley", "tap_cpu": 0.4, "tap_gl": 5.0,
         "per_tap": {"cpu": 80.0, "float64": 1.9, "float32": 1.1}},
    ]  # fmt: skip
    text = per_sample_text(rows, "some renderer")
    assert "CPU loop 20.00–80.00× (0 of 2 within 1.5×)" in text
    assert "GL float64 1.50–1.90× (1 of 2 within 1.5×)" in text  # the bound itself is within
    assert "GL float32 0.50–1.10× (2 of 2 within 1.5×)" in text
    assert "on some renderer" in text
    assert text.count("\n| sssbench |") == 1 and text.count("\n| hdrp |") == 1


def test_gl_verdict_names_a_bound_within_one_standard_error():
    paper = 3.07 / 1.05  # 002 Table 2; reproduced from paper / 1.5 = 1.949
    assert gl_verdict(2.10, 0.05, paper) == ("reproduced", None)
    assert gl_verdict(1.50, 0.05, paper) == ("partly reproduced", None)
    assert gl_verdict(0.90, 0.05, paper) == ("not reproduced", None)
    verdict, bound = gl_verdict(1.93, 0.05, paper)  # below the bound, within one error
    assert verdict == "pending" and bound == pytest.approx(paper / 1.5)
    verdict, bound = gl_verdict(1.98, 0.05, paper)  # above it, within one error
    assert verdict == "pending" and bound == pytest.approx(paper / 1.5)
    assert gl_verdict(1.02, 0.05, paper) == ("pending", 1.0)
    assert gl_verdict(1.93, math.nan, paper) == ("partly reproduced", None)  # no error: plain

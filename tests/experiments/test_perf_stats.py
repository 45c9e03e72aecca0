"""The perf section's ratio statistics (issue 30): the median of per-round ratios, its
bootstrapped standard error and the three-way verdict (met / not met / not resolved). The
section's quick run is ``tests/experiments/test_experiments.py`` (every registered section)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from experiments.perf import (
    DISK_SAMPLES,
    SLOW_Y_OVER_X,
    SLOWER_THAN_LOWEST,
    covered_fixed_sentence,
    disk_line,
    median_ratio,
    memory_state,
    native_cpu_ms,
    ratio_text,
    states_by_run,
    stretch_words,
    verdict_at_most,
    verdict_within,
)


def test_median_ratio_of_constant_ratios_has_no_spread():
    value, se = median_ratio([2.0, 4.0, 6.0, 8.0, 10.0], [1.0, 2.0, 3.0, 4.0, 5.0], scale=0.5)
    assert value == 1.0 and se == 0.0


def test_median_ratio_is_the_median_of_the_per_round_ratios():
    nums, dens = [3.0, 10.0, 1.0, 8.0], [1.0, 2.0, 1.0, 1.0]  # ratios 3, 5, 1, 8
    value, se = median_ratio(nums, dens)
    assert value == 4.0  # (3 + 5) / 2
    assert se > 0


def test_bootstrap_standard_error_approaches_the_asymptotic_one():
    # the median of n normal draws has standard error √(π/2) σ / √n = 1.2533 σ / √n
    n, sigma = 401, 0.1
    z = np.random.default_rng(5).standard_normal(n)
    value, se = median_ratio(list(1.0 + sigma * z), [1.0] * n)
    assert value == pytest.approx(1.0, abs=4 * 1.2533 * sigma / math.sqrt(n))
    assert se == pytest.approx(math.sqrt(math.pi / 2) * sigma / math.sqrt(n), rel=0.25)


def test_one_round_has_no_standard_error():
    value, se = median_ratio([3.0], [2.0])
    assert value == 1.5 and math.isnan(se)


@pytest.mark.parametrize(
    ("value", "se", "want"),
    [
        (0.8, 0.1, "met"),
        (1.2, 0.1, "not met"),
        (1.05, 0.1, "not resolved"),
        (0.95, 0.1, "not resolved"),
        (1.0, 0.0, "not resolved"),  # on the target exactly: no side is shown
        (1.05, math.nan, "not met"),  # no error estimate: the plain comparison
        (0.95, math.nan, "met"),
    ],
)
def test_verdict_at_most(value, se, want):
    assert verdict_at_most(value, se, 1.0) == want


@pytest.mark.parametrize(
    ("value", "se", "want"),
    [
        (6.0, 0.5, "met"),  # the band 5–7 holds 5.5–6.5
        (7.6, 0.5, "not met"),
        (4.4, 0.5, "not met"),
        (6.6, 0.5, "not resolved"),  # 7 within one se of 6.6
        (5.4, 0.5, "not resolved"),  # 5 within one se of 5.4
        (7.0, 0.0, "not resolved"),  # on a bound exactly: no side is shown
        (6.9, math.nan, "met"),  # no error estimate: the plain comparison
        (7.1, math.nan, "not met"),
    ],
)
def test_verdict_within_a_band(value, se, want):
    assert verdict_within(value, se, 5.0, 7.0) == want


def test_verdict_within_one_sided_bands():
    # "at least 3": the infinite bound is never within a standard error
    assert verdict_within(3.5, 0.2, 3.0, math.inf) == "met"
    assert verdict_within(3.1, 0.2, 3.0, math.inf) == "not resolved"
    assert verdict_within(2.5, 0.2, 3.0, math.inf) == "not met"
    # at most: the same as verdict_at_most
    for value, se in ((0.8, 0.1), (1.2, 0.1), (1.05, 0.1), (0.95, math.nan)):
        assert verdict_within(value, se, -math.inf, 1.0) == verdict_at_most(value, se, 1.0)


def test_a_band_is_pooled_over_the_logged_runs():
    """By hand: 12-pass ratios 6.8, 7.4 and 7.3: mean 7.1667, sample sd 0.3215, se 0.1856;
    7 lies within it: not resolved. 7.4, 7.5, 7.6: mean 7.5, se 0.0577: not met. Per-tap gains
    3.4, 3.6 (at least 3): mean 3.5 ± 0.1: met."""
    from experiments.perf import pooled_text

    text, verdict = pooled_text([6.8, 7.4, 7.3], 7.0, 5.0)
    assert verdict == "not resolved" and text.endswith("6.80, 7.40, 7.30×, mean 7.17× ± 0.19")
    assert pooled_text([7.4, 7.5, 7.6], 7.0, 5.0)[1] == "not met"
    assert pooled_text([5.9, 6.1], 7.0, 5.0)[1] == "met"
    text, verdict = pooled_text([3.4, 3.6], math.inf, 3.0)
    assert verdict == "met" and text.endswith("mean 3.50× ± 0.10")


def test_disk_line_states_the_error_and_its_verdict():
    d = {
        "ratio": 1.55,
        "ratio_se": 0.1,
        "ratio_cpu": 1.5,
        "ratio_scalar": None,
        "disk_ms": 10.0,
        "two_pass_ms": 1.0,
        "loop": "test loop",
    }
    line, verdict = disk_line(d, "512²")
    assert verdict == "not resolved"
    assert line.endswith("— **not resolved**.")
    assert ratio_text(1.55, 0.1) in line and f"{DISK_SAMPLES} samples" in line
    line, verdict = disk_line(dict(d, ratio=21.0), "512²")
    assert verdict == "not met" and line.endswith("— **not met**.")


def test_the_logged_runs_of_this_code_at_this_setting_are_pooled(tmp_path):
    """By hand: kornia ratios 1.2 and 0.9 of this code at this setting on this machine (a
    third of another code, a fourth at another setting, a fifth on another machine and a sixth
    logged without one ignored): mean 1.05, sample sd 0.2121, se 0.15, 1.0 within one se: not
    resolved; 1.2, 1.15, 1.1: mean 1.15, sd 0.05, se 0.0289: not met. One run: no clause, the
    run's own verdict stands."""
    from experiments.machine import ANY_MACHINE, run_machine
    from experiments.perf import log_perf_run, logged_figures, mean_se, pooled_text
    from sssbench._digest import code_digest

    log = tmp_path / "perf.jsonl"
    here = "1080p, 2 threads, level avx512"
    this = run_machine()
    # another generation under the same name: a family/model this machine cannot have (a fixed
    # real one, e.g. "25/17", is this machine on some hosts)
    other = dict(this, cpu_model=f"{this.get('cpu_model')}-other")
    log_perf_run({"kornia": 1.2, "disk": 15.0}, here, log)
    log_perf_run({"kornia": 0.5}, "1080p, 1 threads, level avx512", log)
    log_perf_run({"kornia": 0.7}, here, log, machine=other)
    log_perf_run({"kornia": 0.9, "disk": 14.0}, here, log, machine=this)
    with open(log, "a") as out:
        out.write(json.dumps({"code": "other", "setting": here, "figures": {"kornia": 9.0}}))
        out.write("\n")
        unrecorded = {"code": code_digest(), "setting": here, "figures": {"kornia": 2.0}}
        out.write(json.dumps(unrecorded) + "\n")
        out.write("not json\n")
    assert [json.loads(line).get("machine") for line in log.read_text().splitlines()[:2]] == [
        this,
        this,
    ]
    got = logged_figures(log, code_digest(), here, this)
    assert got == {"kornia": [1.2, 0.9], "disk": [15.0, 14.0]}
    assert logged_figures(log, code_digest(), here, other) == {"kornia": [0.7]}
    assert logged_figures(log, code_digest(), here, None) == {"kornia": [2.0]}
    assert logged_figures(log, code_digest(), here, ANY_MACHINE)["kornia"] == [1.2, 0.7, 0.9, 2.0]
    mean, se = mean_se(got["kornia"])
    assert mean == pytest.approx(1.05) and se == pytest.approx(0.15)
    text, verdict = pooled_text(got["kornia"], 1.0)
    assert verdict == "not resolved"
    assert "over the 2 logged runs of this code at this setting on this machine" in text
    assert text.endswith("1.20, 0.90×, mean 1.05× ± 0.15")
    text, verdict = pooled_text([1.2, 1.15, 1.1], 1.0)
    assert verdict == "not met" and text.endswith("1.20, 1.15, 1.10×, mean 1.15× ± 0.03")
    assert pooled_text([1.2], 1.0) == ("", None)
    assert math.isnan(mean_se([3.0])[1])


def test_the_disk_line_takes_the_pooled_verdict():
    d = {"ratio": 1.4, "ratio_se": 0.01, "ratio_cpu": 1.4, "ratio_scalar": None}
    d |= {"disk_ms": 10.0, "two_pass_ms": 5.0, "loop": "C loop"}
    line, ok = disk_line(d, "512²")
    assert ok == "met" and line.endswith("— **met**.")
    line, ok = disk_line(d, "512²", pooled=("; over the 2 logged runs", "not met"))
    assert ok == "not met" and line.endswith("); over the 2 logged runs — **not met**.")


@pytest.mark.parametrize("empty_cold, over", [(0.9, True), (0.3, False)])
def test_covered_fixed_sentence_computes_its_figures(empty_cold, over):
    """The covered-pixels decomposition: the target's allowance is 1.5 × share × the close-up's
    time, the call's own cost is compared with it, and the rest is the far call's work over its
    share (hand-computed: share 0.02, close-up 20 ms -> allowance 0.60 ms)."""
    fixed = {("far", "cold"): 1.1, ("empty", "cold"): empty_cold,
             ("far", "warm"): 0.5, ("empty", "warm"): 0.07}  # fmt: skip
    text = covered_fixed_sentence(fixed, close_ms=20.0, share=0.02)
    assert "allowance of 0.60 ms" in text
    assert f"{empty_cold / 0.6:.2f}× the target's allowance" in text
    assert ("more than" in text) == over and ("less than" in text) == (not over)
    work = 1.1 - empty_cold
    assert f"{work:.2f} ms, is {work / 20.0 / 0.02:.2f}× its share" in text


@pytest.mark.parametrize("native, reach", [(0.5, "would meet"), (0.7, "would not meet")])
def test_native_sentence_bounds_a_leaner_python_path(native, reach):
    """The far call's C calls alone over its share of the close-up (hand-computed: share 0.02,
    close-up 20 ms: 0.5 ms is 1.25×, 0.7 ms 1.75× against the target's 1.5×), and the rest
    of the whole call is the Python around them."""
    fixed = {("far", "cold"): 1.1, ("empty", "cold"): 0.4,
             ("far", "warm"): 0.5, ("empty", "warm"): 0.07}  # fmt: skip
    text = covered_fixed_sentence(fixed, 20.0, 0.02, {"whole": 1.0, "native": native})
    assert f"spends {native:.2f} ms of its 1.00 ms" in text
    assert f"{native / 20.0 / 0.02:.2f}× its share, and so {reach} the target" in text
    assert f"the rest, {1.0 - native:.2f} ms, is the Python" in text
    assert covered_fixed_sentence(fixed, 20.0, 0.02) in text  # the sentence before it, kept


def test_native_cpu_ms_times_the_c_calls_inside_a_call():
    """A two-pass call spends part (not all, not none) of its CPU time inside the entry point,
    a Python-only call none; the library's entry point is restored afterwards."""
    import torch

    from sssbench.gbuffer import GBuffer
    from sssbench.ops import PreintegratedSSS, native
    from sssbench.profiles import SumOfGaussians

    lib = native.library_for(torch.float32)
    if lib is None:
        pytest.skip("no C library")
    entry = lib.sss_gather_f32
    g = GBuffer(torch.rand(1, 3, 256, 256), torch.full((1, 1, 256, 256), 300.0), 0.4)
    op = PreintegratedSSS(SumOfGaussians.from_table("skin_deon6"), 7)
    ms = native_cpu_ms(lambda: op(g), 3)
    assert 0.0 < ms["native"] < ms["whole"]
    assert native_cpu_ms(lambda: sum(range(1000)), 3)["native"] == 0.0
    assert lib.sss_gather_f32 is entry


def test_memory_state_is_the_median_y_over_x_and_the_share_of_slow_calls():
    """Calls whose y pass took 1.1×, 1.7×, 1.05×, 1.8× and 2.0× their x pass: median 1.7×,
    3 of 5 above the slow threshold; a call without both passes is left out; none at all
    gives NaN, not a figure."""
    from sssbench.ops import PassRecord

    def call(x_ms: float, y_ms: float) -> list:
        return [
            PassRecord("preintegrated.x", 7, 100, x_ms),
            PassRecord("preintegrated.y", 7, 100, y_ms),
        ]

    calls = [call(5.0, 5.5), call(5.0, 8.5), call(6.0, 6.3), call(5.0, 9.0), call(4.0, 8.0)]
    calls.append([PassRecord("preintegrated.x", 7, 100, 5.0)])  # no y pass: left out
    state = memory_state(calls)
    assert state["y_over_x"] == pytest.approx(1.7)
    assert state["slow_share"] == pytest.approx(3 / 5)
    assert 1.1 < SLOW_Y_OVER_X < 1.7  # between the two stretches' figures (docs/numerics.md)
    empty = memory_state([])
    assert math.isnan(empty["y_over_x"]) and math.isnan(empty["slow_share"])


def test_stretch_words_judge_the_state_against_the_machines_lowest_logged_y_over_x():
    """The sentence follows the run's own figures (the REPORT once said "a slow stretch" of
    every run, and a fixed threshold of y / x misjudges another machine): on the 26/2 machine
    0.86 with logged 0.85-0.87 is the fastest state seen, 1.11 is a slower one (1.31x the
    lowest); a run below every logged one is the lowest itself; no logged run: not judged;
    no calls: not known."""
    from sssbench.ops import PassRecord

    def state(ratios: list[float]) -> dict[str, float]:
        calls = [[PassRecord("p.x", 7, 100, 5.0), PassRecord("p.y", 7, 100, 5.0 * r)]
                 for r in ratios]  # fmt: skip
        return memory_state(calls)

    logged = [0.87, 0.85, 1.06]
    fast = stretch_words(state([0.86, 0.9, 0.8]), logged)
    assert fast.startswith("the fastest memory state seen there (y / x 1.01× the lowest, 0.85,")
    slow = stretch_words(state([1.11, 1.2, 1.0]), logged)
    assert slow.startswith("a slower memory state (y / x 1.31× the lowest, 0.85, of the 4 runs")
    lowest = stretch_words(state([0.5]), logged)
    assert lowest.startswith("the fastest memory state seen there (y / x 1.00× the lowest, 0.50,")
    assert stretch_words(state([1.6]), []).startswith("not judged")
    assert stretch_words(memory_state([]), logged).startswith("not known")
    assert 1.06 / 0.85 > SLOWER_THAN_LOWEST > 1.17 / 1.06  # both machines' states apart


def test_states_by_run_lists_each_runs_state_beside_its_figures():
    """Two logged runs and this one: each run's y / x, slow share, kornia and floor figures
    in the order logged; runs that did not record their state (fewer y / x than kornia
    figures) give no sentence rather than a misaligned one."""
    prior = {"y_over_x": [1.06, 1.58], "slow_share": [0.0, 0.92], "kornia": [0.75, 1.29],
             "floor": [8.98, 14.08]}  # fmt: skip
    this = {"y_over_x": 1.14, "slow_share": 0.4, "kornia": 0.64, "floor": 8.85}
    text = states_by_run(prior, this)
    assert "y / x 1.06, 1.58, 1.14 (above 1.4× in 0, 92, 40 % of the calls)" in text
    assert "kornia 0.75, 1.29, 0.64×" in text and "the floor 8.98, 14.08, 8.85×" in text
    older = dict(prior, kornia=[0.7, 0.75, 1.29], floor=[9.0, 8.98, 14.08])
    assert states_by_run(older, this) == ""
    assert states_by_run({}, this) == ""  # one run: nothing to set side by side

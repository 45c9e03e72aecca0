"""The cold-run log of the benchmark sections (issue 30): what is logged, and the target's
verdict over every logged run of the same code (mean ± standard error, by hand)."""

import json
import math
import os

import pandas as pd
import pytest

from experiments import benchmark
from sssbench._digest import code_digest
from sssbench.ops import native


def table(resolution="512x512", cold=True, warm=200.0, runs=100.0):
    t = pd.DataFrame({"resolution": [resolution, resolution]})
    t.attrs.update(warm_s=warm, runs_s=runs, cold=cold, load_start=0.5, load_end=1.5)
    return t


def test_only_a_cold_run_at_a_target_resolution_is_logged(tmp_path):
    log = tmp_path / "cold.jsonl"
    assert benchmark.log_cold_run(table(cold=False), log) is None
    assert benchmark.log_cold_run(table(resolution="256x256"), log) is None
    assert not log.exists()
    rec = benchmark.log_cold_run(table(warm=180.04, runs=101.0), log)
    lines = log.read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0]) == rec
    assert rec["resolution"] == "512x512" and rec["code"] == code_digest()
    assert rec["total_s"] == 281.0 and rec["warm_s"] == 180.0 and rec["runs_s"] == 101.0
    # the machine it ran on, read off this one
    assert rec["machine"]["cores"] == os.cpu_count()
    assert rec["machine"]["simd"] in (None, *native.SIMD_LEVELS)
    assert isinstance(rec["machine"]["cpu"], str) and rec["machine"]["cpu"]
    assert rec["machine"]["cpu_model"] == benchmark.cpu_generation()


def test_the_cpu_generation_is_the_first_cpus_family_and_model():
    info = "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 23\nmodel\t\t: 1\n"
    info += "model name\t: AMD EPYC\n\nprocessor\t: 1\ncpu family\t: 25\nmodel\t\t: 17\n"
    assert benchmark.cpu_generation(info) == "23/1"
    assert benchmark.cpu_generation("model name\t: AMD EPYC\n") is None


def test_the_verdict_is_on_every_run_of_this_code(tmp_path):
    log = tmp_path / "cold.jsonl"
    rows = [
        {"resolution": "512x512", "code": code_digest(), "total_s": 280.0},
        {"resolution": "512x512", "code": "other", "total_s": 900.0},  # another code: ignored
        {"resolution": "1080x1920", "code": code_digest(), "total_s": 700.0},  # another size
        {"resolution": "512x512", "code": code_digest(), "total_s": 290.0},
    ]
    log.write_text("\n".join(json.dumps(r) for r in rows) + "\nnot json\n")
    assert benchmark.cold_totals(log, "512x512", code_digest()) == [280.0, 290.0]
    # mean 285, sample sd 7.07, se 5.0: 300 lies 3 standard errors above: met
    t = table(warm=190.0, runs=100.0)
    t.attrs["cold_totals"] = benchmark.cold_totals(log, "512x512", code_digest())
    text = benchmark._cold_clause(t)
    assert "in all 290 s from a cold reference cache" in text
    assert "280, 290 s, mean 285 s ± 5.0 — met" in text
    # a third run of 330 s: mean 300 ± 14.4 (sd 26.46 / √3): the target within one SE
    with open(log, "a") as out:
        out.write(json.dumps({"resolution": "512x512", "code": code_digest(), "total_s": 330.0}))
    totals = benchmark.cold_totals(log, "512x512", code_digest())
    assert totals == [280.0, 290.0, 330.0]
    se = math.sqrt(((280 - 300) ** 2 + (290 - 300) ** 2 + (330 - 300) ** 2) / 2 / 3)
    assert f"mean 300 s ± {se:.1f} — not resolved" in benchmark.cold_verdict(totals, 300.0)
    assert benchmark.cold_verdict([310.0, 320.0], 300.0).endswith("— not met")


def test_a_run_without_logged_totals_is_judged_alone(tmp_path):
    assert benchmark.cold_totals(tmp_path / "absent.jsonl", "512x512", code_digest()) == []
    assert benchmark._cold_clause(table(warm=200.0, runs=90.0)).endswith(
        "(issue 30's target at this resolution: ≤ 300 s; this run only — met)"
    )
    assert "this run only — not met" in benchmark._cold_clause(table(runs=150.0))
    assert "target" not in benchmark._cold_clause(table(cold=False))


def recs(**picks):
    """A recommendations frame: one row per ``scene="label"`` at scale ``0.1 mm/px``."""
    return pd.DataFrame(
        {
            "scene": list(picks),
            "scale": ["0.1 mm/px"] * len(picks),
            "recommended": list(picks.values()),
        }
    )


def test_a_cold_run_logs_its_recommendations(tmp_path):
    log = tmp_path / "cold.jsonl"
    rec = benchmark.log_cold_run(table(), log, recs(face="a 7", pores="b 13"))
    assert rec["recommended"] == {"face 0.1 mm/px": "a 7", "pores 0.1 mm/px": "b 13"}
    assert json.loads(log.read_text().splitlines()[0])["recommended"] == rec["recommended"]
    assert "recommended" not in benchmark.log_cold_run(table(), log)  # none given: none logged


def test_the_recommendations_that_changed_between_runs_of_this_code(tmp_path):
    log = tmp_path / "cold.jsonl"
    code = code_digest()
    assert benchmark.recommendation_changes(log, "512x512", code) == (0, 0, {})
    for picks in ({"face": "a 7", "pores": "b 13"}, {"face": "a 13", "pores": "b 13"}):
        benchmark.log_cold_run(table(), log, recs(**picks))
    with open(log, "a") as out:
        out.write("not json\n")
        # another code, another size, a run without recommendations: none of them counts
        for other in ({"code": "other"}, {"resolution": "1080x1920"}, {}):
            rec = {"resolution": "512x512", "code": code, "total_s": 300.0}
            rec |= other
            if other:
                rec["recommended"] = {"face 0.1 mm/px": "z 33", "pores 0.1 mm/px": "z 33"}
            out.write(json.dumps(rec) + "\n")
    benchmark.log_cold_run(table(), log, recs(face="a 7", pores="b 13"))
    runs, groups, changed = benchmark.recommendation_changes(log, "512x512", code)
    assert (runs, groups) == (3, 2)
    assert changed == {"face 0.1 mm/px": ["a 7", "a 13"]}  # distinct, in the order first seen
    text = benchmark.recommendation_stability(runs, groups, changed)
    assert "Between the 3 logged cold runs" in text
    assert "1 of 2 groups' recommendation changed (face 0.1 mm/px: a 7 / a 13)" in text
    assert "not resolved by one run" in text
    same = benchmark.recommendation_stability(2, 2, {})
    assert same.startswith("All 2 groups' recommendations were the same in the 2 logged")
    assert "not measured yet: one logged" in benchmark.recommendation_stability(1, 2, {})
    assert "not measured yet: no logged" in benchmark.recommendation_stability(0, 0, {})


def test_each_configurations_time_is_logged_by_group(tmp_path):
    """``times``: per group, every ok screen-space configuration with a positive finite
    time; the baseline, the reference, failed runs and missing times are left out."""
    rows = pd.DataFrame(
        {
            "scene": ["face"] * 6 + ["pores"],
            "scale": ["0.1 mm/px"] * 6 + ["1 mm/px"],
            "method": ["identity", "reference", "a", "a", "b", "c", "a"],
            "sampling": [None, None, "uniform", "uniform", None, None, None],
            "samples": pd.array([pd.NA, pd.NA, 7, 13, pd.NA, 5, 7], dtype="Int64"),
            "status": ["ok", "ok", "ok", "ok", "failed", "ok", "ok"],
            "time_ms": [0.0, 900.0, 12.5, 20.0, 3.0, float("nan"), 4.25],
            "resolution": ["512x512"] * 7,
        }
    )
    rows.attrs.update(warm_s=200.0, runs_s=100.0, cold=True, load_start=0.5, load_end=0.5)
    expected = {"face 0.1 mm/px": {"a uniform 7": 12.5, "a uniform 13": 20.0}}
    expected["pores 1 mm/px"] = {"a 7": 4.25}
    assert benchmark.config_times(rows) == expected
    assert benchmark.log_cold_run(rows, tmp_path / "cold.jsonl")["times"] == expected


def test_the_time_ratio_spread_pools_pairs_within_each_code():
    """By hand: code A, three runs of the pair (a, b) with log(t_a / t_b) = 0, 0.2, −0.2
    (variance 0.04, 2 degrees of freedom); code B, two runs with 0.1, −0.1 (variance 0.02,
    1 degree); pooled (0.08 + 0.02) / 3, spread exp(√(1/30)) − 1. A configuration timed in
    one run only, a pair split across codes and a code with one run add nothing."""
    e = math.exp

    def rec(code, **groups):
        return {"code": code, "times": groups}

    records = [
        rec("A", g={"a": 10.0, "b": 10.0, "once": 3.0}),
        rec("A", g={"a": 10.0 * e(0.2), "b": 10.0}),
        rec("A", g={"a": 7.0 * e(-0.2), "b": 7.0}),
        rec("B", h={"x": 5.0 * e(0.1), "y": 5.0}),
        rec("B", h={"x": 2.0 * e(-0.1), "y": 2.0}),
        rec("C", g={"a": 1.0, "b": 9.0}),  # one run of its code
        {"code": "A", "total_s": 300.0},  # no times
    ]
    spread, runs, dof = benchmark.time_ratio_spread(records)
    assert (runs, dof) == (5, 3)
    assert spread == pytest.approx(e(math.sqrt(0.1 / 3)) - 1, rel=1e-12)
    assert math.isnan(benchmark.time_ratio_spread(records[5:])[0])
    assert benchmark.time_ratio_spread([])[1:] == (0, 0)


def test_the_ties_sentence_counts_the_groups_it_names():
    frame = recs(face="a 7", pores="b 13", far="–")
    frame["tied"] = ["a 13, c 5", "–", "–"]
    text = benchmark.ties_sentence(frame, 0.25, 4)
    assert "varies by ±25% (one standard deviation" in text
    assert "between logged cold runs of the same code" in text
    assert "over 4 runs at this resolution" in text
    assert "in 1 of 2 ranked groups another configuration" in text
    assert "not measured yet" in benchmark.ties_sentence(frame, float("nan"), 0)


def test_a_change_the_runs_named_as_a_tie_is_counted(tmp_path):
    """face flips between a 7 and a 13 and both runs with a measured spread named the other
    as a tie; pores flips between b 13 and b 7 but the first of them named no tie: 1 of the
    2 changes was named. A first run whose spread was not measured (it ties equal times
    only, and named none) does not count against face."""
    log = tmp_path / "cold.jsonl"
    code = code_digest()
    for face, face_tied, pores, pores_tied, spread in (
        ("a 13", "–", "b 13", "–", math.nan),
        ("a 7", "a 13", "b 13", "–", 0.2),
        ("a 13", "a 7, c 5", "b 7", "b 13", 0.25),
    ):
        frame = recs(face=face, pores=pores)
        frame["tied"] = [face_tied, pores_tied]
        benchmark.log_cold_run(table(), log, frame, time_spread=spread)
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert logged[2]["tied"] == {"face 0.1 mm/px": ["a 7", "c 5"], "pores 0.1 mm/px": ["b 13"]}
    assert [r["time_spread"] for r in logged] == [None, 0.2, 0.25]
    runs, groups, changed = benchmark.recommendation_changes(log, "512x512", code)
    assert set(changed) == {"face 0.1 mm/px", "pores 0.1 mm/px"}
    named = benchmark.changes_named_as_ties(log, "512x512", code, changed)
    assert named == ["face 0.1 mm/px"]
    text = benchmark.recommendation_stability(runs, groups, changed, named)
    assert text.endswith(
        "In 1 of the 2 changed groups, every run that named its ties with a measured spread "
        "named the other pick as not resolved against its own."
    )
    one = benchmark.recommendation_stability(runs, groups, {"face 0.1 mm/px": ["a"]}, [])
    assert one.endswith(
        "In 0 of the 1 changed group, every run that named its ties with a "
        "measured spread named the other pick as not resolved against its own."
    )


def test_runs_pool_only_with_runs_of_the_same_machine(tmp_path):
    """Two machines' runs of one code are judged apart (CPU name, family and model, cores and
    SIMD level compared; the Python and system not); a run logged without a machine pools
    only with such runs."""
    log = tmp_path / "cold.jsonl"
    code = code_digest()
    fast = {"cpu": "EPYC 9B14", "cores": 2, "python": "3.11.7", "system": "a", "simd": "avx512"}
    slow = {**fast, "cpu": "AMD EPYC", "cpu_model": "23/1", "simd": "avx2"}
    rows = [
        {"resolution": "512x512", "code": code, "total_s": 290.0, "machine": fast},
        {"resolution": "512x512", "code": code, "total_s": 886.0, "machine": slow},
        {
            "resolution": "512x512",
            "code": code,
            "total_s": 280.0,
            "machine": {**fast, "system": "b"},
        },
        {"resolution": "512x512", "code": code, "total_s": 330.0},  # no machine
        {"resolution": "512x512", "code": code, "total_s": 900.0, "machine": {**slow, "cores": 4}},
        # the same name, another generation
        {
            "resolution": "512x512",
            "code": code,
            "total_s": 500.0,
            "machine": {**slow, "cpu_model": "25/17"},
        },
    ]
    log.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    assert benchmark.cold_totals(log, "512x512", code, fast) == [290.0, 280.0]
    assert benchmark.cold_totals(log, "512x512", code, slow) == [886.0]
    assert benchmark.cold_totals(log, "512x512", code, None) == [330.0]
    assert benchmark.cold_totals(log, "512x512", code) == [290.0, 886.0, 280.0, 330.0, 900.0, 500.0]
    # the verdict on the fast machine's two runs alone: mean 285 ± 5.0, met
    t = table(warm=190.0, runs=100.0)
    t.attrs["cold_totals"] = benchmark.cold_totals(log, "512x512", code, fast)
    t.attrs["cold_machine"] = fast
    text = benchmark._cold_clause(t)
    assert (
        "over the 2 cold runs of this code on this machine (EPYC 9B14, 2 cores, SIMD level " in text
    )
    assert "avx512) in experiments/cold_runs.jsonl: 290, 280 s, mean 285 s ± 5.0 — met" in text
    assert benchmark.machine_words(slow) == "AMD EPYC (family/model 23/1), 2 cores, SIMD level avx2"
    assert benchmark.machine_words(None) == "a machine not recorded"


def test_the_time_ratio_spread_pools_within_each_machine():
    """Code A on two machines, two runs each, log(t_a / t_b) = 0.1 and -0.1 on the first,
    1.1 and 0.9 on the second (whose ratio is another): each a sample variance of 0.02 on 1
    degree of freedom, pooled 0.04 / 2; across the machines it would be far larger."""
    e = math.exp
    m1, m2 = {"cpu": "x", "cores": 2, "simd": "avx2"}, {"cpu": "y", "cores": 2, "simd": "avx512"}
    records = [
        {"code": "A", "machine": m1, "times": {"g": {"a": 10.0 * e(0.1), "b": 10.0}}},
        {"code": "A", "machine": m1, "times": {"g": {"a": 10.0 * e(-0.1), "b": 10.0}}},
        {"code": "A", "machine": m2, "times": {"g": {"a": 10.0 * e(1.1), "b": 10.0}}},
        {"code": "A", "machine": m2, "times": {"g": {"a": 10.0 * e(0.9), "b": 10.0}}},
    ]
    spread, runs, dof = benchmark.time_ratio_spread(records)
    assert (runs, dof) == (4, 2)
    assert spread == pytest.approx(e(math.sqrt(0.04 / 2)) - 1, rel=1e-12)

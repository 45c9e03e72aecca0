"""The error budget's sentence (sssbench.score.budget_verdict, sssbench.report.budget_text):
over random budgets and random tables, no sentence contradicts a number it was made from."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest

from sssbench import report
from sssbench.report import tables
from sssbench.report.budget_text import budget_verdicts
from sssbench.score.budget_verdict import NO_HELP, PART_NAMES, PARTS, budget_sentence

PCT = r"(-?\d+) %"


def _random_contributions(rng: np.random.Generator) -> dict[str, float]:
    c = {p: float(rng.uniform(-0.2, 1.0) * 10 ** rng.uniform(-4, -1)) for p in PARTS}
    if rng.random() < 0.2:
        c["recon"] = math.nan  # a store written before err_recon was measured everywhere
    if rng.random() < 0.1:
        c["taps"] = float(rng.uniform(0.0, 0.01) * c["model"])  # taps nearly converged
    return c


def _check(sentence: str | None, subject: str, c: dict[str, float]) -> None:
    """Every claim of the sentence, checked against the contributions it was made from."""
    measured = {p: v for p, v in c.items() if math.isfinite(v)}
    total = sum(measured.values())
    if not total > 0:
        assert sentence is None
        return
    assert sentence is not None and sentence.startswith(subject + ": ")
    shares = {p: v / total for p, v in measured.items()}
    # every part's share as listed, and the total
    for p, s in shares.items():
        m = re.search(re.escape(PART_NAMES[p]) + " " + PCT, sentence.split("(rel RMS", 1)[1])
        assert m is not None and int(m.group(1)) == pytest.approx(100 * s, abs=0.51)
    assert ("reconstruction not measured" in sentence) == ("recon" not in shares)
    m = re.search(r"rel RMS ([\d.e+-]+) =", sentence)
    assert m is not None and float(m.group(1)) == pytest.approx(total, rel=5e-3)
    # the dominant part is the largest share, at the share stated
    m = re.search(r": the (.+?) part is " + PCT + " of the error", sentence)
    assert m is not None
    top = next(p for p in PARTS if PART_NAMES[p] == m.group(1))
    assert shares[top] == max(shares.values())
    assert int(m.group(2)) == pytest.approx(100 * shares[top], abs=0.51)
    # the advice
    taps = shares["taps"]
    up = re.search(r"more taps can remove up to " + PCT, sentence)
    assert (up is not None) == (top == "taps")
    no = re.search(r"more taps will not help \(" + PCT + r"\)", sentence)
    assert (no is not None) == (top != "taps" and taps < NO_HELP)
    most = re.search(r"more taps can remove at most " + PCT, sentence)
    assert (most is not None) == (top != "taps" and taps >= NO_HELP)
    for hit in (up, no, most):
        if hit:
            assert int(hit.group(1)) == pytest.approx(100 * taps, abs=0.51)
    assert ("a kernel closer to the profile" in sentence) == (top == "model")
    assert ("handles this geometry better" in sentence) == (top == "screen")
    assert ("neither a kernel nor taps remove it" in sentence) == (top == "recon")


@pytest.mark.parametrize("seed", range(200))
def test_no_budget_sentence_contradicts_its_numbers(seed):
    rng = np.random.default_rng(seed)
    c = _random_contributions(rng)
    _check(budget_sentence("s · 1 mm/px · m 7", c), "s · 1 mm/px · m 7", c)


def test_an_exact_method_or_an_unmeasured_budget_gets_no_sentence():
    assert budget_sentence("x", dict.fromkeys(PARTS, 0.0)) is None
    assert budget_sentence("x", dict.fromkeys(PARTS, math.nan)) is None
    assert budget_sentence("x", {}) is None


def test_the_example_of_the_issue():
    # face · 0.3 mm/px: the reconstruction part is 70 % of the sum of Gaussians' error
    c = {"taps": 0.001, "model": 0.002, "recon": 0.007, "screen": 0.0}
    s = budget_sentence("face · 0.3 mm/px · sum_of_gaussians 17", c)
    assert s.startswith("face · 0.3 mm/px · sum_of_gaussians 17: the reconstruction part is 70 %")
    assert "more taps can remove at most 10 %" in s and "neither a kernel nor taps" in s


def _random_table(seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for scene in ("s0", "s1", "s2"):
        for m in ("identity", "a", "b", "c"):
            for samples in (7, 17):
                c = _random_contributions(rng)
                budgeted = m != "identity" and rng.random() > 0.1
                ok = m == "identity" or rng.random() > 0.1
                rows.append(
                    {
                        "scene": scene,
                        "method": m,
                        "profile": "skin",
                        "sampling": None,
                        "samples": samples,
                        "stages": tables.MISSING,
                        "resolution": "64x64",
                        "pixel_mm": 0.3,
                        "status": "ok" if ok else "failed",
                        "time_ms": 0.0 if m == "identity" else float(rng.uniform(0.1, 10)),
                        "passes": 1,
                        "rel_rms": float(rng.uniform(0.001, 0.1)),
                        "flip": 0.01,
                        "error_flip_window": 0.01,
                        "error_visible": False,
                        "skill": float(rng.uniform(-1, 1)),
                        "rel_rms_identity": 0.05,
                        "visible": True,
                        "visibility": 0.02,
                        "visibility_window": 0.2,
                        "run_dir": None,
                        **{
                            f"contribution_{p}": (v if budgeted else math.nan) for p, v in c.items()
                        },
                        **{f"err_{p}": (abs(v) if budgeted else math.nan) for p, v in c.items()},
                    }
                )
    df = pd.DataFrame(rows)
    for col in tables.SUMMARY_COLUMNS:
        if col not in df.columns:
            df[col] = None
    df["samples"] = pd.array(df["samples"], dtype="Int64")
    return tables.annotate(df)


@pytest.mark.parametrize("seed", range(10))
def test_the_tables_budget_sentences_match_their_rows(seed):
    table = _random_table(seed)
    out = budget_verdicts(table)
    ok = table[(table["status"] == "ok") & (table["method"] != "identity")]
    ok = ok[ok["contribution_model"].notna()]
    # one sentence per group and method with a budget, of its best-skill configuration
    assert len(out) <= ok.groupby(["scene", "method"]).ngroups
    for _, r in out.iterrows():
        runs = ok[(ok["scene"] == r["scene"]) & (ok["method"] == r["method"])]
        best = runs.loc[runs["skill"].astype(float).idxmax()]
        assert r["config"] == tables.label(best)
        c = {p: float(best[f"contribution_{p}"]) for p in PARTS}
        subject = f"{r['scene']} · {r['scale']} · {r['config']}"
        _check(r["sentence"], subject, c)
    # the same sentences reach summary.md and the console; the console shows the four parts
    md = report.summary_markdown(table, "x")
    console = report.format_console(table)
    for sentence in out["sentence"]:
        assert f"- {sentence}" in md and sentence in console.splitlines()
    header = console.splitlines()[0].split()
    assert all(f"err_{p}" in header for p in PARTS)
    assert "err_recon" in md.split("\n## ", 2)[1].splitlines()[2]  # the group table's header


@pytest.mark.parametrize("seed", range(5))
def test_the_benchmark_sections_budget_counts_equal_its_rows(seed):
    """experiments/benchmark.py's budget sentence (REPORT.md §9): the counts it states are
    the counts of the sentences' dominant parts."""
    from experiments.benchmark import budget_text

    out = budget_verdicts(_random_table(seed))
    text = budget_text(out)
    m = re.search(r"(\d+) in all\): the largest part of the error is (.+?)[;.]", text)
    assert m is not None and int(m.group(1)) == len(out)
    stated = {
        name.strip(): int(n) for name, n in re.findall(r"([a-z\- ()]+?) ×(\d+)", m.group(2))
    }
    named = [re.search(r": the (.+?) part is", s).group(1) for s in out["sentence"]]
    assert stated == {n: named.count(n) for n in stated}
    assert sum(stated.values()) == len(out)
    recon = out["share_recon"].dropna()
    m = re.search(r"measured on (\d+) of them \(every scene\), median share (-?\d+) %", text)
    assert (m is not None) == (len(recon) > 0)
    if m:
        assert int(m.group(1)) == len(recon)
        assert int(m.group(2)) == pytest.approx(100 * recon.median(), abs=0.51)

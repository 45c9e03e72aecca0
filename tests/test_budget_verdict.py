"""The error budget's sentence (sssbench.score.budget_verdict and
sssbench.report.tables.budget_verdicts): over random budgets and random tables, no sentence
contradicts a number it was made from."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest

from sssbench import report
from sssbench.report import tables
from sssbench.report.tables import budget_verdicts
from sssbench.score.budget_verdict import (
    NO_HELP,
    PART_NAMES,
    PARTS,
    budget_sentence,
    dominant_part,
)

PCT = r"(-?\d+) %"
DELTA = r"([+-]\d+) %"


def _random_budget(rng: np.random.Generator) -> tuple[dict, dict, dict]:
    """Random part images (vectors) that add up to an error image: their contributions and
    norms as the budget reports them, and the rel RMS left without each part, computed from
    the vectors (independently of ``error_without``)."""
    d, ref = 40, float(10 ** rng.uniform(0, 2))
    scale = {p: float(10 ** rng.uniform(-4, -1)) for p in PARTS}
    vec = {p: rng.normal(size=d) * scale[p] / math.sqrt(d) * ref for p in PARTS}
    if rng.random() < 0.3:  # two parts that cancel
        vec["screen"] = -0.8 * vec["recon"] + 0.2 * vec["screen"]
    if rng.random() < 0.1:
        vec["taps"] *= 1e-3  # taps nearly converged
    err = sum(vec.values())
    e = float(np.linalg.norm(err))
    c = {p: float(v @ err) / (ref * e) for p, v in vec.items()}
    n = {p: float(np.linalg.norm(v)) / ref for p, v in vec.items()}
    left = {p: float(np.linalg.norm(err - v)) / ref for p, v in vec.items()}
    if rng.random() < 0.2:  # a store written before err_recon was measured everywhere
        c["recon"] = n["recon"] = math.nan
        left.pop("recon")
        # the other parts then hold the convention's image in screen, as such a run did
    return c, n, left


def _check(sentence: str | None, subject: str, c: dict, n: dict, left: dict) -> None:
    """Every claim of the sentence, checked against the numbers it was made from."""
    measured = {p: v for p, v in c.items() if math.isfinite(v)}
    total = sum(measured.values())
    if not total > 0:
        assert sentence is None
        return
    assert sentence is not None and sentence.startswith(subject + ": ")
    shares = {p: v / total for p, v in measured.items()}
    tail = sentence.split("shares of the error: ", 1)[1]
    for p, s in shares.items():
        m = re.search(re.escape(PART_NAMES[p]) + " " + PCT, tail)
        assert m is not None and int(m.group(1)) == pytest.approx(100 * s, abs=0.51)
    assert ("reconstruction not measured" in sentence) == ("recon" not in shares)
    # the dominant part: the one whose removal lowers the error most, at the numbers stated
    m = re.search(
        r": the (.+?) part dominates: without it the rel RMS would be ([\d.e+-]+) instead of "
        r"([\d.e+-]+) \(" + DELTA,
        sentence,
    )
    assert m is not None
    top = next(p for p in PARTS if PART_NAMES[p] == m.group(1))
    if "recon" in left:  # all four parts of the vectors are measured
        assert left[top] == pytest.approx(min(left.values()), rel=1e-9)
        assert float(m.group(2)) == pytest.approx(left[top], rel=5e-3)
    assert float(m.group(3)) == pytest.approx(total, rel=5e-3)
    # the advice
    without_taps = left["taps"] if "recon" in left else None
    no = re.search(r"more taps will not help \(" + DELTA + r"\)", sentence)
    down = re.search(r"more taps can bring it down to ([\d.e+-]+) \(" + DELTA, sentence)
    assert (no is None) != (down is None)
    if without_taps is not None:
        assert (no is not None) == (without_taps > (1 - NO_HELP) * total)
        if down:
            assert float(down.group(1)) == pytest.approx(without_taps, rel=5e-3)
    assert ("a kernel closer to the profile" in sentence) == (top == "model")
    assert ("handles this geometry better" in sentence) == (top == "screen")
    assert ("neither a kernel nor taps remove it" in sentence) == (top == "recon")


@pytest.mark.parametrize("seed", range(200))
def test_no_budget_sentence_contradicts_its_numbers(seed):
    rng = np.random.default_rng(seed)
    c, n, left = _random_budget(rng)
    _check(budget_sentence("s · 1 mm/px · m 7", c, n), "s · 1 mm/px · m 7", c, n, left)


def test_an_exact_method_or_an_unmeasured_budget_gets_no_sentence():
    zero = dict.fromkeys(PARTS, 0.0)
    assert budget_sentence("x", zero, zero) is None
    assert budget_sentence("x", dict.fromkeys(PARTS, math.nan), zero) is None
    assert budget_sentence("x", {}, {}) is None


def test_the_example_of_the_issue():
    # orthogonal parts: taking one out leaves the others in quadrature; the reconstruction
    # part holds 70 % of the squared error
    norms = {"taps": 0.1, "model": math.sqrt(0.29), "recon": math.sqrt(0.7), "screen": 0.0}
    contrib = {k: v * v for k, v in norms.items()}  # ‖E‖ = 1: ⟨P, E⟩ = ‖P‖²
    s = budget_sentence("face · 0.3 mm/px · sum_of_gaussians 17", contrib, norms)
    assert s.startswith(
        "face · 0.3 mm/px · sum_of_gaussians 17: the reconstruction part dominates: without "
        f"it the rel RMS would be {math.sqrt(0.3):.3g} instead of 1"
    )
    assert "reconstruction 70 %" in s and "neither a kernel nor taps" in s
    assert f"more taps can bring it down to {math.sqrt(0.99):.3g}" not in s  # −0.5 %: no help
    assert "more taps will not help (-1 %)" in s


def _random_table(seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for scene in ("s0", "s1", "s2"):
        for m in ("identity", "a", "b", "c"):
            for samples in (7, 17):
                c, n, _ = _random_budget(rng)
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
                        **{f"err_{p}": (v if budgeted else math.nan) for p, v in n.items()},
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
        n = {p: float(best[f"err_{p}"]) for p in PARTS}
        subject = f"{r['scene']} · {r['scale']} · {r['config']}"
        assert r["sentence"] == budget_sentence(subject, c, n)
        assert r["dominant"] == dominant_part(c, n)
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
    m = re.search(
        r"(\d+) in all\): the dominant part \(whose removal lowers the error most\) is (.+?)[;.]",
        text,
    )
    assert m is not None and int(m.group(1)) == len(out)
    stated = {name.strip(): int(n) for name, n in re.findall(r"([a-z\- ()]+?) ×(\d+)", m.group(2))}
    named = [re.search(r": the (.+?) part dominates", s).group(1) for s in out["sentence"]]
    assert stated == {n: named.count(n) for n in stated}
    assert sum(stated.values()) == len(out)
    recon = out["share_recon"].dropna()
    m = re.search(r"measured on (\d+) of them( \(all of them\))?, median share (-?\d+) %", text)
    assert (m is not None) == (len(recon) > 0)
    if m:
        assert int(m.group(1)) == len(recon)
        assert (m.group(2) is not None) == (len(recon) == len(out))
        assert int(m.group(3)) == pytest.approx(100 * recon.median(), abs=0.51)

"""A method's own error is tested for visibility with the same calibrated rule as SSS itself
(issue 27): a method that adds a visible error is flagged "visibly wrong" with its FLIP and
skill in every group, also where SSS is not visible, and the group's verdict says so; no
sentence the report prints about a group contradicts the numbers printed with it (issue 28,
item 8)."""

from __future__ import annotations

import json
import logging
import re

import numpy as np
import pandas as pd
import pytest
from specs import small_spec
from torch import nn

from sssbench import report
from sssbench.report import tables
from sssbench.report.html import write_html
from sssbench.run import registry, runmemo, runner
from sssbench.score.verdict import VISIBLE_FLIP, VISIBLE_LOCAL_FLIP


class BlotchSSS(nn.Module):
    """A broken method: returns the unblurred input with a bright 6×6 blotch in the middle of
    the frame (a visible error that has nothing to do with SSS)."""

    needs = ("mask",)

    def __init__(self, profile) -> None:
        super().__init__()

    def forward(self, gbuffer):
        out = gbuffer.diffuse.clone()
        h, w = out.shape[-2:]
        out[..., h // 2 - 3 : h // 2 + 3, w // 2 - 3 : w // 2 + 3] *= 4.0
        return out


@pytest.fixture
def blotch(monkeypatch):
    BlotchSSS.__module__ = __name__
    monkeypatch.setitem(registry.METHODS, "blotch", registry.MethodEntry(f"{__name__}:BlotchSSS"))
    runmemo.clear()
    yield "blotch"
    runmemo.clear()


#: a scene where SSS is not visible: the sphere's smooth shading at 1 mm/px
HIDDEN = dict(scene="sphere", scene_params={"pixel_mm": 1.0}, resolution=(48, 48))


def _run(tmp_path, method, **kw):
    spec = small_spec(tmp_path, method=method, **(HIDDEN | kw))
    out = runner.execute(spec, tmp_path / method)
    assert out.status == "ok", out.message
    return json.loads((tmp_path / method / "metrics.json").read_text())


def test_a_visibly_wrong_method_is_flagged_where_sss_is_not_visible(tmp_path, blotch, caplog):
    base = _run(tmp_path, "identity")
    with caplog.at_level(logging.INFO, logger="sssbench"):
        bad = _run(tmp_path, blotch)
    # the run's own log line says both, from its numbers
    (line,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("ok ")]
    assert line.endswith("[SSS not visible at this scale] [visibly wrong]"), line
    good = _run(tmp_path, "sum_of_gaussians", sampling="importance", samples=13)
    assert base["visible"] is False and bad["visible"] is False  # SSS invisible here
    assert base["error_visible"] is False and good["error_visible"] is False
    assert bad["error_visible"] is True  # the blotch is plainly visible
    assert bad["flip"] >= VISIBLE_FLIP or bad["error_flip_window"] >= VISIBLE_LOCAL_FLIP
    assert bad["skill"] < 0
    runs, _ = report.load_runs(tmp_path / "s.sqlite")
    table = report.summary_table(runs)
    row = table[table["method"] == "blotch"].iloc[0]
    assert row["visibly_wrong"] and row["note"] == "SSS not visible at this scale"
    assert not table[table["method"] != "blotch"]["visibly_wrong"].any()
    (verdict,) = report.recommendations(table)["verdict"]
    assert verdict.startswith("SSS not visible at this scale")
    assert "1 of 2 configurations are visibly wrong" in verdict and "blotch (FLIP" in verdict
    assert f"skill {row['skill']:+.2f}" in verdict
    # the flag in the three outputs: console, summary.md, report.html
    console = report.format_console(table)
    line = next(ln for ln in console.splitlines() if " blotch " in ln)
    assert "!" in line.split()[-1] and "~" in line.split()[-1]
    md = report.summary_markdown(table, "x")
    assert "**visibly wrong (FLIP" in md and "1 of 2 configurations are visibly wrong" in md
    page = write_html(table, tmp_path, "x", []).read_text()
    assert "visibly wrong (FLIP" in page and "1 of 2 configurations are visibly wrong" in page


# ----------------------------------------------------------------------- property test
METHODS = ["identity", "a", "b", "c", "d"]


def _random_group(rng: np.random.Generator, scene: str) -> list[dict]:
    visible = bool(rng.random() < 0.5)
    vis_mean = float(rng.uniform(0.01, 0.05) if visible else rng.uniform(0, 0.004))
    vis_local = float(rng.uniform(0.0, 0.3) if visible else rng.uniform(0, 0.07))
    err_id = float(rng.uniform(0.001, 0.1))
    rows = []
    for m in METHODS:
        if m == "identity":
            err, flip, local = err_id, vis_mean, vis_local
        else:
            err = float(err_id * rng.uniform(0.0, 3.0))
            flip = float(rng.uniform(0, 0.02))
            local = float(rng.uniform(0, 0.2))
        rows.append(
            {
                "scene": scene,
                "method": m,
                "profile": "skin",
                "sampling": None,
                "samples": pd.NA,
                "stages": tables.MISSING,
                "resolution": "64x64",
                "pixel_mm": 1.0,
                "status": "ok" if rng.random() > 0.1 or m == "identity" else "failed",
                "time_ms": 0.0 if m == "identity" else float(rng.uniform(0.1, 10)),
                "passes": 1,
                "rel_rms": err,
                "flip": flip,
                "error_flip_window": local,
                "error_visible": bool(flip >= VISIBLE_FLIP or local >= VISIBLE_LOCAL_FLIP),
                "skill": 1 - err / err_id,
                "rel_rms_identity": err_id,
                "visible": visible,
                "visibility": vis_mean,
                "visibility_window": vis_local,
                "run_dir": None,
            }
        )
    return rows


def _table(seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = [r for k in range(4) for r in _random_group(rng, f"s{k}")]
    df = pd.DataFrame(rows)
    for col in tables.SUMMARY_COLUMNS:
        if col not in df.columns:
            df[col] = None
    df["samples"] = pd.array([pd.NA] * len(df), dtype="Int64")
    return tables.annotate(df)


def _check_sentence(sentence: str, group: pd.DataFrame) -> None:
    """Every claim the verdict makes about the group, checked against its rows."""
    ok = group[(group["status"] == "ok")]
    screen = ok[ok["method"] != "identity"]
    wrong = screen[screen["error_visible"].astype(bool)]
    right = screen[~screen["error_visible"].astype(bool)]
    hidden = bool((group["visible"] == False).all())  # noqa: E712
    assert ("SSS not visible" in sentence) == hidden
    assert "scores like the unblurred input" not in sentence
    for _, r in wrong.iterrows():  # every visibly wrong configuration is named, with numbers
        if len(wrong) <= 4:
            assert f"{r['method']} (FLIP {r['flip']:.3g}" in sentence
            assert f"skill {r['skill']:+.2f}" in sentence
    for _, r in right.iterrows():
        assert f"{r['method']} (FLIP" not in sentence
    m = re.search(r"(\d+) of (\d+) configurations are visibly wrong", sentence)
    assert (m is not None) == (len(wrong) > 0)
    if m:
        assert int(m.group(1)) == len(wrong)
    if "no configuration's error is visible" in sentence:
        assert wrong.empty
    if hidden:
        mean, local = group["visibility"].iloc[0], group["visibility_window"].iloc[0]
        assert mean < VISIBLE_FLIP and local < VISIBLE_LOCAL_FLIP
        assert f"mean FLIP {mean:.3g}" in sentence and f"local FLIP {local:.3g}" in sentence
        m = re.search(r"skill from ([+\-]\d\.\d\d) to ([+\-]\d\.\d\d)", sentence)
        assert m is not None
        assert float(m.group(1)) == pytest.approx(screen["skill"].min(), abs=0.006)
        assert float(m.group(2)) == pytest.approx(screen["skill"].max(), abs=0.006)
    else:
        ranked = screen
        m = re.search(r"best skill \(([+\-]\d\.\d\d)\)|vs ([+\-]\d\.\d\d) for", sentence)
        assert m is not None
        best = float(m.group(1) or m.group(2))
        assert best == pytest.approx(ranked["skill"].max(), abs=0.006)
        m = re.search(r"(\d+) of (\d+) configurations are worse than doing nothing", sentence)
        n_worse = int((ranked["skill"] <= 0).sum())
        assert (m is not None) == (n_worse > 0)
        if m:
            assert int(m.group(1)) == n_worse and int(m.group(2)) == len(ranked)


@pytest.mark.parametrize("seed", range(40))
def test_no_verdict_contradicts_its_rows(seed):
    table = _table(seed)
    recs = report.recommendations(table)
    for key, group in table.groupby(tables.group_keys(table), dropna=False, sort=True):
        rec = recs[recs["scene"] == key[0]]
        if rec.empty:  # a visible group where every screen-space run failed: no sentence
            assert group[(group["status"] == "ok") & (group["method"] != "identity")].empty
            continue
        _check_sentence(rec["verdict"].iloc[0], group)
    # the same sentences reach the console and summary.md, and every flag matches its row
    console = report.format_console(table).splitlines()
    md = report.summary_markdown(table, "x")
    for sentence in recs["verdict"]:
        assert sentence in md and any(sentence in ln for ln in console)
    for _, r in table.iterrows():
        flags = tables._flags(r)
        # the baseline too: where SSS is visible, doing nothing is visibly wrong
        assert ("visibly wrong" in flags) == bool(r["status"] == "ok" and r["error_visible"])
        assert ("SSS not visible" in flags) == (r["visible"] is False)


@pytest.mark.parametrize("seed", range(10))
def test_the_benchmark_sections_counts_equal_its_rows(seed):
    """experiments/benchmark.py's **Measured** paragraph (REPORT.md §9): every count it
    states is the count of the rows it describes."""
    from experiments.benchmark import measured_text

    table = _table(seed)
    recs = report.recommendations(table)
    text = measured_text(table, recs)
    ok = table[table["status"] == "ok"]
    screen = ok[ok["method"] != "identity"]
    hidden = table.groupby("scene")["visible"].apply(lambda v: bool((v == False).all()))  # noqa: E712
    m = re.search(r"(\d+) of (\d+) scene/scale groups show no visible SSS", text)
    assert m and int(m.group(1)) == int(hidden.sum()) and int(m.group(2)) == len(recs)
    ranked = screen[screen["visible"] != False]  # noqa: E712
    m = re.search(r"Of the (\d+) ranked screen-space configurations, (\d+) are worse", text)
    assert m and int(m.group(1)) == len(ranked)
    assert int(m.group(2)) == int(ranked["worse_than_nothing"].sum())
    wrong = screen[screen["error_visible"].astype(bool)]
    m = re.search(r"(\d+) of (\d+) screen-space configurations are visibly wrong", text)
    assert m and int(m.group(1)) == len(wrong) and int(m.group(2)) == len(screen)
    m = re.search(r"(\d+) of them in groups where SSS is not visible", text)
    assert m and int(m.group(1)) == int((wrong["visible"] == False).sum())  # noqa: E712


@pytest.mark.parametrize(
    ("resolution", "warm_s", "runs_s", "cold", "expected"),
    [
        # issue 30: the 512² benchmark ≤ 300 s and the 1080p one ≤ 30 min, from cold
        ("512x512", 200.0, 99.0, True, "in all 299 s from a cold reference cache (issue 30's"),
        ("512x512", 407.0, 293.0, True, "≤ 300 s; this run only — not met"),
        ("1080x1920", 1391.0, 382.0, True, "≤ 1800 s; this run only — met"),
        ("1080x1920", 1500.0, 382.0, True, "≤ 1800 s; this run only — not met"),
        # a warm cache or another resolution is timed but not judged
        ("512x512", 10.0, 20.0, False, "in all 30 s from a warm reference cache."),
        ("27x48", 1.0, 2.0, True, "in all 3 s from a cold reference cache."),
    ],
)
def test_the_benchmark_section_states_its_cold_time(resolution, warm_s, runs_s, cold, expected):
    """The **Measured** paragraph states the whole run's time (warm-up + runs) and judges it
    against issue 30's targets only where the run was cold at the preset's resolution (on
    this run alone when the table carries no logged totals: tests/experiments/test_cold_log.py
    covers those)."""
    from experiments.benchmark import measured_text

    table = _table(0)
    table["resolution"] = resolution
    table.attrs.update(warm_s=warm_s, runs_s=runs_s, cold=cold, load_start=0.5, load_end=0.5)
    text = measured_text(table, report.recommendations(table))
    assert expected in text
    assert ("target" in text) == (cold and resolution in ("512x512", "1080x1920"))


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("spread", [0.0, 0.3, 1.5])
@pytest.mark.parametrize("close", [False, True])
def test_the_tied_configurations_are_those_within_the_time_spread(seed, spread, close):
    """``tied`` (and the verdict's "is not resolved" clause) names exactly the configurations
    a brute-force pass over the rows finds: ok, not the baseline, skill within 10 % of the
    group's best, not the recommendation, and time at most the recommendation's × (1 +
    spread); the recommendation is the same at every spread. ``close``: every configuration's
    skill in [0.80, 0.88], all within 10 % of the best (0.88 · 0.9 < 0.80), so ties are
    common."""
    table = _table(seed)
    if close:
        screen = table["method"] != "identity"
        rng = np.random.default_rng(1000 + seed)
        table.loc[screen, "skill"] = rng.uniform(0.80, 0.88, int(screen.sum()))
    plain = report.recommendations(table).set_index("scene")
    recs = report.recommendations(table, time_spread=spread).set_index("scene")
    assert recs["recommended"].equals(plain["recommended"])
    for scene, r in recs.iterrows():
        group = table[table["scene"] == scene]
        if r["best"] == tables.MISSING:
            assert r["tied"] == tables.MISSING
            continue
        rows = group[(group["status"] == "ok") & (group["method"] != "identity")]
        best = max(float(s) for s in rows["skill"])
        good = rows[rows["skill"] >= best - 0.1 * abs(best)]
        pick = good[good["method"] == r["recommended"]]
        assert len(pick) == 1 and float(pick["time_ms"].iloc[0]) == good["time_ms"].min()
        limit = float(pick["time_ms"].iloc[0]) * (1 + spread)
        expected = [
            m
            for t, m in sorted(zip(good["time_ms"], good["method"], strict=True))
            if m != r["recommended"] and t <= limit
        ]
        assert r["tied"] == (", ".join(expected) or tables.MISSING)
        assert ("is not resolved" in r["verdict"]) == bool(expected)
        for m in expected:
            assert m in r["verdict"].split("is not resolved")[0]


def test_the_time_spread_is_checked():
    with pytest.raises(ValueError, match="time_spread"):
        report.recommendations(_table(0), time_spread=-0.5)

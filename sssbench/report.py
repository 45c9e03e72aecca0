"""Tables and plots from the run store (DESIGN §6: ``sssbench-report``).

``sssbench-report [STORE_OR_SWEEP_DIR] [--out DIR]`` writes

* ``summary.csv`` — one row per point (the newest stored run of each config): scene, method,
  profile, sampling, samples, status, passes, time_ms and every metric;
* ``summary.md`` — per scene, a method table with the error metrics, time, samples and passes;
* ``error_vs_time.png`` — per scene, run time (log) against relative RMS error (log), each
  method a colour, the Pareto front (no other point is both faster and more accurate) drawn
  as a step line through ringed points; the trials of an Optuna search (``+experiment=optuna``)
  get their own front (red, dashed) beside the grid's (:func:`search_fronts`);
* ``pass_times.png`` — a stacked bar per method of its median pass times (mean over its points):
  where each method spends its time.

Given a sweep directory, the report covers the points of that sweep (the ``point.json`` every
job writes names its config hash and its store); given a store, every point in it.
Tables use pandas, plots matplotlib with the Agg backend.
"""

from __future__ import annotations

import argparse
import json
import math
import sqlite3
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from sssbench.tracking import METRIC_COLUMNS, RunStore

__all__ = [
    "load_runs",
    "summary_table",
    "pareto_front",
    "run_sweeper",
    "search_fronts",
    "write_report",
    "Report",
    "ReportCallback",
    "main",
]

POINT_COLUMNS = ["scene", "method", "profile", "sampling", "samples", "stages", "resolution"]
#: per-run numbers beyond the image metrics (from the store's metrics / info)
DECISION_COLUMNS = [
    "pixel_mm",
    "rel_rms_identity",
    "skill",
    "skill_flip",
    "visible",
    "err_model",
    "err_taps",
    "err_screen",
    "err_recon",
    "contribution_model",
    "contribution_taps",
    "contribution_screen",
    "contribution_recon",
    "error_scale",
    # stochastic methods (sssbench.runner.bias_noise): rel_rms is the mean over seeds
    "bias_rel_rms",
    "noise_rel_rms",
    "seeds",
]
#: columns the report adds per ranking group (:func:`annotate`)
FLAG_COLUMNS = ["pareto", "best", "worse_than_nothing", "note"]
SUMMARY_COLUMNS = [
    *POINT_COLUMNS,
    "status",
    "passes",
    "time_ms",
    *METRIC_COLUMNS,
    *DECISION_COLUMNS,
    "error",
    "run_id",
    "run_dir",
]
#: the error metric of the error-versus-time plot and the Pareto front
PLOT_METRIC = "rel_rms"
#: the methods that are not screen-space candidates: the exact reference (zero error by
#: definition) and the do-nothing baseline (drawn and ranked as the bar to beat)
REFERENCE, BASELINE = "reference", "identity"
#: a configuration within this fraction of the best skill counts as "as good" for the
#: recommendation (the cheapest of those is recommended)
WITHIN = 0.10
#: missing values are written as this everywhere (terminal, Markdown, HTML)
MISSING = "–"


@dataclass(frozen=True)
class Report:
    """Paths of the files a report wrote, and its summary table."""

    out_dir: Path
    summary_csv: Path
    summary_md: Path
    error_vs_time: Path | None
    pass_times: Path | None
    table: pd.DataFrame
    error_budget: Path | None = None
    html: Path | None = None

    def paths(self) -> list[Path]:
        return [
            p
            for p in (
                self.summary_csv,
                self.summary_md,
                self.error_vs_time,
                self.pass_times,
                self.error_budget,
                self.html,
            )
            if p is not None
        ]


# ----------------------------------------------------------------------------- loading
def sweep_points(sweep_dir: str | Path) -> tuple[Path | None, list[str]]:
    """The store and the config hashes of the jobs of a sweep (or run) directory."""
    sweep_dir = Path(sweep_dir)
    store: Path | None = None
    hashes: list[str] = []
    for p in sorted(sweep_dir.rglob("point.json")):
        try:
            point = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        hashes.append(point["config_hash"])
        store = store or Path(point["store"])
    return store, hashes


def load_runs(
    store: str | Path | RunStore, hashes: list[str] | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The newest run per config (``runs``) and their passes (``passes``) as DataFrames.

    Args:
        store: an SQLite run store or its path.
        hashes: keep only these config hashes (a sweep's points); ``None`` keeps all.
    """
    if not isinstance(store, RunStore):
        path = Path(store)
        if not path.is_file():
            raise FileNotFoundError(f"store must be an existing SQLite run store, got {path}")
        store = RunStore(path)
    rows = store.runs(latest=True)
    if hashes is not None:
        keep = set(hashes)
        rows = [r for r in rows if r["config_hash"] in keep]
    runs = pd.DataFrame(rows)
    if runs.empty:
        runs = pd.DataFrame(columns=["id", "config_hash", *SUMMARY_COLUMNS])
    passes = pd.DataFrame(store.passes(runs["id"].tolist() if len(runs) else []))
    if passes.empty:
        passes = pd.DataFrame(columns=["run_id", "idx", "name", "ms_median", "ms_min", "ms_max"])
    return runs, passes


def summary_table(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per point, columns :data:`SUMMARY_COLUMNS` then :data:`FLAG_COLUMNS` (see
    :func:`annotate`), sorted by scene, scale, method, sampling, samples."""
    table = runs.rename(columns={"id": "run_id"})
    configs = list(table["config"]) if "config" in table.columns else [{}] * len(table)
    metrics = list(table["metrics"]) if "metrics" in table.columns else [{}] * len(table)
    infos = list(table["info"]) if "info" in table.columns else [{}] * len(table)
    table["resolution"] = [_resolution(c) for c in configs]
    table["stages"] = [_stages(c) for c in configs]
    for col in DECISION_COLUMNS:
        values = []
        for m, i in zip(metrics, infos, strict=True):
            m, i = m if isinstance(m, dict) else {}, i if isinstance(i, dict) else {}
            values.append(m.get(col, i.get(col)))
        table[col] = values
    for col in SUMMARY_COLUMNS:
        if col not in table.columns:
            table[col] = None
    table = table[SUMMARY_COLUMNS].copy()
    table["samples"] = pd.array(
        [None if pd.isna(v) else int(v) for v in table["samples"]], dtype="Int64"
    )
    for col in DECISION_COLUMNS:
        if col != "visible":
            table[col] = pd.to_numeric(table[col], errors="coerce")
    table = table.sort_values(
        ["scene", "pixel_mm", "resolution", "method", "profile", "sampling", "samples"],
        na_position="first",
    ).reset_index(drop=True)
    return annotate(table)


def _resolution(config: Any) -> str | None:
    res = config.get("resolution") if isinstance(config, dict) else None
    if isinstance(res, list) and len(res) == 2:
        return f"{res[0]}x{res[1]}"
    return None if res is None else str(res)


def _stages(config: Any) -> str:
    stages = config.get("stages") if isinstance(config, dict) else None
    if not stages:
        return MISSING
    return "+".join(sorted(k for k, v in stages.items() if v is not None)) or MISSING


def group_keys(table: pd.DataFrame) -> list[str]:
    """The columns that make a ranking group: one scene at one scale, resolution, profile and
    set of stages (points are only compared with points of the same question)."""
    return ["scene", "scale", "resolution", "profile", "stages"]


def _scale(pixel_mm: Any) -> str:
    if pixel_mm is None or pd.isna(pixel_mm):
        return MISSING
    return f"{float(pixel_mm):.3g} mm/px"


def _candidates(group: pd.DataFrame) -> pd.DataFrame:
    """Screen-space points of a group that may be ranked: ok, SSS visible, not the reference."""
    ok = group[(group["status"] == "ok") & (group["method"] != REFERENCE)]
    if ok.empty:
        return ok
    keep = ok["visible"].map(lambda v: v is not False and not pd.isna(v)).astype(bool)
    return ok[keep]


def annotate(table: pd.DataFrame) -> pd.DataFrame:
    """Add :data:`FLAG_COLUMNS` and ``scale``: per ranking group (:func:`group_keys`),

    - ``pareto``: on the Pareto front of (time, rel_rms) among the ranked points (the
      baseline included: it costs nothing, so it is always on the front);
    - ``best``: the highest skill among the screen-space points;
    - ``worse_than_nothing``: skill <= 0 (no better than the unblurred input);
    - ``note``: ``SSS not visible at this scale`` for points whose reference barely differs
      from the input (:mod:`sssbench.verdict`); they are stored but never ranked.
    """
    table = table.copy()
    table["scale"] = [_scale(v) for v in table["pixel_mm"]]
    for col in ("pareto", "best", "worse_than_nothing"):
        table[col] = False
    table["note"] = ""
    if table.empty:
        return table
    for _, group in table.groupby(group_keys(table), dropna=False, sort=False):
        hidden = group[(group["visible"] == False)].index  # noqa: E712 - None means unknown
        table.loc[hidden, "note"] = "SSS not visible at this scale"
        ranked = _candidates(group)
        if ranked.empty:
            continue
        times = ranked["time_ms"].astype(float).fillna(math.inf).tolist()
        errors = ranked[PLOT_METRIC].astype(float).tolist()
        front = pareto_front(times, errors)
        table.loc[ranked.index[front], "pareto"] = True
        screen = ranked[ranked["method"] != BASELINE]
        skill = screen["skill"].astype(float)
        if skill.notna().any():
            table.loc[skill.idxmax(), "best"] = True
        worse = screen[skill <= 0].index
        table.loc[worse, "worse_than_nothing"] = True
    return table


def recommendations(table: pd.DataFrame) -> pd.DataFrame:
    """Per ranking group: the best configuration, the cheapest within :data:`WITHIN` of its
    skill, the Pareto set and a verdict sentence computed from the numbers."""
    rows = []
    if table.empty:
        return pd.DataFrame(columns=[*group_keys(table), "best", "recommended", "verdict"])
    for key, group in table.groupby(group_keys(table), dropna=False, sort=True):
        base = group[(group["method"] == BASELINE) & (group["status"] == "ok")]
        ranked = _candidates(group)
        screen = ranked[(ranked["method"] != BASELINE) & ranked["skill"].notna()]
        info = dict(zip(group_keys(table), key, strict=True))
        if group["visible"].eq(False).all():
            rows.append(
                {
                    **info,
                    "best": MISSING,
                    "recommended": MISSING,
                    "pareto": MISSING,
                    "verdict": "SSS not visible at this scale: "
                    "every method scores like the unblurred input; not ranked.",
                }
            )
            continue
        if screen.empty:
            continue
        best = screen.loc[screen["skill"].astype(float).idxmax()]
        threshold = float(best["skill"]) - WITHIN * abs(float(best["skill"]))
        good = screen[screen["skill"].astype(float) >= threshold]
        cheap = good.loc[good["time_ms"].astype(float).idxmin()]
        front = ranked[group.loc[ranked.index, "pareto"].astype(bool)]
        worse = screen[screen["skill"].astype(float) <= 0]
        base_err = float(base[PLOT_METRIC].iloc[0]) if len(base) else float("nan")
        if cheap.name == best.name:
            sentence = (
                f"{label(best)} has the best skill ({float(best['skill']):+.2f}) and is the "
                f"cheapest configuration within {WITHIN:.0%} of it "
                f"({float(best['time_ms']):.3g} ms)"
            )
        else:
            sentence = (
                f"{label(cheap)} is the cheapest within {WITHIN:.0%} of the best skill "
                f"({float(cheap['skill']):+.2f} vs {float(best['skill']):+.2f} for "
                f"{label(best)}, {float(cheap['time_ms']):.3g} ms vs "
                f"{float(best['time_ms']):.3g} ms)"
            )
        if not math.isnan(base_err):
            sentence += f"; doing nothing scores rel RMS {base_err:.3g}"
        if len(worse):
            sentence += (
                f"; {len(worse)} of {len(screen)} configurations are worse than doing nothing"
                f" ({', '.join(label(r) for _, r in worse.head(4).iterrows())}"
                f"{', …' if len(worse) > 4 else ''})"
            )
        rows.append(
            {
                **info,
                "best": label(best),
                "recommended": label(cheap),
                "pareto": " → ".join(label(r) for _, r in front.sort_values("time_ms").iterrows()),
                "verdict": sentence + ".",
            }
        )
    return pd.DataFrame(rows)


def label(row: Any) -> str:
    """``method sampling N`` of a table row (what tells two configurations apart)."""
    parts = [str(row["method"])]
    if isinstance(row.get("sampling"), str):
        parts.append(row["sampling"])
    if not pd.isna(row.get("samples")):
        parts.append(str(int(row["samples"])))
    return " ".join(parts)


# ----------------------------------------------------------------------------- analysis
def pareto_front(time_ms: list[float], error: list[float]) -> list[int]:
    """Indices of the Pareto-optimal points (minimise both time and error), fastest first.

    A point is on the front when no other point is at most as slow and at most as wrong, and
    strictly better in one of the two. NaN entries are never on the front.

    Example:
        >>> pareto_front([1, 2, 3, 4], [4, 1, 2, 0.5])
        [0, 1, 3]
    """
    pts = [
        (t, e, i)
        for i, (t, e) in enumerate(zip(time_ms, error, strict=True))
        if not (math.isnan(t) or math.isnan(e))
    ]
    pts.sort(key=lambda p: (p[0], p[1]))
    front: list[int] = []
    best = math.inf
    for _, e, i in pts:
        if e < best:
            front.append(i)
            best = e
    return front


# ----------------------------------------------------------------------------- searches
#: the sweeper whose trials the error-versus-time plot draws with their own Pareto front
SEARCH = "optuna"


def run_sweeper(run_dir: str | None) -> str | None:
    """The Hydra sweeper that launched the run in ``run_dir`` (``basic`` for a grid job,
    ``optuna`` for a trial of an Optuna search), read from the ``.hydra/hydra.yaml`` Hydra
    writes into every job's directory; ``None`` for a single run, a run of the experiments'
    own grids (no Hydra job) or a directory that is gone."""
    import yaml

    if not isinstance(run_dir, str):
        return None
    try:
        text = (Path(run_dir) / ".hydra" / "hydra.yaml").read_text()
        hydra = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))["hydra"]
        if hydra.get("mode") != "MULTIRUN":
            return None
        return str(hydra["runtime"]["choices"]["hydra/sweeper"])
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None


def search_fronts(group: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The Pareto fronts of (time, rel_rms) of one ranking group, fastest first: ``"grid"``
    over its ranked points (:func:`_candidates`) that are not trials of an Optuna search, and
    ``"optuna"`` over those that are (:func:`run_sweeper`); a front without points is left
    out. Without trials, the grid front is the group's ``pareto`` flags (:func:`annotate`)."""
    ranked = _candidates(group)
    trial = ranked["run_dir"].map(lambda d: run_sweeper(d) == SEARCH).astype(bool)
    fronts = {}
    for name, part in (("grid", ranked[~trial]), (SEARCH, ranked[trial])):
        if part.empty:
            continue
        times = part["time_ms"].astype(float).fillna(math.inf).tolist()
        front = pareto_front(times, part[PLOT_METRIC].astype(float).tolist())
        fronts[name] = part.iloc[front]
    return fronts


# ----------------------------------------------------------------------------- writing
def _fmt(value: Any) -> str:
    if value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    if isinstance(value, bool):
        return "yes" if value else ""
    if isinstance(value, float):
        if math.isinf(value):
            return "∞" if value > 0 else "-∞"
        if value == 0:
            return "0"
        if abs(value) >= 1000 or abs(value) < 1e-3:
            return f"{value:.3g}"
        return f"{value:.4g}"
    return str(value)


def _markdown(df: pd.DataFrame) -> str:
    """A GitHub-flavoured Markdown table (no tabulate dependency)."""
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(_fmt(v).replace("|", "\\|") for v in row) + " |")
    return "\n".join(lines)


MD_COLUMNS = [
    "method",
    "sampling",
    "samples",
    "passes",
    "time_ms",
    *METRIC_COLUMNS,
    "skill",
    "err_model",
    "err_taps",
    "err_screen",
    "bias_rel_rms",
    "noise_rel_rms",
    "status",
    "flags",
]


def _flags(row: Any, markdown: bool = True) -> str:
    out = []
    if row["best"]:
        out.append("best")
    if row["pareto"]:
        out.append("Pareto")
    if row["worse_than_nothing"]:
        out.append("**worse than doing nothing**" if markdown else "worse than doing nothing")
    if row["method"] == BASELINE:
        out.append("baseline")
    if row["note"]:
        out.append(row["note"])
    return ", ".join(out)


def summary_markdown(table: pd.DataFrame, source: str) -> str:
    """``summary.md``: per ranking group, one row per point with skill and flags, then the
    recommendation; failures listed at the end."""
    parts = [
        "# sssbench summary",
        "",
        f"Source: `{source}` — {len(table)} points, "
        f"{int((table['status'] == 'ok').sum())} ok. Time = sum of per-pass medians (ms); "
        "rel_rms = RMS error / RMS reference; psnr in dB (∞ = exact); delta_e = mean CIE ΔE76 "
        "of tone-mapped sRGB; flip = mean LDR-FLIP; skill = 1 − rel_rms / rel_rms of doing "
        "nothing (the `identity` baseline: > 0 beats it); err_* = the error budget "
        "(docs/error_budget.md); for stochastic methods rel_rms is the mean over seeds, "
        "bias_rel_rms the error of the seed mean and noise_rel_rms the std across seeds "
        f"(relative to the reference RMS). {MISSING} = not applicable.",
    ]
    recs = recommendations(table)
    table = table.assign(flags=[_flags(r) for _, r in table.iterrows()])
    for key, group in table.groupby(group_keys(table), dropna=False, sort=True):
        info = dict(zip(group_keys(table), key, strict=True))
        title = f"{info['scene']} · {info['scale']} · {info['resolution']} · {info['profile']}"
        if info["stages"] != MISSING:
            title += f" · stages {info['stages']}"
        parts += ["", f"## {title}", "", _markdown(group[MD_COLUMNS])]
        rec = recs
        for k, v in info.items():
            rec = rec[rec[k] == v] if k in rec.columns else rec
        if len(rec):
            r = rec.iloc[0]
            parts += ["", f"**Recommendation.** {r['verdict']}"]
            if r["pareto"] != MISSING:
                parts += ["", f"Pareto front (fastest first): {r['pareto']}."]
    failed = table[table["status"] != "ok"]
    if len(failed):
        parts += ["", "## Failed or timed-out runs", ""]
        parts.append(_markdown(failed[[*POINT_COLUMNS, "status", "error"]]))
    return "\n".join(parts) + "\n"


#: colour of the Optuna trials' Pareto front
SEARCH_COLOUR = "tab:red"
#: marker per sampling rule (the same in every plot)
MARKERS = {"importance": "o", "uniform": "s", "power": "^", None: "D"}


def _marker(sampling: Any) -> str:
    if isinstance(sampling, str):
        return MARKERS.get(sampling, "P")
    return MARKERS[None]


def _log_ticks(axis: Any, lo: float, hi: float) -> None:
    """Readable log ticks: 1-2-5 labels within two decades, one label per decade beyond,
    no minor labels (they overlap into unreadable runs)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    decades = math.log10(max(hi, 1e-300) / max(lo, 1e-300)) if lo > 0 and hi > 0 else 3
    subs = (1.0, 2.0, 5.0) if decades <= 2 else (1.0,)
    axis.set_major_locator(LogLocator(base=10, subs=subs, numticks=12))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _panels(n: int, width: float = 5.0, height: float = 4.0):
    import matplotlib.pyplot as plt

    ncols = min(3, max(n, 1))
    nrows = math.ceil(max(n, 1) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(width * ncols, height * nrows), squeeze=False)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    return fig, list(axes.flat)[:n]


def _title(info: dict[str, Any]) -> str:
    t = f"{info['scene']} · {info['scale']} · {info['resolution']}"
    return t + (f" · {info['stages']}" if info.get("stages", MISSING) != MISSING else "")


def _plot_error_vs_time(table: pd.DataFrame, path: Path) -> Path | None:
    """Per ranking group: time against rel_rms, colour per method, marker per sampling,
    samples written next to each point, the Pareto front, the do-nothing baseline as a dashed
    line and the exact reference as the zero-error anchor (a star on the floor)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    ok = table[(table["status"] == "ok") & table["time_ms"].notna() & table[PLOT_METRIC].notna()]
    if ok.empty:
        return None
    methods = sorted(ok["method"].unique())
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    groups = list(ok.groupby(group_keys(ok), dropna=False, sort=True))
    fig, axes = _panels(len(groups))
    searched = False  # some panel has Optuna trials
    for ax, (key, sub) in zip(axes, groups, strict=True):
        info = dict(zip(group_keys(ok), key, strict=True))
        sub = sub.reset_index()
        err = sub[PLOT_METRIC].astype(float)
        time = sub["time_ms"].astype(float)
        positive = err[err > 0]
        floor = float(positive.min()) / 3 if len(positive) else 1e-6
        tpos = time[time > 0]
        tmin = float(tpos.min()) if len(tpos) else 1e-3
        for _, r in sub.iterrows():
            if r["method"] in (BASELINE, REFERENCE):
                continue
            e = max(float(r[PLOT_METRIC]), floor)
            t = max(float(r["time_ms"]), tmin / 3)
            ax.scatter(
                t,
                e,
                color=colours[r["method"]],
                marker=_marker(r["sampling"]),
                s=34,
                zorder=3,
                edgecolors="k" if r["worse_than_nothing"] else "none",
            )
            if not pd.isna(r["samples"]):
                ax.annotate(
                    str(int(r["samples"])),
                    (t, e),
                    textcoords="offset points",
                    xytext=(4, 3),
                    fontsize=6,
                    color=colours[r["method"]],
                )
        base = sub[sub["method"] == BASELINE]
        if len(base):
            be = float(base[PLOT_METRIC].iloc[0])
            ax.axhline(max(be, floor), color="0.3", ls="--", lw=1, zorder=1)
            ax.annotate(
                "doing nothing (identity)",
                (0.02, max(be, floor)),
                xycoords=("axes fraction", "data"),
                textcoords="offset points",
                xytext=(0, 3),
                fontsize=7,
                color="0.3",
            )
        ref = sub[sub["method"] == REFERENCE]
        if len(ref):
            ax.scatter(
                max(float(ref["time_ms"].iloc[0]), tmin / 3),
                floor,
                marker="*",
                s=140,
                color="gold",
                edgecolors="k",
                zorder=5,
            )
            ax.annotate(
                "exact reference (zero error)",
                (float(ref["time_ms"].iloc[0]), floor),
                textcoords="offset points",
                xytext=(-10, 6),
                fontsize=6,
                ha="right",
            )
        for name, front in search_fronts(sub).items():  # the grid's and the search's
            searched |= name == SEARCH
            colour, ls = ("k", "-") if name == "grid" else (SEARCH_COLOUR, "--")
            ft = [max(float(t), tmin / 3) for t in front["time_ms"]]
            fe = [max(float(e), floor) for e in front[PLOT_METRIC]]
            ax.step(ft, fe, where="post", color=colour, ls=ls, lw=1, alpha=0.6, zorder=2)
            ax.scatter(ft, fe, s=120, facecolors="none", edgecolors=colour, zorder=4)
        ax.set_xscale("log")
        ax.set_yscale("log")
        lo_t, hi_t = ax.get_xlim()
        lo_e, hi_e = ax.get_ylim()
        _log_ticks(ax.xaxis, lo_t, hi_t)
        _log_ticks(ax.yaxis, lo_e, hi_e)
        hidden = " (SSS not visible)" if sub["visible"].eq(False).all() else ""
        ax.set_title(_title(info) + hidden, fontsize=9)
        ax.set_xlabel("time (ms, sum of pass medians)")
        ax.set_ylabel(f"{PLOT_METRIC} (zero drawn at the floor)")
        ax.grid(True, which="major", alpha=0.3)
    handles = [
        Line2D([], [], ls="", marker="o", color=colours[m], label=m)
        for m in methods
        if m not in (BASELINE, REFERENCE)
    ]
    samplings = sorted({s for s in ok["sampling"] if isinstance(s, str)})
    handles += [
        Line2D([], [], ls="", marker=_marker(s), color="0.4", label=f"{s} sampling")
        for s in samplings
    ]
    front_label = "Pareto front (grid)" if searched else "Pareto front"
    handles.append(Line2D([], [], color="k", alpha=0.6, label=front_label))
    if searched:
        handles.append(
            Line2D([], [], color=SEARCH_COLOUR, ls="--", alpha=0.6, label="Optuna trials' front")
        )
    handles += [
        Line2D([], [], color="0.3", ls="--", label="doing nothing"),
        Line2D(
            [],
            [],
            ls="",
            marker="o",
            mfc="none",
            mec="k",
            label="worse than doing nothing (black edge)",
        ),
    ]
    ncol = 3 * min(3, len(axes))
    legend_rows = math.ceil(len(handles) / ncol)
    fig.legend(
        handles=handles, loc="lower center", ncol=ncol, fontsize=7, bbox_to_anchor=(0.5, 0.0)
    )
    fig.tight_layout(rect=(0, min(0.4, 0.25 * legend_rows / fig.get_figheight()), 1, 1))
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _plot_pass_times(table: pd.DataFrame, passes: pd.DataFrame, path: Path) -> Path | None:
    """Per scene: a stacked bar per method of its median pass times (mean over the method's
    points in that scene)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table["status"] == "ok"]
    if ok.empty or passes.empty:
        return None
    merged = passes.merge(ok[["run_id", "method", "scene"]], on="run_id")
    merged = merged[merged["method"] != REFERENCE]
    if merged.empty:
        return None
    order = list(dict.fromkeys(merged.sort_values(["run_id", "idx"])["name"]))
    cmap = plt.get_cmap("tab20")
    colours = {n: cmap(i % 20) for i, n in enumerate(order)}
    scenes = sorted(merged["scene"].unique())
    fig, axes = _panels(len(scenes), width=5.5, height=0.9 + 0.35 * merged["method"].nunique())
    for ax, scene in zip(axes, scenes, strict=True):
        sub = merged[merged["scene"] == scene]
        per_run = sub.groupby(["method", "run_id", "name"], as_index=False)["ms_median"].sum()
        n_runs = per_run.groupby("method")["run_id"].nunique()
        total = per_run.groupby(["method", "name"])["ms_median"].sum()
        mean = total.div(n_runs, level="method").unstack("name").fillna(0.0)
        mean = mean[[c for c in order if c in mean.columns]]
        left = pd.Series(0.0, index=mean.index)
        for name in mean.columns:
            ax.barh(mean.index, mean[name], left=left, color=colours[name], label=name)
            left = left + mean[name]
        ax.set_title(scene, fontsize=9)
        ax.set_xlabel("mean time per run (ms)")
        ax.tick_params(labelsize=7)
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[n]) for n in order]
    fig.legend(handles, order, fontsize=6, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.suptitle("where each method spends its time, per scene", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


#: the parts of the error budget, bottom to top (docs/error_budget.md)
BUDGET_PARTS = ("err_model", "err_taps", "err_screen")


def _plot_budget(table: pd.DataFrame, path: Path) -> Path | None:
    """Per ranking group: the error budget of each configuration as stacked bars of the
    parts' signed contributions ``⟨part, error⟩ / (‖R‖ ‖error‖)``, which add up exactly to
    the configuration's rel RMS (the black mark): model, taps, screen space and the
    reconstruction convention (docs/error_budget.md) — so a user sees whether more taps, a
    better kernel or depth awareness would help. A negative part cancels some of the others."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[(table["status"] == "ok") & table["contribution_model"].notna()]
    ok = ok[~ok["method"].isin((BASELINE, REFERENCE))]
    if ok.empty:
        return None
    groups = list(ok.groupby(group_keys(ok), dropna=False, sort=True))
    fig, axes = _panels(len(groups), width=5.5, height=3.6)
    parts = ("model", "taps", "screen", "recon")
    colours = dict(zip(parts, ("tab:blue", "tab:orange", "tab:green", "tab:gray"), strict=True))
    for ax, (key, sub) in zip(axes, groups, strict=True):
        info = dict(zip(group_keys(ok), key, strict=True))
        sub = sub.sort_values(["method", "samples"]).head(14)
        labels = [label(r) for _, r in sub.iterrows()]
        up = [0.0] * len(sub)
        down = [0.0] * len(sub)
        for part in parts:
            vals = sub[f"contribution_{part}"].astype(float).fillna(0.0).tolist()
            base = [u if v >= 0 else d for u, d, v in zip(up, down, vals, strict=True)]
            ax.bar(labels, vals, bottom=base, color=colours[part], label=f"err_{part}")
            up = [u + max(v, 0.0) for u, v in zip(up, vals, strict=True)]
            down = [d + min(v, 0.0) for d, v in zip(down, vals, strict=True)]
        ax.scatter(
            labels,
            sub[PLOT_METRIC].astype(float),
            marker="_",
            s=200,
            color="k",
            zorder=3,
            label="rel_rms (total)",
        )
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_title(_title(info), fontsize=9)
        ax.tick_params(axis="x", labelrotation=60, labelsize=6)
        ax.set_ylabel("contribution to rel RMS")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(
    source: str | Path,
    out_dir: str | Path | None = None,
    *,
    store: str | Path | None = None,
    html: bool = False,
) -> Report:
    """Write the report files for a store or a sweep directory.

    Args:
        source: an SQLite run store, or a sweep / run directory of the app.
        out_dir: where to write; default ``<sweep dir>/report`` or ``<store dir>/report``.
        store: the store to read when ``source`` is a directory (default: the one its jobs
            name in their ``point.json``).
        html: also write ``report.html`` (:mod:`sssbench.html_report`).

    Returns:
        A :class:`Report` with the written paths and the summary table.
    """
    source = Path(source).expanduser().resolve()
    if source.is_dir():
        found, hashes = sweep_points(source)
        store_path = Path(store) if store is not None else found
        if store_path is None:
            candidate = source / "sssbench.sqlite"
            if not candidate.is_file():
                raise FileNotFoundError(
                    f"no point.json under {source} and no store given: is it an sssbench sweep?"
                )
            store_path, hashes = candidate, None
        default_out = source / "report"
    elif source.is_file():
        store_path, hashes = source, None
        default_out = source.parent / "report"
    else:
        raise FileNotFoundError(f"source must be a run store or a sweep directory, got {source}")
    out = Path(out_dir) if out_dir is not None else default_out
    out.mkdir(parents=True, exist_ok=True)
    runs, passes = load_runs(store_path, hashes)
    table = summary_table(runs)
    csv_path = out / "summary.csv"
    table.to_csv(csv_path, index=False)
    md_path = out / "summary.md"
    md_path.write_text(summary_markdown(table, str(source)))
    plot = _plot_error_vs_time(table, out / "error_vs_time.png")
    bars = _plot_pass_times(table, passes, out / "pass_times.png")
    budget = _plot_budget(table, out / "error_budget.png")
    page = None
    if html:
        from sssbench.html_report import write_html

        page = write_html(
            table, out, str(source), [p for p in (plot, budget, bars) if p is not None]
        )
    return Report(out, csv_path, md_path, plot, bars, table, budget, page)


def format_console(table: pd.DataFrame) -> str:
    """A compact text table for the terminal: sampling and scale shown, skill against doing
    nothing, flags (``*`` best, ``P`` Pareto, ``!`` worse than doing nothing, ``~`` SSS not
    visible), then one recommendation line per scene and scale."""
    if table.empty:
        return "(no runs)"
    cols = [
        "scene",
        "scale",
        "method",
        "sampling",
        "samples",
        "passes",
        "time_ms",
        "rel_rms",
        "skill",
        "flip",
        "status",
    ]
    shown = table[cols].copy()
    shown["samples"] = [MISSING if pd.isna(v) else str(int(v)) for v in shown["samples"]]
    shown["sampling"] = [v if isinstance(v, str) else MISSING for v in shown["sampling"]]
    shown["passes"] = [MISSING if pd.isna(v) else str(int(v)) for v in shown["passes"]]
    for c in ("time_ms", "rel_rms", "skill", "flip"):
        shown[c] = [_fmt(None if pd.isna(v) else float(v)) for v in shown[c]]
    shown["flags"] = [
        "".join(
            f
            for f, on in (
                ("*", r["best"]),
                ("P", r["pareto"]),
                ("!", r["worse_than_nothing"]),
                ("~", bool(r["note"])),
            )
            if on
        )
        for _, r in table.iterrows()
    ]
    lines = [
        shown.to_string(index=False),
        "",
        "flags: * best skill, P Pareto front, ! worse than doing nothing, "
        "~ SSS not visible at this scale (not ranked)",
    ]
    for _, r in recommendations(table).iterrows():
        where = f"{r['scene']} · {r['scale']} · {r['resolution']}"
        where += f" · {r['stages']}" if r["stages"] != MISSING else ""
        lines.append(f"{where}: {r['verdict']}")
    return "\n".join(lines)


def print_report(report: Report, file: Any = None) -> None:
    file = file or sys.stdout
    print(format_console(report.table), file=file)
    print("", file=file)
    for p in report.paths():
        print(f"report: {p}", file=file)


try:
    from hydra.experimental.callback import Callback as _HydraCallback
except ImportError:  # pragma: no cover
    _HydraCallback = object  # type: ignore[assignment,misc]


class ReportCallback(_HydraCallback):
    """Hydra callback: at the end of a multirun, write the report of the sweep directory and
    print the summary table and the report paths (``hydra.callbacks.report`` in a preset)."""

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir)).resolve()
        try:
            report = write_report(sweep_dir, html=True)
        except Exception as exc:  # the report must never hide the sweep's own outcome
            print(
                f"sssbench-report: could not write the report of {sweep_dir}: {exc}",
                file=sys.stderr,
            )
            return
        print("", flush=True)
        print_report(report)
        sys.stdout.flush()


_SQLITE_HEADER = b"SQLite format 3\x00"
_EXPECTED = "expected an sssbench run store (SQLite with a runs table) or a sweep directory"


def _check_store_file(path: Path) -> None:
    """Raise ``ValueError`` unless ``path`` is an SQLite file with the store's tables, reading
    it only (a report never turns another file into a store)."""
    if not path.is_file():
        raise ValueError(f"{path}: no such file; {_EXPECTED}")
    with open(path, "rb") as f:
        header = f.read(len(_SQLITE_HEADER))
    if header != _SQLITE_HEADER:
        raise ValueError(f"{path}: not an SQLite database; {_EXPECTED}")
    try:
        conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
        try:
            names = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
        finally:
            conn.close()
    except sqlite3.DatabaseError as exc:
        raise ValueError(f"{path}: unreadable SQLite database ({exc}); {_EXPECTED}") from exc
    if not {"runs", "passes"} <= names:
        raise ValueError(f"{path}: an SQLite database without sssbench's runs table; {_EXPECTED}")


def _check_source(source: Path, store: str | None) -> None:
    """Raise ``ValueError`` naming the path unless ``source`` (and the store it leads to) is
    what :func:`write_report` reads: a run store, or a sweep directory whose every
    ``point.json`` is a JSON object with ``config_hash`` and ``store``."""
    if not source.exists():
        raise ValueError(f"{source}: no such file or directory; {_EXPECTED}")
    if not source.is_dir():
        _check_store_file(source)
        return
    stores = [] if store is None else [Path(store)]
    for p in sorted(source.rglob("point.json")):
        try:
            point = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{p}: malformed point.json ({exc}); expected a JSON object") from exc
        if not isinstance(point, dict) or not {"config_hash", "store"} <= point.keys():
            raise ValueError(
                f"{p}: malformed point.json; expected a JSON object with config_hash and store"
            )
        stores.append(Path(point["store"]))
    if not stores:
        if not (source / "sssbench.sqlite").is_file():
            raise ValueError(f"{source}: no point.json and no sssbench.sqlite; {_EXPECTED}")
        stores.append(source / "sssbench.sqlite")
    _check_store_file(stores[0])  # write_report reads the given or the first named store


def main(argv: list[str] | None = None) -> int:
    """``sssbench-report [STORE_OR_SWEEP_DIR] [--out DIR] [--store STORE]``.

    On a source that is not a run store or a sweep directory (a text or binary file, an SQLite
    file of something else, a malformed ``point.json``, a missing path) it prints one line on
    stderr naming the path and what was expected and returns 2, writing nothing.
    """
    parser = argparse.ArgumentParser(
        prog="sssbench-report",
        description="Summary tables and plots from an sssbench run store or sweep directory.",
    )
    parser.add_argument(
        "source",
        nargs="?",
        default="sssbench.sqlite",
        help="run store (.sqlite) or sweep/run directory (default: ./sssbench.sqlite)",
    )
    parser.add_argument("--out", default=None, help="output directory (default: beside source)")
    parser.add_argument("--store", default=None, help="store to read for a sweep directory")
    parser.add_argument(
        "--html", action="store_true", help="also write report.html (self-contained page)"
    )
    args = parser.parse_args(argv)
    try:
        _check_source(Path(args.source).expanduser(), args.store)
        report = write_report(args.source, args.out, store=args.store, html=args.html)
    except (OSError, ValueError, KeyError, sqlite3.DatabaseError) as exc:
        print(f"sssbench-report: {exc}".replace("\n", " "), file=sys.stderr)
        return 2
    print_report(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The report's tables: the run store's points as one table, flags per ranking group
(best, Pareto front, worse than doing nothing, visibly wrong, SSS not visible), the computed
recommendation per group, and their text forms (Markdown, console). Tables use pandas.

One module because the flags, the verdict sentences and the three text forms read the same
columns under the same group rule: a sentence printed above a table must be computed from that
table's rows (tests/test_visibly_wrong.py checks every sentence against them), which is easiest
to keep true where both are written.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from sssbench.score.budget_verdict import PARTS, budget_sentence, budget_shares, dominant_part
from sssbench.store.tracking import METRIC_COLUMNS, RunStore

__all__ = [
    "BUDGET_COLUMNS",
    "budget_verdicts",
    "load_runs",
    "summary_table",
    "annotate",
    "recommendations",
    "pareto_front",
    "run_sweeper",
    "search_fronts",
    "summary_markdown",
    "format_console",
    "config_text",
    "Report",
]

POINT_COLUMNS = ["scene", "method", "profile", "sampling", "samples", "stages", "resolution"]
#: per-run numbers beyond the image metrics (from the store's metrics / info)
DECISION_COLUMNS = [
    "pixel_mm",
    "rel_rms_identity",
    "skill",
    "skill_flip",
    "visible",
    "visibility",
    "visibility_window",
    "error_flip_window",
    "error_visible",
    "err_model",
    "err_taps",
    "err_screen",
    "err_recon",
    "contribution_model",
    "contribution_taps",
    "contribution_screen",
    "contribution_recon",
    "error_scale",
    # with backend=gl: the device the pass times come from (sssbench.run.settings.gl_times)
    "renderer",
    "gl_version",
    "timing_note",
    # stochastic methods (sssbench.run.runner.bias_noise): rel_rms is the mean over seeds
    "bias_rel_rms",
    "noise_rel_rms",
    "seeds",
]
#: decision columns that hold text (the GL renderer beside the times), never numbers
TEXT_COLUMNS = ("renderer", "gl_version", "timing_note")
#: columns the report adds per ranking group (:func:`annotate`)
FLAG_COLUMNS = ["pareto", "best", "worse_than_nothing", "visibly_wrong", "note"]
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
        store = RunStore(path, readonly=True)  # reading never writes (no migration)
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
    for col in ("scene", "method", "profile", "sampling"):  # rows that stored a config group
        table[col] = [
            config_text(c[col]) if isinstance(c, dict) and isinstance(c.get(col), dict) else v
            for c, v in zip(configs, table[col], strict=True)
        ]
    table["samples"] = pd.array(
        [None if pd.isna(v) else int(v) for v in table["samples"]], dtype="Int64"
    )
    for col in DECISION_COLUMNS:
        if col not in ("visible", "error_visible", *TEXT_COLUMNS):
            table[col] = pd.to_numeric(table[col], errors="coerce")
    table = table.sort_values(
        ["scene", "pixel_mm", "resolution", "method", "profile", "sampling", "samples"],
        na_position="first",
    ).reset_index(drop=True)
    return annotate(table)


def config_text(value: Any, prefix: str = "") -> str:
    """A stored configuration as readable ``key=value`` text (nested keys dotted), never a
    raw Python dict: ``{"name": "file", "params": {"pixel_mm": 0.3}}`` ->
    ``name=file, params.pixel_mm=0.3``."""
    if isinstance(value, dict):
        if not value:
            return f"{prefix}={{}}" if prefix else ""
        parts = [config_text(v, f"{prefix}.{k}" if prefix else str(k)) for k, v in value.items()]
        return ", ".join(p for p in parts if p)
    if isinstance(value, (list, tuple)):
        text = "[" + ",".join(str(v) for v in value) + "]"
    else:
        text = "null" if value is None else str(value)
    return f"{prefix}={text}" if prefix else text


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
    - ``visibly_wrong``: the run's own error is visible (``error_visible``: its result against
      the reference passes the calibrated visibility rule of :mod:`sssbench.score.verdict`),
      in every group, ranked or not: a method can add a visible error where SSS is not
      visible;
    - ``note``: ``SSS not visible at this scale`` for points whose reference barely differs
      from the input (:mod:`sssbench.score.verdict`); they are stored but never ranked.
    """
    table = table.copy()
    table["scale"] = [_scale(v) for v in table["pixel_mm"]]
    for col in ("pareto", "best", "worse_than_nothing"):
        table[col] = False
    table["visibly_wrong"] = [
        bool(status == "ok" and method != REFERENCE and wrong is True)
        for status, method, wrong in zip(
            table["status"],
            table["method"],
            table["error_visible"] if "error_visible" in table.columns else [None] * len(table),
            strict=True,
        )
    ]
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


def _num(value: Any, fmt: str = ".3g") -> str:
    return MISSING if value is None or pd.isna(value) else format(float(value), fmt)


def _wrong_list(rows: pd.DataFrame) -> str:
    """``label (FLIP mean m, local l, skill s)`` of visibly wrong rows, the four worst first."""
    rows = rows.sort_values("flip", ascending=False)
    text = ", ".join(
        f"{label(r)} (FLIP {_num(r['flip'])}, local {_num(r.get('error_flip_window'))}, "
        f"skill {_num(r['skill'], '+.2f')})"
        for _, r in rows.head(4).iterrows()
    )
    return text + (", …" if len(rows) > 4 else "")


def _hidden_verdict(group: pd.DataFrame) -> str:
    """The verdict of a group where SSS is not visible, from its numbers: the unblurred
    input's FLIP against the bars, then the methods whose own error is visible (or that none
    is), and the range of skills."""
    from sssbench.score.verdict import VISIBLE_FLIP, VISIBLE_LOCAL_FLIP

    ok = group[(group["status"] == "ok") & (group["method"] != REFERENCE)]
    screen = ok[ok["method"] != BASELINE]
    mean = group["visibility"].dropna() if "visibility" in group.columns else pd.Series()
    local = (
        group["visibility_window"].dropna() if "visibility_window" in group.columns else pd.Series()
    )
    sentence = "SSS not visible at this scale"
    if len(mean) and len(local):
        sentence += (
            f" (the unblurred input against the reference: mean FLIP {_num(mean.iloc[0])} < "
            f"{VISIBLE_FLIP}, local FLIP {_num(local.iloc[0])} < {VISIBLE_LOCAL_FLIP})"
        )
    sentence += ": not ranked; doing nothing looks like the reference"
    wrong = screen[screen["visibly_wrong"].astype(bool)]
    known = screen["error_visible"].map(lambda v: isinstance(v, bool)) if len(screen) else []
    if len(wrong):
        sentence += (
            f"; but {len(wrong)} of {len(screen)} configurations are visibly wrong (their "
            f"own error passes the visibility bar): {_wrong_list(wrong)}"
        )
    elif len(screen) and bool(pd.Series(known).all()):
        sentence += f"; no configuration's error is visible either ({len(screen)} tested)"
    skills = screen["skill"].astype(float).dropna()
    if len(skills):
        sentence += f"; skill from {skills.min():+.2f} to {skills.max():+.2f}" + (
            " (differences below the visibility bar)" if not len(wrong) else ""
        )
    return sentence + "."


def recommendations(table: pd.DataFrame, time_spread: float = 0.0) -> pd.DataFrame:
    """Per ranking group: the best configuration, the cheapest within :data:`WITHIN` of its
    skill (``recommended``), the other configurations within :data:`WITHIN` it is not
    resolved as cheaper than (``tied``), the Pareto set and a verdict sentence computed from
    the numbers (in a group where SSS is not visible, the visibility numbers and the
    configurations whose own error is visible; in a ranked group, also those that are
    visibly wrong).

    ``time_spread`` is the run-to-run spread of the ratio of two configurations' times that
    the caller measured (relative, >= 0; :func:`sssbench.score.verdict.not_resolved_cheaper`):
    a qualifying configuration whose ``time_ms`` is within it of the recommended one's is
    ``tied`` with it, and the verdict says the run does not resolve which is cheaper. The
    default 0 ties only equal times; ``recommended`` is the cheaper one by this run's times
    either way."""
    from sssbench._checks import check_scalar
    from sssbench.score.verdict import not_resolved_cheaper

    time_spread = check_scalar("time_spread", time_spread, 0.0)
    rows = []
    if table.empty:
        return pd.DataFrame(columns=[*group_keys(table), "best", "recommended", "tied", "verdict"])
    if "visibly_wrong" not in table.columns:
        table = annotate(table)
    for key, group in table.groupby(group_keys(table), dropna=False, sort=True):
        base = group[(group["method"] == BASELINE) & (group["status"] == "ok")]
        ranked = _candidates(group)
        screen = ranked[(ranked["method"] != BASELINE) & ranked["skill"].notna()]
        info = dict(zip(group_keys(table), key, strict=True))
        wrong_rows = group[group["visibly_wrong"].astype(bool) & (group["method"] != BASELINE)]
        wrong = ", ".join(label(r) for _, r in wrong_rows.iterrows()) or MISSING
        if group["visible"].eq(False).all():
            rows.append(
                {
                    **info,
                    "best": MISSING,
                    "recommended": MISSING,
                    "tied": MISSING,
                    "pareto": MISSING,
                    "visibly_wrong": wrong,
                    "verdict": _hidden_verdict(group),
                }
            )
            continue
        if screen.empty:
            continue
        best = screen.loc[screen["skill"].astype(float).idxmax()]
        threshold = float(best["skill"]) - WITHIN * abs(float(best["skill"]))
        good = screen[screen["skill"].astype(float) >= threshold]
        cheap = good.loc[good["time_ms"].astype(float).idxmin()]
        others = good.drop(index=cheap.name).sort_values("time_ms")
        near = not_resolved_cheaper(
            others["time_ms"].astype(float).tolist(), float(cheap["time_ms"]), time_spread
        )
        tied = others[near]
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
        if len(tied):
            within = (
                f"within {time_spread:.0%} of its time, the measured run-to-run spread of a "
                "time ratio"
                if time_spread > 0
                else "the same time"
            )
            sentence += (
                f"; which is cheaper, it or {', '.join(label(r) for _, r in tied.iterrows())} "
                f"({within}: {', '.join(f'{float(t):.3g} ms' for t in tied['time_ms'])}), "
                "is not resolved"
            )
        if bool(group.loc[cheap.name, "visibly_wrong"]):
            sentence += f", though its own error is still visible (FLIP {_num(cheap['flip'])})"
        if not math.isnan(base_err):
            sentence += f"; doing nothing scores rel RMS {base_err:.3g}"
        if len(worse):
            sentence += (
                f"; {len(worse)} of {len(screen)} configurations are worse than doing nothing"
                f" ({', '.join(label(r) for _, r in worse.head(4).iterrows())}"
                f"{', …' if len(worse) > 4 else ''})"
            )
        if len(wrong_rows):
            sentence += (
                f"; {len(wrong_rows)} of {len(screen)} configurations are visibly wrong: "
                f"{_wrong_list(wrong_rows)}"
            )
        rows.append(
            {
                **info,
                "best": label(best),
                "recommended": label(cheap),
                "tied": ", ".join(label(r) for _, r in tied.iterrows()) or MISSING,
                "pareto": " → ".join(label(r) for _, r in front.sort_values("time_ms").iterrows()),
                "visibly_wrong": wrong,
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


# ----------------------------------------------------------------------------- budget
#: the budget's four parts (rel RMS norms) as table columns, in the sentence's order
BUDGET_COLUMNS = [f"err_{p}" for p in PARTS]


def _parts(row: pd.Series, prefix: str) -> dict[str, float]:
    """``{part: row[prefix + part]}`` (NaN where missing)."""
    out = {}
    for p in PARTS:
        v = row.get(f"{prefix}{p}")
        out[p] = math.nan if v is None or pd.isna(v) else float(v)
    return out


def budget_verdicts(table: pd.DataFrame) -> pd.DataFrame:
    """Per ranking group (:func:`~sssbench.report.tables.group_keys`) and screen-space method:
    the method's configuration with the best skill among its runs with a budget (the most
    taps where no skill is known), its parts' shares of the error (``share_taps`` …, NaN
    where not measured), the dominant part (:func:`~sssbench.score.budget_verdict.dominant_part`)
    and the sentence. Groups or methods without a budget give no row."""
    keys = group_keys(table)
    shares = [f"share_{p}" for p in PARTS]
    cols = [*keys, "method", "config", "rel_rms", *shares, "dominant", "sentence"]
    rows = []
    if table.empty or "contribution_model" not in table.columns:
        return pd.DataFrame(columns=cols)
    ok = table[(table["status"] == "ok") & ~table["method"].isin((BASELINE, REFERENCE))]
    ok = ok[ok["contribution_model"].notna()]
    for key, group in ok.groupby([*keys, "method"], dropna=False, sort=True):
        info = dict(zip([*keys, "method"], key, strict=True))
        skill = group["skill"].astype(float)
        if skill.notna().any():
            row = group.loc[skill.idxmax()]
        else:
            row = group.sort_values("samples", na_position="first").iloc[-1]
        subject = f"{info['scene']} · {info['scale']} · {label(row)}"
        contrib, norms = _parts(row, "contribution_"), _parts(row, "err_")
        sentence = budget_sentence(subject, contrib, norms)
        if sentence is None:
            continue
        shares = budget_shares(contrib) or {}
        rows.append(
            {
                **info,
                "config": label(row),
                "rel_rms": float(sum(contrib[p] for p in shares)),
                **{f"share_{p}": shares.get(p, math.nan) for p in PARTS},
                "dominant": dominant_part(contrib, norms),
                "sentence": sentence,
            }
        )
    return pd.DataFrame(rows, columns=cols)


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
    "err_recon",
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
    if row.get("visibly_wrong"):
        text = (
            f"visibly wrong (FLIP {_num(row['flip'])}, local {_num(row.get('error_flip_window'))},"
            f" skill {_num(row['skill'], '+.2f')})"
        )
        out.append(f"**{text}**" if markdown else text)
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
    budgets = budget_verdicts(table)
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
        lines = _group_rows(budgets, info)["sentence"].tolist()
        if lines:
            head = "**Error budget** (each part's share of the error, docs/error_budget.md):"
            parts += ["", head]
            parts += [""] + [f"- {line}" for line in lines]
    for line in device_lines(table):
        parts += ["", line]
    failed = table[table["status"] != "ok"]
    if len(failed):
        parts += ["", "## Failed or timed-out runs", ""]
        parts.append(_markdown(failed[[*POINT_COLUMNS, "status", "error"]]))
    return "\n".join(parts) + "\n"


def _group_rows(rows: pd.DataFrame, info: dict[str, Any]) -> pd.DataFrame:
    """The rows of ``rows`` in the ranking group ``info`` (its group keys)."""
    for k, v in info.items():
        if k in rows.columns:
            rows = rows[rows[k].isna()] if v is None or v is pd.NA else rows[rows[k] == v]
    return rows


def device_lines(table: pd.DataFrame) -> list[str]:
    """One line per GL renderer the table's times come from (``backend=gl``): the renderer and
    its version beside the times, and, on a software rasteriser, that they are its times."""
    if "renderer" not in table.columns:
        return []
    out = []
    rows = table[table["renderer"].notna() & (table["renderer"] != "")]
    for (renderer, version, note), group in rows.groupby(
        ["renderer", "gl_version", "timing_note"], dropna=False, sort=True
    ):
        line = f"GL pass times (GL_TIME_ELAPSED) of {len(group)} run(s): {renderer}, {version}"
        if isinstance(note, str) and note:
            line += f" — {note}"
        out.append(line)
    return out


def format_console(table: pd.DataFrame) -> str:
    """A compact text table for the terminal: sampling and scale shown (and the stages when
    the rows differ in them, so two points of a stage sweep never look alike), skill against
    doing nothing, flags (``*`` best, ``P`` Pareto, ``!`` visibly wrong, ``-`` worse than doing
    nothing, ``~`` SSS not visible), then one recommendation line per scene and scale."""
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
    if table["stages"].nunique(dropna=False) > 1:  # a sweep varies a stage: show which ran
        cols.insert(cols.index("samples") + 1, "stages")
    budget = [c for c in ("err_taps", "err_model", "err_recon", "err_screen") if c in table]
    if budget and table[budget].notna().any().any():  # the error budget's four parts
        cols[cols.index("status") : cols.index("status")] = budget
    else:
        budget = []
    shown = table[cols].copy()
    shown["samples"] = [MISSING if pd.isna(v) else str(int(v)) for v in shown["samples"]]
    shown["sampling"] = [v if isinstance(v, str) else MISSING for v in shown["sampling"]]
    shown["passes"] = [MISSING if pd.isna(v) else str(int(v)) for v in shown["passes"]]
    for c in ("time_ms", "rel_rms", "skill", "flip", *budget):
        shown[c] = [_fmt(None if pd.isna(v) else float(v)) for v in shown[c]]
    shown["flags"] = [
        "".join(
            f
            for f, on in (
                ("*", r["best"]),
                ("P", r["pareto"]),
                ("!", r.get("visibly_wrong", False)),
                ("-", r["worse_than_nothing"]),
                ("~", bool(r["note"])),
            )
            if on
        )
        for _, r in table.iterrows()
    ]
    lines = [
        shown.to_string(index=False),
        "",
        "flags: * best skill, P Pareto front, ! visibly wrong (its own error passes the "
        "visibility bar), - worse than doing nothing, ~ SSS not visible at this scale (not "
        "ranked)",
    ]
    lines += device_lines(table)
    for _, r in recommendations(table).iterrows():
        where = f"{r['scene']} · {r['scale']} · {r['resolution']}"
        where += f" · {r['stages']}" if r["stages"] != MISSING else ""
        lines.append(f"{where}: {r['verdict']}")
    sentences = budget_verdicts(table)["sentence"].tolist()
    if sentences:
        lines += ["", "error budget (each part's share of the error, docs/error_budget.md):"]
        lines += sentences
    return "\n".join(lines)

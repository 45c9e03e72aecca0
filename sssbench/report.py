"""Tables and plots from the run store (DESIGN §6: ``sssbench-report``).

``sssbench-report [STORE_OR_SWEEP_DIR] [--out DIR]`` writes

* ``summary.csv`` — one row per point (the newest stored run of each config): scene, method,
  profile, sampling, samples, status, passes, time_ms and every metric;
* ``summary.md`` — per scene, a method table with the error metrics, time, samples and passes;
* ``error_vs_time.png`` — per scene, run time (log) against relative RMS error (log), each
  method a colour, the Pareto front (no other point is both faster and more accurate) drawn
  as a step line through ringed points;
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
    "write_report",
    "Report",
    "ReportCallback",
    "main",
]

POINT_COLUMNS = ["scene", "method", "profile", "sampling", "samples", "resolution"]
SUMMARY_COLUMNS = [
    *POINT_COLUMNS,
    "status",
    "passes",
    "time_ms",
    *METRIC_COLUMNS,
    "error",
    "run_id",
    "run_dir",
]
#: the error metric of the error-versus-time plot and the Pareto front
PLOT_METRIC = "rel_rms"


@dataclass(frozen=True)
class Report:
    """Paths of the files a report wrote, and its summary table."""

    out_dir: Path
    summary_csv: Path
    summary_md: Path
    error_vs_time: Path | None
    pass_times: Path | None
    table: pd.DataFrame

    def paths(self) -> list[Path]:
        return [
            p
            for p in (self.summary_csv, self.summary_md, self.error_vs_time, self.pass_times)
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
    """One row per point, columns :data:`SUMMARY_COLUMNS`, sorted by scene, method, samples."""
    table = runs.rename(columns={"id": "run_id"})
    if "config" in table.columns:
        table["resolution"] = [_resolution(c) for c in table["config"]]
    for col in SUMMARY_COLUMNS:
        if col not in table.columns:
            table[col] = None
    table = table[SUMMARY_COLUMNS].copy()
    table["samples"] = pd.array(
        [None if pd.isna(v) else int(v) for v in table["samples"]], dtype="Int64"
    )
    return table.sort_values(["scene", "method", "profile", "sampling", "samples"]).reset_index(
        drop=True
    )


def _resolution(config: Any) -> str | None:
    res = config.get("resolution") if isinstance(config, dict) else None
    if isinstance(res, list) and len(res) == 2:
        return f"{res[0]}x{res[1]}"
    return None if res is None else str(res)


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


# ----------------------------------------------------------------------------- writing
def _fmt(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
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
    "resolution",
    "profile",
    "sampling",
    "samples",
    "passes",
    "time_ms",
    *METRIC_COLUMNS,
    "status",
]


def summary_markdown(table: pd.DataFrame, source: str) -> str:
    """``summary.md``: per scene, one row per method point; failures listed at the end."""
    parts = [
        "# sssbench summary",
        "",
        f"Source: `{source}` — {len(table)} points, "
        f"{int((table['status'] == 'ok').sum())} ok. Time = sum of per-pass medians (ms); "
        "rel_rms = RMS error / RMS reference; psnr in dB (∞ = exact); delta_e = mean CIE ΔE76 "
        "of tone-mapped sRGB; flip = mean LDR-FLIP.",
    ]
    for scene, group in table.groupby("scene", sort=True):
        parts += ["", f"## {scene}", "", _markdown(group[MD_COLUMNS])]
    failed = table[table["status"] != "ok"]
    if len(failed):
        parts += ["", "## Failed or timed-out runs", ""]
        parts.append(_markdown(failed[[*POINT_COLUMNS, "status", "error"]]))
    return "\n".join(parts) + "\n"


def _plot_error_vs_time(table: pd.DataFrame, path: Path) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    ok = table[(table["status"] == "ok") & table["time_ms"].notna() & table[PLOT_METRIC].notna()]
    if ok.empty:
        return None
    scenes = sorted(ok["scene"].unique())
    methods = sorted(ok["method"].unique())
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    ncols = min(3, len(scenes))
    nrows = math.ceil(len(scenes) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5 * ncols, 4 * nrows), squeeze=False)
    for ax, scene in zip(axes.flat, scenes, strict=False):
        sub = ok[ok["scene"] == scene].reset_index(drop=True)
        err = sub[PLOT_METRIC].astype(float)
        positive = err[err > 0]
        floor = float(positive.min()) / 3 if len(positive) else 1e-6
        shown = err.clip(lower=floor)
        for m in methods:
            sel = sub["method"] == m
            if not sel.any():
                continue
            exact = sel & (err <= 0)
            if (sel & ~exact).any():
                ax.scatter(
                    sub.loc[sel & ~exact, "time_ms"],
                    shown[sel & ~exact],
                    color=colours[m],
                    label=m,
                    s=30,
                    zorder=3,
                )
            if exact.any():
                ax.scatter(
                    sub.loc[exact, "time_ms"],
                    shown[exact],
                    color=colours[m],
                    marker="v",
                    s=40,
                    zorder=3,
                    label=f"{m} (exact)",
                )
        front = pareto_front(sub["time_ms"].astype(float).tolist(), err.tolist())
        ft = sub.loc[front, "time_ms"].astype(float)
        fe = shown[front]
        ax.step(ft, fe, where="post", color="k", lw=1, alpha=0.6, zorder=2, label="Pareto front")
        ax.scatter(ft, fe, s=120, facecolors="none", edgecolors="k", zorder=4)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(scene)
        ax.set_xlabel("time (ms, sum of pass medians)")
        ax.set_ylabel(f"{PLOT_METRIC} (zero shown at the floor)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(scenes) :]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_pass_times(table: pd.DataFrame, passes: pd.DataFrame, path: Path) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table["status"] == "ok"]
    if ok.empty or passes.empty:
        return None
    merged = passes.merge(ok[["run_id", "method"]], on="run_id")
    if merged.empty:
        return None
    # per method: sum a pass name's medians within a run, then average over the method's runs
    per_run = merged.groupby(["method", "run_id", "name"], as_index=False)["ms_median"].sum()
    n_runs = per_run.groupby("method")["run_id"].nunique()
    total = per_run.groupby(["method", "name"])["ms_median"].sum()
    mean = total.div(n_runs, level="method").unstack("name").fillna(0.0)
    order = list(dict.fromkeys(merged.sort_values(["run_id", "idx"])["name"]))
    mean = mean[[c for c in order if c in mean.columns]]
    fig, ax = plt.subplots(figsize=(7, 1.2 + 0.5 * len(mean)))
    left = pd.Series(0.0, index=mean.index)
    cmap = plt.get_cmap("tab20")
    for i, name in enumerate(mean.columns):
        ax.barh(mean.index, mean[name], left=left, color=cmap(i % 20), label=name)
        left = left + mean[name]
    ax.set_xlabel("mean time per run (ms, median of repeats per pass)")
    ax.set_title("where each method spends its time")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def write_report(
    source: str | Path, out_dir: str | Path | None = None, *, store: str | Path | None = None
) -> Report:
    """Write the report files for a store or a sweep directory.

    Args:
        source: an SQLite run store, or a sweep / run directory of the app.
        out_dir: where to write; default ``<sweep dir>/report`` or ``<store dir>/report``.
        store: the store to read when ``source`` is a directory (default: the one its jobs
            name in their ``point.json``).

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
    return Report(out, csv_path, md_path, plot, bars, table)


def format_console(table: pd.DataFrame) -> str:
    """A compact text table for the terminal."""
    cols = [
        "scene",
        "method",
        "samples",
        "resolution",
        "passes",
        "time_ms",
        "rel_rms",
        "psnr",
        "flip",
        "status",
    ]
    if table.empty:
        return "(no runs)"
    shown = table[cols].copy()
    shown["samples"] = ["–" if pd.isna(v) else str(int(v)) for v in shown["samples"]]
    for c in ("time_ms", "rel_rms", "psnr", "flip"):
        shown[c] = [_fmt(None if pd.isna(v) else float(v)) for v in shown[c]]
    return shown.to_string(index=False)


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
            report = write_report(sweep_dir)
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
    args = parser.parse_args(argv)
    try:
        _check_source(Path(args.source).expanduser(), args.store)
        report = write_report(args.source, args.out, store=args.store)
    except (OSError, ValueError, KeyError, sqlite3.DatabaseError) as exc:
        print(f"sssbench-report: {exc}".replace("\n", " "), file=sys.stderr)
        return 2
    print_report(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())

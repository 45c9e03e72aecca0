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

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sssbench.report.plots import plot_budget, plot_error_vs_time, plot_pass_times
from sssbench.report.tables import (
    Report,
    format_console,
    load_runs,
    summary_markdown,
    summary_table,
    sweep_points,
)

__all__ = ["write_report", "print_report"]


def write_report(
    source: str | Path,
    out_dir: str | Path | None = None,
    *,
    store: str | Path | None = None,
    html: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Report:
    """Write the report files for a store or a sweep directory.

    Args:
        source: an SQLite run store, or a sweep / run directory of the app.
        out_dir: where to write; default ``<sweep dir>/report`` or ``<store dir>/report``.
        store: the store to read when ``source`` is a directory (default: the one its jobs
            name in their ``point.json``).
        html: also write ``report.html`` (:mod:`sssbench.report.html`).
        progress: called with one line per step (reading, tables, each plot, each group of
            the page), so a long report is never silent; ``None``: quiet.

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
    say = progress or (lambda line: None)
    say(f"report: reading the runs of {source}")
    runs, passes = load_runs(store_path, hashes)
    say(f"report: {len(runs)} points; summary tables")
    table = summary_table(runs)
    csv_path = out / "summary.csv"
    table.to_csv(csv_path, index=False)
    md_path = out / "summary.md"
    md_path.write_text(summary_markdown(table, str(source)))
    say("report: plots (error vs time, pass times, error budget)")
    plot = plot_error_vs_time(table, out / "error_vs_time.png")
    bars = plot_pass_times(table, passes, out / "pass_times.png")
    budget = plot_budget(table, out / "error_budget.png")
    page = None
    if html:
        from sssbench.report.html import write_html

        page = write_html(
            table,
            out,
            str(source),
            [p for p in (plot, budget, bars) if p is not None],
            progress=progress,
        )
    return Report(out, csv_path, md_path, plot, bars, table, budget, page)


def print_report(report: Report, file: Any = None) -> None:
    file = file or sys.stdout
    print(format_console(report.table), file=file)
    print("", file=file)
    for p in report.paths():
        print(f"report: {p}", file=file)

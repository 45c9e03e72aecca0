"""Tables, recommendations, plots and the HTML page from the run store (DESIGN §6:
``sssbench-report``).

``sssbench-report [STORE_OR_SWEEP_DIR] [--out DIR] [--html]`` writes ``summary.csv``,
``summary.md``, ``error_vs_time.png``, ``pass_times.png``, ``error_budget.png`` and, with
``--html``, ``report.html``. The package reads the run store only; its modules, each a job:

- :mod:`~sssbench.report.tables` — points as a table, flags per group, recommendations, text;
- :mod:`~sssbench.report.plots` — the figures, drawn from the table;
- :mod:`~sssbench.report.html` — the self-contained page, drawn from the table;
- :mod:`~sssbench.report.files` — :func:`write_report`: all of the above into a folder;
- :mod:`~sssbench.report.cli` — the command line and the Hydra callback.
"""

from sssbench.report.cli import ReportCallback, main
from sssbench.report.files import print_report, write_report
from sssbench.report.plots import BUDGET_PARTS, MARKERS
from sssbench.report.tables import (
    BASELINE,
    MISSING,
    REFERENCE,
    Report,
    annotate,
    config_text,
    format_console,
    load_runs,
    pareto_front,
    recommendations,
    run_sweeper,
    search_fronts,
    summary_markdown,
    summary_table,
)

__all__ = [
    "BASELINE",
    "BUDGET_PARTS",
    "MARKERS",
    "MISSING",
    "REFERENCE",
    "Report",
    "ReportCallback",
    "annotate",
    "config_text",
    "format_console",
    "load_runs",
    "main",
    "pareto_front",
    "print_report",
    "recommendations",
    "run_sweeper",
    "search_fronts",
    "summary_markdown",
    "summary_table",
    "write_report",
]

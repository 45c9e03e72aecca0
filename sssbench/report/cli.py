"""``sssbench-report``: the command line and the Hydra callback that write a report
(:func:`sssbench.report.files.write_report`) and print its table.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
from pathlib import Path
from typing import Any

from sssbench._console import quiet_third_party
from sssbench.report.files import print_report, write_report
from sssbench.store.tracking import read_only_uri

__all__ = ["ReportCallback", "main"]

try:
    from hydra.experimental.callback import Callback as _HydraCallback
except ImportError:  # pragma: no cover
    _HydraCallback = object  # type: ignore[assignment,misc]


def _say(line: str) -> None:
    """A progress line of the report step (stdout, with the table and the paths; stderr
    carries errors only)."""
    print(line, flush=True)


class ReportCallback(_HydraCallback):
    """Hydra callback: at the end of a multirun, write the report of the sweep directory and
    print the summary table and the report paths (``hydra.callbacks.report`` in a preset)."""

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir)).resolve()
        try:
            report = write_report(sweep_dir, html=True, progress=_say)
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
        conn = sqlite3.connect(read_only_uri(path), uri=True)
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
    quiet_third_party()
    try:
        _check_source(Path(args.source).expanduser(), args.store)
        report = write_report(
            args.source, args.out, store=args.store, html=args.html, progress=_say
        )
    except (OSError, ValueError, KeyError, sqlite3.DatabaseError) as exc:
        print(f"sssbench-report: {exc}".replace("\n", " "), file=sys.stderr)
        return 2
    print_report(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())

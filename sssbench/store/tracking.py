"""The run store: an embedded SQLite database of every run of the app (DESIGN §6).

One row per run in ``runs`` (the run's config as JSON and its hash, status ``ok`` / ``failed`` /
``timeout``, the metrics, the error message, timestamps, where it ran) and one row per timed pass
in ``passes``. A sweep is resumable: :meth:`RunStore.is_done` tells whether a config already has
an ``ok`` row, and the app skips such points unless forced.

Safety with parallel writers (joblib workers, SLURM array tasks on one file system):

* WAL journal (readers never block the writer) and a busy timeout, so a writer waits for the
  lock instead of failing;
* one ``BEGIN IMMEDIATE`` transaction per run write — the run row and all its pass rows commit
  together or not at all, so a crash never leaves a half-written run;
* a retry with back-off around the whole transaction when the lock stays busy beyond the
  timeout;
* **at most one ``ok`` row per point**: a partial unique index on ``config_hash`` where
  ``status = 'ok'`` makes the database itself refuse a second one. :meth:`RunStore.record` of an
  ``ok`` run deletes the point's previous ``ok`` row (and, by cascade, its passes) in the same
  transaction as its insert, so a forced re-run supersedes, and two sweeps that run the same
  point at once both finish: the later write is the point's result, nothing is half-written.
  ``failed`` / ``timeout`` rows are history and are all kept. A store written before the index
  existed is migrated when opened **for writing** only: the file is first copied to
  ``<name>.pre-migration-<UTC time>.bak`` (SQLite's backup API), a warning says so, and of
  duplicate ``ok`` rows the latest (largest id) is kept;
* **reading never writes**: ``RunStore(path, readonly=True)`` (what ``sssbench-report`` uses)
  opens the file with SQLite's ``mode=ro`` (:func:`read_only_uri`: ``immutable`` for an idle
  WAL store, whose ``-wal`` / ``-shm`` files a read would otherwise create): no schema, no
  migration, no journal-mode switch — the file and its folder stay byte for byte what they
  were; the readers select the latest row per point anyway, so an unmigrated store reads the
  same.

WAL needs all writers on one host (shared memory); on a network file system shared by several
nodes use ``journal_mode="delete"`` (the app's ``store_journal=delete``), see ``docs/sweeps.md``.

Example:
    >>> import tempfile, os
    >>> store = RunStore(os.path.join(tempfile.mkdtemp(), "runs.sqlite"))
    >>> run = RunRecord(config={"scene": "sphere"}, status="ok", metrics={"rmse": 0.1})
    >>> run_id = store.record(run)
    >>> store.is_done(config_hash({"scene": "sphere"}))
    True
"""

from __future__ import annotations

import hashlib
import logging
import math
import random
import sqlite3
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sssbench import _json

__all__ = [
    "RunStore",
    "RunRecord",
    "PassStats",
    "config_hash",
    "utc_now",
    "STATUSES",
    "METRIC_COLUMNS",
    "read_only_uri",
    "check_journal_mode",
    "JOURNAL_MODES",
]

log = logging.getLogger(__name__)

STATUSES = ("ok", "failed", "timeout")
#: SQLite journal modes a store may use: ``wal`` (one host), ``delete`` or ``truncate``
#: (a store on a network file system written from several nodes)
JOURNAL_MODES = ("wal", "delete", "truncate")


def check_journal_mode(name: str, value: object) -> str:
    """``value`` lower-cased if it is one of :data:`JOURNAL_MODES`, else a ``ValueError`` naming
    ``name`` (``journal_mode``; the app's ``store_journal``)."""
    if not isinstance(value, str) or value.lower() not in JOURNAL_MODES:
        raise ValueError(f"{name} must be one of {list(JOURNAL_MODES)}, got {value!r}")
    return value.lower()


#: metrics that get their own column (all metrics are also kept in ``metrics_json``)
METRIC_COLUMNS = ("rmse", "rel_rms", "psnr", "ssim", "delta_e", "flip")
#: config keys copied into their own columns for querying
KEY_COLUMNS = ("scene", "method", "profile", "sampling", "samples")

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS runs (
    id           INTEGER PRIMARY KEY AUTOINCREMENT,
    config_hash  TEXT NOT NULL,
    config_json  TEXT NOT NULL,
    scene        TEXT,
    method       TEXT,
    profile      TEXT,
    sampling     TEXT,
    samples      INTEGER,
    status       TEXT NOT NULL CHECK (status IN {STATUSES!r}),
    error        TEXT,
    time_ms      REAL,
    passes       INTEGER,
    {", ".join(f"{m} REAL" for m in METRIC_COLUMNS)},
    metrics_json TEXT NOT NULL DEFAULT '{{}}',
    info_json    TEXT NOT NULL DEFAULT '{{}}',
    run_dir      TEXT,
    sweep_dir    TEXT,
    started_at   TEXT NOT NULL,
    finished_at  TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS runs_hash_status ON runs (config_hash, status);
CREATE UNIQUE INDEX IF NOT EXISTS runs_one_ok ON runs (config_hash) WHERE status = 'ok';
CREATE INDEX IF NOT EXISTS runs_sweep ON runs (sweep_dir, finished_at);
CREATE TABLE IF NOT EXISTS passes (
    run_id     INTEGER NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
    idx        INTEGER NOT NULL,
    name       TEXT NOT NULL,
    samples    INTEGER,
    pixels     INTEGER,
    ms_median  REAL,
    ms_min     REAL,
    ms_max     REAL,
    repeats    INTEGER,
    PRIMARY KEY (run_id, idx)
);
"""

#: migration of stores written before ``runs_one_ok``: keep the latest ``ok`` row per point
#: (passes of the others go by ``ON DELETE CASCADE``)
_DEDUPLICATE_OK = """
DELETE FROM runs WHERE status = 'ok' AND id NOT IN (
    SELECT MAX(id) FROM runs WHERE status = 'ok' GROUP BY config_hash
)
"""


def read_only_uri(path: str | Path) -> str:
    """The SQLite URI that reads ``path`` without writing anything: ``mode=ro``, plus
    ``immutable=1`` for a WAL database no writer has open (no ``-wal`` file): a read-only
    connection to a WAL database would otherwise create ``-wal`` and ``-shm`` files beside it
    and leave them there. A store in rollback-journal mode, or with a writer at work (its
    ``-wal`` exists), is read with ``mode=ro`` and SQLite's own locking."""
    path = Path(path).expanduser().resolve()
    uri = f"{path.as_uri()}?mode=ro"
    try:
        with open(path, "rb") as f:
            header = f.read(20)
    except OSError:
        return uri
    wal = len(header) == 20 and header[18] == 2  # file format read version 2: WAL
    if wal and not path.with_name(path.name + "-wal").exists():
        uri += "&immutable=1"
    return uri


def utc_now() -> str:
    """The current time as an ISO 8601 UTC string with microseconds (sorts lexically)."""
    return datetime.now(UTC).isoformat(timespec="microseconds")


def _canonical(obj: Any) -> str:
    return _json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def config_hash(config: dict[str, Any]) -> str:
    """SHA-256 (hex, 16 chars) of the canonical JSON of a run's defining config.

    Key order does not matter; the caller decides which keys define a point (the app leaves
    out run-control keys such as ``store``, ``force`` and ``timeout_s``).
    """
    if not isinstance(config, dict):
        raise TypeError(f"config must be a dict, got {type(config).__name__}")
    return hashlib.sha256(_canonical(config).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class PassStats:
    """Timing of one pass over the repeats of a run (milliseconds)."""

    name: str
    samples: int
    pixels: int
    ms_median: float
    ms_min: float
    ms_max: float
    repeats: int


@dataclass
class RunRecord:
    """Everything stored about one run.

    Args:
        config: the run's defining config (JSON-serialisable); hashed with :func:`config_hash`.
        status: ``"ok"``, ``"failed"`` or ``"timeout"``.
        metrics: metric name -> value (``rmse``, ``psnr`` ... and anything else).
        passes: per-pass timings, in execution order.
        time_ms: run time = sum of the pass medians (ms).
        error: the error message of a failed / timed-out run.
        info: extra JSON (thread count, library versions, skipped stages, cache hits ...).
        run_dir, sweep_dir: where the run wrote its files.
        started_at, finished_at: ISO UTC timestamps (:func:`utc_now`); default now.
    """

    config: dict[str, Any]
    status: str
    metrics: dict[str, float] = field(default_factory=dict)
    passes: Sequence[PassStats] = ()
    time_ms: float | None = None
    error: str | None = None
    info: dict[str, Any] = field(default_factory=dict)
    run_dir: str | None = None
    sweep_dir: str | None = None
    started_at: str = field(default_factory=utc_now)
    finished_at: str = field(default_factory=utc_now)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {list(STATUSES)}, got {self.status!r}")
        if not isinstance(self.config, dict):
            raise TypeError(f"config must be a dict, got {type(self.config).__name__}")


def _num(value: Any) -> float | None:
    """A float for a REAL column (``inf`` is kept; ``None``/NaN become NULL)."""
    if value is None:
        return None
    value = float(value)
    return None if math.isnan(value) else value


class RunStore:
    """An SQLite run store at ``path`` (created with its tables on first use).

    Args:
        path: database file; its parent directory is created.
        timeout_s: how long one attempt waits for a busy lock (SQLite busy timeout).
        retries: further attempts, with jittered exponential back-off, when a write still finds
            the database locked.
        journal_mode: ``"wal"`` (default, one host) or ``"delete"`` (network file systems).
        readonly: open an existing store for reading only (SQLite ``mode=ro``): nothing is
            created, migrated or switched, and :meth:`record` is refused.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        timeout_s: float = 30.0,
        retries: int = 8,
        journal_mode: str = "wal",
        readonly: bool = False,
    ) -> None:
        journal_mode = check_journal_mode("journal_mode", journal_mode)
        self.path = Path(path).expanduser().resolve()
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.journal_mode = journal_mode
        self.readonly = bool(readonly)
        if self.readonly:
            if not self.path.is_file():
                raise FileNotFoundError(f"store {self.path}: no such file (opened read-only)")
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._retry(self._init_schema)

    # ------------------------------------------------------------------ connections
    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        if self.readonly:
            uri = read_only_uri(self.path)
            conn = sqlite3.connect(uri, uri=True, timeout=self.timeout_s, isolation_level=None)
        else:
            conn = sqlite3.connect(self.path, timeout=self.timeout_s, isolation_level=None)
        try:
            conn.row_factory = sqlite3.Row
            conn.execute(f"PRAGMA busy_timeout = {int(self.timeout_s * 1000)}")
            if not self.readonly:
                conn.execute("PRAGMA foreign_keys = ON")
            yield conn
        finally:
            conn.close()

    def _retry(self, fn: Any) -> Any:
        delay = 0.05
        for attempt in range(self.retries + 1):
            try:
                return fn()
            except sqlite3.OperationalError as exc:
                msg = str(exc).lower()
                if attempt == self.retries or not ("locked" in msg or "busy" in msg):
                    raise
                time.sleep(delay * (1 + random.random()))
                delay = min(delay * 2, 2.0)
        raise AssertionError("unreachable")

    def _needs_migration(self) -> bool:
        """An older store: a ``runs`` table without the ``runs_one_ok`` index."""
        with self._connect() as conn:
            names = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
        return "runs" in names and "runs_one_ok" not in names

    def _backup(self) -> Path:
        """Copy the store (consistently: SQLite's backup API) before migrating it."""
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%fZ")
        target = self.path.with_name(f"{self.path.name}.pre-migration-{stamp}.bak")
        src = sqlite3.connect(read_only_uri(self.path), uri=True)
        try:
            dst = sqlite3.connect(target)
            try:
                src.backup(dst)
            finally:
                dst.close()
        finally:
            src.close()
        return target

    def _init_schema(self) -> None:
        if self._needs_migration():
            backup = self._backup()
            log.warning(
                "migrating run store %s to the one-ok-row-per-point schema (duplicate ok rows: "
                "the latest is kept); a copy of the store before migration is at %s",
                self.path, backup,
            )  # fmt: skip
        with self._connect() as conn:
            mode = conn.execute(f"PRAGMA journal_mode = {self.journal_mode}").fetchone()[0]
            if mode.lower() != self.journal_mode and self.journal_mode == "wal":
                raise sqlite3.OperationalError(f"could not switch {self.path} to WAL (got {mode})")
            conn.execute("BEGIN IMMEDIATE")
            try:
                for statement in _SCHEMA.split(";"):
                    if "runs_one_ok" in statement:  # migrate older stores before the index
                        conn.execute(_DEDUPLICATE_OK)
                    if statement.strip():
                        conn.execute(statement)
                conn.execute("COMMIT")
            except BaseException:
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
                raise

    # ------------------------------------------------------------------ writes
    def record(self, run: RunRecord) -> int:
        if self.readonly:
            raise ValueError(f"store {self.path} is open read-only; open it with readonly=False")
        """Store one run and its passes in a single transaction; return the run id.

        An ``ok`` run replaces the point's previous ``ok`` row and its passes (one ``ok`` row
        per config hash, see the module doc); other statuses are appended.
        """
        if not isinstance(run, RunRecord):
            raise TypeError(f"run must be a RunRecord, got {type(run).__name__}")
        cfg = run.config
        row = {
            "config_hash": config_hash(cfg),
            "config_json": _canonical(cfg),
            **{k: cfg.get(k) for k in KEY_COLUMNS},
            "status": run.status,
            "error": run.error,
            "time_ms": _num(run.time_ms),
            "passes": len(run.passes),
            **{m: _num(run.metrics.get(m)) for m in METRIC_COLUMNS},
            "metrics_json": _json.dumps(run.metrics, sort_keys=True),
            "info_json": _json.dumps(run.info, sort_keys=True, default=str),
            "run_dir": run.run_dir,
            "sweep_dir": run.sweep_dir,
            "started_at": run.started_at,
            "finished_at": run.finished_at,
        }
        for key in ("scene", "method", "profile", "sampling"):
            if isinstance(row[key], dict):  # a config group: its name, not a Python repr
                row[key] = row[key].get("name", _canonical(row[key]))
            if row[key] is not None:
                row[key] = str(row[key])
        if row["samples"] is not None:
            row["samples"] = int(row["samples"])
        cols = ", ".join(row)
        marks = ", ".join(f":{k}" for k in row)

        def write() -> int:
            with self._connect() as conn:
                conn.execute("BEGIN IMMEDIATE")
                try:
                    if row["status"] == "ok":  # supersede: one ok row per point (module doc)
                        conn.execute(
                            "DELETE FROM runs WHERE config_hash = ? AND status = 'ok'",
                            (row["config_hash"],),
                        )
                    cur = conn.execute(f"INSERT INTO runs ({cols}) VALUES ({marks})", row)
                    run_id = int(cur.lastrowid)
                    conn.executemany(
                        "INSERT INTO passes (run_id, idx, name, samples, pixels, ms_median, "
                        "ms_min, ms_max, repeats) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        [
                            (
                                run_id,
                                i,
                                p.name,
                                int(p.samples),
                                int(p.pixels),
                                float(p.ms_median),
                                float(p.ms_min),
                                float(p.ms_max),
                                int(p.repeats),
                            )
                            for i, p in enumerate(run.passes)
                        ],
                    )
                    conn.execute("COMMIT")
                except BaseException:
                    if conn.in_transaction:
                        conn.execute("ROLLBACK")
                    raise
                return run_id

        return self._retry(write)

    # ------------------------------------------------------------------ reads
    def is_done(self, hash_: str) -> bool:
        """Whether a run with this config hash is stored with status ``ok``."""

        def read() -> bool:
            with self._connect() as conn:
                cur = conn.execute(
                    "SELECT 1 FROM runs WHERE config_hash = ? AND status = 'ok' LIMIT 1", (hash_,)
                )
                return cur.fetchone() is not None

        return self._retry(read)

    def runs(self, *, latest: bool = False, status: str | None = None) -> list[dict[str, Any]]:
        """Stored runs as dicts (``config``, ``metrics`` and ``info`` decoded), oldest first.

        Args:
            latest: keep only the newest row per config hash (a forced re-run supersedes).
            status: keep only rows with this status (applied after ``latest``).
        """
        query = "SELECT * FROM runs"
        if latest:
            query += " WHERE id IN (SELECT MAX(id) FROM runs GROUP BY config_hash)"
        query += " ORDER BY id"

        def read() -> list[dict[str, Any]]:
            with self._connect() as conn:
                return [dict(r) for r in conn.execute(query).fetchall()]

        rows = self._retry(read)
        out = []
        for r in rows:
            if status is not None and r["status"] != status:
                continue
            r["config"] = _json.loads(r.pop("config_json"))
            r["metrics"] = _json.loads(r.pop("metrics_json"))
            r["info"] = _json.loads(r.pop("info_json"))
            out.append(r)
        return out

    def passes(self, run_ids: Sequence[int] | None = None) -> list[dict[str, Any]]:
        """Pass rows (``run_id, idx, name, samples, pixels, ms_median, ms_min, ms_max,
        repeats``), ordered by run and position."""

        def read() -> list[dict[str, Any]]:
            with self._connect() as conn:
                rows = conn.execute("SELECT * FROM passes ORDER BY run_id, idx").fetchall()
                return [dict(r) for r in rows]

        rows = self._retry(read)
        if run_ids is not None:
            keep = set(int(i) for i in run_ids)
            rows = [r for r in rows if r["run_id"] in keep]
        return rows

    def failures_since(self, since: str, sweep_dir: str | None = None) -> list[dict[str, Any]]:
        """Runs not ``ok`` that finished at or after ``since`` (ISO UTC), optionally only those
        of one sweep directory: how the app decides its exit status after a sweep."""
        query = (
            "SELECT id, status, error, run_dir FROM runs WHERE status != 'ok' AND finished_at >= ?"
        )
        args: list[Any] = [since]
        if sweep_dir is not None:
            query += " AND sweep_dir = ?"
            args.append(sweep_dir)

        def read() -> list[dict[str, Any]]:
            with self._connect() as conn:
                return [dict(r) for r in conn.execute(query, args).fetchall()]

        return self._retry(read)

    def __len__(self) -> int:
        def read() -> int:
            with self._connect() as conn:
                return int(conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0])

        return self._retry(read)

    def __repr__(self) -> str:
        return f"RunStore({str(self.path)!r})"

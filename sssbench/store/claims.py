"""Claims on the points being run, kept in the run store: one job runs a point at a time.

Two jobs of one sweep can hold the same point: the do-nothing baseline's point, for one, does
not depend on the sample count, so a sweep over sample counts lists it once per count. Under a
parallel launcher (joblib, SLURM arrays) both used to find it unstored and both ran it (issue
30: 13 of 18 baseline points ran twice in one joblib paper benchmark). The store kept one
``ok`` row either way; the second run was wasted time.

Before running a point a job now **claims** it (:meth:`PointClaims.claim`), in one
``BEGIN IMMEDIATE`` transaction of the store's database, which also reads whether the point is
already stored. The answer is one of:

- ``"mine"``: nobody else holds it: the job runs it and releases the claim when it has recorded
  the run (:meth:`PointClaims.release`, also after a failure);
- ``"done"``: an ``ok`` row of the point finished at or after ``since`` (the job's start; for a
  run that is not forced, any ``ok`` row): the job skips it;
- ``"busy"``: another live job holds it: :meth:`PointClaims.wait` polls until that job has
  released it (then ``"done"`` if it stored the point ``ok``, else the claim passes to the
  waiter, which runs the point: a failed point is tried again, as before).

A claim is **live** while its holder is: on the same host, while the holder's process exists
(``os.kill(pid, 0)``: a crashed job's claim is taken over at once); on another host (a SLURM
node writing the same store, ``store_journal=delete``), until its lease ends: the claim's time
plus ``lease_s`` (the runner gives the run's time limit plus :data:`LEASE_MARGIN_S`, or
:data:`LEASE_NO_LIMIT_S` for a run without one). A choice: a job on another host that dies
without releasing blocks its point for at most the lease; a heartbeat would shorten that, at
the cost of a thread writing the store during every timed run.

The table ``claims`` is created on first use (``CREATE TABLE IF NOT EXISTS``, once per
:class:`PointClaims`); readers of the store (``readonly=True``) never touch it. A waiting job
logs one line when it starts waiting and one every :data:`WAIT_LOG_S` seconds after, each naming
the holder, how long it has waited and, for a holder on another host, when its lease ends.
"""

from __future__ import annotations

import logging
import os
import socket
import time
import uuid
from typing import Literal

from sssbench.store.tracking import RunStore, utc_now

__all__ = [
    "PointClaims", "ClaimAnswer", "LEASE_MARGIN_S", "LEASE_NO_LIMIT_S", "POLL_S", "WAIT_LOG_S",
]  # fmt: skip

log = logging.getLogger(__name__)

ClaimAnswer = Literal["mine", "done", "busy"]

#: seconds added to a run's time limit for its claim's lease (building, scoring, recording)
LEASE_MARGIN_S = 600.0
#: a claim's lease for a run without a time limit (s)
LEASE_NO_LIMIT_S = 6 * 3600.0
#: how often a waiting job asks again (s)
POLL_S = 0.25
#: how often a waiting job says it is still waiting (s): a wait on a holder on another host
#: that died can last up to its lease, and a log that says nothing for that long looks hung
WAIT_LOG_S = 60.0

_SCHEMA = """
CREATE TABLE IF NOT EXISTS claims (
    config_hash TEXT PRIMARY KEY,
    owner       TEXT NOT NULL,
    host        TEXT NOT NULL,
    pid         INTEGER NOT NULL,
    claimed_at  TEXT NOT NULL,
    expires     REAL NOT NULL
)
"""


def _pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (one owned by another user counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _live(host: str, pid: int, expires: float, now: float) -> bool:
    """Whether a claim by (``host``, ``pid``) with lease end ``expires`` (Unix time, s) still
    holds at ``now`` (module doc)."""
    if now >= expires:
        return False
    return _pid_alive(pid) if host == socket.gethostname() else True


class PointClaims:
    """This job's claims on points of ``store`` (module doc).

    Args:
        store: the run store (opened for writing).
        lease_s: how long a claim holds for a job on another host (s, > 0).
        owner: this job's name in the table (default: host, pid and a random suffix, so two
            claimants in one process, as in the tests, differ).
    """

    def __init__(self, store: RunStore, lease_s: float, owner: str | None = None) -> None:
        if store.readonly:
            raise ValueError(f"store {store.path} is open read-only; claims need a writable store")
        if not lease_s > 0:
            raise ValueError(f"lease_s must be > 0 seconds, got {lease_s!r}")
        self.store = store
        self.lease_s = float(lease_s)
        self.host = socket.gethostname()
        self.pid = os.getpid()
        self.owner = owner or f"{self.host}:{self.pid}:{uuid.uuid4().hex[:8]}"
        self._schema_ready = False  # the table exists (created by this object)

    def _schema(self, conn) -> None:
        """Create the ``claims`` table unless this object already has."""
        if not self._schema_ready:
            conn.execute(_SCHEMA)
            self._schema_ready = True

    def claim(self, hash_: str, since: str = "") -> ClaimAnswer:
        """Claim the point ``hash_`` in one transaction: ``"done"`` if an ``ok`` row of it
        finished at or after ``since`` (an ISO time as :func:`utc_now` writes; ``""``: any),
        ``"busy"`` if another live job holds it, else ``"mine"`` (the claim is written)."""

        def write() -> ClaimAnswer:
            with self.store._connect() as conn:
                self._schema(conn)
                conn.execute("BEGIN IMMEDIATE")
                try:
                    answer = self._claim_in(conn, hash_, since)
                    conn.execute("COMMIT")
                except BaseException:
                    if conn.in_transaction:
                        conn.execute("ROLLBACK")
                    raise
                return answer

        return self.store._retry(write)

    def _claim_in(self, conn, hash_: str, since: str) -> ClaimAnswer:
        done = conn.execute(
            "SELECT 1 FROM runs WHERE config_hash = ? AND status = 'ok' AND finished_at >= ? "
            "LIMIT 1",
            (hash_, since),
        ).fetchone()
        if done is not None:
            return "done"
        row = conn.execute(
            "SELECT owner, host, pid, expires FROM claims WHERE config_hash = ?", (hash_,)
        ).fetchone()
        now = time.time()
        if row is not None and row["owner"] != self.owner:
            if _live(row["host"], int(row["pid"]), float(row["expires"]), now):
                return "busy"
            log.info("taking over %s's claim on point %s (no longer live)", row["owner"], hash_)
        conn.execute(
            "INSERT OR REPLACE INTO claims (config_hash, owner, host, pid, claimed_at, expires) "
            "VALUES (?, ?, ?, ?, ?, ?)",
            (hash_, self.owner, self.host, self.pid, utc_now(), now + self.lease_s),
        )
        return "mine"

    def holder(self, hash_: str) -> str | None:
        """The owner of the claim on ``hash_``, or ``None`` (live or not)."""
        row = self._holder_row(hash_)
        return None if row is None else row[0]

    def _holder_row(self, hash_: str) -> tuple[str, str, float] | None:
        """``(owner, host, lease end in Unix s)`` of the claim on ``hash_``, or ``None``."""

        def read() -> tuple[str, str, float] | None:
            with self.store._connect() as conn:
                self._schema(conn)
                row = conn.execute(
                    "SELECT owner, host, expires FROM claims WHERE config_hash = ?", (hash_,)
                ).fetchone()
                return None if row is None else (str(row[0]), str(row[1]), float(row[2]))

        return self.store._retry(read)

    def _log_wait(self, what: str, hash_: str, waited_s: float | None) -> None:
        """One line about a wait on ``hash_`` (``what`` names the point): its holder, for one
        on another host when its lease ends, and ``waited_s`` so far (``None``: starting)."""
        row = self._holder_row(hash_)
        holder = "another job" if row is None else row[0]
        lease = ""
        if row is not None and row[1] != self.host:
            end = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(row[2]))
            lease = f" (on host {row[1]}: if that job died, its claim lapses at {end})"
        if waited_s is None:
            log.info("waiting for %s: the same point is being run by %s%s", what, holder, lease)
        else:
            log.info(
                "still waiting for %s after %.0f s: held by %s%s", what, waited_s, holder, lease
            )

    def wait(self, hash_: str, since: str = "", label: str = "") -> ClaimAnswer:
        """:meth:`claim` until the answer is ``"mine"`` or ``"done"`` (every :data:`POLL_S`
        seconds while ``"busy"``), logging one line when the wait starts and one every
        :data:`WAIT_LOG_S` seconds after (each names the holder; module doc); ``label`` names
        the point in them."""
        answer = self.claim(hash_, since)
        if answer != "busy":
            return answer
        what = label or hash_
        self._log_wait(what, hash_, None)
        start = last = time.monotonic()
        while answer == "busy":
            time.sleep(POLL_S)
            answer = self.claim(hash_, since)
            now = time.monotonic()
            if answer == "busy" and now - last >= WAIT_LOG_S:
                self._log_wait(what, hash_, now - start)
                last = now
        return answer

    def release(self, hash_: str) -> None:
        """Drop this job's claim on ``hash_`` (nothing if another job holds it)."""

        def write() -> None:
            with self.store._connect() as conn:
                self._schema(conn)
                conn.execute(
                    "DELETE FROM claims WHERE config_hash = ? AND owner = ?", (hash_, self.owner)
                )

        self.store._retry(write)

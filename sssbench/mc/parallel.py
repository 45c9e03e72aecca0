"""Independent Monte Carlo walks in worker processes (one torch thread each).

A walk runs on one core (:mod:`sssbench.mc.fused`: its step is a single loop over the
photons); a second core is used by a second walk of independent photons, whose float64
tallies are summed afterwards.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
from collections.abc import Callable
from typing import TypeVar

__all__ = ["run_jobs", "cpu_seconds"]

T = TypeVar("T")


def run_jobs(fn: Callable[[tuple], T], jobs: list[tuple], workers: int) -> list[T]:
    """``[fn(job) for job in jobs]``, in ``workers`` processes when > 1: forked where the
    platform can (no re-import of the caller's script; ``fn`` should run torch on one thread,
    so that the parent's thread pool is never used after the fork), else spawned (``fn`` and
    the jobs must then be picklable)."""
    if workers <= 1 or len(jobs) <= 1:
        return [fn(j) for j in jobs]
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    with concurrent.futures.ProcessPoolExecutor(min(workers, len(jobs)), mp_context=ctx) as ex:
        return list(ex.map(fn, jobs))


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its waited-for children (the
    workers of :func:`run_jobs` once it has returned; this process's only where the platform
    has no ``resource`` module)."""
    import time

    try:
        import resource
    except ImportError:  # pragma: no cover - not Unix
        return time.process_time()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime

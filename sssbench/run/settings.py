"""A run's process settings and timing: torch threads and the gather backend for the run
(restored after it), the wall-time limit, the versions recorded, the per-pass statistics
over timed repeats (median / min / max, the cyclic garbage collector paused while they run:
:func:`collector_paused`), and the lock that lets a sweep's processes run side by
side while each run's timed section runs alone (:func:`timing_slot`)."""

from __future__ import annotations

import contextlib
import gc
import os
import platform
import signal
import statistics
import threading
import time
from collections.abc import Callable, Iterator
from importlib import metadata
from typing import Any

import torch

from sssbench.store.tracking import PassStats

__all__ = [
    "RunTimeout",
    "backend_used",
    "checkpoint",
    "collector_paused",
    "exclusive_timing",
    "timing_slot",
    "pass_stats",
    "time_limit",
    "time_runs",
    "warm_runs",
    "gl_times",
    "times_on_device",
    "torch_settings",
    "versions",
]


def pass_stats(runs: list[list[Any]]) -> list[PassStats]:
    """Per-pass median / min / max over repeats (passes matched by position and name)."""
    if not runs:
        return []
    n = len(runs[0])
    for r in runs[1:]:
        if [p.name for p in r] != [p.name for p in runs[0]]:
            raise RuntimeError(
                "the pipeline ran different passes in different repeats: "
                f"{[p.name for p in runs[0]]} vs {[p.name for p in r]}"
            )
    out = []
    for i in range(n):
        ms = [r[i].ms for r in runs]
        first = runs[0][i]
        out.append(
            PassStats(
                first.name,
                first.samples,
                first.pixels,
                statistics.median(ms),
                min(ms),
                max(ms),
                len(ms),
            )
        )
    return out


def warm_runs(pipeline: Any, gbuffer: Any, warmup: int) -> None:
    """Run ``pipeline`` on ``gbuffer`` ``warmup`` times untimed (inference mode): the calls
    :func:`time_runs` makes before its timed ones, for a caller that makes them elsewhere
    (the runner: while the sweep's other processes finish their step, see
    :func:`exclusive_timing`)."""
    with torch.inference_mode():
        for _ in range(warmup):
            pipeline.run(gbuffer)


def time_runs(
    pipeline: Any, gbuffer: Any, warmup: int, repeats: int
) -> tuple[Any, list[PassStats]]:
    """Run ``pipeline`` on ``gbuffer`` ``warmup`` times untimed (:func:`warm_runs`), then
    ``repeats`` (>= 1) times timed (inference mode, the cyclic garbage collector paused:
    :func:`collector_paused`); return the last run's output and the per-pass statistics."""
    warm_runs(pipeline, gbuffer, warmup)
    with torch.inference_mode(), collector_paused():
        records = []
        for _ in range(repeats):
            out = pipeline.run(gbuffer)
            records.append(out.records)
    return out, pass_stats(records)


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """The block runs with Python's cyclic garbage collector off, as :mod:`timeit` times;
    its state before is restored after. The collector starts a collection when allocations
    reach a threshold, wherever that happens: inside a timed call, its time is counted as the
    call's. A full collection scans every tracked object (0.07–0.14 s in the app's main
    process, measured on the README's main job: against a 2 ms pass), and the main job ran 9
    of them in 24 runs. Paused, the collection comes after the timed calls instead. Memory
    freed by reference counting (tensors, nearly everything) is freed as before."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


#: the open lock files of :func:`timing_slot` in this process (``None``: not in a slot): the
#: slot itself and its gate (``<slot>.gate``)
_SLOT: dict[str, int | None] = {"fd": None, "gate": None}


@contextlib.contextmanager
def timing_slot(path: str | os.PathLike[str]) -> Iterator[None]:
    """Work beside other processes of a sweep, each run's timing alone.

    While the block runs this process holds a *shared* lock (``flock``) on the file ``path``
    (created if missing); :func:`exclusive_timing` — the runner's timed section — turns it into
    an *exclusive* one and back. So any number of processes may build scenes and score at once,
    but a timed section starts only when every other process of the slot has stopped its work
    (each is blocked in its own lock call, sleeping) and none resumes before it ends: the passes
    are timed as if they ran alone.

    A process that wants to time first closes a second lock file, the *gate* (``<path>.gate``,
    held exclusive while it waits for the slot), so no other process starts new shared work;
    the others stop at their next :func:`checkpoint` (the runner calls one between the steps
    of its scoring: reference, FLIP, metrics, budget, …) or at the end of their run, not at the
    end of their whole scoring. So the scoring of one run overlaps the scoring of the other
    processes' runs, and a timed section waits for at most one scoring step of each other
    process. No process ever waits for the gate while it holds the slot, so the locks cannot
    deadlock. POSIX only (``fcntl``); nested slots are an error.
    """
    import fcntl

    if _SLOT["fd"] is not None:
        raise RuntimeError("timing_slot is already held by this process (nested slots)")
    fd = os.open(os.fspath(path), os.O_RDWR | os.O_CREAT, 0o600)
    gate = os.open(os.fspath(path) + ".gate", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        _pass_gate(gate)
        fcntl.flock(fd, fcntl.LOCK_SH)
        _SLOT["fd"], _SLOT["gate"] = fd, gate
        yield
    finally:
        _SLOT["fd"] = _SLOT["gate"] = None
        os.close(fd)  # releases the lock
        os.close(gate)


def _pass_gate(gate: int) -> None:
    """Wait until no process of the slot is waiting to time (the gate is free), then go on."""
    import fcntl

    fcntl.flock(gate, fcntl.LOCK_SH)
    fcntl.flock(gate, fcntl.LOCK_UN)


@contextlib.contextmanager
def exclusive_timing(while_waiting: Callable[[], object] | None = None) -> Iterator[None]:
    """The block runs with no other process of this process's :func:`timing_slot` at work
    (the exclusive lock; back to shared after it); a no-op outside a slot.

    ``while_waiting``: untimed work of this process that may run beside the others' (the
    run's warm-up calls), called once the gate is closed and before the exclusive lock is
    taken: while it runs, the other processes finish the step of work they are in (and
    stop at their next checkpoint) instead of this process waiting for them idle. It runs
    under the shared lock, so never beside another process's timed section. Measured on a
    warm 512² paper benchmark (2 processes): the timed sections had waited 32 s in all for
    the others' current step, against 21 s of timing (issue 30)."""
    fd, gate = _SLOT["fd"], _SLOT["gate"]
    if fd is None or gate is None:
        if while_waiting is not None:
            while_waiting()
        yield
        return
    import fcntl

    fcntl.flock(fd, fcntl.LOCK_UN)  # never wait for the gate while holding the slot
    try:
        fcntl.flock(gate, fcntl.LOCK_EX)  # no process of the slot starts new shared work
        try:
            if while_waiting is not None:
                # shared again: waits for a timed section of another process to end (it
                # holds the exclusive lock), then works beside the others' current step
                fcntl.flock(fd, fcntl.LOCK_SH)
                while_waiting()
            # (from shared: not atomic, but no process can time meanwhile: the gate is ours)
            fcntl.flock(fd, fcntl.LOCK_EX)  # the others stop at their next checkpoint
        finally:
            fcntl.flock(gate, fcntl.LOCK_UN)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_SH)


def checkpoint() -> None:
    """A point between two steps of untimed work where a process of this process's
    :func:`timing_slot` that waits to time may go first: returns at once when none waits,
    after that process's timed section otherwise; a no-op outside a slot."""
    fd, gate = _SLOT["fd"], _SLOT["gate"]
    if fd is None or gate is None:
        return
    import fcntl

    fcntl.flock(fd, fcntl.LOCK_UN)
    try:
        _pass_gate(gate)
    finally:
        fcntl.flock(fd, fcntl.LOCK_SH)


class RunTimeout(Exception):
    """The run exceeded ``timeout_s``."""


@contextlib.contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Raise :class:`RunTimeout` after ``seconds`` of wall time (SIGALRM in the main thread;
    elsewhere the limit is checked when the block ends)."""
    if not seconds or seconds <= 0:
        yield
        return
    start = time.monotonic()
    use_signal = (
        hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
    )
    if use_signal:

        def handler(signum: int, frame: Any) -> None:
            raise RunTimeout(f"run exceeded timeout_s={seconds:g} s")

        previous = signal.signal(signal.SIGALRM, handler)
        signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        if use_signal:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
    if time.monotonic() - start > seconds:
        raise RunTimeout(f"run exceeded timeout_s={seconds:g} s")


@contextlib.contextmanager
def torch_settings(threads: int | None, backend: str) -> Iterator[None]:
    """Set torch's intra-op threads and the gather backend for a block; restore both."""
    from sssbench.ops import backend as use_backend

    before_threads = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(int(threads))
    try:
        with use_backend(backend):
            yield
    finally:
        torch.set_num_threads(before_threads)


def backend_used(backend: str, dtype: str = "float32") -> str:
    """The tap-loop backend a run in ``dtype`` (``"float32"``, ``"float64"``) really used:
    ``native`` falls back to ``torch`` without a C compiler, or without the library of the
    dtype's loops (see :func:`sssbench.ops.native.library_for`)."""
    from sssbench.ops import native

    if backend != "native":
        return backend
    return "torch" if native.library_for(getattr(torch, dtype, None)) is None else backend


def versions() -> dict[str, str]:
    """Python and package versions of the run."""
    out = {"python": platform.python_version()}
    for pkg in (
        "sssbench",
        "torch",
        "kornia",
        "numpy",
        "scikit-image",
        "hydra-core",
        "flip-evaluator",
        "pandas",
        "openexr",
        "mlflow",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


#: the methods with no pass on any device (nothing to time on GL)
_NO_PASSES = ("identity", "reference")


def times_on_device(backend: str, method_name: str) -> bool:
    """Whether the run's passes are timed on the GL device (``backend=gl``, a method with
    passes): its CPU-side pipeline then runs once, for the image, not ``warmup + repeats``
    times."""
    return backend == "gl" and method_name not in _NO_PASSES


def gl_times(
    method_name: str, pipeline: Any, gbuffer: Any, warmup: int, repeats: int
) -> tuple[list[PassStats], dict[str, Any]] | None:
    """With ``backend=gl``: the method's passes timed on the GL device (``GL_TIME_ELAPSED``
    queries, ``warmup`` untimed runs, median / min / max over ``repeats``;
    :func:`sssbench.gl.run_method`) and the renderer (``GL_RENDERER``, ``GL_VERSION`` and,
    on llvmpipe, the note that these are a software rasteriser's times; for the disk,
    ``gl_disk_geometry``: ``float64`` or ``float32``). ``None`` for the
    baseline and the reference, which run no pass. A method without a GL schedule (halo
    reduction; a disk option without a shader, e.g. ``adaptive``) raises
    :class:`sssbench.gl.GLMethodError` naming it: the run fails, it is never timed on the CPU
    instead. The run's passes and ``time_ms`` are then the method's
    passes on the device (its blend passes included); the pipeline's other stages (specular,
    translucency, ...) compute on the CPU and are not in the time."""
    if method_name in _NO_PASSES:
        return None
    from sssbench import gl

    run = gl.run_method(pipeline.method, gbuffer, repeats=max(repeats, 1), warmup=warmup)
    info = run.renderer
    record = {
        "renderer": str(info.get("renderer", "")),
        "gl_version": str(info.get("version", "")),
        "timing_note": str(info.get("note", "") or ""),
        "time_source": "GL_TIME_ELAPSED",
    }
    if "disk_geometry" in info:  # the precision of the disk shader's sample geometry
        record["gl_disk_geometry"] = str(info["disk_geometry"])
    return pass_stats(run.repeats), record

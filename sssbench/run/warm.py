"""Warm a sweep's caches in parallel, so its runs can be timed one at a time.

A cold sweep spends most of its time on what the runs read from the reference cache (the
exact references and the error budget's converged limits), not on the timed passes. Those
entries are pure functions of the scene, the profile and the method, so they can be computed
by several processes at once; the passes must be timed alone (two timed runs side by side
share the memory bandwidth and the caches). :func:`warm` computes every entry a list of runs
will read with :func:`sssbench.run.runner.prepare` in ``workers`` processes of one thread
each; the runs then find them cached. Each scene (and scale) is two tasks: its bilinear
reference (the error budget's ``err_recon``, the larger half: about 1.7× the box reference's
time on the 256² face portrait, measured) and its box reference with the budget's converged
limits (scaled by the reference). All the bilinear tasks are queued first (the larger jobs
first), so both processes stay busy until the end and the last task is a small one. The
native tap loop the limits run on is built once, under a lock: the parent starts the build
while the workers compute the first references (which do not need it), and a worker that
needs the library before it is ready waits for it instead of compiling the same source too.

A task that fails is reported and skipped: the run itself computes what is missing and
records its own failure, so warming never changes what is stored.
"""

from __future__ import annotations

import multiprocessing
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

from sssbench._checks import check_int
from sssbench.run.spec import RunSpec

__all__ = ["warm", "group_by_scene", "scene_group", "tasks"]


def scene_group(spec: RunSpec) -> str:
    """What the runs of one task share: the scene (and its parameters), the profile and the
    reference's options (runs of one group read the same reference)."""
    import json

    return json.dumps(
        [
            spec.scene,
            spec.scene_params,
            list(spec.resolution),
            spec.seed,
            spec.dtype,
            spec.profile,
            spec.profile_kind,
            spec.profile_params,
            spec.reference_params,
            sorted((k, v) for k, v in spec.stages.items() if v is not None),
        ],
        sort_keys=True,
        default=repr,
    )


def group_by_scene(specs: Sequence[RunSpec]) -> list[list[RunSpec]]:
    """``specs`` split into groups of runs on the same scene, profile and reference, in the
    order their first run appears."""
    groups: dict[str, list[RunSpec]] = {}
    for spec in specs:
        groups.setdefault(scene_group(spec), []).append(spec)
    return list(groups.values())


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)


def _prepare_group(specs: list[RunSpec], part: str = "all") -> list[str]:
    """Prepare every run of one group (``part`` of :func:`sssbench.run.runner.prepare`; the
    bilinear reference is one per group: its first run with a budget); the errors, one line
    each."""
    from sssbench.run import runner
    from sssbench.run.budget_step import has_budget

    if part == "bilinear":
        specs = [s for s in specs if s.budget and has_budget(s)][:1]
    elif any(s.budget and has_budget(s) for s in specs):
        _native_library(True)  # the converged limits run the tap loop: one compile for all
    errors = []
    for spec in specs:
        try:
            runner.prepare(spec, part)
        except Exception as exc:  # the run records its own failure
            errors.append(f"{runner.run_label(spec)}: {type(exc).__name__}: {exc}")
    return errors


def tasks(specs: Sequence[RunSpec]) -> list[tuple[str, list[RunSpec]]]:
    """The warm-up's tasks, in the order they are queued: ``("bilinear", group)`` for every
    scene group with a budgeted run, then ``("reference", group)`` for every group (the box
    reference and the converged limits)."""
    from sssbench.run.budget_step import has_budget

    groups = group_by_scene(specs)
    bilinear = [("bilinear", g) for g in groups if any(s.budget and has_budget(s) for s in g)]
    return bilinear + [("reference", g) for g in groups]


def _native_library(float64: bool) -> None:
    """Build (or load) the native tap loop under a lock file beside it, shared by the warm-up's
    processes: the first one compiles, the others wait (blocked, not compiling the same source
    again) and load its library. ``float64``: the runs will run float64 passes
    (:func:`sssbench.run.budget_step.runs_float64`), so the float64 loops are built too, side
    by side with the others (:func:`sssbench.ops.native.want_float64`). A failure is the runs'
    to report (they fall back to the torch loop and warn themselves)."""
    try:
        import fcntl

        from sssbench.ops import native

        if float64:
            native.want_float64()

        folder = native.cache_dir()
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        with open(folder / "build.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            native.library()
            if float64:  # built with it from cold; alone if the gather library was cached
                native.library64()
    except Exception:  # the runs report it
        pass


def warm(specs: Sequence[RunSpec], workers: int = 2, *, progress: bool = True) -> float:
    """Compute the cached entries ``specs`` will read, ``workers`` processes at a time.

    Args:
        specs: the runs of a sweep (runs already stored ok are left out by the caller).
        workers: processes (one torch thread each); 1 prepares in this process.
        progress: print one line per finished scene group.

    Returns:
        the wall time of warming (s).
    """
    check_int("workers", workers, 1)
    if workers == 1 or len(group_by_scene(specs)) <= 1:
        queue = [("all", g) for g in group_by_scene(specs)]
    else:
        queue = tasks(specs)
    t0 = time.perf_counter()

    def report(k: int, task: tuple[str, list[RunSpec]], errors: list[str], took: float) -> None:
        part, group = task
        if progress:
            s = group[0]
            what = {"all": "runs prepared", "reference": "runs: reference and limits"}.get(
                part, "runs: bilinear reference"
            )
            print(
                f"  [warm {k}/{len(queue)}] {s.scene} {s.scene_params}: {len(group)} {what} "
                f"in {took:.0f} s ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        for line in errors:
            print(f"    warm failed (the run will retry): {line}", flush=True)

    if workers == 1 or len(queue) <= 1:
        for k, task in enumerate(queue, 1):
            start = time.perf_counter()
            errors = _prepare_group(task[1], task[0])
            report(k, task, errors, time.perf_counter() - start)
        return time.perf_counter() - t0
    from sssbench.run.budget_step import runs_float64

    float64 = any(runs_float64(s) for s in specs)
    builder = threading.Thread(target=_native_library, args=(float64,), daemon=True)
    builder.start()  # a compiler process: it does not hold this process's GIL
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker) as pool:
        futures = {pool.submit(_timed_prepare, group, part): (part, group) for part, group in queue}
        for k, future in enumerate(as_completed(futures), 1):
            took = float("nan")
            try:
                errors, took = future.result()
            except Exception as exc:  # a worker died: its runs compute their own entries
                errors = [f"worker: {type(exc).__name__}: {exc}"]
            report(k, futures[future], errors, took)
    builder.join()
    return time.perf_counter() - t0


def _timed_prepare(specs: list[RunSpec], part: str) -> tuple[list[str], float]:
    """:func:`_prepare_group` and its wall time (s), in a worker."""
    start = time.perf_counter()
    errors = _prepare_group(specs, part)
    return errors, time.perf_counter() - start

"""A sweep's runs in several processes, each run's timed section alone.

A cold sweep's runs spend most of their time outside the timed passes: building the scene,
scoring (FLIP, SSIM, ΔE), the error budget, a stochastic method's further seeds. Those parts
can run on every core; the passes cannot (two timed runs side by side share the memory
bandwidth and the caches). :func:`run_parallel` runs the jobs of a sweep in ``workers``
processes (with the caller's torch threads: the benchmark's one), every run inside a
:func:`sssbench.run.settings.timing_slot` on one lock file: while a run is timed, every
other worker is blocked in its lock call (not computing), so the times are those of a run
alone; the rest overlaps.

One task per scene group (:func:`sssbench.run.warm.scene_group`), so a worker builds a
scene and scores its baseline once for all the runs on it (:mod:`sssbench.run.runmemo`).
What is stored is what :func:`sssbench.run.runner.execute` stores for each run alone.
"""

from __future__ import annotations

import multiprocessing
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from sssbench._checks import check_int
from sssbench.run.spec import RunSpec
from sssbench.store.tracking import config_hash

__all__ = ["run_parallel"]


def _init_worker(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def _run_group(
    items: list[tuple[int, RunSpec]], run_root: str, lock: str
) -> list[tuple[int, str, str]]:
    """Execute the runs ``items`` (index, spec) in this worker, each in the timing slot;
    ``(index, config hash, status)`` per run."""
    from sssbench.run import runner
    from sssbench.run.settings import timing_slot

    out = []
    for k, spec in items:
        with timing_slot(lock):
            outcome = runner.execute(spec, Path(run_root) / f"{k}", sweep_dir=run_root)
        out.append((k, outcome.config_hash, outcome.status))
    return out


def run_parallel(
    specs: Sequence[RunSpec],
    run_root: str | Path,
    workers: int = 2,
    *,
    progress: bool = True,
) -> list[tuple[str, str]]:
    """Execute every run of ``specs`` (run directories ``run_root/<index>``), ``workers``
    processes at a time, each run's timing alone (see the module docstring); 1 runs them in
    this process, in order.

    Returns:
        ``(config hash, status)`` per spec, in the order of ``specs`` (status ``"lost"`` for
        the runs of a task whose worker process died: nothing of them is stored).
    """
    from sssbench.run import runner
    from sssbench.run.warm import scene_group

    check_int("workers", workers, 1)
    run_root = Path(run_root)
    t0 = time.perf_counter()
    results: dict[int, tuple[str, str]] = {}
    if workers == 1:
        for k, spec in enumerate(specs):
            outcome = runner.execute(spec, run_root / f"{k}", sweep_dir=run_root)
            results[k] = (outcome.config_hash, outcome.status)
        return [results[k] for k in range(len(specs))]
    groups: dict[str, list[tuple[int, RunSpec]]] = {}
    for k, spec in enumerate(specs):
        groups.setdefault(scene_group(spec), []).append((k, spec))
    tasks = list(groups.values())
    import torch

    context = multiprocessing.get_context("spawn")
    # the workers run with this process's torch threads: a run without its own ``threads``
    # is timed (and recorded) as it would be here
    init = (_init_worker, (torch.get_num_threads(),))
    with (
        tempfile.TemporaryDirectory(prefix="sssbench-timing-") as tmp,
        ProcessPoolExecutor(
            workers, mp_context=context, initializer=init[0], initargs=init[1]
        ) as pool,
    ):
        lock = str(Path(tmp) / "timing.lock")
        futures = {pool.submit(_run_group, items, str(run_root), lock): items for items in tasks}
        done = 0
        for future in as_completed(futures):
            try:
                finished = future.result()
            except Exception as exc:  # a worker died: its group's runs are not stored
                print(f"  runs lost with their worker: {type(exc).__name__}: {exc}", flush=True)
                finished = [(k, config_hash(s.point()), "lost") for k, s in futures[future]]
            for k, h, status in finished:
                results[k] = (h, status)
            done += len(futures[future])
            if progress:
                s = futures[future][0][1]
                per = (time.perf_counter() - t0) / done
                print(
                    f"  [{done}/{len(specs)}] {s.scene} {s.scene_params}: "
                    f"{', '.join(sorted({results[k][1] for k, _ in futures[future]}))} "
                    f"(ETA {per * (len(specs) - done):.0f} s)",
                    flush=True,
                )
    return [results[k] for k in range(len(specs))]

"""Warm a sweep's caches in parallel, so its runs can be timed one at a time.

A cold sweep spends most of its time on what the runs read from the reference cache (the
exact references and the error budget's converged limits), not on the timed passes. Those
entries are pure functions of the scene, the profile and the method, so they can be computed
by several processes at once; the passes must be timed alone (two timed runs side by side
share the memory bandwidth and the caches). :func:`warm` computes every entry a list of runs
will read with :func:`sssbench.run.runner.prepare`, one scene (and scale) per task, in
``workers`` processes of one thread each; the runs then find them cached.

A task that fails is reported and skipped: the run itself computes what is missing and
records its own failure, so warming never changes what is stored.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

from sssbench._checks import check_int
from sssbench.run.spec import RunSpec

__all__ = ["warm", "group_by_scene"]


def _scene_group(spec: RunSpec) -> str:
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
        groups.setdefault(_scene_group(spec), []).append(spec)
    return list(groups.values())


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)


def _prepare_group(specs: list[RunSpec]) -> list[str]:
    """Prepare every run of one group; the errors, one line each."""
    from sssbench.run import runner

    errors = []
    for spec in specs:
        try:
            runner.prepare(spec)
        except Exception as exc:  # the run records its own failure
            errors.append(f"{runner.run_label(spec)}: {type(exc).__name__}: {exc}")
    return errors


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
    groups = group_by_scene(specs)
    t0 = time.perf_counter()

    def report(k: int, group: list[RunSpec], errors: list[str]) -> None:
        if progress:
            s = group[0]
            print(
                f"  [warm {k}/{len(groups)}] {s.scene} {s.scene_params}: {len(group)} runs "
                f"prepared ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        for line in errors:
            print(f"    warm failed (the run will retry): {line}", flush=True)

    if workers == 1 or len(groups) <= 1:
        for k, group in enumerate(groups, 1):
            report(k, group, _prepare_group(group))
        return time.perf_counter() - t0
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker) as pool:
        futures = {pool.submit(_prepare_group, group): group for group in groups}
        for k, future in enumerate(as_completed(futures), 1):
            try:
                errors = future.result()
            except Exception as exc:  # a worker died: its runs compute their own entries
                errors = [f"worker: {type(exc).__name__}: {exc}"]
            report(k, futures[future], errors)
    return time.perf_counter() - t0

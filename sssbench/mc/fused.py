"""One Monte Carlo step function, fused by ``torch.compile`` where it can be, eager otherwise.

A photon step is ~30 elementwise torch operations over the batch; eagerly, each is a pass
over memory with its own call overhead (measured: ~30 ns per photon and step eagerly,
~6 ns compiled, one core). :class:`Fused` hands the same Python function to
``torch.compile`` (inductor: one generated C++ loop for all of them, compiled with the
system's C++ compiler) on first use and falls back to calling it eagerly — same function,
same random numbers, results equal up to float rounding — when

* compilation is disabled (environment ``SSSBENCH_MC_COMPILE=0``),
* the batch is small (fewer than :data:`MIN_COMPILED` photons: the draining tail, where the
  step costs little, and sizes 0/1, which dynamic shapes specialise and would recompile),
* or compiling or running the compiled function raises (no compiler, unsupported platform):
  a warning is issued once and the function stays eager from then on.

The function is compiled with dynamic shapes (one compilation for every batch size) while
torch runs on ONE intra-op thread: the generated loop bakes in the thread count it was
compiled with, and the walks run one per process (:mod:`sssbench.mc.scene`). The compiled
code lives in this process (and in processes forked from it after the first call) and in
inductor's on-disk cache, which makes the next process's compilation a cache load.

Reproducibility: for a fixed seed a run is reproducible on the same path (compiled, or
eager); the two paths may differ in float32 rounding (fused multiply-adds), hence in rare
branch decisions, which changes individual photons but not the estimates' distribution.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import torch

__all__ = ["Fused", "MIN_COMPILED", "compile_enabled", "torch_threads"]

#: batches smaller than this run eagerly (module doc)
MIN_COMPILED = 64


def compile_enabled() -> bool:
    """False when the environment sets ``SSSBENCH_MC_COMPILE=0`` (or ``false``/``no``/``off``)."""
    return os.environ.get("SSSBENCH_MC_COMPILE", "1").strip().lower() not in {
        "0",
        "false",
        "no",
        "off",
    }


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` torch intra-op threads, restoring the caller's count
    after (None: leave it as is)."""
    if threads is None:
        yield
        return
    saved = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(saved)


class Fused:
    """``fn(*tensors, *constants)`` compiled on first use, eager as the fallback (module doc).

    The first argument must be a tensor whose last dimension is the batch size. ``fn`` may
    write its results into its arguments only after it has read them all (compiled code
    fails at compilation, before it runs: the call is then simply repeated eagerly).
    """

    def __init__(self, fn: Callable) -> None:
        self.fn = fn
        self._compiled: Callable | None = None
        self.failed: str | None = None  # the error that disabled compilation, if any

    @property
    def active(self) -> bool:
        """Whether large batches run compiled (enabled and not failed)."""
        return self.failed is None and compile_enabled()

    def __call__(self, *args: object) -> object:
        if not self.active or args[0].shape[-1] < MIN_COMPILED:  # type: ignore[union-attr]
            return self.fn(*args)
        if torch.get_num_threads() != 1:
            raise RuntimeError("Fused step functions run with torch.set_num_threads(1)")
        try:
            if self._compiled is None:
                # one compile worker: no process pool for a single small kernel (and none
                # left behind when the caller forks walk processes)
                self._compiled = torch.compile(
                    self.fn, dynamic=True, options={"compile_threads": 1}
                )
            return self._compiled(*args)
        except Exception as err:  # noqa: BLE001 - any compiler failure: fall back, say so
            self.failed = f"{type(err).__name__}: {err}"
            warnings.warn(
                f"torch.compile of {self.fn.__name__} failed ({self.failed[:200]}); the Monte "
                "Carlo walk continues eagerly (slower, same estimates)",
                RuntimeWarning,
                stacklevel=2,
            )
            return self.fn(*args)

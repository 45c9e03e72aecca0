"""Per-pass records (DESIGN §3 ``PassRecord``): every pass that runs leaves one.

Passes record themselves: :func:`sssbench.ops.separable_pass` and the other primitive
operators call :func:`timed_pass`, which appends a :class:`PassRecord` to the innermost active
:func:`record_passes` context (a context variable, so threads stay separate). A context sees
every pass run inside its block: when a nested context closes (e.g. the one
:meth:`sssbench.ops.Pipeline.run` keeps for its result), its records are appended to the
enclosing one too — a caller timing a pipeline with ``record_passes`` gets its passes, not an
empty list read as 0 ms. Outside such a context recording costs one ``perf_counter`` call.
"""

from __future__ import annotations

import contextlib
import contextvars
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass

__all__ = ["PassRecord", "record_passes", "timed_pass", "add_record"]


@dataclass(frozen=True)
class PassRecord:
    """One executed pass.

    Attributes:
        name: pass name, e.g. ``"preintegrated.x"``.
        samples: taps gathered per pixel.
        pixels: pixels the pass computed (after stencil).
        ms: wall time in milliseconds.
    """

    name: str
    samples: int
    pixels: int
    ms: float

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


_ACTIVE: contextvars.ContextVar[list[PassRecord] | None] = contextvars.ContextVar(
    "sssbench_pass_records", default=None
)


@contextlib.contextmanager
def record_passes() -> Iterator[list[PassRecord]]:
    """Collect the :class:`PassRecord` of every pass run inside the ``with`` block, nested
    contexts' passes included (they are handed to the enclosing context when they close)."""
    records: list[PassRecord] = []
    outer = _ACTIVE.get()
    token = _ACTIVE.set(records)
    try:
        yield records
    finally:
        _ACTIVE.reset(token)
        if outer is not None:
            outer.extend(records)


def add_record(record: PassRecord) -> None:
    """Append ``record`` to the active collection, if any."""
    records = _ACTIVE.get()
    if records is not None:
        records.append(record)


@contextlib.contextmanager
def timed_pass(name: str, samples: int, pixels: int) -> Iterator[None]:
    """Time the ``with`` block and record it as one pass."""
    start = time.perf_counter()
    try:
        yield
    finally:
        add_record(PassRecord(name, int(samples), int(pixels), (time.perf_counter() - start) * 1e3))

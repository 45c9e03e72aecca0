"""What every run of a sweep on the same scene recomputes, kept for the next run in-process.

A sweep runs many methods on one scene (the paper benchmark: 14 runs per scene and scale).
Each run used to rebuild the scene's G-buffer (about 1 s for the 512² ``face``) and to score
the do-nothing baseline against the reference (two FLIP evaluations, about 0.6 s each at 512²),
although neither depends on the method (nor does the error budget's flat-plane truth, an
FFT convolution of the scene). This module keeps them, in memory, for the runs that
follow in the same process (a joblib or SLURM worker keeps its own).

It cannot go stale or be corrupted by a run:

- the key is everything the value is computed from (the runner passes the scene's name,
  parameters, resolution, seed, fields and dtype; the baseline adds the reference's cache key,
  which holds the code digest of the reference, the profile's digest and the stages);
- a value is handed out as a deep copy of its tensors, so a run that writes into its G-buffer
  or its images (in place, under ``inference_mode``, through NumPy) never reaches the kept
  one; the copy of a 512² G-buffer takes a few milliseconds; copies are made outside
  inference mode, so they are normal tensors whichever mode the caller is in;
- user files (``scene=file``) are never kept: the file may change between runs.

Bounded: the :data:`MAX_ENTRIES` most recently used values are kept.
"""

from __future__ import annotations

import copy
import json
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

__all__ = ["MAX_ENTRIES", "clear", "memo_key", "remembered"]

#: values kept at most: a scene's G-buffer, its baseline and its budget truth (the true
#: kernel on the flat plane, :func:`sssbench.run.budget_step.budget_truth`) for the current
#: sweep group and the one before (a 1080p float64 G-buffer is ~0.25 GB, a 1080p image
#: 50 MB: the memo stays under ~1 GB)
MAX_ENTRIES = 6

T = TypeVar("T")

_VALUES: OrderedDict[str, Any] = OrderedDict()
_LOCK = threading.Lock()


def memo_key(kind: str, key: Mapping[str, Any]) -> str:
    """A canonical string of ``key`` (sorted JSON) under the namespace ``kind``."""
    return kind + ":" + json.dumps(dict(key), sort_keys=True, default=repr)


def remembered(kind: str, key: Mapping[str, Any], compute: Callable[[], T]) -> T:
    """``compute()``, or a deep copy of the value it returned for the same ``(kind, key)``.

    Args:
        kind: namespace of the value (e.g. ``"scene"``, ``"baseline"``).
        key: everything the value depends on (JSON-serialisable; other objects are keyed by
            their ``repr``, so pass digests rather than objects whose ``repr`` is not their
            content).
        compute: builds the value when it is not kept.

    Returns:
        a value the caller owns (tensors are copies of the kept ones).
    """
    k = memo_key(kind, key)
    with _LOCK:
        if k in _VALUES:
            _VALUES.move_to_end(k)
            return _copy(_VALUES[k])
    value = compute()
    with _LOCK:
        _VALUES[k] = _copy(value)
        while len(_VALUES) > MAX_ENTRIES:
            _VALUES.popitem(last=False)
    return value


def _copy(value: T) -> T:
    """A deep copy made outside inference mode: normal tensors, whatever mode the caller is
    in (a tensor made under ``torch.inference_mode()`` can be written to only there, and a
    value kept here serves callers in either mode)."""
    import torch

    with torch.inference_mode(False):
        return copy.deepcopy(value)


def clear() -> None:
    """Forget every kept value."""
    with _LOCK:
        _VALUES.clear()

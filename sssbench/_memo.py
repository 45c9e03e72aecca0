"""Memoisation of values a renderer computes once per G-buffer (stencils, level-of-detail
masks, validated fields), keyed on the identity and version of the tensors they come from.

Lives below the G-buffer (which memoises its field checks) and the operators (stencils).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TypeVar

import torch

__all__ = ["memoised", "memo_scope"]

#: memo of :func:`memoised`: key -> (the key tensors themselves, value)
_MEMO: OrderedDict[tuple, tuple[tuple, object]] = OrderedDict()
_MEMO_SIZE = 64

T = TypeVar("T")


def _tensor_key(t: torch.Tensor | None) -> tuple:
    if t is None:
        return (None,)
    # the memo keeps t alive, so no other tensor object can get its id while cached; the data
    # pointer catches a storage swapped in under it, the version an in-place write
    return (id(t), t.data_ptr(), None if t.is_inference() else t._version)


#: the memo of the innermost :func:`memo_scope`, or ``None`` outside any
_SCOPE: ContextVar[dict | None] = ContextVar("sssbench_memo_scope", default=None)


@contextmanager
def memo_scope() -> Iterator[None]:
    """Within this block (one operator call), :func:`memoised` also caches values computed
    from inference tensors, which carry no version counter: nothing writes the G-buffer
    during a call. Nested scopes share the outermost one."""
    token = _SCOPE.set({}) if _SCOPE.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            _SCOPE.reset(token)


def memoised(
    tensors: tuple[torch.Tensor | None, ...], tag: Hashable, compute: Callable[[], T]
) -> T:
    """``compute()``, memoised on ``tag`` and the identity and contents of ``tensors``.

    For what a renderer computes once per G-buffer and every pass reuses (the stencil, 002 §4;
    per-step LOD stencils, 003 §7.3.2). Across calls, the key holds each tensor's storage,
    offset, shape, strides and version counter, and the memo keeps the tensors themselves, so
    a storage cannot be freed and reused while cached and an in-place torch write misses (a
    write through a NumPy view of the tensor is not seen: build a new tensor instead). The
    least recently used entries beyond 64 are dropped. Inference tensors (made under
    ``torch.inference_mode``) have no version counter: for them the value is cached only
    within the current :func:`memo_scope`. ``compute`` must depend only on ``tensors`` and
    ``tag``.
    """
    key = (tag, *(_tensor_key(t) for t in tensors))
    inference = any(t is not None and t.is_inference() for t in tensors)
    memo = _SCOPE.get() if inference else _MEMO
    if memo is None:
        return compute()
    hit = memo.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], tensors, strict=True)):
        if memo is _MEMO:
            _MEMO.move_to_end(key)
        return hit[1]  # type: ignore[return-value]
    value = compute()
    memo[key] = (tensors, value)
    while memo is _MEMO and len(_MEMO) > _MEMO_SIZE:
        _MEMO.popitem(last=False)
    return value

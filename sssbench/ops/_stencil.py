"""Stencilled per-pixel stages: compute an elementwise function only where ``mask > 0``.

The gather primitive compacts active pixels itself; the pipeline's elementwise stages
(translucency, texturing, specular add) use :func:`apply_on_active` so that they, too, compute
nothing outside the stencil (002 §4, 003 §7.3.1) and record how many pixels they touched.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TypeVar

import torch

__all__ = [
    "active_pixels",
    "apply_on_active",
    "image_spans",
    "image_stencils",
    "memoised",
    "memo_scope",
]

#: memo of :func:`memoised`: key -> (the key tensors themselves, value)
_MEMO: OrderedDict[tuple, tuple[tuple, object]] = OrderedDict()
_MEMO_SIZE = 64

T = TypeVar("T")


def _tensor_key(t: torch.Tensor | None) -> tuple:
    if t is None:
        return (None,)
    return (
        t.data_ptr(),  # the memo keeps t alive, so no other tensor can get this address
        tuple(t.shape),
        t.stride(),
        t.dtype,
        t.device,
        None if t.is_inference() else t._version,
    )


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


def active_pixels(mask: torch.Tensor | None, numel: int) -> torch.Tensor | None:
    """Flat indices of the pixels with ``mask > 0``, or ``None`` (every pixel) without mask."""
    if mask is None:
        return None
    lists = image_stencils(mask)  # one stencil per mask, shared with the passes
    if len(lists) == 1:
        return lists[0]
    hw = mask.shape[-2] * mask.shape[-1]
    return torch.cat([lin + bi * hw for bi, lin in enumerate(lists)])


def image_stencils(mask: torch.Tensor) -> list[torch.Tensor]:
    """Per image, the flat indices (int64, into ``H·W``) of the pixels with ``mask > 0``.

    Built once per mask and reused by every pass of every call on the same G-buffer (a
    renderer writes its stencil once, with the G-buffer, 002 §4); see :func:`memoised`.

    Args:
        mask: ``(B, 1, H, W)`` stencil / strength.

    Returns:
        ``B`` int64 tensors of active flat indices.
    """
    return memoised(
        (mask,), "stencil", lambda: [torch.nonzero(m.reshape(-1) > 0).squeeze(1) for m in mask]
    )


def image_spans(mask: torch.Tensor | None, shape: tuple[int, int, int]) -> list[torch.Tensor]:
    """Per image, the runs of active pixels, row by row: ``(S, 3)`` int64 ``(row, first
    column, end column)`` sorted by row then column, the stencil as the native loop walks it.

    Derived from :func:`image_stencils` and memoised with it; without a mask every row is one
    run.

    Args:
        mask: ``(B, 1, H, W)`` stencil / strength, or ``None``.
        shape: ``(B, H, W)``.
    """
    b, h, w = shape
    if mask is None:
        rows = torch.arange(h, dtype=torch.int64)
        full = torch.stack([rows, torch.zeros_like(rows), torch.full_like(rows, w)], 1)
        return [full] * b

    def runs(lin: torch.Tensor) -> torch.Tensor:
        if lin.numel() == 0:
            return torch.zeros(0, 3, dtype=torch.int64)
        row, col = lin // w, lin % w
        start = torch.ones_like(lin, dtype=torch.bool)  # a run starts where the next pixel
        start[1:] = (lin[1:] != lin[:-1] + 1) | (row[1:] != row[:-1])  # is not the previous + 1
        first = torch.nonzero(start).squeeze(1)
        last = torch.cat([first[1:], first.new_tensor([lin.numel()])]) - 1
        return torch.stack([row[first], col[first], col[last] + 1], 1).contiguous()

    return memoised((mask,), "spans", lambda: [runs(lin) for lin in image_stencils(mask)])


def apply_on_active(
    fn: Callable[..., torch.Tensor],
    out: torch.Tensor,
    inputs: Sequence[torch.Tensor],
    active: torch.Tensor | None,
) -> torch.Tensor:
    """``out`` with ``fn(*inputs)`` written into the active pixels only.

    Args:
        fn: elementwise function of channels-last rows ``(N, C_k)`` returning ``(N, C)``.
        out: ``(B, C, H, W)`` image whose inactive pixels are kept.
        inputs: ``(B, C_k, H, W)`` images, fetched at the active pixels.
        active: flat pixel indices from :func:`active_pixels` (``None``: every pixel).

    Returns:
        ``(B, C, H, W)``.
    """
    b, c, h, w = out.shape

    def rows(x: torch.Tensor) -> torch.Tensor:
        flat = x.permute(0, 2, 3, 1).reshape(b * h * w, x.shape[1])
        return flat if active is None else flat[active]

    result = fn(*(rows(x) for x in inputs))
    if active is None:
        flat_out = result
    else:
        flat_out = out.permute(0, 2, 3, 1).reshape(b * h * w, c).index_copy(0, active, result)
    return flat_out.reshape(b, h, w, c).permute(0, 3, 1, 2).contiguous()

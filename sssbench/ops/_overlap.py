"""Exact memory overlap of strided tensors, for in-place calls (docs/reliability.md, issue 29
class 15): whether a view has two elements on one byte, and whether two views share a byte,
decided from sizes, strides and element sizes — torch's ``_debug_has_internal_overlap``
answers "cannot tell" for most strided views, which must not be read as "yes"."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["has_internal_overlap", "shares_memory"]


def _byte_range(t: torch.Tensor) -> tuple[int, int] | None:
    """``[first, end)`` addresses of the bytes ``t`` can touch (``None``: no element)."""
    if t.numel() == 0:
        return None
    base, item = t.data_ptr(), t.element_size()
    if t.is_contiguous():  # the rule: no walk over the strides
        return base, base + t.numel() * item
    lo = hi = 0  # elements from the first one's address (data_ptr: storage offset included)
    for size, stride in zip(t.shape, t.stride(), strict=True):
        if stride >= 0:
            hi += (size - 1) * stride
        else:
            lo += (size - 1) * stride
    return base + lo * item, base + (hi + 1) * item


def _runs(t: torch.Tensor) -> tuple[np.ndarray, int, bool]:
    """The bytes ``t`` touches as runs: ``(sorted start addresses, run length in bytes,
    whether some dimension of size > 1 has stride 0)``. Dimensions of size 1 are dropped,
    negative strides flipped (same address set), and the innermost dimensions that tile each
    other exactly (stride 1, then stride = the run so far) merged into one contiguous run; the
    remaining dimensions are enumerated (a window view of an image: one run per row)."""
    item = t.element_size()
    base = t.data_ptr()
    dims = []
    stride0 = False
    for size, stride in zip(t.shape, t.stride(), strict=True):
        if size == 1:
            continue
        if stride == 0:
            stride0 = True
            continue
        if stride < 0:
            base += (size - 1) * stride * item
            stride = -stride
        dims.append((stride, size))
    dims.sort()
    run = 1  # elements
    while dims and dims[0][0] == run:
        run *= dims.pop(0)[1]
    starts = np.zeros(1, dtype=np.int64)
    for stride, size in dims:
        starts = (starts[:, None] + np.arange(size, dtype=np.int64) * (stride * item)).ravel()
    return np.sort(starts) + base, run * item, stride0


def has_internal_overlap(t: torch.Tensor) -> bool:
    """Whether two elements of ``t`` share a byte, decided exactly from its sizes and strides
    (torch's ``_debug_has_internal_overlap`` answers "cannot tell" for most strided views)."""
    if t.numel() <= 1:
        return False
    quick = torch._debug_has_internal_overlap(t)  # 0: no, 1: yes, 2: cannot tell
    if quick != 2:
        return quick == 1
    starts, length, stride0 = _runs(t)
    return stride0 or bool((np.diff(starts) < length).any())


def shares_memory(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Whether ``a`` and ``b`` touch a common byte, decided exactly (interleaved but disjoint
    views, e.g. the even and the odd columns of one image, do not)."""
    ra, rb = _byte_range(a), _byte_range(b)
    if ra is None or rb is None or not (ra[0] < rb[1] and rb[0] < ra[1]):
        return False
    sa, la, _ = _runs(a)
    sb, lb, _ = _runs(b)
    if len(sa) > len(sb):
        sa, la, sb, lb = sb, lb, sa, la
    # for each run [s, s + la) of a: the run of b starting last before its end reaches
    # farthest (all runs of b have one length); they meet iff that one ends after s
    i = np.searchsorted(sb, sa + la, side="left") - 1
    ok = i >= 0
    return bool((sb[i[ok]] + lb > sa[ok]).any())

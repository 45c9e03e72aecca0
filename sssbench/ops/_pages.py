"""Large kept workspaces in 2 MB pages (Linux's transparent huge pages, ``madvise`` mode).

A tensor from :func:`torch.empty` lives in 4 KB pages unless the whole process runs with
``THP_MEM_ALLOC_ENABLE=1``. A y sweep reads each plane of its inputs a strip row at a time,
one row ``W`` elements after the last: every row of every plane is then a page of its own, a
TLB miss and a stream the hardware prefetcher does not follow across the page. In 2 MB pages
one entry covers 273 such rows of a 1080p float32 plane (7.5 KB each).

:func:`huge_page_empty` is for buffers a caller allocates once and keeps (the fused sum of
Gaussians' per-Gaussian images, 150 MB at 1080p): the mapping is made with ``mmap`` and
``madvise(MADV_HUGEPAGE)``, aligned to 2 MB, and unmapped when the tensor is freed. The values
are the same whatever the pages, so the results are too; where the platform has no
``MADV_HUGEPAGE`` (or the mapping fails) it is :func:`torch.empty`.

Its cost is the first touch: on the project's 2-core virtual machine, filling a fresh 150 MB
tensor took 22-615 ms in 2 MB pages (seven fresh processes; no compaction stall counted in
``/proc/vmstat``: the host backing memory the guest had not touched before) against
25-62 ms in 4 KB pages, and 4-9 ms either way once touched. So it is for a buffer kept across
many calls: the fused sum of Gaussians' first call at 1080p took 615 and 753 ms against
38 and 41 ms with :func:`torch.empty` (two fresh processes each), each later call about
1.2 ms less (issue 30, docs/numerics.md).
"""

from __future__ import annotations

import mmap

import numpy as np
import torch

__all__ = ["HUGE_PAGE", "huge_page_empty"]

#: bytes of a transparent huge page on x86-64 and of the alignment asked for
HUGE_PAGE = 2 << 20

#: numpy's dtype of each torch dtype a workspace may have
_NUMPY = {torch.float32: np.float32, torch.float64: np.float64}


def huge_page_empty(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """An uninitialised contiguous CPU tensor of ``shape`` and ``dtype`` (float32 or float64)
    whose memory is advised into 2 MB pages and starts on a 2 MB boundary (the kernel backs it
    with huge pages where it can, else with 4 KB ones: only the speed differs).
    :func:`torch.empty` on a platform without ``MADV_HUGEPAGE``, for another dtype, or when
    the mapping is refused."""
    np_dtype = _NUMPY.get(dtype)
    count = 1
    for n in shape:
        count *= int(n)
    advice = getattr(mmap, "MADV_HUGEPAGE", None)
    flags = getattr(mmap, "MAP_PRIVATE", 0) | getattr(mmap, "MAP_ANONYMOUS", 0)
    if np_dtype is None or advice is None or count == 0 or not flags:
        return torch.empty(shape, dtype=dtype)
    nbytes = count * np.dtype(np_dtype).itemsize
    try:
        # private and anonymous: shared anonymous memory is shmem, which this advice leaves
        # in small pages (its own sysfs switch)
        region = mmap.mmap(-1, nbytes + HUGE_PAGE, flags=flags)
        region.madvise(advice)
    except (OSError, ValueError):
        return torch.empty(shape, dtype=dtype)
    raw = np.frombuffer(region, dtype=np.uint8)  # keeps the mapping alive
    start = (-raw.ctypes.data) % HUGE_PAGE
    array = raw[start : start + nbytes].view(np_dtype).reshape(shape)
    return torch.from_numpy(array)

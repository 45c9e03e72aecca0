"""Stencilled per-pixel stages: compute an elementwise function only where ``mask > 0``.

The gather primitive compacts active pixels itself; the pipeline's elementwise stages
(translucency, texturing, specular add) use :func:`apply_on_active` so that they, too, compute
nothing outside the stencil (002 §4, 003 §7.3.1) and record how many pixels they touched.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

import torch

from sssbench._memo import call_scoped, memoised, seal_of
from sssbench.ops import native

__all__ = ["active_pixels", "apply_on_active", "image_spans", "image_stencils", "write_active"]


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

    Rebuilt from the mask's contents on every operator call by one read of the mask in C
    (``sss_spans``; ``torch.nonzero`` without the native library) and shared by the
    call's passes (:func:`~sssbench._memo.call_scoped`): rebuilding reads the mask once,
    half the bytes of a bitwise check against a kept snapshot, so a cross-call memo would
    cost more than it saves, and a stencil that is never kept cannot go stale. Under a seal
    of the mask (:meth:`~sssbench.gbuffer.GBuffer.sealed`: its owner's promise, verified at
    the seal's verification points, that it does not change) the runs are memoised across
    calls instead (:func:`~sssbench._memo.memoised`, an O(1) check on the seal), so that a
    call's fixed cost does not scale with the image: the scan of a 1080p float32 mask took
    1.0 ms of a far shot's 4.2 ms call (1.6 % of its pixels covered; issue 30). Without a
    mask every row is one run.

    Args:
        mask: ``(B, 1, H, W)`` stencil / strength, or ``None``.
        shape: ``(B, H, W)``.
    """
    b, h, w = shape
    if mask is None:
        rows = torch.arange(h, dtype=torch.int64)
        full = torch.stack([rows, torch.zeros_like(rows), torch.full_like(rows, w)], 1)
        return [full] * b
    if seal_of(mask) is not None:  # kept while the seal holds: O(1) per call
        return memoised((mask,), "spans", lambda: _runs(mask, h, w))
    return call_scoped((mask,), "spans", lambda: _runs(mask, h, w))


def _runs(mask: torch.Tensor, h: int, w: int) -> list[torch.Tensor]:
    """The ``(S, 3)`` runs of each image of a ``(B, 1, H, W)`` mask (see :func:`image_spans`):
    one C scan per image, the images found by address (no torch call but the output's), or
    ``torch.nonzero`` without the C library."""
    lib = native.library_for(mask.dtype)
    fn = _SPANS.get(mask.dtype)
    if lib is None or fn is None or mask.device.type != "cpu":
        return [_runs_of_indices(torch.nonzero(m.reshape(-1) > 0).squeeze(1), w) for m in mask]
    m = mask if mask.is_contiguous() else mask.detach().contiguous()
    step = m.stride(0) * m.element_size()
    return [_scan(getattr(lib, fn), m.data_ptr() + bi * step, h, w) for bi in range(m.shape[0])]


def _scan(fn: Callable[..., int], address: int, h: int, w: int) -> torch.Tensor:
    """The runs of the ``(h, w)`` plane of mask values at ``address`` by the C scan ``fn``."""
    cap = 4 * h + 1024  # a few runs per row; counted exactly when there are more
    while True:
        out = torch.empty(cap, 3, dtype=torch.int64)
        n = fn(address, h, w, out.data_ptr(), cap)
        if n <= cap:
            return out[:n]
        cap = n


#: the C scan per mask dtype
_SPANS = {torch.float32: "sss_spans_f32", torch.float64: "sss_spans_f64"}


def _runs_of_indices(lin: torch.Tensor, w: int) -> torch.Tensor:
    """The runs of sorted flat indices ``lin`` (int64, into ``H·W``) of an image ``w`` wide."""
    if lin.numel() == 0:
        return torch.zeros(0, 3, dtype=torch.int64)
    row, col = lin // w, lin % w
    start = torch.ones_like(lin, dtype=torch.bool)  # a run starts where the next pixel
    start[1:] = (lin[1:] != lin[:-1] + 1) | (row[1:] != row[:-1])  # is not the previous + 1
    first = torch.nonzero(start).squeeze(1)
    last = torch.cat([first[1:], first.new_tensor([lin.numel()])]) - 1
    return torch.stack([row[first], col[first], col[last] + 1], 1).contiguous()


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
    if active is not None:
        return write_active(out, active, result)
    return result.reshape(b, h, w, c).permute(0, 3, 1, 2).contiguous()


def write_active(image: torch.Tensor, active: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    """A contiguous copy of ``image`` ``(B, C, H, W)`` with the pixels ``active`` (sorted flat
    indices into ``B·H·W``, as :func:`active_pixels` gives them) set to ``rows`` ``(N, C)``:
    written plane by plane into each image's ``(C, H·W)`` view (copies only: the same values
    as an index copy into a channels-last copy transposed back, which took 3× as long on a
    512² image, 244 405 active pixels, measured)."""
    out = image.clone(memory_format=torch.contiguous_format)
    b, c, h, w = out.shape
    hw = h * w
    cuts = torch.searchsorted(active, torch.arange(b + 1) * hw).tolist()
    for bi, (lo, hi) in enumerate(itertools.pairwise(cuts)):
        out[bi].view(c, hw).index_copy_(1, active[lo:hi] - bi * hw, rows[lo:hi].t())
    return out

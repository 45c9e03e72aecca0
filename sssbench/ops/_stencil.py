"""Stencilled per-pixel stages: compute an elementwise function only where ``mask > 0``.

The gather primitive compacts active pixels itself; the pipeline's elementwise stages
(translucency, texturing, specular add) use :func:`apply_on_active` so that they, too, compute
nothing outside the stencil (002 §4, 003 §7.3.1) and record how many pixels they touched.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

__all__ = ["active_pixels", "apply_on_active"]


def active_pixels(mask: torch.Tensor | None, numel: int) -> torch.Tensor | None:
    """Flat indices of the pixels with ``mask > 0``, or ``None`` (every pixel) without mask."""
    if mask is None:
        return None
    return torch.nonzero(mask.reshape(-1) > 0).squeeze(1)


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

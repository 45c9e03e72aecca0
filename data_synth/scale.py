"""Physical scale of the synthetic scenes: millimetres of skin per pixel at the focus.

Every scene has a **focus**: the surface point on the view axis (the image centre). A scene built
with ``pixel_mm = p`` puts its focus at the depth

    z_f = p · H / (2 tan(fov_y / 2))                      (pinhole, DESIGN §2)

so one pixel there covers ``p`` mm whatever the resolution: at fixed ``p``, doubling ``H`` doubles
the field of view in mm (the camera steps back at a fixed ``fov_y``), it does not refine the same
framing. :func:`pixel_footprint_mm` reads the scale back from a G-buffer.

:data:`SCALES` names the scales of real use (mm per pixel at the skin): an extreme close-up (a
1080p cheek, ~0.05–0.1), a portrait (~0.3), a medium shot (~1) and a far / crowd shot (3 and up).
Skin's widest Gaussian is a few mm (``skin_deon6``: σ ≈ 2.7 mm), so screen-space SSS is visible
only well below 1 mm per pixel.
"""

from __future__ import annotations

import math

import torch

from sssbench._checks import check_choice, check_scalar
from sssbench.gbuffer import GBuffer, pixel_size_mm

__all__ = ["SCALES", "focus_depth", "pixel_footprint_mm", "resolve_pixel_mm"]

#: named scales, mm of skin per pixel at the focus
SCALES: dict[str, float] = {"close": 0.07, "portrait": 0.3, "medium": 1.0, "far": 3.0}


def resolve_pixel_mm(value: object) -> float:
    """``pixel_mm`` as a number: a positive number or a key of :data:`SCALES`."""
    if isinstance(value, str):
        check_choice("pixel_mm", value, list(SCALES))
        return SCALES[value]
    return check_scalar("pixel_mm", value, 0.0, low_inclusive=False)


def focus_depth(pixel_mm: float, height: int, fov_y: float) -> float:
    """Depth (mm) where one of ``height`` pixels covers ``pixel_mm``: ``p H / (2 tan(fov_y/2))``."""
    return pixel_mm * height / (2.0 * math.tan(fov_y / 2.0))


def pixel_footprint_mm(gbuffer: GBuffer) -> torch.Tensor:
    """Skin footprint of one pixel at the focus (the view axis), mm per pixel, ``(B,)``.

    The depth on the axis is the mean of the pixels whose centres are nearest to it (the centre
    pixel for odd sizes; the 2 or 4 central pixels, i.e. bilinear at the image centre, for even
    ones), turned into a footprint by :func:`sssbench.gbuffer.pixel_size_mm`.

    Example:
        >>> from data_synth import make_scene
        >>> g = make_scene("step_edge", (8, 8), dtype=torch.float64, pixel_mm=0.25)
        >>> round(float(pixel_footprint_mm(g)[0]), 12)
        0.25
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    _, h, w = gbuffer.shape
    rows = [h // 2] if h % 2 else [h // 2 - 1, h // 2]
    cols = [w // 2] if w % 2 else [w // 2 - 1, w // 2]
    z = gbuffer.depth[:, 0, rows][:, :, cols].mean(dim=(1, 2))
    return pixel_size_mm(z, gbuffer.fov_y, h)

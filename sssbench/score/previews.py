"""Preview images of a run: a labelled strip result | reference | error with a colour bar.

Error maps show ``|result − reference|`` (mean over RGB) relative to the reference's peak, on
a scale given by the caller (one scale for all methods of a scene, so their maps compare) or
the run's own maximum. The strip is at least 256 px high; the three single images are also
written at native resolution for the HTML report.
"""

from __future__ import annotations

from pathlib import Path

import torch

__all__ = ["preview_strip", "relative_error", "strip_layout", "MIN_HEIGHT_PX"]

#: smallest height of the strip's panels on screen (pixels)
MIN_HEIGHT_PX = 256


def relative_error(result: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """``(H, W)`` float64 ``|result − reference|`` (RGB mean) over the reference's peak, for
    the first image of the batch."""
    err = (result[:1].double() - reference[:1].double()).abs().mean(1)[0]
    peak = float(reference[:1].double().max())
    return err / (peak if peak > 0 else 1.0)


#: the strip's margins in pixels: above the panels (the title and the panel labels), between
#: panels, around them, and the colour bar's width and the room for its tick labels
_TOP_PX, _GAP_PX, _EDGE_PX, _BAR_PX, _TICKS_PX = 44, 10, 10, 16, 76


def strip_layout(h: int, w: int) -> dict[str, object]:
    """Where :func:`preview_strip` puts things for an ``h × w`` image, in pixels of the
    strip.

    Returns:
        ``scale``: each image pixel is drawn as ``scale × scale`` strip pixels, the smallest
        integer that makes a panel at least :data:`MIN_HEIGHT_PX` high unless that makes it
        wider than 2048 px (1 for larger images; never resampled); ``size``: ``(height,
        width)`` of the strip; ``panels``: the ``(row, column)`` of the top-left pixel of the
        result, reference and error panels, each ``(h · scale, w · scale)`` inside a 1-pixel
        black frame; ``bar``: ``(row, column, height, width)`` of the colour bar."""
    # ceil(MIN_HEIGHT_PX / h), but a panel no wider than 2048 px for a flat image (1 × 4096)
    scale = max(1, min(-(-MIN_HEIGHT_PX // h), 2048 // w))
    ph, pw = h * scale, w * scale
    row = _TOP_PX + 1  # inside the frame
    cols = [_EDGE_PX + 1 + i * (pw + 2 + _GAP_PX) for i in range(3)]
    bar_col = cols[2] + pw + 1 + _GAP_PX
    width = bar_col + _BAR_PX + _TICKS_PX
    return {
        "scale": scale,
        "size": (row + ph + 1 + _EDGE_PX, width),
        "panels": [(row, c) for c in cols],
        "bar": (row, bar_col, ph, _BAR_PX),
    }


def preview_strip(
    run_dir: Path,
    result: torch.Tensor,
    reference: torch.Tensor,
    *,
    error_scale: float | None = None,
    title: str = "",
) -> list[str]:
    """Write ``result.png``, ``reference.png``, ``error.png`` (native resolution) and
    ``preview.png`` (the labelled strip with a colour bar); return their file names.

    The strip's panels are the three images' own pixels, each drawn as an integer block
    (:func:`strip_layout`: never resampled), pasted into a matplotlib figure that draws only
    the text labels and one colour-bar axes. Until 2026-12-05 it was three matplotlib axes
    with constrained layout, which resampled each panel to the layout's size and cost about
    0.3 s of CPU per run (axes, ticks, layout, resampling; docs/sweeps.md).

    Args:
        run_dir: output directory.
        result, reference: ``(B, 3, H, W)`` linear radiance (the first image is shown).
        error_scale: top of the relative-error colour scale (> 0), or ``None`` for the
            run's own maximum.
        title: strip title (scene, method).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    from sssbench.score.metrics import tonemap

    run_dir = Path(run_dir)
    pixels = {}  # name -> (H, W, 4) uint8, as matplotlib's imsave converts them
    for name, img in (("result", result), ("reference", reference)):
        rgb = tonemap(img[:1].double().clamp(min=0)).squeeze(0).permute(1, 2, 0).clamp(0, 1)
        pixels[name] = ScalarMappable().to_rgba(rgb.numpy(), bytes=True)
    rel = relative_error(result, reference).numpy()
    vmax = error_scale if error_scale and error_scale > 0 else max(float(rel.max()), 1e-12)
    colour = ScalarMappable(Normalize(0.0, vmax), cmap="magma")
    pixels["error"] = colour.to_rgba(rel, bytes=True)
    for name, rgba in pixels.items():
        matplotlib.image.imsave(run_dir / f"{name}.png", rgba)

    h, w = rel.shape
    lay = strip_layout(h, w)
    k = lay["scale"]
    height, width = lay["size"]
    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    canvas = FigureCanvasAgg(fig)

    def at(row: float, col: float) -> tuple[float, float]:
        """Figure fraction of the strip pixel (row from the top, column from the left)."""
        return col / width, 1.0 - row / height

    labels = ("result", "reference", "|error| / reference peak")
    for (r, c), label in zip(lay["panels"], labels, strict=True):
        fig.text(*at(r - 4, c + w * k / 2), label, ha="center", va="bottom", fontsize=9)
    if title:
        fig.text(*at(4, width / 2), title, ha="center", va="top", fontsize=10)
    br, bc, bh, bw = lay["bar"]
    x0, y1 = at(br, bc)
    x1, y0 = at(br + bh, bc + bw)
    fig.colorbar(colour, cax=fig.add_axes((x0, y0, x1 - x0, y1 - y0)))
    canvas.draw()  # the labels and the colour bar; the panels are pasted in below
    drawn = np.asarray(canvas.buffer_rgba())
    # Agg sizes its canvas from figsize · dpi, a float product that a matplotlib version may
    # truncate one pixel short: the strip keeps the layout's size either way
    strip = np.full((height, width, 4), 255, dtype=np.uint8)
    rows, cols = min(height, drawn.shape[0]), min(width, drawn.shape[1])
    strip[:rows, :cols] = drawn[:rows, :cols]
    for (r, c), name in zip(lay["panels"], ("result", "reference", "error"), strict=True):
        strip[r - 1 : r + h * k + 1, c - 1 : c + w * k + 1] = (0, 0, 0, 255)  # the frame
        strip[r : r + h * k, c : c + w * k] = pixels[name].repeat(k, 0).repeat(k, 1)
    matplotlib.image.imsave(run_dir / "preview.png", strip)
    return ["result.png", "reference.png", "error.png", "preview.png"]

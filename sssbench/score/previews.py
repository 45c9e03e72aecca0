"""Preview images of a run: a labelled strip result | reference | error with a colour bar.

Error maps show ``|result − reference|`` (mean over RGB) relative to the reference's peak, on
a scale given by the caller (one scale for all methods of a scene, so their maps compare) or
the run's own maximum. The strip is at least 256 px high; the three single images are also
written at native resolution for the HTML report.
"""

from __future__ import annotations

from pathlib import Path

import torch

__all__ = ["preview_strip", "relative_error", "MIN_HEIGHT_PX"]

#: smallest height of the strip's panels on screen (pixels)
MIN_HEIGHT_PX = 256


def relative_error(result: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """``(H, W)`` float64 ``|result − reference|`` (RGB mean) over the reference's peak, for
    the first image of the batch."""
    err = (result[:1].double() - reference[:1].double()).abs().mean(1)[0]
    peak = float(reference[:1].double().max())
    return err / (peak if peak > 0 else 1.0)


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
    import matplotlib.pyplot as plt

    from sssbench.score.metrics import tonemap

    run_dir = Path(run_dir)
    images = {}
    for name, img in (("result", result), ("reference", reference)):
        rgb = tonemap(img[:1].double().clamp(min=0)).squeeze(0).permute(1, 2, 0).clamp(0, 1)
        images[name] = rgb.numpy()
        matplotlib.image.imsave(run_dir / f"{name}.png", images[name])
    rel = relative_error(result, reference).numpy()
    vmax = error_scale if error_scale and error_scale > 0 else max(float(rel.max()), 1e-12)
    matplotlib.image.imsave(run_dir / "error.png", rel, cmap="magma", vmin=0.0, vmax=vmax)

    h, w = rel.shape
    scale = max(1.0, MIN_HEIGHT_PX / h)
    dpi = 100
    fig_h = h * scale / dpi + 0.6
    fig_w = 3 * w * scale / dpi + 1.2
    fig, axes = plt.subplots(1, 3, figsize=(fig_w, fig_h), dpi=dpi, constrained_layout=True)
    for ax, (label, data) in zip(
        axes, (("result", images["result"]), ("reference", images["reference"])), strict=False
    ):
        ax.imshow(data, interpolation="nearest")
        ax.set_title(label, fontsize=9)
    im = axes[2].imshow(rel, cmap="magma", vmin=0.0, vmax=vmax, interpolation="nearest")
    axes[2].set_title("|error| / reference peak", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.02)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.savefig(run_dir / "preview.png")
    plt.close(fig)
    return ["result.png", "reference.png", "error.png", "preview.png"]

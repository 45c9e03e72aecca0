"""Real-image textures for the synthetic skin (scikit-image's bundled images, no download).

``skimage.data.gravel()`` (512², a gravel photograph) stands in for the pore relief and
``skimage.data.moon()`` (512², a lunar photograph) for blotchy albedo variation. Both are
normalised to zero mean and unit standard deviation and sampled with wrap-around bilinear
interpolation at texel coordinates.
"""

from __future__ import annotations

import functools

import skimage.data
import torch
import torch.nn.functional as F

__all__ = ["bilinear_wrap", "mip_level", "texture"]

_SOURCES = {"gravel": skimage.data.gravel, "moon": skimage.data.moon}


@functools.lru_cache(maxsize=4)
def _normalised(name: str) -> torch.Tensor:
    tex = torch.from_numpy(_SOURCES[name]()).to(torch.float64)
    return (tex - tex.mean()) / tex.std()


def texture(name: str) -> torch.Tensor:
    """``(512, 512)`` float64 texture ``name`` (``"gravel"`` or ``"moon"``), mean 0, std 1.

    A fresh copy each call (the decoded image is cached read-only, so callers cannot alter it).
    """
    return _normalised(name).clone()


def mip_level(tex: torch.Tensor, level: int) -> torch.Tensor:
    """``tex (h, w)`` averaged over ``2^level`` texel blocks (a box-filtered mip level).

    Sampling a relief finer than a pixel aliases; one level chosen from the pixel footprint
    keeps the per-pixel sample close to the pixel's average.
    """
    out = tex
    for _ in range(level):
        if min(out.shape) < 2:
            break
        out = F.avg_pool2d(out[None, None], 2)[0, 0]
    return out


def bilinear_wrap(tex: torch.Tensor, r: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of ``tex (h, w)`` at fractional texel (row, col), tiling the texture."""
    h, w = tex.shape
    r0, c0 = r.floor(), c.floor()
    fr, fc = r - r0, c - c0
    r0, c0 = r0.long() % h, c0.long() % w
    r1, c1 = (r0 + 1) % h, (c0 + 1) % w
    top = tex[r0, c0] * (1 - fc) + tex[r0, c1] * fc
    bottom = tex[r1, c0] * (1 - fc) + tex[r1, c1] * fc
    return top * (1 - fr) + bottom * fr

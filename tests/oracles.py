"""Independent oracles shared by several test files (closed forms, not the code under test)."""

import math

import numpy as np
import torch
from scipy.special import ndtr

from sssbench.gbuffer import GBuffer, view_positions
from sssbench.profiles import SumOfGaussians

FOV = math.radians(20)


def flat(diffuse: torch.Tensor, z: float = 300.0) -> GBuffer:
    """A fronto-parallel plane at depth ``z`` mm carrying ``diffuse``."""
    b, _, h, w = diffuse.shape
    return GBuffer(diffuse, torch.full((b, 1, h, w), z, dtype=diffuse.dtype), FOV)


def step_response(p: SumOfGaussians, x: np.ndarray, edge: float, lo: float, hi: float):
    """Analytic response of a vertical step: lo + (hi-lo) Σ w_i Φ((x-edge)/σ_i) / Σ w_i."""
    s = np.sqrt(p.variances.numpy())
    w = p.weights.numpy()
    frac = (ndtr((x[:, None] - edge) / s) @ w) / w.sum(0)
    return lo + (hi - lo) * frac  # (n, 3)


def step_gbuffer(h: int, w: int, z: float, lo: float, hi: float, dtype=torch.float64):
    """A plane with irradiance ``lo`` left of column w//2 and ``hi`` from it on.

    Returns the G-buffer, the x positions (mm) of the pixel centres and the boundary x (mm).
    """
    e = w // 2
    img = torch.full((1, 3, h, w), lo, dtype=dtype)
    img[..., e:] = hi
    g = flat(img, z)
    pos = view_positions(g.depth, FOV)
    pix = 2 * z * math.tan(FOV / 2) / h
    x = pos[0, 0, 0].numpy()
    edge = float(x[e]) - pix / 2  # boundary between columns e-1 and e
    return g, x, edge


def rel_rms_np(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).mean() / (b**2).mean()))

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


def _minmod_np(z: np.ndarray, lat: np.ndarray, axis: int) -> np.ndarray:
    """Minmod of the one-sided slopes dz/dlat along ``axis`` (0 where they disagree), |·| ≤
    tan 85°: the surface definition of the reference (its cells' tilt)."""
    dz, dl = np.diff(z, axis=axis), np.diff(lat, axis=axis)
    fwd = dz / np.where(dl == 0, 1.0, dl)
    pad_hi = [(0, 0)] * z.ndim
    pad_lo = [(0, 0)] * z.ndim
    pad_hi[axis], pad_lo[axis] = (0, 1), (1, 0)
    a, b = np.pad(fwd, pad_hi), np.pad(fwd, pad_lo)
    s = np.where(a * b > 0, np.sign(a) * np.minimum(np.abs(a), np.abs(b)), 0.0)
    lim = math.tan(math.radians(85.0))
    return np.clip(s, -lim, lim)


def brute_force_reference(
    g: GBuffer,
    p: SumOfGaussians,
    targets: np.ndarray,
    pad: int,
    reconstruction: str = "box",
    nodes_per_sigma: float = 3.0,
) -> np.ndarray:
    """The reference's surface integral by brute force (numpy, float64), at some pixels.

    The surface is the image extended by ``pad`` pixels (clamp-to-edge), one planar patch per
    pixel with ``mask > 0``: centre at the view position of the pixel, lateral half-size
    ``z tan(fov/2) / (H/2) / 2``, tilted by the minmod depth slopes. Every patch is cut into
    ``m × m`` sub-patches no larger than σ_min / ``nodes_per_sigma`` in 3D (four quadrants at
    least) with a 4×4 Gauss–Legendre rule each; the irradiance at a node is the pixel's
    (box) or the bilinear interpolation between the centres in the patch's parameters
    (bilinear); the profile is evaluated at the node's 3D distance. Returns ``(n, 3)``:
    ``Σ q R dA / Σ s R dA`` at ``targets`` ``(n, 2)`` (row, col).
    """
    d = g.depth[0, 0].numpy()
    e = g.diffuse[0].numpy()
    s = (g.mask_or_ones()[0, 0].numpy() > 0).astype(float)
    h, w = d.shape
    dp = np.pad(d, pad, mode="edge")
    sp = np.pad(s, pad, mode="edge")
    ep = np.pad(e * s, ((0, 0), (pad, pad), (pad, pad)), mode="edge")
    t = math.tan(g.fov_y / 2)
    cols = np.arange(-pad, w + pad) + 0.5
    rows = np.arange(-pad, h + pad) + 0.5
    x = ((cols - w / 2) / (h / 2))[None, :] * dp * t
    y = ((h / 2 - rows) / (h / 2))[:, None] * dp * t
    half = 0.5 * dp * 2 * t / h * sp
    sx = _minmod_np(dp, x, 1)
    sy = _minmod_np(dp, y, 0)
    # bilinear neighbours: one more replicated border
    qq = np.concatenate([ep, sp[None]], 0)
    qb = np.pad(qq, ((0, 0), (1, 1), (1, 1)), mode="edge")
    gx, gw = np.polynomial.legendre.leggauss(4)
    var = p.variances.numpy()
    wts = p.weights.numpy()
    ext = half * np.sqrt(2 + (np.abs(sx) + np.abs(sy)) ** 2)  # patch radius
    on = np.argwhere(sp > 0)
    cen = np.stack([x[on[:, 0], on[:, 1]], y[on[:, 0], on[:, 1]], dp[on[:, 0], on[:, 1]]], 1)
    num = np.zeros((len(targets), 3))
    den = np.zeros((len(targets), 3))
    for i, (tr, tc) in enumerate(targets):
        x0 = np.array([x[tr + pad, tc + pad], y[tr + pad, tc + pad], dp[tr + pad, tc + pad]])
        dist = np.sqrt(((cen - x0) ** 2).sum(1))
        for vg, wg in zip(var, wts, strict=True):
            sg = math.sqrt(vg)
            near = on[dist - ext[on[:, 0], on[:, 1]] < 9 * sg]  # beyond: below e^-40
            msub = np.maximum(2, np.ceil(2 * ext[near[:, 0], near[:, 1]] * nodes_per_sigma / sg))
            msub = (msub + msub % 2).astype(int)  # even: quadrant edges are sub-patch edges
            for m in np.unique(msub):
                r, c = near[msub == m].T
                edges = np.linspace(-1, 1, m + 1)
                u = (((edges[:-1] + edges[1:]) / 2)[:, None] + gx[None, :] / m).ravel()
                wu = np.tile(gw / m, m)
                uu, vv = np.meshgrid(u, u, indexing="ij")
                ww = np.outer(wu, wu)
                hh = half[r, c][:, None, None]
                ss, tt = uu[None] * hh, vv[None] * hh
                px = x[r, c][:, None, None] + ss
                py = y[r, c][:, None, None] + tt
                pz = dp[r, c][:, None, None] + sx[r, c][:, None, None] * ss
                pz = pz + sy[r, c][:, None, None] * tt
                area = np.sqrt(1 + sx[r, c] ** 2 + sy[r, c] ** 2)[:, None, None] * hh**2 * ww
                if reconstruction == "box":
                    q = qq[:, r, c][:, :, None, None] * np.ones_like(uu)
                else:
                    q = 0.0
                    for a in (-1, 0, 1):
                        wa = np.maximum(0, 1 - np.abs(uu / 2 - a))  # Λ(s/2h − a), s = u h
                        for b in (-1, 0, 1):
                            wb = np.maximum(0, 1 - np.abs(vv / 2 - b))
                            q = q + qb[:, r + 1 - b, c + 1 + a][:, :, None, None] * (wa * wb)
                r2 = (px - x0[0]) ** 2 + (py - x0[1]) ** 2 + (pz - x0[2]) ** 2
                prof = np.exp(-r2 / (2 * vg)) / (2 * math.pi * vg) * area
                tot = (q * prof[None]).reshape(4, -1).sum(1)
                num[i] += tot[:3] * wg
                den[i] += tot[3] * wg
    return num / den

"""Claim 4 — the empirical four-Gaussian pole fit (001 Appendix A, Fig. 11).

Evaluates 001 eq. 10 for :func:`~sssbench.profiles.empirical_pole_fit` against the exact pole
``P(r, σ_tr, z)`` on a log grid over ``σ_tr, z ∈ [0.001, 15]`` (the square of 001 Fig. 11), and,
as a diagnosis, the best that any weights could do with the same four variance ratios
(linear least squares of eq. 6 in the weights).

    python -m experiments.run pole_fit [--quick]
"""

from __future__ import annotations

import math
import sys

import matplotlib.pyplot as plt
import numpy as np
import torch
from matplotlib.colors import LogNorm

from experiments.common import Context, Section, main, md_table
from sssbench.profiles.empirical import VARIANCE_RATIOS, pole_fit_error

TITLE = "4. Empirical pole fit error map (001 App. A, Fig. 11)"
THRESHOLD = 0.2  # %, 001 Fig. 11 caption


def _pole(r: np.ndarray, sigma: float, z: float) -> np.ndarray:
    d = np.sqrt(r**2 + z**2)
    return (1 + sigma * d) * np.exp(-sigma * d) / d**3  # 001 eq. 17


def best_weights_error(x: float) -> float:
    """001 eq. 10 of the least-squares weights for the fixed variances ``VARIANCE_RATIOS · v0``
    (pole with z = 1, σ = x: the relative error depends only on ``x = σ z``)."""
    v0 = 1.0 / (1 + x)
    v = np.array(VARIANCE_RATIOS) * v0
    edges = np.concatenate([[0.0], np.geomspace(1e-3, 200 + 100 / max(x, 1e-2), 200)])
    gx, gw = np.polynomial.legendre.leggauss(12)
    a, b = edges[:-1, None], edges[1:, None]
    r = (0.5 * (b - a) * gx + 0.5 * (b + a)).ravel()
    w = (0.5 * (b - a) * gw).ravel()
    s = np.sqrt(r * w)
    m = s[:, None] * np.exp(-(r[:, None] ** 2) / (2 * v)) / (2 * math.pi * v)
    y = s * _pole(r, x, 1.0)
    coef = np.linalg.lstsq(m, y, rcond=None)[0]
    return float(np.linalg.norm(m @ coef - y) / np.linalg.norm(y))


def run(ctx: Context) -> Section:
    n = 6 if ctx.quick else 36
    axis = np.geomspace(1e-3, 15.0, n)
    sig, zz = np.meshgrid(axis, axis, indexing="ij")
    flat_s, flat_z = sig.ravel(), zz.ravel()
    pad = (-len(flat_s)) % 3
    fs = np.concatenate([flat_s, np.full(pad, 1.0)])
    fz = np.concatenate([flat_z, np.full(pad, 1.0)])
    errs = []
    for i in range(0, len(fs), 3):  # three (σ, z) points per call, one per channel
        errs.append(
            pole_fit_error(torch.tensor(fs[i : i + 3]), torch.tensor(fz[i : i + 3])).numpy()
        )
    emap = 100 * np.concatenate(errs)[: len(flat_s)].reshape(n, n)
    below = emap < THRESHOLD
    frac = float(below.mean())

    xs = np.geomspace(1e-6, 225.0, 6 if ctx.quick else 60)
    e_emp = [100 * float(pole_fit_error(torch.tensor([x, x, x]), torch.ones(3))[0]) for x in xs]
    e_best = [100 * best_weights_error(x) for x in xs]

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    ax = axes[0]
    pc = ax.pcolormesh(axis, axis, emap.T, norm=LogNorm(), cmap="magma", shading="nearest")
    ax.contour(axis, axis, emap.T, levels=[THRESHOLD], colors="c")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("σ_tr (1/mm)")
    ax.set_ylabel("z (mm)")
    ax.set_title("eq. 10 error (%) of the empirical fit")
    fig.colorbar(pc, ax=ax)
    ax = axes[1]
    ax.loglog(xs, e_emp, label="empirical C_i (001 App. A)")
    ax.loglog(xs, e_best, label="least-squares weights, same variances")
    ax.axhline(THRESHOLD, color="c", ls=":", label="0.2 % (Fig. 11 caption)")
    ax.set_xlabel("x = σ_tr z")
    ax.set_ylabel("error (%)")
    ax.legend(fontsize=7)
    ax.set_title("error depends only on σ_tr z")
    link = ctx.figure(fig)

    i_min = int(np.argmin(e_emp))
    rows = [
        [f"{x:.3g}", e, b]
        for x, e, b in zip(
            xs[:: max(1, len(xs) // 10)],
            e_emp[:: max(1, len(xs) // 10)],
            e_best[:: max(1, len(xs) // 10)],
            strict=True,
        )
    ]
    measured = (
        f"Over the {n}×{n} log grid of σ_tr, z ∈ [0.001, 15] the error ranges from "
        f"{emap.min():.3g} % to {emap.max():.3g} %; it is below 0.2 % on {100 * frac:.3g} % "
        f"of the grid. Its minimum along x = σ_tr z is {e_emp[i_min]:.3g} % at x ≈ "
        f"{xs[i_min]:.2g}. Even the least-squares-optimal weights for the same four variance "
        f"ratios reach only {min(e_best):.3g} % at best."
    )
    verdict = "reproduced" if frac > 0.5 else "not reproduced"
    reason = (
        "The error is nowhere near “< 0.2 % for a wide range”. Likely reason: the four fixed "
        "variance ratios (0.2304, 0.7225, 2.6569, 13.6)·v0 cannot represent the pole to 0.2 % "
        "whatever the weights (right panel, orange), and the printed C_i curves add most of "
        "the remaining error for x < 0.3 (they sum to ≈6.33 at x = 0, not 2π). Either the "
        "caption's metric differs from eq. 10 (e.g. an un-normalised or squared error), or "
        "the printed constants lost digits. Implementation cross-checked: the same code fits "
        "the dipole of §4 to the paper's digits (section 3)."
        if verdict == "not reproduced"
        else "Below 0.2 % over most of the square."
    )
    return Section(
        TITLE,
        "“The error metric (10) for the fast-empirical pole fit is computed for a single pole "
        "equation with z and σ_tr in the range [.001, 15]. Errors are less than 0.2% for a "
        "wide range of scattering parameters.” (001 Fig. 11)",
        measured,
        verdict,
        reason,
        body=md_table(rows, ["x = σ_tr z", "empirical fit (%)", "best weights (%)"]),
        figures=[link],
        data={"min": float(emap.min()), "max": float(emap.max()), "frac_below": frac},
    )


if __name__ == "__main__":
    sys.exit(main("pole_fit", run))

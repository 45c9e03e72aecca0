"""Claim 2 — the step edge (000 Fig. 7): profiles across a vertical shadow boundary.

On ``step_edge`` (a camera-facing plane, irradiance 0.1 | 1.0) with the six-Gaussian skin,
compares with the exact reference: the pre-integrated kernel (exact for an axis-aligned step
against the exact reference; its floor is then split into taps and the irradiance
reconstruction convention), the artist model's close fit (000 Table 2), one Gaussian
(001 eq. 6 fit), the 12-pass sum of six Gaussians, and SVD rank 1 and 3.

    python -m experiments.run step_edge [--quick]
"""

from __future__ import annotations

import sys

import matplotlib.pyplot as plt
import torch

import sssbench.ops as ops
from experiments.common import Context, Section, errors, main, md_table, op_available, reference
from experiments.common import scene as make
from sssbench.profiles import SumOfGaussians, fit_sum_of_gaussians
from sssbench.score.metrics import rel_rms

TITLE = "2. The step edge (000 Fig. 7)"


def methods(prof: SumOfGaussians, taps: int) -> dict:
    one = fit_sum_of_gaussians(prof, 1, shared_variances=True).profile
    ext = 4 * float(prof.length_scales()[1])
    out = {
        f"pre-integrated ({taps} taps)": lambda: ops.PreintegratedSSS(prof, taps),
        "one Gaussian": lambda: ops.PreintegratedSSS(one, taps),
        "sum of 6 Gaussians (12 passes)": lambda: ops.SumOfGaussiansSSS(prof, taps),
        "SVD rank 1": lambda: ops.LowRankSSS(prof, 1, n=101, extent=ext),
        "SVD rank 3": lambda: ops.LowRankSSS(prof, 3, n=101, extent=ext),
    }
    if op_available("ArtistSSS"):
        out["artist close fit"] = lambda: ops.ArtistSSS.preset("multi_layer_close_fit", taps)
    return out


def run(ctx: Context) -> Section:
    prof = SumOfGaussians.from_table("skin_deon6")
    res = (8, 96) if ctx.quick else (16, 256)
    taps = 17 if ctx.quick else 33
    g = make("step_edge", res, fields=["mask"])
    ref = reference("step_edge", res, prof)
    px = 0.2  # mm per pixel (step_edge default)
    x = (torch.arange(res[1]) + 0.5 - res[1] / 2) * px
    row = res[0] // 2
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.3))
    rows, data = [], {}
    for c, ax in zip((0, 2), axes, strict=True):
        ax.plot(x, ref[0, c, row], "k", lw=2.5, label="reference")
    for name, build in methods(prof, taps).items():
        with torch.inference_mode():
            out = build()(g)
        e = errors(out, ref, g)
        ksum = float((out[0, :, row] - ref[0, :, row]).abs().max())
        rows.append([name, e["rel_rms"], e["psnr"], ksum])
        data[name] = e
        for c, ax in zip((0, 2), axes, strict=True):
            ax.plot(x, out[0, c, row], "--", lw=1, label=name)
    for c, ax in zip(("red", "blue"), axes, strict=True):
        ax.set_xlim(-6, 6)
        ax.set_xlabel("x (mm)")
        ax.set_title(f"{c} channel across the edge")
    axes[0].legend(fontsize=6)
    link = ctx.figure(fig)

    pre = data[f"pre-integrated ({taps} taps)"]["rel_rms"]
    best_other = min(v["rel_rms"] for k, v in data.items() if not k.startswith("pre-"))
    ordered = data["SVD rank 1"]["rel_rms"] > data["SVD rank 3"]["rel_rms"]
    ok = pre <= best_other * 1.05 and ordered
    # where the pre-integrated floor comes from: taps, or the irradiance reconstruction (the
    # gather reads the image bilinearly; the box reference integrates constant pixel cells)
    g64 = g.to(torch.float64)
    counts = (33, 129) if ctx.quick else (33, 129, 513, 1025)
    with torch.inference_mode():
        box = ops.ReferenceSSS(prof)(g64)
        bilinear = ops.ReferenceSSS(prof, reconstruction="bilinear")(g64)
        conv = []
        for n in counts:
            out = ops.PreintegratedSSS(prof, n)(g64)
            conv.append((n, rel_rms(out, box, g64.mask), rel_rms(out, bilinear, g64.mask)))
    convention = rel_rms(bilinear, box, g64.mask)
    last = conv[-1]
    floor_is_convention = abs(last[1] - convention) < 0.2 * convention and last[2] < last[1] / 5
    measured = (
        "Relative RMS error against the exact reference: "
        + "; ".join(f"{k} {v['rel_rms']:.3g}" for k, v in data.items())
        + ". Pre-integrated at "
        + ", ".join(str(n) for n, _, _ in conv)
        + " taps: "
        + ", ".join(f"{b:.3g}" for _, b, _ in conv)
        + " against the box reference, "
        + ", ".join(f"{b:.3g}" for _, _, b in conv)
        + " against the bilinear-reconstruction reference (the two references differ by "
        + f"{convention:.3g})."
    )
    floor_text = (
        f" Its floor against the box reference ({last[1]:.3g} at {last[0]} taps) is the "
        f"irradiance reconstruction convention ({convention:.3g}), not the taps: against the "
        f"bilinear reference it keeps falling, to {last[2]:.3g}."
        if floor_is_convention
        else f" At {last[0]} taps it scores {last[1]:.3g} (box) and {last[2]:.3g} (bilinear)."
    )
    return Section(
        TITLE,
        "“A_p reproduces the exact 2D convolution with R_d in the presence of additively "
        "separable irradiance signals, such as straight shadow boundaries” (000 §4); Fig. 7: "
        "SVD converges rapidly (rank 3 close to the true kernel), the sum of Gaussians needs "
        "several convolutions, the artist close fit is perceptually close.",
        measured,
        "reproduced" if ok else "partly reproduced",
        (
            "The pre-integrated kernel is the most accurate two-pass method; rank 1 is clearly "
            "worse than rank 3; one Gaussian misses the profile's long tail and sharp peak. The "
            "artist close fit (000 Table 2) was fitted to a different skin profile, so its "
            "error includes that mismatch; the paper's claim for it is perceptual." + floor_text
        )
        if ok
        else "The pre-integrated kernel is not the most accurate here (see table)." + floor_text,
        body=md_table(rows, ["method", "rel_rms", "PSNR (dB)", "max |error| on the row"]),
        figures=[link],
        data=data,
    )


if __name__ == "__main__":
    sys.exit(main("step_edge", run))

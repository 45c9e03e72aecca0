"""Claim 8 — the test-bed extensions of 004 §3.2–3.3: what each buys and costs.

Against the pre-integrated baseline (skin_deon6, 7 importance taps), each extension's error
change against the exact surface reference and its extra time (median of ``record_passes``
sums, one thread):

* translucency (004 §3.2, eq. 3.10) on ``backlit_ear`` — adds light the surface reference
  does not model, so only its cost and the energy it adds are reported;
* halo reduction, cross bilateral on normals (004 §3.3.1) on ``halo``;
* skin / non-skin Lab bilateral (004 §3.3.2) on ``head_close`` (skin next to hair/eyes);
* curvature modulation, the three strategies of 004 §3.3.3, on ``head_close``.

    python -m experiments.run extensions [--quick]
"""

from __future__ import annotations

import sys

import matplotlib.pyplot as plt
import torch

from experiments.benchmark import timed
from experiments.common import Context, Section, errors, main, md_table, reference
from experiments.common import scene as make
from sssbench.ops import CurvatureModulation, PreintegratedSSS, Translucency
from sssbench.ops.curvature import CURVATURE_STRATEGIES
from sssbench.profiles import SumOfGaussians

TITLE = "8. Extensions: translucency, halo, Lab bilateral, curvature (004 §3.2–3.3)"


class _Curved(torch.nn.Module):
    def __init__(self, base: PreintegratedSSS, strategy: str) -> None:
        super().__init__()
        self.base, self.curv = base, CurvatureModulation(strategy)

    def forward(self, g):
        return self.base(g, width=self.curv(g))


class _WithTranslucency(torch.nn.Module):
    def __init__(self, base: PreintegratedSSS) -> None:
        super().__init__()
        self.base, self.tr = base, Translucency("skin_deon6", 0.5, 8.0)

    def forward(self, g):
        return self.tr(g, self.base(g))


def run(ctx: Context) -> Section:
    prof = SumOfGaussians.from_table("skin_deon6")
    res = (24, 24) if ctx.quick else (96, 96)
    reps = 1 if ctx.quick else 5
    base = PreintegratedSSS(prof, 7)
    cases = {
        "backlit_ear": {"translucency": _WithTranslucency(base)},
        "halo": {"halo: normal bilateral": PreintegratedSSS(prof, 7, halo="bilateral")},
        "head_close": {
            "Lab bilateral (skin / non-skin)": PreintegratedSSS(prof, 7, halo="lab"),
            **{f"curvature: {s}": _Curved(base, s) for s in CURVATURE_STRATEGIES},
        },
    }
    rows, bars = [], []
    for sc, ops in cases.items():
        g = make(sc, res)
        ref = reference(sc, res, prof)
        out0, ms0 = timed(base, g, reps)
        e0 = errors(out0, ref, g)
        rows.append([sc, "baseline (pre-integrated, 7 taps)", e0["rel_rms"], e0["psnr"], ms0, "–"])
        for name, op in ops.items():
            out, ms = timed(op, g, reps)
            e = errors(out, ref, g)
            if name == "translucency":
                added = float((out - out0).sum() / out0.sum())
                rows.append([sc, name, "n/a", "n/a", ms, f"+{100 * added:.3g} % light"])
            else:
                d = e["psnr"] - e0["psnr"]
                rows.append([sc, name, e["rel_rms"], e["psnr"], ms, f"{d:+.2f} dB"])
                bars.append((f"{sc}: {name}", d, ms / ms0))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3), sharey=True)
    labels = [b[0] for b in bars]
    axes[0].barh(labels, [b[1] for b in bars])
    axes[0].set_xlabel("PSNR change vs baseline (dB)")
    axes[1].barh(labels, [b[2] for b in bars], color="tab:orange")
    axes[1].set_xlabel("time / baseline time")
    axes[0].tick_params(labelsize=6)
    link = ctx.figure(fig)
    measured = "; ".join(f"{b[0]} {b[1]:+.2f} dB at {b[2]:.2g}× the time" for b in bars) + "."
    return Section(
        TITLE,
        "004 §3.2–3.3 add translucency through thin parts (eq. 3.10), a cross bilateral "
        "filter that reduces halos at depth/normal discontinuities, a Lab colour bilateral "
        "that keeps skin from bleeding into non-skin regions, and three curvature "
        "strategies; the thesis shows them as visual improvements with timings (Ch. 5), "
        "without an error figure.",
        measured,
        "not comparable",
        "The thesis states no error numbers to compare with; this is the measured trade-off "
        "against our exact surface reference. A negative dB change means the extension moves "
        "the image away from the physical reference (halo / Lab weights and curvature "
        "modulation are artistic corrections, not physics); translucency adds transmitted "
        "light, which the surface reference does not model.",
        body=md_table(rows, ["scene", "variant", "rel_rms", "PSNR", "ms", "change"])
        + f"\n\nResolution {res[0]}×{res[1]}.",
        figures=[link],
        data={"bars": bars},
    )


if __name__ == "__main__":
    sys.exit(main("extensions", run))

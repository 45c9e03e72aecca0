"""Claim 6 — cost: time per method against taps per pass; sum of Gaussians vs separable.

Times every method at ``head_cheek``, ``head_mid`` and ``head_far`` (no reference needed) with
:func:`~sssbench.ops.record_passes`: per configuration the median over repeats of the summed
pass times, all in one process on one thread, so ratios compare like with like.

    python -m experiments.run cost [--quick]
"""

from __future__ import annotations

import sys

import matplotlib.pyplot as plt

from experiments.common import Context, Section, main, md_table, timed
from experiments.common import scene as make
from experiments.methods import available
from sssbench.profiles import SumOfGaussians

TITLE = "6. Cost: time against taps, sum of Gaussians vs separable (000 §8, 002 T.2, 004 T.5.2)"
SAMPLES = (7, 9, 17, 33)


def run(ctx: Context) -> Section:
    prof = SumOfGaussians.from_table("skin_deon6")
    methods = available()
    scenes = ("head_cheek", "head_far") if ctx.quick else ("head_cheek", "head_mid", "head_far")
    samples = (7, 9) if ctx.quick else SAMPLES
    res = (16, 16) if ctx.quick else (192, 192)
    repeats = 1 if ctx.quick else 7
    t: dict[tuple[str, str, int], float] = {}
    for sc in scenes:
        g = make(sc, res, fields=["mask"])
        for m, factory in methods.items():
            for n in samples:
                t[sc, m, n] = timed(factory(prof, n), g, repeats)[1]
        if "sum_of_gaussians" in methods:
            from sssbench.ops import SumOfGaussiansSSS

            for n in samples:  # every Gaussian everywhere: the pure count of convolutions
                op = SumOfGaussiansSSS(prof, n, lod=False)
                t[sc, "sum_of_gaussians (no LOD)", n] = timed(op, g, repeats)[1]

    fig, axes = plt.subplots(1, len(scenes), figsize=(3.3 * len(scenes), 3), sharey=True)
    for ax, sc in zip(axes, scenes, strict=True):
        for m in methods:
            ax.loglog(samples, [t[sc, m, n] for n in samples], "-o", ms=3, label=m)
        ax.set_title(sc, fontsize=9)
        ax.set_xlabel("taps per pass")
    axes[0].set_ylabel("time (ms, median, 1 thread)")
    axes[0].legend(fontsize=6)
    link = ctx.figure(fig)

    names = sorted({k[1] for k in t}, key=lambda m: (m not in methods, m))
    rows = [[sc, m, *[t[sc, m, n] for n in samples]] for sc in scenes for m in names]
    ratio_rows, ratios, ratios_nolod = [], {}, {}
    if "sum_of_gaussians" in methods:
        for sc in scenes:
            for n in samples:
                ratios[sc, n] = t[sc, "sum_of_gaussians", n] / t[sc, "preintegrated", n]
                ratios_nolod[sc, n] = (
                    t[sc, "sum_of_gaussians (no LOD)", n] / t[sc, "preintegrated", n]
                )
            ratio_rows.append([sc, "LOD on", *[ratios[sc, n] for n in samples]])
            ratio_rows.append([sc, "no LOD", *[ratios_nolod[sc, n] for n in samples]])
    n7 = samples[0]
    close = ratios.get(("head_cheek", n7), float("nan"))
    all_r = list(ratios.values())
    nolod = list(ratios_nolod.values())
    measured = (
        f"Sum of Gaussians (skin_deon6: 6 Gaussians, 12 passes) over pre-integrated (2 passes) "
        f"at {n7} taps: {close:.2g}× close-up; over every scene and tap count "
        f"{min(all_r):.2g}–{max(all_r):.2g}×; without its level of detail (all 12 passes at "
        f"every pixel) {min(nolod):.2g}–{max(nolod):.2g}×. Time grows about linearly with taps "
        "(figure)."
    )
    close_nolod = ratios_nolod.get(("head_cheek", n7), float("nan"))
    # "about 6×": within 20 % of 6, for what renders (with LOD) and for the convolution count
    # (no LOD); one of the two only is a partial reproduction
    near = [4.8 <= r <= 7.2 for r in (close, close_nolod)]
    in_range = all(near)
    return Section(
        TITLE,
        "Cost is about the number of convolutions (000 §8): the 12-pass sum of Gaussians "
        "against a 2-pass separable kernel, about 6× (000 §8, 002 Table 2); 004 Table 5.2 / "
        "Fig. 5.1 report 5.2× at close-up and time growing with samples per pass.",
        measured,
        "reproduced" if in_range else "partly reproduced" if any(near) else "not reproduced",
        f"Close-up at {n7} taps: {close:.2g}× with level of detail, {close_nolod:.2g}× without "
        "— the paper's ~6× (5.2× close-up) is the count of convolutions, which the no-LOD "
        "ratio measures; LOD lowers it as the head recedes (narrow Gaussians drop out)."
        if in_range
        else (
            f"Close-up at {n7} taps: {close:.2g}× (LOD), {close_nolod:.2g}× (no LOD), not ~6×. "
            "Likely reasons: the level of detail skips narrow Gaussians per pixel, and on a CPU "
            "the per-pass cost (stencil compaction, pixels per pass) differs from a GPU's; the "
            "papers time GPU shaders at 720p–1080p."
        ),
        body=md_table(rows, ["scene", "method", *[f"{n} taps (ms)" for n in samples]])
        + "\n\nSum of Gaussians / pre-integrated time ratio:\n\n"
        + md_table(ratio_rows, ["scene", "sum of Gaussians", *[f"{n} taps" for n in samples]])
        + f"\n\nResolution {res[0]}×{res[1]}, median of {repeats} repeats after one warm-up.",
        figures=[link],
        data={"ratios": {f"{k[0]}_{k[1]}": v for k, v in ratios.items()}},
    )


if __name__ == "__main__":
    sys.exit(main("cost", run))

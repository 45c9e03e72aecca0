"""Claim 1 — the skin kernel is low rank (000 §3 Fig. 2, 4, 7; 002 §3.1 Fig. 2).

Singular-value energy of the discretised skin kernel per channel (:func:`~sssbench.kernels.
low_rank`), and the error of the rank-1/3/6 SVD methods (:class:`~sssbench.ops.LowRankSSS`)
against the exact reference on ``step_edge`` and the close-up head (``head_cheek``: the
``head`` scene at the distance where the kernel spans several pixels).

    python -m experiments.run low_rank [--quick]
"""

from __future__ import annotations

import sys

import matplotlib.pyplot as plt
import torch

from experiments.common import Context, Section, errors, main, md_table, op_available, reference
from experiments.common import scene as make
from sssbench.kernels import low_rank
from sssbench.profiles import Dipole, SumOfGaussians

TITLE = "1. The skin kernel is low rank (000 Fig. 2, 4, 7; 002 Fig. 2)"
RANKS = (1, 3, 6)


def energy_part(ctx: Context) -> tuple[dict, plt.Figure]:
    n = 21 if ctx.quick else 101
    out = {}
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    for ax, (label, prof) in zip(
        axes,
        (
            ("skin_deon6 (6 Gaussians)", SumOfGaussians.from_table("skin_deon6")),
            ("Skin1 dipole", Dipole.from_material("skin1")),
        ),
        strict=True,
    ):
        ext = 4 * float(prof.length_scales()[1]) if isinstance(prof, SumOfGaussians) else 10.0
        lr = low_rank(prof, 1, extent=ext, n=n)
        s = lr.singular_values
        sq = lr.energy  # s² / Σ s² (library definition)
        lin = s / s.sum(0, keepdim=True)  # s / Σ s
        out[label] = {"sq": sq[:6].T.tolist(), "lin": lin[:6].T.tolist(), "extent": ext, "n": n}
        for c, col in enumerate("rgb"):
            ax.semilogy(range(1, 16), 100 * sq[:15, c], "-o", color=col, ms=3)
            ax.semilogy(range(1, 16), 100 * lin[:15, c], ":", color=col)
        ax.set_title(f"{label}: {n}² cells, ±{ext:.3g} mm")
        ax.set_xlabel("singular value index")
        ax.set_ylabel("energy (%)")
    axes[0].plot([], [], "k-o", ms=3, label="s_i² / Σ s²")
    axes[0].plot([], [], "k:", label="s_i / Σ s")
    axes[0].legend(fontsize=7)
    return out, fig


def error_part(ctx: Context) -> tuple[list, dict]:
    prof = SumOfGaussians.from_table("skin_deon6")
    cases = (
        [("step_edge", (4, 48)), ("head_cheek", (16, 16))]
        if ctx.quick
        else [("step_edge", (32, 256)), ("head_cheek", (96, 96))]
    )
    rows, data = [], {}
    for name, res in cases:
        g = make(name, res, fields=["mask"])
        ref = reference(name, res, prof)
        from sssbench.ops import LowRankSSS, PreintegratedSSS

        for rank in RANKS:
            op = LowRankSSS(prof, rank, n=21 if ctx.quick else 61, extent=4 * 7.41**0.5)
            with torch.inference_mode():
                e = errors(op(g), ref, g)
            ksum = [round(float(x), 3) for x in op.kernel_sum]
            rows.append([name, f"SVD rank {rank}", 2 * rank, e["rel_rms"], e["psnr"], str(ksum)])
            data[f"{name}_rank{rank}"] = e
        with torch.inference_mode():
            e = errors(PreintegratedSSS(prof, 9 if ctx.quick else 33)(g), ref, g)
        rows.append([name, "pre-integrated (33 taps)", 2, e["rel_rms"], e["psnr"], "[1, 1, 1]"])
        data[f"{name}_preint"] = e
    return rows, data


def run(ctx: Context) -> Section:
    energy, fig = energy_part(ctx)
    links = [ctx.figure(fig, "low_rank_energy")]
    first = {k: [v["sq"][c][0] for c in range(3)] for k, v in energy.items()}
    first_lin = {k: [v["lin"][c][0] for c in range(3)] for k, v in energy.items()}
    e_rows = [
        [
            k,
            *[
                f"{100 * a:.1f} / {100 * b:.1f}"
                for a, b in zip(first[k], first_lin[k], strict=True)
            ],
        ]
        for k in energy
    ]
    body = "First singular value's share, `s₁²/Σs²` / `s₁/Σs` (%):\n\n" + md_table(
        e_rows, ["kernel", "R", "G", "B"]
    )
    sk = first["skin_deon6 (6 Gaussians)"]
    sk_lin = first_lin["skin_deon6 (6 Gaussians)"]
    measured = (
        f"The first singular value holds {100 * min(sk):.0f}–{100 * max(sk):.0f} % of the "
        f"squared-singular-value energy of the 6-Gaussian skin kernel "
        f"({100 * min(sk_lin):.0f}–{100 * max(sk_lin):.0f} % of Σ s); the spectrum decays "
        "geometrically after a few values (figure)."
    )
    if op_available("LowRankSSS"):
        rows, data = error_part(ctx)
        body += "\n\nError against the exact reference (skin_deon6, mask region):\n\n" + md_table(
            rows, ["scene", "method", "passes", "rel_rms", "PSNR (dB)", "kernel sum R,G,B"]
        )
        errs = {r[0]: {} for r in rows}
        for r in rows:
            errs[r[0]][r[1]] = r[3]
        fig, ax = plt.subplots(figsize=(4.5, 3))
        for name, d in errs.items():
            ax.semilogy(RANKS, [d[f"SVD rank {k}"] for k in RANKS], "-o", label=name)
            ax.axhline(d["pre-integrated (33 taps)"], ls=":", lw=1, color=ax.lines[-1].get_color())
        ax.set_xlabel("SVD rank N (2N passes)")
        ax.set_ylabel("rel. RMS error")
        ax.set_title("dotted: pre-integrated (2 passes)")
        ax.legend(fontsize=7)
        links.append(ctx.figure(fig, "low_rank_error"))
        decreasing = all(
            d["SVD rank 1"] > d["SVD rank 3"] >= 0.95 * d["SVD rank 6"] for d in errs.values()
        )
        rank1_poor = all(d["SVD rank 1"] > 3 * d["SVD rank 6"] for d in errs.values())
        measured += (
            " Rank-1/3/6 relative RMS errors: "
            + "; ".join(
                f"{n} " + " / ".join(f"{d[f'SVD rank {k}']:.3g}" for k in RANKS)
                for n, d in errs.items()
            )
            + "."
        )
        ok = decreasing and rank1_poor
        # "~80 %" holds under both readings of "energy" (s1/Σs and s1²/Σs²) or only one
        near80 = all(0.7 < x < 0.9 for x in [*sk, *sk_lin])
        verdict = "reproduced" if ok and near80 else "partly reproduced"
        reason = (
            "Qualitatively as claimed: energy concentrates in the first singular value, rank 1 "
            "is clearly worse (it also loses energy: kernel sum < 1, 000 §3) and rank 3 already "
            "reaches the floor set by the kernel's cell discretisation (rank 6 ≈ rank 3), as "
            "000 Fig. 4/7 show. The “~80 %” of 002 Fig. 2 is not what we measure for most "
            "channels: the share depends on the undefined energy definition and on the "
            "discretisation (extent, cell size relative to the narrowest Gaussian) — we show "
            "both definitions."
        )
        if not ok:
            reason = "Not every expected ordering holds (see table). " + reason
    else:
        data = {}
        verdict = "pending"
        reason = "Energy part done; rank-N errors wait for `LowRankSSS` (not landed)."
    return Section(
        TITLE,
        "“most of the energy of typical diffusion kernels is stored in the first few singular "
        "values, and in particular in the first one” (000 §3, Fig. 2); “the first eigen value "
        "storing most of the total energy (~80 %)” (002 §3.1, Fig. 2); “Using the SVD’s rank-1 "
        "… leads to poor results … Higher-rank SVD-based approximations (N ≈ 2–6) converge very "
        "rapidly to the original kernel” (000 §3, Fig. 4, 7).",
        measured,
        verdict,
        reason,
        body=body,
        figures=links,
        data={"first_energy": first, "errors": data},
    )


if __name__ == "__main__":
    sys.exit(main("low_rank", run))

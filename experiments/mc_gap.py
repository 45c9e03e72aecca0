"""The gap: the diffusion-profile reference against Monte Carlo light transport, next to each
screen-space method's error against both (issue 19, item 4).

For every scene with an analytic Monte Carlo model (:data:`data_synth.mc_scenes.MC_SCENES`:
a plane with a shadow edge, a light dot, a thin slab lit from behind through a window — with
and without the translucency stage — and a sphere under a directional light), every method
and the do-nothing baseline ``identity`` run as the app runs them with ``reference=mc``
(:func:`sssbench.app.compose_spec`, :func:`sssbench.run.runner.execute`; profile ``skin_jg10``,
simulated as the measured skin1 of JMLH01). Each run stores its relative RMS error against
the exact profile reference (``rel_rms``) and against the MC, noise-corrected
(``rel_rms_mc``, with its jackknife standard error), and the profile reference's own error
against the MC (``reference_vs_mc``, the diffusion model's — and the profile table's — own
error). Per scene the verdict compares ``reference_vs_mc`` with the best method's
``rel_rms``: when the first is larger, a better profile would matter more than a better
screen-space method.

Cost: the MC's collisions per second (``mc_photons``, ``mc_seconds``) of each scene, as run
(cache hits keep the time of the run that filled the cache), and a timed walk on 1 and 2
worker processes: wall time, CPU time (with a core per process, 2 processes would run at
2 × collisions / CPU seconds), the one-off compilation of the fused walk step and the load
average while measuring. The verdict's speed target is wall time on 2 cores.

    python -m experiments.run mc_gap [--quick]
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from experiments.common import Context, Section, main, md_table
from sssbench import _json
from sssbench.app import compose_spec
from sssbench.run import runner

TITLE = "The gap: diffusion profiles and screen-space methods against light transport"
METHODS = ["identity", "preintegrated", "sum_of_gaussians", "low_rank", "jimenez2012"]
#: (label, overrides) of the scenes
SCENES = [
    ("step_edge", ["scene=step_edge"]),
    ("light_dot", ["scene=light_dot"]),
    ("backlit_slab", ["scene=backlit_slab"]),
    ("backlit_slab + translucency", ["scene=backlit_slab", "translucency=on"]),
    ("sphere", ["scene=sphere"]),
]


def _runs(ctx: Context) -> list[dict]:
    res = 32 if ctx.quick else 128
    scenes = [SCENES[0], SCENES[-1]] if ctx.quick else SCENES
    methods = METHODS[:2] if ctx.quick else METHODS
    fixed = [
        f"resolution=[{res},{res}]",
        "repeats=1",
        "warmup=0",
        "budget=false",
        "previews=false",
        "reference=mc",
        "profile=skin_jg10",
    ]
    # photons: the flat scenes' kernel serves every pixel; the sphere's 128² need ~3 000 per
    # pixel that shows it for a ~1e-3 resolution of the noise-corrected errors
    photons = {"sphere": 30_000 if ctx.quick else 16_000_000}
    rows = []
    with tempfile.TemporaryDirectory(prefix="sssbench-mc-gap-") as tmp:
        store = Path(tmp) / "runs.sqlite"
        for label, overrides in scenes:
            for method in methods:
                n = photons.get(label, 30_000 if ctx.quick else 2_000_000)
                budget = f"+reference_params.mc_photons={n}"
                spec = compose_spec(f"method={method}", *overrides, *fixed, budget, store=store)
                run_dir = Path(tmp) / f"{label}-{method}".replace(" ", "_")
                out = runner.execute(spec, run_dir)
                if out.status != "ok":
                    raise RuntimeError(f"{label} / {method}: {out.status}: {out.message}")
                payload = _json.loads((run_dir / "metrics.json").read_text())
                keep = ("mc_photons", "mc_seconds")
                rows.append({"scene": label, "method": method, **out.metrics,
                             **{k: payload[k] for k in keep}})  # fmt: skip
    return rows


def _scene_cost(ctx: Context) -> dict[str, float]:
    """Collisions per second of the sphere's walks (64², 4 batches) in 1 and 2 worker
    processes (wall time, fork included; not cached), their CPU time, the one-off compilation
    of the fused step (timed first, before either) and the machine's load while measuring."""
    import os
    import time

    import data_synth
    from sssbench.mc.scene import sphere_walk_rate
    from sssbench.mc.transport import _STEP, Ball, warm_up

    g = data_synth.make_scene("sphere", (64, 64), fields=[])
    t0 = time.perf_counter()
    warm_up(Ball((0.0, 0.0, 0.0), 1.0))
    out = {"compile_s": time.perf_counter() - t0, "compiled": float(_STEP.active)}
    photons = 60_000 if ctx.quick else 4_000_000
    load0 = os.getloadavg()[0]
    for workers in (1, 2):
        inter, wall, cpu = sphere_walk_rate(g, "skin1", photons=photons, workers=workers)
        out[f"rate_{workers}"] = inter / wall
        out[f"wall_{workers}"] = wall
        out[f"cpu_{workers}"] = cpu
        out["interactions"] = inter
    # each of the 2 processes on a core of its own: collisions per CPU second, times 2
    out["rate_cpu_2"] = 2 * out["interactions"] / out["cpu_2"]
    out["load"] = 0.5 * (load0 + os.getloadavg()[0])
    out["cores"] = float(os.cpu_count() or 1)
    return out


def _verdicts(rows: list[dict]) -> list[str]:
    """One sentence per scene, computed from its numbers."""
    out = []
    for label in dict.fromkeys(r["scene"] for r in rows):
        sel = [r for r in rows if r["scene"] == label]
        gap = sel[0]["reference_vs_mc"]
        gap_se = sel[0]["reference_vs_mc_se"]
        methods = [r for r in sel if r["method"] != "identity"]
        best = min(methods, key=lambda r: r["rel_rms"])
        best_mc = min(methods, key=lambda r: r["rel_rms_mc"])
        base = next(r for r in sel if r["method"] == "identity")
        if abs(gap - best["rel_rms"]) <= 2 * gap_se:
            lead = (
                f"on **{label}** the MC cannot tell whether the profile or the method matters "
                f"more: the profile reference is {100 * gap:.3g} ± {100 * gap_se:.2g} % from "
                f"light transport, the best method ({best['method']}) "
                f"{100 * best['rel_rms']:.3g} % from the profile reference"
            )
        elif gap > best["rel_rms"]:
            lead = (
                f"on **{label}** a better profile would matter more than a better screen-space "
                f"method: the profile reference is {100 * gap:.3g} ± {100 * gap_se:.2g} % from "
                f"light transport, the best method ({best['method']}) {100 * best['rel_rms']:.3g}"
                " % from the profile reference"
            )
        else:
            lead = (
                f"on **{label}** the screen-space method matters more than the profile: the "
                f"best method ({best['method']}) is {100 * best['rel_rms']:.3g} % from the "
                f"profile reference, which is {100 * gap:.3g} ± {100 * gap_se:.2g} % from "
                "light transport"
            )
        beats = best_mc["rel_rms_mc"] < base["rel_rms_mc"]
        tail = (
            f"; against transport the closest is {best_mc['method']} "
            f"({100 * best_mc['rel_rms_mc']:.3g} %), "
            + (
                f"better than doing nothing (identity {100 * base['rel_rms_mc']:.3g} %)"
                if beats
                else f"no better than doing nothing (identity {100 * base['rel_rms_mc']:.3g} %)"
            )
        )
        out.append(lead + tail + ".")
    return out


def run(ctx: Context) -> Section:
    cost = _scene_cost(ctx)  # first: its warm-up is this process's compilation of the step
    rows = _runs(ctx)
    labels = list(dict.fromkeys(r["scene"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    table = md_table(
        [
            [
                r["scene"],
                r["method"],
                f"{100 * r['rel_rms']:.3g}",
                f"{100 * r['rel_rms_mc']:.3g} ± {100 * r['rel_rms_mc_se']:.2g}",
            ]
            for r in rows
        ],
        ["scene", "method", "vs profile reference (%)", "vs Monte Carlo, noise-corrected (%)"],
    )
    gaps = md_table(
        [
            [
                lab,
                f"{100 * r['reference_vs_mc']:.3g} ± {100 * r['reference_vs_mc_se']:.2g}",
                f"{r['mc_photons']:.3g}",
                f"{r['mc_seconds']:.3g}",
            ]
            for lab in labels
            for r in [next(x for x in rows if x["scene"] == lab)]
        ],
        ["scene", "profile reference vs MC (%)", "MC photons", "MC walks (s, all batches)"],
    )
    fig, ax = plt.subplots(figsize=(8, 3.6))
    x = np.arange(len(labels))
    width = 0.8 / (len(methods) + 1)
    gap_vals = [next(r for r in rows if r["scene"] == lab)["reference_vs_mc"] for lab in labels]
    ax.bar(x - 0.4 + width / 2, 100 * np.array(gap_vals), width, color="k",
           label="profile reference vs MC")  # fmt: skip
    for j, m in enumerate(methods):
        vals = [next(r for r in rows if r["scene"] == lab and r["method"] == m) for lab in labels]
        ax.bar(x - 0.4 + (j + 1.5) * width, [100 * v["rel_rms"] for v in vals], width,
               label=f"{m} vs profile", alpha=0.85)  # fmt: skip
        ax.scatter(x - 0.4 + (j + 1.5) * width, [100 * v["rel_rms_mc"] for v in vals],
                   marker="x", color="k", s=14, zorder=3)  # fmt: skip
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("relative RMS error (%)")
    ax.set_title("bars: error vs the profile reference; ×: vs Monte Carlo (noise-corrected)")
    ax.legend(fontsize=6, ncol=2)
    link = ctx.figure(fig)
    sentences = _verdicts(rows)
    closer = sum(
        1 for lab in labels
        if next(r for r in rows if r["scene"] == lab)["reference_vs_mc"]
        > min(r["rel_rms"] for r in rows if r["scene"] == lab and r["method"] != "identity")
    )  # fmt: skip
    res = 32 if ctx.quick else 128
    mc_rates = [r["mc_photons"] for r in rows]
    measured = (
        f"{len(labels)} scenes at {res}², {len(methods)} methods (with the baseline identity), "
        f"profile skin_jg10, Monte Carlo of skin1 (JMLH01, η = 1.3). On {closer} of "
        f"{len(labels)} scenes the exact profile reference is farther from light transport "
        f"than the best screen-space method is from the profile reference. MC cost (sphere "
        f"64², {cost['interactions']:.3g} collisions): {cost['rate_1']:.3g} collisions/s in "
        f"1 process, {cost['rate_2']:.3g}/s in 2 (wall {cost['wall_1']:.3g} s and "
        f"{cost['wall_2']:.3g} s, fork included; target 2e7/s on 2 cores); CPU time "
        f"{cost['cpu_1']:.3g} s and {cost['cpu_2']:.3g} s, i.e. {cost['rate_cpu_2']:.3g}/s with "
        f"a core per process; the walk step "
        + (
            f"compiled once per process in {cost['compile_s']:.3g} s (before the timings; "
            "inductor's disk cache, when warm, makes this a load). "
            if cost["compiled"]
            else "ran eagerly (torch.compile unavailable or disabled). "
        )
        + f"Load average while measuring: {cost['load']:.2g} on {cost['cores']:.0f} cores"
        + (" (shared machine: the wall rates are lower bounds)." if cost["load"] > 1.5 else ".")
    )
    body = (
        "Per scene:\n\n- "
        + "\n- ".join(x[:1].upper() + x[1:] for x in sentences)
        + "\n\nThe profile reference's own error against light transport (the same for every "
        "method of a scene):\n\n"
        + gaps
        + "\n\nEvery run (relative RMS over the SSS region; the MC error has the MC variance "
        "subtracted, ± its jackknife standard error over 8 independent batches):\n\n"
        + table
        + "\n\nWhat is compared: the diffuse SSS result (the pipeline's image without the "
        "specular it adds), texturing off, against the MC exitance divided by the material's "
        "diffuse albedo at normal incidence (1 − F(0)) R_d, which is the irradiance itself on "
        "a uniformly lit plane, as a normalised profile gives (docs/mc.md). The profile "
        "reference's gap thus holds both the diffusion approximation's error and the "
        "difference between the published skin table and the measured skin1 (red light "
        "travels ~3.7 mm in skin1, 1/σ_tr), plus Fresnel and the angle of incidence on the "
        "sphere, which no profile models. Flat scenes are computed through an MC pixel-transfer "
        "kernel (exact convolution, so their noise is correlated across pixels; the jackknife "
        "accounts for it)."
    )
    # issue 19's targets: >= 2e7 collisions/s on 2 cores; a 128² reference in <= 10 min
    # with a noise-corrected error resolution of 1e-3
    sphere = [r for r in rows if r["scene"] == "sphere"]
    worst_se = max(r["rel_rms_mc_se"] for r in sphere) if sphere else math.nan
    mc_minutes = (sphere[0]["mc_seconds"] / 60) if sphere else math.nan
    fast = cost["rate_2"] >= 2e7
    fast_cpu = cost["rate_cpu_2"] >= 2e7
    resolved = worst_se <= 1e-3 and mc_minutes <= 10
    # the target is wall time on 2 cores; CPU time says what 2 free cores would give
    verdict = "target met" if fast and resolved else "target not met"
    reason = (
        f"Cost: {cost['rate_2']:.3g} collisions/s on 2 processes in wall time, "
        f"{cost['rate_cpu_2']:.3g}/s in CPU time with a core per process "
        f"({'meets' if fast else 'misses'} 2e7/s in wall time, "
        f"{'meets' if fast_cpu else 'misses'} it in CPU time); the sphere's MC reference at "
        f"{res}² took "
        f"{mc_minutes:.3g} min of walks with a largest noise-corrected error standard error of "
        f"{worst_se:.2g} ({'meets' if resolved else 'misses'} 1e-3 within 10 min). "
        + (sentences[-1][:1].upper() + sentences[-1][1:] if sentences else "")
    )
    return Section(
        TITLE,
        "Issue 19: a screen-space method is only as good as the profile it approximates; the "
        "exact profile reference says nothing about how far the profile itself is from light "
        "transport (000 Fig. 6 and 004 used Monte Carlo references).",
        measured,
        verdict,
        reason,
        body=body,
        figures=[link],
        data={"rows": rows, "cost": cost, "photons": mc_rates},
    )


if __name__ == "__main__":
    sys.exit(main("mc_gap", run))

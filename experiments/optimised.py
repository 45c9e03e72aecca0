"""Beyond the papers — taps optimised through the passes against the published rules (issue 18).

For 5, 7, 9 and 13 taps at the portrait (0.3 mm/px) and medium (1 mm/px) scales, the
pre-integrated kernel's taps are fitted by gradient descent through the method's own two
depth-aware passes (:func:`sssbench.tune.optimise.optimise`, default training set: a
textured face, a shadow edge and a light disc at 96²) and evaluated on HELD-OUT scenes that
share nothing with the training set (other geometry, textures and seeds, 128²): the procedural
head, the sphere, and the skin patch textured by a photograph (``pores``). The error is the SSS
stage's (the method's scattered diffuse against the exact :class:`~sssbench.ops.ReferenceSSS`,
rel RMS over the mask), against the best of the published rules (importance, uniform, power)
at equal taps and passes, with the do-nothing baseline (identity). The error budget
(:mod:`sssbench.score.budget`) of the importance kernel at 7 taps shows what limits the gain.

    python -m experiments.run optimised [--quick]
"""

from __future__ import annotations

import os
import sys
import time

import matplotlib.pyplot as plt
import torch

from experiments.common import Context, Section, main, md_table
from sssbench.ops import IdentitySSS, Jimenez2012SSS, PreintegratedSSS, SumOfGaussiansSSS
from sssbench.profiles import SumOfGaussians
from sssbench.score.budget import error_budget
from sssbench.score.metrics import rel_rms
from sssbench.score.verdict import (
    VISIBLE_FLIP,
    VISIBLE_LOCAL_FLIP,
    VISIBLE_WINDOW,
    is_visible,
    visibility_stats,
)
from sssbench.tune import optimise as opt

TITLE = "Beyond the papers: taps optimised through the passes (issue 18)"
SCALES = {"portrait": 0.3, "medium": 1.0}
TAPS = (5, 7, 9, 13)
RULES = ("importance", "uniform", "power")
#: held out: none of these scenes, textures or seeds is in opt.DEFAULT_TRAINING
HELD_OUT = (
    opt.TrainingScene("head", (128, 128), seed=7),
    opt.TrainingScene("sphere", (128, 128), seed=7),
    opt.TrainingScene("pores", (128, 128), seed=7),
)
#: the goal of issue 18: at least this much less error at these tap counts
GOAL, GOAL_TAPS = 0.30, (7, 9)
#: the other parametrisations (sssbench.kernels.parametrise), at the goal's tap counts: the sum
#: of Gaussians' per-Gaussian tap sets against its placement rules, the 2012 kernel's
#: strength / falloff / width against its published parameter sets (the shader's defaults as
#: configured, conf/method/jimenez2012.yaml, width 3 mm, and 002 Table 1's at that width)
JIMENEZ_WIDTH = 3.0
OTHERS = {
    "sum_of_gaussians": ({}, lambda prof, n, px: SumOfGaussiansSSS(prof, n, "optimised",
                                                                 pixel_mm=px)),
    "jimenez2012": (
        {"strength": (0.48, 0.41, 0.28), "falloff": (1.0, 0.37, 0.3), "width": JIMENEZ_WIDTH},
        lambda prof, n, px: Jimenez2012SSS.preset("shader_default", JIMENEZ_WIDTH, n,
                                                  profile=prof, sampling="optimised",
                                                  pixel_mm=px),
    ),
}  # fmt: skip


def _error(method, g, ref) -> float:
    with torch.no_grad():
        return rel_rms(method(g), ref, (g.mask > 0).to(ref.dtype))


def run(ctx: Context) -> Section:
    prof = SumOfGaussians.from_table("skin_deon6")
    taps = (5, 7) if ctx.quick else TAPS
    held = HELD_OUT
    training = opt.DEFAULT_TRAINING
    steps = None
    if ctx.quick:
        held = tuple(opt.TrainingScene(s.name, (24, 24), s.seed) for s in HELD_OUT[:2])
        training = (opt.TrainingScene("step_edge", (24, 24)),)
        steps = 3
    train_names = {(s.name, s.seed) for s in training}
    if train_names & {(s.name, s.seed) for s in held}:
        raise RuntimeError("training and held-out scenes overlap")

    rows, fits, data = [], [], {}
    fit_seconds: dict[str, float] = {}
    held_scenes: dict[str, list] = {}
    for scale, px in SCALES.items():
        scenes = held_scenes[scale] = []
        for s in held:
            g = s.build(px)
            scenes.append((s.name, g, opt.sss_reference(s, g, prof, px)))
        ident = {name: _error(IdentitySSS(), g, ref) for name, g, ref in scenes}
        # visible: the project's criterion (sssbench.score.verdict): the FLIP of the input against
        # the reference, its mean or its most-changed 7×7 window
        stats = {name: visibility_stats(ref, g.diffuse, g.mask) for name, g, ref in scenes}
        flips = {name: st[0] for name, st in stats.items()}
        seen = {name: is_visible(*st) for name, st in stats.items()}
        for n in taps:
            t0 = time.perf_counter()
            fit = opt.optimise(prof, taps=n, pixel_mm=px, training=training, steps=steps)
            if n == 7:
                fit_seconds[scale] = fit.seconds
            how = "yes" if fit.cached else f"no ({time.perf_counter() - t0:.0f} s)"
            fits.append(["preintegrated", scale, n, fit.start, fit.init_loss, fit.loss,
                         fit.seconds, how])  # fmt: skip
            method = PreintegratedSSS(prof, n, "optimised", pixel_mm=px)
            for name, g, ref in scenes:
                rule_err = {r: _error(PreintegratedSSS(prof, n, r), g, ref) for r in RULES}
                best_rule = min(rule_err, key=rule_err.get)
                e_opt = _error(method, g, ref)
                gain = 1.0 - e_opt / rule_err[best_rule]
                data[f"{scale}/{n}/{name}"] = {
                    "identity": ident[name], **rule_err, "best_rule": best_rule,
                    "optimised": e_opt, "reduction": gain, "flip": flips[name],
                    "visible": seen[name],
                }  # fmt: skip
                rows.append([scale, n, name, "yes" if seen[name] else "no",
                             ident[name], *rule_err.values(),
                             best_rule, e_opt, f"{100 * gain:.0f} %"])  # fmt: skip

    # the other parametrisations at the goal's tap counts, against their published starts
    other_rows, others = [], {}
    other_taps = (7,) if ctx.quick else GOAL_TAPS
    for name, (options, make) in OTHERS.items():
        spec = opt.METHOD_FITS[name]
        for scale, px in SCALES.items():
            for n in other_taps:
                t0 = time.perf_counter()
                fit = opt.optimise(prof, name, n, px, training=training, steps=steps,
                                   options=options)  # fmt: skip
                how = "yes" if fit.cached else f"no ({time.perf_counter() - t0:.0f} s)"
                fits.append([name, scale, n, fit.start, fit.init_loss, fit.loss, fit.seconds,
                             how])  # fmt: skip
                method = make(prof, n, px)
                published = spec.starts(prof, n, opt.method_options(name, options))
                for sname, g, ref in held_scenes[scale]:
                    errs = {k: _error(m, g, ref) for k, m in published.items()}
                    best = min(errs, key=errs.get)
                    e_opt = _error(method, g, ref)
                    case = data[f"{scale}/{n}/{sname}"]
                    gain = 1.0 - e_opt / errs[best]
                    others[f"{name}/{scale}/{n}/{sname}"] = {
                        "identity": case["identity"], **errs, "best_rule": best,
                        "optimised": e_opt, "reduction": gain, "visible": case["visible"],
                        "params": fit.params,
                    }  # fmt: skip
                    other_rows.append([name, scale, n, sname,
                                       "yes" if case["visible"] else "no", case["identity"],
                                       best, errs[best], e_opt, f"{100 * gain:.0f} %"])  # fmt: skip

    # what limits it: the error budget at 7 taps of each method's published kernel
    # (docs/error_budget.md): the pre-integrated importance kernel, the sum of Gaussians'
    # uniform taps (003), the 2012 shader's defaults at the configured width
    budget_rows = []
    budgets = {
        "preintegrated": ("importance", lambda k: PreintegratedSSS(prof, k)),
        "sum_of_gaussians": ("uniform", lambda k: SumOfGaussiansSSS(prof, k)),
        "jimenez2012": ("given", lambda k: Jimenez2012SSS.preset("shader_default",
                                                                 JIMENEZ_WIDTH, k)),
    }  # fmt: skip
    if not ctx.quick:
        for method, (start, build) in budgets.items():
            for scale, px in SCALES.items():
                for s in held:
                    g = s.build(px).to(torch.float64)
                    ref = opt.sss_reference(s, s.build(px), prof, px)
                    b = error_budget(build, 7, g, prof, reference=ref, recon=False)
                    key = f"{scale}/7/{s.name}"
                    case = data[key] if method == "preintegrated" else others[f"{method}/{key}"]
                    budget_rows.append([method, start, scale, s.name, b.total, b.taps,
                                        b.model, b.screen, b.contributions["taps"],
                                        case["optimised"]])  # fmt: skip
                    data[f"budget/{method}/{scale}/{s.name}"] = b.as_dict()

    # item 5: one fresh 7-tap fit timed (wall and this process's CPU time, 1 torch thread)
    timing = None
    if not ctx.quick:
        wall, cpu = time.perf_counter(), time.process_time()
        opt.optimise(prof, taps=7, pixel_mm=SCALES["portrait"], cache=False)  # refs cached
        timing = (time.perf_counter() - wall, time.process_time() - cpu, os.getloadavg()[0])

    # figure: error against taps per scale, per held-out scene
    fig, axes = plt.subplots(1, len(SCALES), figsize=(9, 3.3), sharey=True)
    colours = dict(zip([s.name for s in held], ["C0", "C1", "C2"], strict=False))
    for ax, (scale, px) in zip(axes, SCALES.items(), strict=True):
        for s in held:
            d = [data[f"{scale}/{n}/{s.name}"] for n in taps]
            c = colours[s.name]
            ax.plot(taps, [min(x[r] for r in RULES) for x in d], "--o", c=c, ms=3,
                    label=f"{s.name}: best rule")  # fmt: skip
            ax.plot(taps, [x["optimised"] for x in d], "-s", c=c, ms=3,
                    label=f"{s.name}: optimised")  # fmt: skip
            ax.axhline(d[0]["identity"], c=c, ls=":", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("taps per pass")
        ax.set_title(f"{scale} ({px} mm/px); dotted: identity", fontsize=9)
    axes[0].set_ylabel("held-out rel. RMS (SSS stage)")
    axes[-1].legend(fontsize=6)
    link = ctx.figure(fig)

    # the verdict, from the numbers
    cases = {k: v for k, v in data.items() if not k.startswith("budget")}
    visible = {k: v for k, v in cases.items() if v["visible"]}
    goal_cases, met_gain, worse, worse_visible, gains = _goal(cases)
    ok = bool(goal_cases) and len(met_gain) == len(goal_cases) and not worse
    other_text = []
    for name in OTHERS:
        mine = {k.split("/", 1)[1]: v for k, v in others.items() if k.startswith(f"{name}/")}
        g_cases, g_met, g_worse, g_worse_visible, g_gains = _goal(mine)
        ok = ok and bool(g_cases) and len(g_met) == len(g_cases) and not g_worse
        other_text.append(
            f"{name}: {100 * min(g_gains, default=float('nan')):.0f}–"
            f"{100 * max(g_gains, default=float('nan')):.0f} % less error than its best "
            f"published start where SSS is visible ({len(g_met)} of {len(g_cases)} reach "
            f"{GOAL:.0%}), more error in {len(g_worse)} of {len(mine)} cases"
            + (f" ({', '.join(g_worse)})" if g_worse else "")
            + f", {len(g_worse_visible)} of them visible"
        )
    t7 = ", ".join(f"{k} {v:.0f} s" for k, v in fit_seconds.items())
    n_visible = len({(k.split("/")[0], k.split("/")[2]) for k in visible})
    measured = (
        f"On {len(held)} held-out scenes at {len(SCALES)} scales, SSS is visible (FLIP of "
        f"the input against the reference ≥ {VISIBLE_FLIP} on average or ≥ "
        f"{VISIBLE_LOCAL_FLIP} over its most-changed {VISIBLE_WINDOW}×{VISIBLE_WINDOW} window, "
        "sssbench.score.verdict) in "
        f"{n_visible} scene-scale cases. "
        f"At {' and '.join(map(str, GOAL_TAPS))} taps the optimised "
        f"kernel has {100 * min(gains, default=float('nan')):.0f}–"
        f"{100 * max(gains, default=float('nan')):.0f} % less error than the best published "
        f"rule in these cases ({len(met_gain)} of {len(goal_cases)} reach {GOAL:.0%}); "
        f"over all tap counts and scenes it has more error than the best rule in {len(worse)} "
        f"of {sum(not k.startswith('budget') for k in data)} cases"
        + (f" ({', '.join(worse)})" if worse else "")
        + f", {len(worse_visible)} of them where SSS is visible. The other "
        f"parametrisations at {' and '.join(map(str, other_taps))} taps, against their "
        "published starts at equal taps and passes: "
        + "; ".join(other_text)
        + f". One 7-tap fit (3 training scenes at 96², 1 torch thread), as stored: {t7}"
        + (
            f"; timed afresh in this run at the portrait scale (training references from the "
            f"cache): {timing[0]:.0f} s wall, "
            f"{timing[1]:.0f} s CPU (≤ 300 s: {'yes' if timing[0] <= 300 else 'no'} wall, "
            f"{'yes' if timing[1] <= 300 else 'no'} CPU; 1-minute load average "
            f"{timing[2]:.1f} on {os.cpu_count()} cores at the end of the fit"
            + (
                ", so the wall time is inflated: the CPU time is what one core spends)"
                if timing[2] > 1.0
                else ")"
            )
            if timing
            else ""
        )
        + "."
    )
    reason = (
        f"Goal (≥ {GOAL:.0%} less error at 7 and 9 taps on every held-out scene where SSS is "
        f"visible, never more error): {'met' if ok else 'not met'}. "
        + _limits(data, others, budget_rows)
    )
    body = (
        "Held-out error (rel RMS of the SSS stage over the mask; skin_deon6; 128²; the "
        "optimised kernel was fitted on face, step_edge and light_dot at 96² — other scenes, "
        "textures and seeds):\n\n"
        + md_table(
            rows,
            [
                "scale",
                "taps",
                "scene",
                "SSS visible",
                "identity",
                *RULES,
                "best rule",
                "optimised",
                "less error",
            ],
        )  # fmt: skip
        + "\n\nFits (training loss: the mean over the training scenes of the rel RMS divided "
        "by the best published rule's on that scene, for the best single rule and the fitted "
        "kernel; seconds of the fit as "
        "stored with the cached kernel; 1 torch thread on a 2-core machine shared with 5 "
        "other jobs, so times are inflated):\n\n"
        + md_table(
            fits,
            [
                "method",
                "scale",
                "taps",
                "start",
                "best start (train)",
                "optimised (train)",
                "fit s",
                "cached",
            ],
        )  # fmt: skip
        + "\n\nThe other parametrisations (held-out rel RMS as above; the sum of Gaussians' "
        "per-Gaussian tap sets against its uniform / power / importance taps, the 2012 "
        "kernel's strength, falloff and width against the 2012 shader's defaults (given) and "
        f"002 Table 1's strength and falloff, both at the configured width {JIMENEZ_WIDTH} mm; "
        "equal taps and passes):\n\n"
        + md_table(
            other_rows,
            [
                "method",
                "scale",
                "taps",
                "scene",
                "SSS visible",
                "identity",
                "best published",
                "its error",
                "optimised",
                "less error",
            ],
        )  # fmt: skip
        + "\n\nFitted 2012 parameters (strength, falloff per channel; width mm): "
        + "; ".join(
            f"{k.split('/')[1]} {k.split('/')[2]} taps: t = "
            + "/".join(f"{x:.2f}" for x in v["params"]["strength"])
            + ", f = "
            + "/".join(f"{x:.2f}" for x in v["params"]["falloff"])
            + f", width {v['params']['width']:.2f}"
            for k, v in others.items()
            if k.startswith("jimenez2012/") and k.endswith("/head")
        )
    )
    if budget_rows:
        body += (
            "\n\nWhat limits it — the error budget at 7 taps of each method's published kernel "
            "(docs/error_budget.md; taps = M_7 − M_∞, model = the separable kernel against the "
            "profile on a flat plane, screen = the rest). Better taps can remove at most about "
            "the taps part; model and screen error belong to the separable model and the "
            "screen-space pass and stay:\n\n"
            + md_table(
                budget_rows,
                [
                    "method",
                    "kernel",
                    "scale",
                    "scene",
                    "total",
                    "taps",
                    "model",
                    "screen",
                    "taps contribution",
                    "optimised total",
                ],
            )  # fmt: skip
        )
    return Section(
        TITLE,
        "Issue 18 (not a paper's claim): every method places its taps by a rule from its paper "
        "that ignores the pixel grid and the depth-aware pass; taps fitted by gradient descent "
        "through the differentiable passes should have ≥ 30 % less error at 7 and 9 taps on "
        "held-out scenes, and never more.",
        measured,
        "target met" if ok else "target not met",
        reason,
        body=body,
        figures=[link],
        data={
            "cases": data,
            "other_methods": others,
            "fit_seconds_7": fit_seconds,
            "fresh_fit_wall_cpu_s": timing,
        },
    )


def _goal(cases: dict) -> tuple[dict, list, list, list, list]:
    """Of ``{"scale/taps/scene": case}``: the goal's cases (SSS visible, taps in
    :data:`GOAL_TAPS`), those reaching :data:`GOAL`, the cases with more error than the best
    published start (all, and where SSS is visible) and the goal cases' reductions."""
    goal_cases = {k: v for k, v in cases.items()
                  if v["visible"] and int(k.split("/")[1]) in GOAL_TAPS}  # fmt: skip
    met = [k for k, v in goal_cases.items() if v["reduction"] >= GOAL]
    worse = [k for k, v in cases.items() if v["reduction"] < 0]
    worse_visible = [k for k in worse if cases[k]["visible"]]
    return goal_cases, met, worse, worse_visible, [v["reduction"] for v in goal_cases.values()]


def _limits(data: dict, others: dict, budget_rows: list) -> str:
    """What limits the gain, from the 7-tap budget rows (computed, not fixed prose)."""
    parts = []
    for method, start, scale, name, total, taps, model, screen, _, e_opt in budget_rows:
        key = f"{scale}/7/{name}"
        case = data[key] if method == "preintegrated" else others[f"{method}/{key}"]
        if not case["visible"]:
            continue
        removed = 1.0 - e_opt / total
        parts.append(
            f"{method} {scale} {name}: the {start} kernel's {total:.3g} has a taps part of "
            f"{taps:.3g} ({taps / total:.0%} of it) beside model {model:.3g} and screen "
            f"{screen:.3g}; the fit {'removes' if removed >= 0 else 'adds'} {abs(removed):.0%} "
            "of it"
            + (" (more than the taps part: it also compensates part of the model and "
               "screen-space error on this scene)" if removed > taps / total else "")
            + f" and the best published start ({case['best_rule']}) "
            f"{max(0.0, 1 - case[case['best_rule']] / total):.0%}"
        )  # fmt: skip
    if not parts:
        return ""
    return (
        "What limits it (7 taps, the error budget of each method's published kernel on the "
        "visible cases): " + "; ".join(parts) + ". Where the best rule already leaves little "
        "taps error, what remains is the separable model's and the screen-space pass's (depth "
        "steps, silhouettes), which no choice of taps in two passes removes; the 2012 kernel's "
        "fit also changes its shape (strength, falloff, width), so it can remove model error "
        "too."
    )


if __name__ == "__main__":
    sys.exit(main("optimised", run))

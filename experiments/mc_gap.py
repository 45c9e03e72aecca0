"""The gap: the diffusion-profile reference against Monte Carlo light transport, next to each
screen-space method's error against both (issue 19, item 4; issue 31).

For every scene with an analytic Monte Carlo model (:data:`data_synth.mc_scenes.MC_SCENES`:
a plane with a shadow edge, a light dot, a thin slab lit from behind through a window — with
and without the translucency stage — and a sphere under a directional light), every method
and the do-nothing baseline ``identity`` run as the app runs them with ``reference=mc``
(:func:`sssbench.app.compose_spec`, :func:`sssbench.run.runner.execute`; profile ``skin_jg10``,
simulated as the measured skin1 of JMLH01). The images the runner scores are kept
(:func:`_capture`) and scored here against the same MC batches:

* **normalised** error: the diffuse image against the MC exitance divided by the MC's own
  diffuse albedo ``ρ_MC = (1 − F(0)) R_d`` (what the app's ``rel_rms_mc`` reports: radial
  shape, Fresnel and angle of incidence, curvature, thin parts — but no albedo error);
* **absolute** error, what a user sees: the diffuse image times the diffusion model's albedo
  of the material, ``ρ_dip = (1 − F(0)) R_d^dipole`` (a normalised profile carries no albedo;
  a renderer using diffusion theory gets it from the dipole), against the MC's physical
  exitance ``M``. The **albedo part** is the error of an image of exactly the MC's shape
  scaled by ``ρ_dip/ρ_MC`` (per channel, weighted by the image's energy).

Both with the MC noise subtracted and a jackknife standard error over the MC's independent
batches; differences between two images are paired (the same deleted batch for both,
:func:`sssbench.mc.significance.scene_errors`), and every verdict goes through
:func:`sssbench.mc.significance.compare` (resolved beyond ``K_SIGMA`` standard errors,
differences below :data:`TOL` are "no difference"). A scene where no method differs from
another beyond the noise is labelled "cannot rank".

Medium mismatch: the profile table ``skin_jg10`` is a fit to a skin model, not to skin1; its
radial energy distribution is tabulated against the skin1 searchlight MC and the skin1
dipole (both normalised), so the share of the gap that is the table's choice is visible.

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
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import torch

from experiments.common import Context, Section, main, md_table
from sssbench import _json
from sssbench.app import compose_spec
from sssbench.mc.boundary import normal_specular
from sssbench.mc.significance import K_SIGMA, bootstrap, compare, scene_errors
from sssbench.run import runner
from sssbench.run.inputs import without_specular

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
PROFILE = "skin_jg10"
#: independent MC batches per scene (jackknife standard errors)
BATCHES = 16
#: differences of relative RMS errors below this are "no difference" (images equal to
#: rounding: a 4e-9 difference is no finding however small its noise)
TOL = 1e-4


@contextmanager
def _capture(store: list[dict]) -> Iterator[None]:
    """Keep the images the runner scores against the MC (the inputs of the runner's MC step,
    :func:`sssbench.run.mc_step.mc_metrics`:
    the run's result, the exact profile reference, the do-nothing baseline, the G-buffer and
    the spec), the runner itself unchanged."""
    original = runner.mc_metrics  # the name the runner's step calls

    def keep(spec, gbuffer, result, reference, identity):  # noqa: ANN001, ANN202
        out = original(spec, gbuffer, result, reference, identity)
        diffuse = {
            k: without_specular(v, gbuffer)[:1].detach().double().clone()
            for k, v in (("result", result), ("reference", reference), ("identity", identity))
        }
        store.append({"spec": spec, "gbuffer": gbuffer, **diffuse})
        return out

    runner.mc_metrics = keep
    try:
        yield
    finally:
        runner.mc_metrics = original


def _runs(ctx: Context) -> tuple[list[dict], list[dict]]:
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
        f"profile={PROFILE}",
        f"+reference_params.mc_batches={BATCHES}",
    ]
    # photons: the flat scenes' kernel serves every pixel; the sphere's 128² need ~3 000 per
    # pixel that shows it for a ~1e-3 resolution of the noise-corrected errors
    photons = {"sphere": 30_000 if ctx.quick else 16_000_000}
    rows, images = [], []
    with tempfile.TemporaryDirectory(prefix="sssbench-mc-gap-") as tmp, _capture(images):
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
                keep = ("mc_photons", "mc_seconds", "mc_material")
                rows.append({"scene": label, "method": method, **out.metrics,
                             **{k: payload[k] for k in keep}})  # fmt: skip
                images[-1]["label"], images[-1]["method"] = label, method
    return rows, images


def _scene_mc(spec, gbuffer):  # noqa: ANN001, ANN202 - the runner's MC of the run (cache hit)
    from sssbench.mc.scene import scene_mc

    opts = spec.mc_params
    return scene_mc(
        spec.scene,
        gbuffer,
        spec.scene_params,
        opts.get("mc_material", spec.profile),
        photons=opts.get("mc_photons"),
        batches=opts.get("mc_batches", 8),
        seed=opts.get("mc_seed", spec.seed),
        workers=opts.get("mc_workers"),
    )


def _dipole_albedo(material: str) -> torch.Tensor:
    """``(1 − F(0)) R_d`` of the dipole of the simulated material (η = 1.3)."""
    from sssbench.mc.scene import PROFILE_MATERIALS
    from sssbench.profiles import Dipole

    dip = Dipole.from_material(PROFILE_MATERIALS.get(material, material))
    return (1 - normal_specular(1.3)) * dip.total()


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


def _score(images: list[dict]) -> dict[str, dict]:
    """Per scene: normalised and absolute errors (± s.e.) of every method, the profile
    reference and identity; their paired differences; the albedo part."""
    out: dict[str, dict] = {}
    for label in dict.fromkeys(x["label"] for x in images):
        sel = [x for x in images if x["label"] == label]
        first = sel[0]
        spec, gbuffer = first["spec"], first["gbuffer"]
        mc = _scene_mc(spec, gbuffer)
        region = mc.mask & (gbuffer.mask_or_ones()[0, 0] > 0)
        imgs = {x["method"]: x["result"] for x in sel}
        imgs["profile reference"] = first["reference"]
        material = str(spec.mc_params.get("mc_material", spec.profile))
        rho_dip = _dipole_albedo(material)
        rho_mc, rho_se = mc.rho, mc.rho_stderr
        norm_err, norm_diff = scene_errors(imgs, mc.batches, region)
        abs_batches = mc.batches * rho_mc.view(1, 3, 1, 1)
        abs_imgs = {k: v * rho_dip.view(1, 3, 1, 1) for k, v in imgs.items()}
        abs_err, abs_diff = scene_errors(abs_imgs, abs_batches, region)
        # the albedo part: an image of the MC's own shape scaled by ρ_dip/ρ_MC, per channel
        # weighted by Σ M² over the region; s.e. by the bootstrap over ρ_MC
        m = abs_batches.mean(0)[:, region]
        w = (m * m).sum(1)

        def albedo_part(rho: torch.Tensor, w=w, rho_dip=rho_dip) -> torch.Tensor:  # noqa: ANN001
            a = rho_dip[None] / rho - 1
            return torch.sqrt((a * a * w).sum(-1) / w.sum())

        alb, alb_se = bootstrap(albedo_part, rho_mc, rho_se)
        out[label] = {
            "norm": norm_err,
            "abs": abs_err,
            "norm_diff": norm_diff,
            "abs_diff": abs_diff,
            "albedo_part": (float(alb), float(alb_se)),
            "albedo_rel": (
                (rho_dip / rho_mc - 1).tolist(),
                (rho_dip * rho_se / rho_mc**2).tolist(),
            ),
            "rho_mc": rho_mc.tolist(),
            "rho_dip": rho_dip.tolist(),
            "photons": int(mc.photons),
            "batches": int(mc.batches.shape[0]),
            "material": material,
        }
    return out


def _ranking(label: str, sc: dict, kind: str, methods: list[str]) -> tuple[str, dict]:
    """Ranking of the methods against transport by the rule: the resolved pairs, the
    methods that beat doing nothing; "cannot rank" when no pair is resolved."""
    err, diff = sc[kind], sc[f"{kind}_diff"]
    photons = sc["photons"]
    resolved, against_identity = 0, {}
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            d, s = diff(a, b)
            if compare(d, s, tol=TOL).resolved:
                resolved += 1
    for a in methods:
        if a != "identity":
            d, s = diff(a, "identity")
            against_identity[a] = compare(d, s, photons=photons, tol=TOL)
    best = min(methods, key=lambda k: err[k][0])
    tied = [
        k for k in methods
        if k != best and not compare(*diff(best, k), tol=TOL).resolved
    ]  # fmt: skip
    if resolved == 0:
        text = f"cannot rank (no pair of methods differs beyond {K_SIGMA:g} s.e. at " \
               f"{photons:.3g} photons)"  # fmt: skip
    else:
        text = f"closest {best} ({100 * err[best][0]:.3g} ± {100 * err[best][1]:.2g} %)"
        if tied:
            text += " tied (not resolved) with " + ", ".join(tied)

    def named(verdicts: tuple[str, ...]) -> str:
        return ", ".join(
            f"{a} ({100 * v.diff:+.2g} ± {100 * v.se:.1g} %)"
            for a, v in against_identity.items()
            if v.verdict in verdicts or (verdicts == ("",) and not v.resolved)
        )

    if "identity" in methods:
        parts = []
        for head, which in (
            ("better than doing nothing", ("closer",)),
            ("worse than doing nothing", ("worse",)),
            ("not distinguishable from doing nothing", ("",)),
        ):
            if named(which):
                parts.append(f"{head}: {named(which)}")
        text += "; " + "; ".join(parts)
    return text, {"resolved_pairs": resolved, "best": best, "tied": tied,
                  "vs_identity": {a: v.verdict for a, v in against_identity.items()}}  # fmt: skip


def _verdicts(rows: list[dict], scores: dict[str, dict]) -> tuple[list[str], dict]:
    """One sentence per scene, every comparison through the rule."""
    out, data = [], {}
    for label, sc in scores.items():
        sel = [r for r in rows if r["scene"] == label]
        methods = [r["method"] for r in sel]
        others = [r for r in sel if r["method"] != "identity"]
        best = min(others, key=lambda r: r["rel_rms"])
        photons = sc["photons"]
        parts = []
        for kind, name in (("norm", "normalised"), ("abs", "absolute")):
            gap, gap_se = sc[kind]["profile reference"]
            # the best method's error against the profile reference is noiseless
            v = compare(best["rel_rms"] - gap, gap_se, photons=photons, tol=TOL)
            if v.verdict == "closer":
                lead = "a better profile would matter more than a better screen-space method"
            elif v.verdict == "worse":
                lead = "the screen-space method matters more than the profile"
            else:
                lead = f"profile and method are {v.verdict}"
            rank, rdata = _ranking(label, sc, kind, methods)
            parts.append(
                f"{name}: {lead} (profile reference {100 * gap:.3g} ± {100 * gap_se:.2g} % from "
                f"transport, best method {best['method']} {100 * best['rel_rms']:.3g} % from "
                f"the profile reference); against transport {rank}"
            )
            data[f"{label}/{kind}"] = {"profile_vs_method": v.verdict, **rdata}
        alb, alb_se = sc["albedo_part"]
        out.append(
            f"**{label}** ({photons:.3g} photons, {sc['batches']} batches) — "
            + "; ".join(parts)
            + f". Albedo part of the absolute error: {100 * alb:.3g} ± {100 * alb_se:.2g} %."
        )
    return out, data


def _pct(v: object) -> str:
    """A share in % (3 digits), ``< 0.01`` below 0.01 %."""
    v = 100 * float(v)
    return "< 0.01" if v < 0.01 else f"{v:.3g}"


def _mismatch(quick: bool) -> tuple[str, list]:
    """The profile table against the simulated medium: share of the (normalised) energy per
    band of skin_jg10, of the skin1 dipole and of the skin1 searchlight MC (± s.e.)."""
    from experiments.mc_profiles import BANDS, PHOTONS, WORKERS, band_energy, radii_for
    from sssbench.mc import searchlight_result
    from sssbench.mc.scene import PROFILE_MATERIALS
    from sssbench.profiles import Dipole, SumOfGaussians

    material = PROFILE_MATERIALS[PROFILE]
    dip = Dipole.from_material(material)
    photons = 4000 if quick else PHOTONS
    res = searchlight_result(material, radii_for(dip), photons=photons, seed=0,
                             workers=1 if quick else WORKERS)  # fmt: skip
    table = SumOfGaussians.from_table(PROFILE)
    rows, data = [], []
    tot = res.reflected
    for lo, hi in BANDS:
        m, se = res.band(lo, hi)

        # the band's share of the total (its noise dominates: the total's relative s.e. is
        # several times smaller and positively correlated with the band's)
        frac, frac_se = m / tot, se / tot
        sog = band_energy(table, lo, hi) / table.total()
        dp = band_energy(dip, lo, hi) / dip.total()
        rows.append(
            [
                f"{lo:g}–{hi:g} mm",
                " / ".join(_pct(v) for v in sog),
                " / ".join(_pct(v) for v in dp),
                " / ".join(
                    f"{100 * float(f):.3g} ± {100 * float(s):.1g}"
                    for f, s in zip(frac, frac_se, strict=True)
                ),  # fmt: skip
            ]
        )
        data.append([sog.tolist(), dp.tolist(), frac.tolist(), frac_se.tolist()])
    head = [
        "band",
        f"{PROFILE} (% of its energy, R/G/B)",
        f"dipole of {material} (%)",
        f"MC {material}, {photons:.3g} photons (% ± s.e.)",
    ]
    return md_table(rows, head), data


def run(ctx: Context) -> Section:
    cost = _scene_cost(ctx)  # first: its warm-up is this process's compilation of the step
    rows, images = _runs(ctx)
    scores = _score(images)
    del images
    labels = list(scores)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    sentences, vdata = _verdicts(rows, scores)
    table_rows = []
    for r in rows:
        sc = scores[r["scene"]]
        n, a = sc["norm"][r["method"]], sc["abs"][r["method"]]
        table_rows.append(
            [
                r["scene"],
                r["method"],
                f"{100 * r['rel_rms']:.3g}",
                f"{100 * n[0]:.3g} ± {100 * n[1]:.2g}",
                f"{100 * a[0]:.3g} ± {100 * a[1]:.2g}",
            ]
        )
    table = md_table(
        table_rows,
        [
            "scene",
            "method",
            "vs profile reference (%)",
            "vs MC, normalised (%)",
            "vs MC, absolute (%)",
        ],
    )
    gaps = md_table(
        [
            [
                lab,
                f"{100 * sc['norm']['profile reference'][0]:.3g} ± "
                f"{100 * sc['norm']['profile reference'][1]:.2g}",
                f"{100 * sc['abs']['profile reference'][0]:.3g} ± "
                f"{100 * sc['abs']['profile reference'][1]:.2g}",
                f"{100 * sc['albedo_part'][0]:.3g} ± {100 * sc['albedo_part'][1]:.2g}",
                " / ".join(
                    f"{100 * e:+.3g} ± {100 * s:.1g}"
                    for e, s in zip(*sc["albedo_rel"], strict=True)
                ),
                f"{sc['photons']:.3g}",
                f"{r['mc_seconds']:.3g}",
            ]
            for lab, sc in scores.items()
            for r in [next(x for x in rows if x["scene"] == lab)]
        ],
        [
            "scene",
            "profile reference vs MC, normalised (%)",
            "absolute (%)",
            "albedo part (%)",
            "ρ_dip/ρ_MC − 1 (%, R/G/B)",
            "MC photons",
            "MC walks (s)",
        ],
    )
    mismatch, mismatch_data = _mismatch(ctx.quick)
    fig, ax = plt.subplots(figsize=(8, 3.6))
    x = np.arange(len(labels))
    width = 0.8 / (len(methods) + 1)
    for kind, mk, col in (("norm", "o", "k"), ("abs", "s", "grey")):
        g = [scores[lab][kind]["profile reference"] for lab in labels]
        ax.errorbar(x - 0.4 + width / 2, [100 * v[0] for v in g], yerr=[100 * v[1] for v in g],
                    fmt=mk, color=col, ms=4,
                    label=f"profile reference vs MC ({kind})")  # fmt: skip
    for j, m in enumerate(methods):
        vals = [next(r for r in rows if r["scene"] == lab and r["method"] == m) for lab in labels]
        ax.bar(x - 0.4 + (j + 1.5) * width, [100 * v["rel_rms"] for v in vals], width,
               label=f"{m} vs profile", alpha=0.85)  # fmt: skip
        ax.errorbar(x - 0.4 + (j + 1.5) * width,
                    [100 * scores[lab]["norm"][m][0] for lab in labels],
                    yerr=[100 * scores[lab]["norm"][m][1] for lab in labels],
                    fmt="x", color="k", ms=4, zorder=3)  # fmt: skip
        ax.errorbar(x - 0.4 + (j + 1.5) * width,
                    [100 * scores[lab]["abs"][m][0] for lab in labels],
                    yerr=[100 * scores[lab]["abs"][m][1] for lab in labels],
                    fmt="+", color="grey", ms=5, zorder=3)  # fmt: skip
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("relative RMS error (%)")
    ax.set_title("bars: vs the profile reference; ×: vs MC normalised, +: absolute (± s.e.)",
                 fontsize=8)  # fmt: skip
    ax.legend(fontsize=6, ncol=2)
    link = ctx.figure(fig)
    res = 32 if ctx.quick else 128
    cannot = [
        lab for lab in labels
        if all(vdata[f"{lab}/{k}"]["resolved_pairs"] == 0 for k in ("norm", "abs"))
    ]  # fmt: skip
    profile_first = [
        lab for lab in labels if vdata[f"{lab}/abs"]["profile_vs_method"] == "closer"
    ]  # fmt: skip
    measured = (
        f"{len(labels)} scenes at {res}², {len(methods)} methods (with the baseline identity), "
        f"profile {PROFILE}, Monte Carlo of skin1 (JMLH01, η = 1.3; isotropic scattering with "
        f"σs′), {BATCHES} independent MC batches per scene. Against the absolute MC exitance "
        f"(what a user sees, albedo included), the exact profile reference is farther from "
        f"transport than the best method is from the profile reference, beyond "
        f"{K_SIGMA:g} s.e., on {len(profile_first)} of {len(labels)} scenes"
        + (f" ({', '.join(profile_first)})" if profile_first else "")
        + "; methods cannot be ranked against transport on "
        + (", ".join(cannot) if cannot else "no scene")
        + f". MC cost (sphere 64², {cost['interactions']:.3g} collisions): "
        f"{cost['rate_1']:.3g} collisions/s in 1 process, {cost['rate_2']:.3g}/s in 2 (wall "
        f"{cost['wall_1']:.3g} s and {cost['wall_2']:.3g} s, fork included; target 2e7/s on 2 "
        f"cores); CPU time {cost['cpu_1']:.3g} s and {cost['cpu_2']:.3g} s, i.e. "
        f"{cost['rate_cpu_2']:.3g}/s with a core per process; the walk step "
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
        "Per scene (every comparison by sssbench.mc.significance.compare: resolved beyond "
        f"{K_SIGMA:g} paired jackknife standard errors over the MC batches; differences below "
        f"{100 * TOL:g} % are 'no difference'; the numbers after a method are its error minus "
        "identity's, in percentage points, ± s.e.):\n\n- "
        + "\n- ".join(sentences)
        + "\n\nThe profile reference's own error against light transport (the same for every "
        "method of a scene). Normalised: both sides divided by their own diffuse albedo (the "
        "radial shape, Fresnel, angle of incidence, curvature, thin parts); absolute: the image "
        "times the dipole's diffuse albedo (1 − F(0)) R_d of skin1 against the physical MC "
        "exitance; the albedo part is what the dipole's albedo alone contributes:\n\n"
        + gaps
        + "\n\nEvery run (relative RMS over the SSS region; the MC errors have the MC variance "
        f"subtracted, ± jackknife standard errors over {BATCHES} batches):\n\n"
        + table
        + "\n\nMedium mismatch: the profile table is a fit to a skin model, the MC simulates "
        "the measured skin1. Share of each profile's energy per band (normalised to its total; "
        "the MC's total includes the cut-off energy):\n\n"
        + mismatch
        + "\n\nWhat is compared: the diffuse SSS result (the pipeline's image without the "
        "specular it adds), texturing off. The profile reference's gap thus holds both the "
        "diffusion approximation's error and the difference between the published skin table "
        "and the measured skin1 (table above), plus Fresnel and the angle of incidence on the "
        "sphere, which no profile models. Flat scenes are computed through an MC pixel-transfer "
        "kernel (exact convolution, so their noise is correlated across pixels; the jackknife "
        "over batches accounts for it). Physics: isotropic scattering with the reduced "
        "coefficient σs′ (similarity approximation; the material table gives no anisotropy)."
    )
    # issue 19's targets: >= 2e7 collisions/s on 2 cores; a 128² reference in <= 10 min
    # with a noise-corrected error resolution of 1e-3
    sphere = scores.get("sphere")
    worst_se = max(v[1] for v in sphere["norm"].values()) if sphere else math.nan
    sphere_row = next((r for r in rows if r["scene"] == "sphere"), None)
    mc_minutes = (sphere_row["mc_seconds"] / 60) if sphere_row else math.nan
    fast = cost["rate_2"] >= 2e7
    fast_cpu = cost["rate_cpu_2"] >= 2e7
    resolved = worst_se <= 1e-3 and mc_minutes <= 10
    verdict = "target met" if fast and resolved else "target not met"
    reason = (
        f"Cost: {cost['rate_2']:.3g} collisions/s on 2 processes in wall time, "
        f"{cost['rate_cpu_2']:.3g}/s in CPU time with a core per process "
        f"({'meets' if fast else 'misses'} 2e7/s in wall time, "
        f"{'meets' if fast_cpu else 'misses'} it in CPU time); the sphere's MC reference at "
        f"{res}² took {mc_minutes:.3g} min of walks with a largest noise-corrected error "
        f"standard error of {worst_se:.2g} ({'meets' if resolved else 'misses'} 1e-3 within "
        "10 min). " + (sentences[-1] if sentences else "")
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
        data={
            "rows": rows,
            "cost": cost,
            "verdicts": vdata,
            "errors": {
                lab: {k: sc[k] for k in ("norm", "abs", "albedo_part", "albedo_rel", "photons")}
                for lab, sc in scores.items()
            },
            "mismatch": mismatch_data,
        },
    )


if __name__ == "__main__":
    sys.exit(main("mc_gap", run))

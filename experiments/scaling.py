"""Cost as the work grows (issue 30): time against resolution, taps and covered pixels.

    python -m experiments.run scaling [--quick]

Times, through the public operators as the app builds them (:func:`experiments.methods.build`),
the two-pass pre-integrated kernel (002), the sum of Gaussians (000 / 003), the disk (HDRP) and
the exact reference (:class:`~sssbench.ops.ReferenceSSS`) on ``step_edge`` — a flat skin plane
at a fixed 0.2 mm per pixel, so a kernel's window in pixels is the same at every resolution and
the work is exactly pixels × taps × passes — along three axes:

- **resolution**: 256² → 4K (3840×2160) and 128², every pixel covered, each method's
  default taps;
- **taps** per pass (the disk: samples per pixel): 7 → 65, at :data:`TAPS_RES`;
- **covered pixels**: the stencil (mask) cut to a centred disc of 1/16 … all of the frame at
  :data:`COVER_RES` (every per-pixel pass computes only where ``mask > 0``).

Per point: the median wall time of ``op(g)`` (one thread, ``torch.inference_mode``) over
repeats interleaved across the methods (:data:`REPEATS`; one repeat for a call predicted over
:data:`SLOW_S`), after one untimed warm-up call. Along each axis a method's next point is
predicted from its last (time ∝ work) and skipped, with the reason stated, when the prediction
exceeds :data:`BUDGET_S` — the full section stays within ~10 minutes on an idle machine, and a
faster operator (a native disk) reaches further with no change here. Per method and axis, the
exponent ``k`` of ``t ≈ c · x^k`` is the least-squares slope in log-log with its standard error
``√(s² / Σ(ln x − mean)²)``, ``s²`` the residual variance over ``n − 2`` degrees of freedom.

The reference is timed twice: ``auto`` (what a run on this scene uses: FFT convolutions, this
plane's depth being constant) and ``multipole`` (what ``auto`` uses on a curved skin surface,
e.g. the face; far slower). The reference's peak memory at 4K (``auto``) is measured in a fresh
child process as in :mod:`experiments.reference_speed`: the peak resident set (``VmHWM``) after
resetting it once the scene is built, so the scene's own allocation is not counted.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import time
from typing import Any

import torch

from experiments.common import Context, Section, main, md_table
from experiments.common import scene as make_scene

PROFILE = "skin_deon6"
SCENE = "step_edge"
#: the resolution axis (H, W): 256² → 4K UHD, and 128² below it (a slope for the slow methods,
#: which the budget stops early)
RESOLUTIONS = ((128, 128), (256, 256), (512, 512), (1024, 1024), (2048, 2048), (2160, 3840))
QUICK_RESOLUTIONS = ((16, 16), (24, 24), (32, 32))
#: the taps axis and its resolution
TAPS = (7, 13, 25, 49, 65)
QUICK_TAPS = (7, 13, 25)
TAPS_RES = (256, 256)
#: the covered-pixels axis: fractions of the frame in the stencil, and its resolution
COVER = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0)
COVER_RES = (512, 512)
QUICK_COVER_RES = (32, 32)
#: interleaved repeats per point (one for a call predicted over SLOW_S seconds; FAST_REPEATS
#: for a call under FAST_S, whose median a loaded machine otherwise scatters)
REPEATS = 3
SLOW_S = 5.0
FAST_REPEATS = 9
FAST_S = 0.5
#: a point predicted to take longer than this (one call, seconds) is skipped
BUDGET_S = 60.0
#: the methods, in the plot's order: label -> (registry name, options)
METHODS = {
    "two-pass (pre-integrated)": ("preintegrated", {}),
    "sum of Gaussians": ("sum_of_gaussians", {}),
    "disk": ("disk", {}),
    "reference (auto: FFT here)": ("reference", {"method": "auto"}),
    "reference (multipole: curved skin)": ("reference", {"method": "multipole"}),
}
#: methods with taps (the taps axis)
WITH_TAPS = ("two-pass (pre-integrated)", "sum of Gaussians", "disk")


# ----------------------------------------------------------------------------- the fit
def fit_exponent(x: list[float], t: list[float]) -> tuple[float, float]:
    """Least-squares slope ``k`` of ``ln t = ln c + k ln x`` and its standard error.

    Args:
        x: the work (pixels, taps, covered pixels), > 0; at least two distinct values.
        t: the times, > 0, same length.

    Returns:
        ``(k, se)``; ``se`` is NaN with two points (no residual degree of freedom).
    """
    if len(x) != len(t) or len(x) < 2:
        raise ValueError(f"x and t must have the same length >= 2, got {len(x)} and {len(t)}")
    if min(x) <= 0 or min(t) <= 0:
        raise ValueError("x and t must be positive (log-log fit)")
    lx, lt = [math.log(v) for v in x], [math.log(v) for v in t]
    mx, mt = statistics.fmean(lx), statistics.fmean(lt)
    sxx = sum((a - mx) ** 2 for a in lx)
    if sxx == 0:
        raise ValueError("x must take at least two distinct values")
    k = sum((a - mx) * (b - mt) for a, b in zip(lx, lt, strict=True)) / sxx
    n = len(x)
    if n < 3:
        return k, float("nan")
    resid = [b - mt - k * (a - mx) for a, b in zip(lx, lt, strict=True)]
    s2 = sum(r * r for r in resid) / (n - 2)
    return k, math.sqrt(s2 / sxx)


# ----------------------------------------------------------------------------- timing
def _op(label: str, profile: Any, taps: int | None = None) -> Any:
    from experiments.methods import build
    from sssbench.run import registry

    name, options = METHODS[label]
    if name == "reference":
        from sssbench.ops import ReferenceSSS

        return ReferenceSSS(profile, **options)
    op = build(name, profile, taps)
    assert isinstance(op, registry.method_class(name))
    return op


def _disc_mask(g: Any, fraction: float) -> Any:
    """``g`` with its stencil cut to a centred disc of ``fraction`` of the frame's pixels."""
    _, h, w = g.shape
    if fraction >= 1.0:
        return g.replace(mask=torch.ones_like(g.depth))
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=torch.float64) - (h - 1) / 2,
        torch.arange(w, dtype=torch.float64) - (w - 1) / 2,
        indexing="ij",
    )
    r = math.sqrt(fraction * h * w / math.pi)
    mask = ((yy**2 + xx**2) <= r * r).to(g.depth.dtype)[None, None]
    return g.replace(mask=mask.expand_as(g.depth).contiguous())


def _wall(op: Any, g: Any) -> float:
    with torch.inference_mode():
        t = time.perf_counter()
        op(g)
        return time.perf_counter() - t


def _axis(
    points: list[tuple[float, Any, dict[str, int]]],
    labels: tuple[str, ...],
    profile: Any,
    ctx: Context,
) -> tuple[dict[str, list[tuple[float, float]]], list[str]]:
    """Time ``labels`` at each ``(x, make_gbuffer, {label: taps})`` of ``points`` (increasing
    work); a point predicted over the budget is skipped with the method's later points.
    Returns label -> [(x, seconds)] and one note per skipped method."""
    times: dict[str, list[tuple[float, float]]] = {m: [] for m in labels}
    stopped: set[str] = set()
    notes: list[str] = []
    budget = 2.0 if ctx.quick else BUDGET_S
    for x, make, taps in points:
        live = []
        for m in labels:
            if m in stopped:
                continue
            guess = times[m][-1][1] * x / times[m][-1][0] if times[m] else 0.0  # t ∝ work
            if guess > budget:
                stopped.add(m)
                notes.append(
                    f"{m} from x = {x:.4g} (one call predicted {guess:.0f} s > {budget:g} s)"
                )
                continue
            live.append((m, _op(m, profile, taps.get(m)), guess))
        if not live:
            continue
        g = make()
        for _, op, guess in live:  # warm-up (native builds, first-call costs) of quick calls
            if guess <= SLOW_S:
                _wall(op, g)
        samples: dict[str, list[float]] = {m: [] for m, _, _ in live}
        for rep in range(1 if ctx.quick else FAST_REPEATS):  # interleaved: load falls alike
            for m, op, guess in live:
                slowest = max(guess, min(samples[m])) if samples[m] else guess
                if rep > 0 and (slowest > SLOW_S or (rep >= REPEATS and slowest > FAST_S)):
                    continue
                samples[m].append(_wall(op, g))
        del g
        for m, _, _ in live:
            times[m].append((x, statistics.median(samples[m])))
        print(f"  x = {x:.4g}: " + ", ".join(f"{m} {times[m][-1][1]:.3g} s" for m, _, _ in live))
    return times, notes


def reference_peak_4k(size: tuple[int, int]) -> dict[str, float]:
    """In this process: build the scene, reset the peak RSS, time one default reference
    call; its seconds and peak resident memory (GiB; the scene's own peak excluded)."""
    import resource

    from sssbench.ops import ReferenceSSS
    from sssbench.profiles import SumOfGaussians

    torch.set_num_threads(1)
    g = make_scene(SCENE, size)
    op = ReferenceSSS(SumOfGaussians.from_table(PROFILE))
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        reset = True
    except OSError:
        reset = False
    with open("/proc/self/status") as f:
        rss0 = next(float(line.split()[1]) for line in f if line.startswith("VmRSS:"))
    t = _wall(op, g)
    peak = float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    if reset:
        with open("/proc/self/status") as f:
            peak = next(float(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    return {
        "seconds": t,
        "peak_gib": peak / 1024**2,
        "before_gib": rss0 / 1024**2,
        "reset": reset,
        "gbuffer_gib": sum(
            v.numel() * v.element_size() for v in vars(g).values() if isinstance(v, torch.Tensor)
        )
        / 1024**3,
    }


def _child_reference(size: tuple[int, int]) -> dict[str, float]:
    code = (
        "import json; from experiments.scaling import reference_peak_4k; "
        f"print(json.dumps(reference_peak_4k({size!r})))"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.run(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, env=env, check=True, text=True
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ----------------------------------------------------------------------------- the section
def _figure(ctx: Context, axes_data: dict[str, dict[str, list[tuple[float, float]]]]) -> str:
    import matplotlib.pyplot as plt

    titles = {
        "resolution": "resolution (pixels, all covered)",
        "taps": f"taps per pass ({TAPS_RES[0]}², disk: samples)",
        "covered": "covered pixels (stencil)",
    }
    fig, axs = plt.subplots(1, 3, figsize=(11, 3.4), sharey=False)
    for ax, (axis, data) in zip(axs, axes_data.items(), strict=True):
        for i, (m, pts) in enumerate(data.items()):
            if not pts:
                continue
            xs, ts = zip(*pts, strict=True)
            ax.loglog(xs, ts, "-o", ms=3, color=f"C{i}", label=m)
        ax.set_xlabel(titles[axis], fontsize=8)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axs[0].set_ylabel("wall time per call (s, median, 1 thread)", fontsize=8)
    handles, labels = axs[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=5, fontsize=7, frameon=False)
    fig.suptitle(f"Cost as the work grows: {SCENE}, {PROFILE}, 0.2 mm per pixel", fontsize=9)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    return ctx.figure(fig)


def run(ctx: Context) -> Section:
    from sssbench.profiles import SumOfGaussians

    profile = SumOfGaussians.from_table(PROFILE)
    load_before = os.getloadavg()[0]
    labels = tuple(METHODS)
    resolutions = QUICK_RESOLUTIONS if ctx.quick else RESOLUTIONS
    taps_axis = QUICK_TAPS if ctx.quick else TAPS
    taps_res = QUICK_RESOLUTIONS[0] if ctx.quick else TAPS_RES
    cover_res = QUICK_COVER_RES if ctx.quick else COVER_RES
    big = resolutions[-1]

    # the 4K reference first (a fresh process: its peak memory), then the in-process axes
    print(f"reference at {big[1]}×{big[0]} in a child process (peak memory) ...", flush=True)
    peak = _child_reference(big)
    data: dict[str, dict[str, list[tuple[float, float]]]] = {}
    notes: list[str] = []
    print("resolution axis", flush=True)

    def full(size: tuple[int, int]) -> Any:
        return lambda: _disc_mask(make_scene(SCENE, size), 1.0)

    auto_ref = labels[3]  # its largest point is the child's call
    others = tuple(m for m in labels if m != auto_ref)
    data["resolution"], n1 = _axis(
        [(float(h * w), full((h, w)), {}) for h, w in resolutions], others, profile, ctx
    )
    ref_pts, n2 = _axis(
        [(float(h * w), full((h, w)), {}) for h, w in resolutions[:-1]], (auto_ref,), profile, ctx
    )
    data["resolution"][auto_ref] = ref_pts[auto_ref] + [(float(big[0] * big[1]), peak["seconds"])]
    data["resolution"] = {m: data["resolution"][m] for m in labels}
    notes += n1 + n2

    print("taps axis", flush=True)
    data["taps"], n3 = _axis(
        [(float(n), full(taps_res), dict.fromkeys(WITH_TAPS, n)) for n in taps_axis],
        WITH_TAPS,
        profile,
        ctx,
    )
    notes += n3

    print("covered-pixels axis", flush=True)
    g_cover = make_scene(SCENE, cover_res)
    cover_points = []
    for f in COVER:
        covered = float((_disc_mask(g_cover, f).mask > 0).sum())
        cover_points.append((covered, lambda f=f: _disc_mask(g_cover, f), {}))
    data["covered"], n4 = _axis(cover_points, labels, profile, ctx)
    notes += n4
    load_after = os.getloadavg()[0]

    # fits
    fits: dict[tuple[str, str], tuple[float, float, int]] = {}
    for axis, per in data.items():
        for m, pts in per.items():
            if len(pts) >= 2:
                xs, ts = zip(*pts, strict=True)
                k, se = fit_exponent(list(xs), list(ts))
                fits[axis, m] = (k, se, len(pts))
    link = _figure(ctx, data)

    def fmt_fit(axis: str, m: str) -> str:
        if axis == "taps" and m not in WITH_TAPS:
            return "no taps"
        if (axis, m) not in fits:
            return "not fitted (under 2 points)"
        k, se, n = fits[axis, m]
        return f"{k:.2f} ± {se:.2f} (n={n})" if math.isfinite(se) else f"{k:.2f} (n={n})"

    fit_rows = [[m, *[fmt_fit(a, m) for a in ("resolution", "taps", "covered")]] for m in labels]
    time_rows = []
    for axis, per in data.items():
        for m, pts in per.items():
            for x, t in pts:
                time_rows.append([axis, m, f"{x:.6g}", f"{t * 1e3:.4g}"])

    # the verdict: the screen-space methods linear in pixels and in covered pixels (the work
    # is pixels × taps × passes); taps may be sub-linear (a fixed per-pixel cost per pass)
    screen = labels[:3]
    linear = [
        (a, m)
        for a in ("resolution", "covered")
        for m in screen
        if (a, m) in fits and fits[a, m][2] >= 3
    ]
    off = [
        f"{m} against {a}: {fits[a, m][0]:.2f}"
        for a, m in linear
        if abs(fits[a, m][0] - 1.0) > max(0.15, 2 * fits[a, m][1])
    ]
    busy = max(load_before, load_after) > (os.cpu_count() or 1)
    ref = labels[3]
    k_ref = fits.get(("resolution", ref), (float("nan"), float("nan"), 0))
    k_cov = fits.get(("covered", ref), (float("nan"), float("nan"), 0))
    measured = (
        "Fitted exponents k of t ∝ x^k (table): the two-pass kernel "
        f"{fmt_fit('resolution', labels[0])} in pixels and {fmt_fit('taps', labels[0])} in "
        "taps; the sum of Gaussians "
        f"{fmt_fit('resolution', labels[1])} and {fmt_fit('taps', labels[1])}; the disk "
        f"{fmt_fit('resolution', labels[2])} and {fmt_fit('taps', labels[2])}; the reference (FFT "
        f"on this plane) {k_ref[0]:.2f} in pixels and {k_cov[0]:.2f} in covered pixels (the FFT "
        f"convolves the whole frame whatever the stencil). The reference at {big[1]}×{big[0]}: "
        f"{peak['seconds']:.1f} s, peak resident memory {peak['peak_gib']:.2f} GiB"
        + ("" if peak["reset"] else " (the process's peak, scene included)")
        + f" (its G-buffer alone {peak['gbuffer_gib']:.2f} GiB). Load average "
        f"{load_before:.1f} before, {load_after:.1f} after on {os.cpu_count()} cores"
        + (
            ": a shared machine, so absolute times are inflated; the exponents (ratios within "
            "one run) are less affected."
            if busy
            else "."
        )
    )
    if ctx.quick:
        verdict, reason = "pending", "Quick run on tiny images: not the measurement."
    elif not off:
        verdict = "reproduced"
        reason = (
            "Every screen-space method's time is linear in the pixels it covers (exponent within "
            "0.15, or two standard errors, of 1): cost = passes × taps × covered pixels."
        )
    else:
        verdict = "partly reproduced"
        reason = (
            "Not linear: " + "; ".join(off) + ". An exponent below 1 is a cost that does not grow "
            "with the work: per pass, the whole frame is read and the stencil compacted whatever "
            "the covered pixels, and per pixel a fixed cost besides its taps."
        )
    body = (
        "Fitted exponent k of t ≈ c · x^k (least squares in log-log, ± its standard error; n "
        "points):\n\n"
        + md_table(fit_rows, ["method", "pixels (resolution)", "taps", "covered pixels"])
        + "\n\n"
        + (("Skipped: " + "; ".join(notes) + ".\n\n") if notes else "")
        + f"Reference at {big[1]}×{big[0]} (`ReferenceSSS`, auto = FFT here, float32 G-buffer, "
        f"fresh process): {peak['seconds']:.1f} s, peak RSS {peak['peak_gib']:.2f} GiB "
        f"(RSS {peak['before_gib']:.2f} GiB before the call).\n\n"
        "<details><summary>Every timed point (ms)</summary>\n\n"
        + md_table(time_rows, ["axis", "method", "x", "ms"])
        + "\n\n</details>"
    )
    return Section(
        title="Cost as the work grows: resolution, taps, covered pixels",
        claim=(
            "A screen-space pass costs taps × covered pixels (000 §8, 002, 004 Fig. 5.1: time "
            "grows with samples per pass); the exact reference's cost grows with the frame "
            "(issue 30: how far each method scales, up to 4K)."
        ),
        measured=measured,
        verdict=verdict,
        reason=reason,
        body=body,
        figures=[link],
        data={
            "fits": {f"{a}|{m}": list(v) for (a, m), v in fits.items()},
            "peak_4k": peak,
            "load": [load_before, load_after],
        },
    )


if __name__ == "__main__":
    sys.exit(main("scaling", run))

"""Numerical stability of sssbench under stiff and extreme parameters (issue 8).

    python -m experiments.run stability [--quick]     # or: python -m experiments.stability

Writes ``experiments/sections/stability.md`` (the report framework's ``Section``): one row per
group of cases with the number of parameter combinations and the worst value of each check.
``--quick`` is the grid that ``tests/reliability/test_extremes.py`` runs case by case.

Checks, per case (``tests/reliability/test_extremes.py`` runs the quick grid as a test):

* **finite**: no NaN or Inf in any kernel weight, offset, profile total or image.
* **constant**: a normalised kernel maps a constant image to itself: ``|out − c| / c`` at most
  :data:`CONST_TOL` (1e-5 float32, 1e-12 float64) after both passes.
* **range**: with non-negative weights the output of a random image stays within the input's
  ``[min, max]`` (up to :data:`CONST_TOL` relative); with ``follow_surface="gaussian"`` on a
  non-flat surface the weights are attenuated without renormalisation (000 eq. 7), so there
  the bound is ``[0, max]``.
* **f32 vs f64**: the float32 result against the float64 result of the *same* (float32-rounded)
  inputs, ``max |out32 − out64| / max |input|`` at most :data:`F32_TOL` = 1e-5, plus
  ``4 · ulp32(max depth) / surface_scale`` with follow-surface (float32 resolves depth
  differences only to the depth's ulp; documented in ``docs/numerics.md``).

Groups (parameters chosen to be stiff, not typical):

* ``width``: kernel σ from 0.01 px to 40 px (wider than the 16 px image), 1, 2, 3 and 513 taps,
  importance and uniform placement, on a depth ramp.
* ``camera``: one 1 mm kernel at depths 1e-3 … 1e6 mm and ``fov_y`` 1e-6, 0.5 and π − 1e-6,
  flat and ramp surfaces, follow-surface off / lerp / gaussian.
* ``mask``: strength (mask) 0, 0.5, 1 and random, follow-surface modes, flat and step surfaces.
* ``variance``: single-Gaussian profiles with variances 1e-6 … 1e6 mm² (twelve decades), all
  placements and tap counts.
* ``jimenez2012``: strength 0 / 0.5 / 1, falloff 0 / 0.3 / 1, 1 / 2 / 3 / 513 taps, both
  quadratures.
* ``artist``: degenerate σ' (0 and 1), weights 0 and 1, scales 1e-3 and 1e3 mm.
* ``dipole``: Spectralon (σa = 0, power-law tail) and Ketchup (blue: α' = 0.02) and more.
* ``c_curves``: the empirical fit's C_i at x = 0 … 1e-4 (continuity at 0) and pole fits there.
* ``layers``: layer composition at R2⁺R1⁻ = 1 − 10⁻ᵏ (the series either converges with the
  energy the closed form predicts, or raises the documented ``max_terms`` error).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial

import torch

from experiments.common import Context, Section, main
from sssbench.gbuffer import GBuffer, pixel_size_mm
from sssbench.kernels import Kernel1D, artist, jimenez2012, preintegrated
from sssbench.ops import separable_pass
from sssbench.profiles import Dipole, Layer, SumOfGaussians, compose_layers
from sssbench.profiles.empirical import c_curves, empirical_dipole_fit, empirical_pole_fit

#: constant-image tolerance (relative), per dtype
CONST_TOL = {torch.float32: 1e-5, torch.float64: 1e-12}
#: float32 against float64 on the same inputs: max |Δ| / max |input|
F32_TOL = 1e-5
#: with follow-surface: + F32_DEPTH_FACTOR · ulp32(max depth) / surface_scale
F32_DEPTH_FACTOR = 4.0
FOLLOW = (None, "lerp", "gaussian")


@dataclass
class Outcome:
    """Measured values of one case; ``ok`` is the conjunction of all checks."""

    group: str
    label: str
    finite: bool = True
    const_err32: float = 0.0
    const_err64: float = 0.0
    range_excess: float = 0.0  # how far outside the allowed range, relative to max |input|
    f32_err: float = 0.0
    f32_allow: float = 0.0  # the case's float32 tolerance (F32_TOL unless follow-surface)
    error: str = ""  # a raised exception, when raising is the expected outcome
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return (
            self.finite
            and self.const_err32 <= CONST_TOL[torch.float32]
            and self.const_err64 <= CONST_TOL[torch.float64]
            and self.range_excess <= CONST_TOL[torch.float32]
            and self.f32_err <= max(F32_TOL, self.f32_allow)
        )


# ----------------------------------------------------------------------------- images
def _depth(kind: str, z: float, size: int) -> torch.Tensor:
    d = torch.full((1, 1, size, size), z, dtype=torch.float64)
    cols = torch.arange(size, dtype=torch.float64)
    if kind == "ramp":
        d = d * (1 + 0.5 * cols / size)
    elif kind == "steps":
        d = d * torch.where(cols < size // 2, 1.0, 2.0)
    return d


def _mask(kind: str | float | None, size: int, gen: torch.Generator) -> torch.Tensor | None:
    if kind is None:
        return None
    if kind == "random":
        return torch.rand(1, 1, size, size, generator=gen, dtype=torch.float64)
    return torch.full((1, 1, size, size), float(kind), dtype=torch.float64)


def check_kernel(kernel: Kernel1D, *, normalised: bool = True) -> tuple[bool, float]:
    """(finite and sorted, worst |Σw − 1| in float64)."""
    finite = bool(torch.isfinite(kernel.offsets).all() and torch.isfinite(kernel.weights).all())
    sorted_ = bool((kernel.offsets[1:] >= kernel.offsets[:-1]).all())
    err = float((kernel.weights.double().sum(0) - 1).abs().max()) if normalised else 0.0
    return finite and sorted_, err


def run_pass_case(
    group: str,
    label: str,
    kernel: Kernel1D,
    *,
    width: float = 1.0,
    depth: str = "flat",
    z: float = 500.0,
    fov: float = 0.5,
    size: int = 16,
    follow: str | None = None,
    surface_scale: float | None = None,
    mask: str | float | None = None,
    seed: int = 0,
) -> Outcome:
    """Two passes (x then y) of ``kernel`` on a constant and a random image, float32 and 64."""
    out = Outcome(group, label)
    finite, sum_err = check_kernel(kernel)
    out.finite = finite
    out.const_err64 = max(out.const_err64, sum_err)
    if not finite:
        return out
    gen = torch.Generator().manual_seed(seed)
    d64 = _depth(depth, z, size)
    m64 = _mask(mask, size, gen)
    rnd = 0.2 + 0.7 * torch.rand(1, 3, size, size, generator=gen, dtype=torch.float64)
    nonneg = bool((kernel.weights >= 0).all())
    gaussian_loss = follow == "gaussian" and depth != "flat"
    opts = {"width": width, "follow_surface": follow}
    if follow is not None:
        opts["surface_scale"] = surface_scale if surface_scale is not None else kernel.extent or 1.0
    results = {}
    for dtype in (torch.float32, torch.float64):
        # the float64 run sees the float32-rounded inputs: the comparison isolates the
        # arithmetic of the passes from the rounding of the inputs
        depth_t = d64.to(torch.float32).to(dtype)
        mask_t = None if m64 is None else m64.to(torch.float32).to(dtype)
        for name, img in (("const", torch.full_like(rnd, 0.7)), ("rand", rnd)):
            img = img.to(torch.float32).to(dtype)
            g = GBuffer(img, depth_t, fov, mask=mask_t)
            res = separable_pass(img, kernel, "x", g, **opts)
            res = separable_pass(res, kernel, "y", g, **opts)
            results[(dtype, name)] = res
            if not bool(torch.isfinite(res).all()):
                out.finite = False
                return out
            lo, hi = float(img.min()), float(img.max())
            if name == "const" and not gaussian_loss:
                err = float((res - img).abs().max() / img.abs().max())
                if dtype == torch.float32:
                    out.const_err32 = max(out.const_err32, err)
                else:
                    out.const_err64 = max(out.const_err64, err)
            if nonneg:
                lo_allowed = 0.0 if gaussian_loss else lo
                excess = max(lo_allowed - float(res.min()), float(res.max()) - hi, 0.0) / hi
                out.range_excess = max(out.range_excess, excess)
    # a K-term float32 sum is good to K · 2⁻²⁴ (standard bound): above 513 taps that exceeds 1e-5
    out.f32_allow = max(F32_TOL, len(kernel) * 2.0**-24)
    for name in ("const", "rand"):
        a, b = results[(torch.float32, name)], results[(torch.float64, name)]
        scale = float(b.abs().max()) or 1.0
        out.f32_err = max(out.f32_err, float((a.double() - b).abs().max()) / scale)
    if follow is not None:
        # follow-surface weights depend on |Δz| / surface_scale; float32 resolves Δz only to
        # the depth's ulp, an error of the *inputs' precision*, not of the arithmetic
        ulp = float(torch.finfo(torch.float32).eps) * float(d64.max())
        out.f32_allow += F32_DEPTH_FACTOR * ulp / opts["surface_scale"]
    return out


# ----------------------------------------------------------------------------- groups
UNIT = SumOfGaussians(torch.tensor([1.0], dtype=torch.float64), torch.ones(1, 3))
_KERNELS: dict[tuple, Kernel1D] = {}


def unit_kernel(samples: int, sampling: str) -> Kernel1D:
    """Taps of a unit-σ Gaussian (mm), cached; scale with :meth:`Kernel1D.scaled`."""
    key = (samples, sampling)
    if key not in _KERNELS:
        _KERNELS[key] = preintegrated(UNIT, samples, sampling)
    return _KERNELS[key]


def group_width(quick: bool) -> Iterator[Callable[[], Outcome]]:
    widths = (0.01, 0.3, 1.0, 4.0, 40.0) if quick else (0.01, 0.1, 0.3, 1.0, 2.0, 4.0, 10.0, 40.0)
    samples = (1, 2, 3) if quick else (1, 2, 3, 5, 7, 25, 513, 1025)
    samplings = ("importance", "uniform") if quick else ("importance", "uniform", "power")
    size = 16
    z, fov = 500.0, 0.5
    px = float(pixel_size_mm(torch.tensor(z), fov, size))
    grid = [(w, s, sp) for w in widths for s in samples for sp in samplings]
    if quick:  # 513 taps at the two extreme widths only (the pytest time budget)
        grid += [(w, 513, sp) for w in (0.01, 40.0) for sp in samplings]
    for w, s, sp in grid:
        label = f"σ={w:g} px, K={s}, {sp}"

        def case(w=w, s=s, sp=sp, label=label) -> Outcome:
            k = unit_kernel(s, sp).scaled(w * px)
            return run_pass_case("width", label, k, depth="ramp", z=z, fov=fov, size=size)

        yield case


def group_camera(quick: bool) -> Iterator[Callable[[], Outcome]]:
    depths = (1e-3, 1.0, 1e3, 1e6) if quick else (1e-3, 1e-2, 1.0, 30.0, 1e3, 1e5, 1e6)
    fovs = (1e-6, 0.5, math.pi - 1e-6) if quick else (1e-9, 1e-6, 1e-3, 0.5, 2.0, math.pi - 1e-6)
    for z in depths:
        for fov in fovs:
            for surface in ("flat", "ramp"):
                for follow in FOLLOW:
                    label = f"z={z:g} mm, fov={fov:.3g}, {surface}, follow={follow}"

                    def case(z=z, fov=fov, surface=surface, follow=follow, label=label) -> Outcome:
                        k = unit_kernel(7, "importance")  # σ = 1 mm
                        return run_pass_case(
                            "camera", label, k, depth=surface, z=z, fov=fov, follow=follow,
                            surface_scale=1.0, size=12,
                        )  # fmt: skip

                    yield case


def group_mask(quick: bool) -> Iterator[Callable[[], Outcome]]:
    for mask in (0.0, 0.5, 1.0, "random"):
        for follow in FOLLOW:
            for surface in ("flat", "steps"):
                label = f"mask={mask}, follow={follow}, {surface}"

                def case(mask=mask, follow=follow, surface=surface, label=label) -> Outcome:
                    k = unit_kernel(9, "importance").scaled(3.0)
                    return run_pass_case(
                        "mask", label, k, depth=surface, mask=mask, follow=follow, surface_scale=3.0
                    )

                yield case


def group_variance(quick: bool) -> Iterator[Callable[[], Outcome]]:
    exps = range(-6, 7)  # 1e-6 … 1e6 mm²: twelve decades
    samples = (1, 2, 3) if quick else (1, 2, 3, 7, 513, 1025)
    grid = [(e, s, sp) for e in exps for s in samples for sp in ("importance", "uniform", "power")]
    if quick:
        grid += [(e, 513, "importance") for e in (-6, 0, 6)]
    for e, s, sp in grid:
        label = f"v=1e{e} mm², K={s}, {sp}"

        def case(e=e, s=s, sp=sp, label=label) -> Outcome:
            prof = SumOfGaussians(torch.tensor([10.0**e]), torch.tensor([[1.0, 0.5, 0.1]]))
            k = preintegrated(prof, s, sp)
            # z chosen so that the kernel is about 2 px wide: the pass sees every tap
            z = 2 * 10 ** (e / 2) * 8 / (2 * math.tan(0.25)) / 2
            return run_pass_case("variance", label, k, z=z, size=8)

        yield case


def group_jimenez2012(quick: bool) -> Iterator[Callable[[], Outcome]]:
    samples = (1, 2, 3) if quick else (1, 2, 3, 4, 11, 25, 513, 1025)
    grid = [
        (t, f, s, q)
        for t in (0.0, 0.5, 1.0)
        for f in (0.0, 0.3, 1.0)
        for s in samples
        for q in ("shader", "integrated")
    ]
    if quick:
        grid += [(1.0, f, 513, "shader") for f in (0.0, 1.0)]
    for t, f, s, q in grid:
        label = f"strength={t}, falloff={f}, K={s}, {q}"

        def case(t=t, f=f, s=s, q=q, label=label) -> Outcome:
            k = jimenez2012(t, f, s, quadrature=q)
            return run_pass_case("jimenez2012", label, k, width=2.0, size=10)

        yield case


def group_artist(quick: bool) -> Iterator[Callable[[], Outcome]]:
    for near, far in ((0.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
        for weight in (0.0, 1.0):
            for scale in (1e-3, 1e3):
                for s in (1, 3) if quick else (1, 3, 513):
                    label = f"σ'n={near}, σ'f={far}, w={weight}, s={scale:g} mm, K={s}"

                    def case(near=near, far=far, weight=weight, scale=scale, s=s, label=label):
                        k = artist(near, far, weight, scale, s)
                        return run_pass_case(
                            "artist", label, k, follow="gaussian",
                            surface_scale=max(far * scale, 1e-9), depth="ramp", size=10,
                        )  # fmt: skip

                    yield case


def group_dipole(quick: bool) -> Iterator[Callable[[], Outcome]]:
    materials = ("spectralon", "ketchup") if quick else ("spectralon", "ketchup", "marble", "skin1")
    samplings = ("uniform",) if quick else ("uniform", "importance")
    for mat in materials:
        for sp in samplings:
            for s in (1, 2, 3, 513) if sp == "uniform" else (1, 3, 7, 513):
                label = f"{mat}, K={s}, {sp}"

                def case(mat=mat, s=s, sp=sp, label=label) -> Outcome:
                    prof = Dipole.from_material(mat)
                    vals = torch.cat([prof.total(), prof.second_moment(), prof(0.0)])
                    k = preintegrated(prof, s, sp)
                    out = run_pass_case("dipole", label, k, z=3000.0, size=10)
                    out.finite = out.finite and bool(torch.isfinite(vals).all())
                    out.extra["radius_mm"] = prof.radius()
                    return out

                yield case
    for mat in ("spectralon", "ketchup"):
        label = f"{mat}, empirical 8-Gaussian fit"

        def fit_case(mat=mat, label=label) -> Outcome:
            sog = empirical_dipole_fit(mat)
            finite = bool(torch.isfinite(sog.variances).all() and torch.isfinite(sog.weights).all())
            out = run_pass_case("dipole", label, preintegrated(sog, 7), z=3000.0, size=10)
            out.finite = out.finite and finite and bool((sog.variances > 0).all())
            return out

        yield fit_case


def group_c_curves(quick: bool) -> Iterator[Callable[[], Outcome]]:
    xs = [0.0, 1e-300, 1e-200, 1e-100, 1e-30, 1e-16, 1e-12, 1e-8, 1e-6, 1e-4]
    c0 = c_curves(0.0)
    for x in xs:
        label = f"C_i(x={x:g})"

        def case(x=x, label=label) -> Outcome:
            out = Outcome("c_curves", label)
            c = c_curves(x)
            out.finite = bool(torch.isfinite(c).all())
            # continuity at 0: |C(x) − C(0)| ≤ 10 x (the curves' slopes at 0 are below 10)
            jump = float((c - c0).abs().max())
            out.extra["jump"] = jump
            if jump > 10 * x + 1e-15:
                out.finite = False
            for z in (1e-3, 1.0, 1e3):
                sog = empirical_pole_fit(x / z, z)
                t = sog.total()
                out.finite = out.finite and bool(torch.isfinite(t).all() and (t > 0).all())
            return out

        yield case


def group_layers(quick: bool) -> Iterator[Callable[[], Outcome]]:
    ks = (1, 2, 3, 6, 9, 12) if quick else (1, 2, 3, 4, 5, 6, 7, 9, 12, 15)
    # lossless slabs (R + T = 1: the prefactor T² vanishes with 1 − ρ) and slabs with T = 0.3
    # (the series needs ~log(eps)/log(ρ) terms: refused beyond max_terms)
    for k in ks:
        for lossless in (True, False):
            rho = 1 - 10.0**-k
            label = f"R2+R1- = 1 − 1e-{k}, {'R+T=1' if lossless else 'T=0.3'}"
            yield partial(_layer_case, rho, lossless, label)


def _layer_case(rho: float, lossless: bool, label: str) -> Outcome:
    out = Outcome("layers", label)
    r = math.sqrt(rho)
    t = 1 - r if lossless else 0.3
    z = torch.zeros(2, 3, dtype=torch.float64)

    def slab() -> Layer:
        rp = z.clone()
        rp[1] = r
        tp = z.clone()
        tp[1] = t
        return Layer(rp, rp.clone(), tp, tp.clone(), 0.01)

    try:
        lay = compose_layers(slab(), slab(), max_terms=5_000)
    except ValueError as exc:
        out.error = str(exc)
        out.finite = "max_terms" in str(exc)  # the documented refusal, not a NaN
        return out
    got = lay.r_plus.sum(0)
    want = r + t * r * t / (1 - rho)  # 001 eq. 3–5 summed in closed form
    out.finite = bool(torch.isfinite(lay.r_plus).all() and torch.isfinite(lay.t_plus).all())
    out.extra["energy_err"] = float((got - want).abs().max())
    # eq. 13 truncation: at most eps = 1e-6 of energy missing
    out.finite = out.finite and out.extra["energy_err"] <= 1e-6
    return out


GROUPS: dict[str, Callable[[bool], Iterator[Callable[[], Outcome]]]] = {
    "width": group_width,
    "camera": group_camera,
    "mask": group_mask,
    "variance": group_variance,
    "jimenez2012": group_jimenez2012,
    "artist": group_artist,
    "dipole": group_dipole,
    "c_curves": group_c_curves,
    "layers": group_layers,
}


def cases(quick: bool = True) -> list[tuple[str, Callable[[], Outcome]]]:
    return [(g, c) for g, make in GROUPS.items() for c in make(quick)]


# ----------------------------------------------------------------------------- report
def table(outcomes: list[Outcome], seconds: dict[str, float]) -> str:
    rows = [
        "| group | cases | failed | all finite | max const err f32 | max const err f64 "
        "| max range excess | max f32 vs f64 | raised (documented) | s |",
        "|---|---:|---:|:---:|---:|---:|---:|---:|---:|---:|",
    ]
    for g in GROUPS:
        sel = [o for o in outcomes if o.group == g]
        if not sel:
            continue
        rows.append(
            f"| {g} | {len(sel)} | {sum(not o.ok for o in sel)} "
            f"| {'yes' if all(o.finite for o in sel) else 'NO'} "
            f"| {max(o.const_err32 for o in sel):.1e} | {max(o.const_err64 for o in sel):.1e} "
            f"| {max(o.range_excess for o in sel):.1e} | {max(o.f32_err for o in sel):.1e} "
            f"| {sum(bool(o.error) for o in sel)} | {seconds.get(g, 0.0):.1f} |"
        )
    return "\n".join(rows)


TITLE = "Numerical stability under extreme parameters (issue 8)"


def evaluate(quick: bool) -> tuple[list[Outcome], dict[str, float]]:
    outcomes: list[Outcome] = []
    seconds: dict[str, float] = {}
    for g, case in cases(quick):
        t0 = time.perf_counter()
        outcomes.append(case())
        seconds[g] = seconds.get(g, 0.0) + time.perf_counter() - t0
    return outcomes, seconds


def run(ctx: Context) -> Section:
    outcomes, seconds = evaluate(ctx.quick)
    failed = [o for o in outcomes if not o.ok]
    worst = sorted(outcomes, key=lambda o: o.f32_err, reverse=True)[:5]
    layers = [o for o in outcomes if o.group == "layers"]
    body = [
        table(outcomes, seconds),
        "",
        "Largest float32 vs float64 differences (all within their tolerance: these use "
        "follow-surface with a `surface_scale` near the float32 ulp of the depth):",
        "",
        *[
            f"- {o.group}: {o.label}: {o.f32_err:.2e} (allowed {max(F32_TOL, o.f32_allow):.1e})"
            for o in worst
        ],
        "",
        "Layer composition near R2⁺R1⁻ = 1 (energy of R12⁺ against the closed form, or the "
        "documented refusal):",
        "",
        *[
            f"- {o.label}: "
            + (
                f"refused: {o.error.split(';')[0][:100]}…"
                if o.error
                else f"|ΔE| = {o.extra.get('energy_err', 0):.1e}"
            )
            for o in layers
        ],
    ]
    if failed:
        body += ["", "Failing cases:", "", *[f"- {o.group}: {o.label}" for o in failed]]
    measured = (
        f"{len(outcomes)} parameter combinations, {len(failed)} failing. Each case builds a "
        "kernel (or profile) at an extreme and runs two depth-aware passes on a constant and a "
        "random image in float32 and float64. Checks: no NaN or Inf; a normalised kernel maps "
        f"a constant image to itself within {CONST_TOL[torch.float32]:g} (float32) / "
        f"{CONST_TOL[torch.float64]:g} (float64); non-negative kernels stay within the "
        "input's [min, max] ([0, max] for follow-surface gaussian on non-flat depth, which "
        "attenuates without renormalising, 000 eq. 7); float32 within "
        f"max({F32_TOL:g}, K · 2⁻²⁴) × max|input| of float64 on the same inputs (K taps), plus "
        f"{F32_DEPTH_FACTOR:g} · ulp32(max depth) / surface_scale with follow-surface "
        "(`docs/numerics.md`)."
    )
    return Section(
        title=TITLE,
        claim=(
            "Not a paper claim: DESIGN §2 — no silent NaN; float64 must work and float32 is the "
            "default, so both must agree to a stated tolerance at any parameter a user can pass."
        ),
        measured=measured,
        verdict="target met" if not failed else "target not met",
        reason=(
            "Every case finite and within tolerance."
            if not failed
            else f"{len(failed)} cases outside tolerance (listed below)."
        ),
        body="\n".join(body),
        data={"cases": len(outcomes), "failed": len(failed)},
    )


if __name__ == "__main__":
    sys.exit(main("stability", run))

"""How much light the two disk estimators let across a depth step (part of the disk section).

Issue 26 claims that at a 1–2 mm depth step HDRP's weight — ``EvalBurley(r3D) · rcpPdf(r2D)``,
the profile in polar measure at the 3D distance over the polar density at the disk radius,
i.e. sssbench's ``R(d)/pdf`` times ``r3D / r2D`` (:mod:`sssbench.ops.disk` module doc) — lets
30–60 % more light across than ``R(d)/pdf``. Measured here: a camera-facing plane
(:func:`crossing_scene`, ``STEP_PIXEL_MM`` per pixel) whose right half lies ``h`` mm further
away and is *unlit* (irradiance 0); the energy that crosses the step is the scattered light
summed over that half (mean of the three channels, per unit of lit irradiance), for each
estimator (``samples`` per pixel, ``frames`` accumulated, mean over seeds, normalised as the
engines are) and for the exact reference (:class:`~sssbench.ops.ReferenceSSS`, float64), at
steps of 0 (no step), 0.5, 1 and 2 mm. Profile: the six-Gaussian skin fit (``skin_deon6``;
HDRP's rules run with its tabulated sampler), as the estimator table of the section: the exact
reference of Burley's profile on a stepped surface costs minutes per image here.

Where the engines' estimators are documented: HDRP's in Unity-Technologies/Graphics
``com.unity.render-pipelines.high-definition/Runtime/Material/SubsurfaceScattering/
SubsurfaceScattering.compute`` (``EvaluateSss``, ``EvaluateSample``) and
``DiffusionProfile.hlsl``, after Golubev 2018 (SIGGRAPH Advances); UE5's screen-space Burley
pass in ``Engine/Source/Runtime/Renderer/Private/PostProcess/SubsurfaceBurleyNormalized.cpp``
and its shaders; EEVEE's in Blender's ``eevee_subsurface.cc`` and ``eevee_subsurface_*``
shaders (docs/gl.md, "The disk shader").

Run on its own (it rewrites only its block of ``experiments/sections/disk.md``)::

    python -m experiments.disk_crossing [--quick]
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import torch

from experiments.common import ROOT, md_table
from sssbench.gbuffer import GBuffer
from sssbench.ops import DiskSSS, ReferenceSSS
from sssbench.profiles import SumOfGaussians

#: step heights (mm); 0: no step (the light that crosses the lit/unlit boundary anyway)
CROSS_STEPS_MM = (0.0, 0.5, 1.0, 2.0)
#: footprint of a pixel (mm)
STEP_PIXEL_MM = 0.2
#: the block's markers in sections/disk.md
START, END = "<!-- disk_crossing:start -->", "<!-- disk_crossing:end -->"


def crossing_scene(res: int, step_mm: float) -> GBuffer:
    """``(1, ·, res, res)``: a camera-facing plane, left half lit (1) at depth ``z0``, right
    half unlit (0) at ``z0 + step_mm``."""
    fov = math.radians(25.0)
    z0 = STEP_PIXEL_MM * res / (2 * math.tan(fov / 2))
    far = torch.arange(res).view(1, 1, 1, res) >= res // 2
    depth = torch.where(far, z0 + step_mm, z0).to(torch.float32).expand(1, 1, res, res)
    light = torch.where(far, 0.0, 1.0).to(torch.float32).expand(1, 3, res, res)
    return GBuffer(light.contiguous(), depth.contiguous(), fov)


def crossed(image: torch.Tensor, res: int) -> float:
    """Light on the unlit half (sum over its pixels, mean over channels) per lit pixel row
    (a column's worth of lit irradiance: the unit of the crossing)."""
    return float(image.double()[..., res // 2 :].sum() / 3 / res)


def measure(quick: bool = False) -> dict:
    """Crossed energy per step for the reference and both estimators (module doc)."""
    prof = SumOfGaussians.from_table("skin_deon6")
    res = 16 if quick else 48
    # the crossed energy sums ~res²/2 pixels, so its noise is small (the se columns): 4 frames
    # and 2 seeds keep a full run to minutes (the torch disk loops over samples × frames)
    samples, frames, seeds = (16, 2, 2) if quick else (64, 4, 2)
    steps = CROSS_STEPS_MM[:3] if quick else CROSS_STEPS_MM
    rows = {}
    for h in steps:
        g = crossing_scene(res, h)
        ref = ReferenceSSS(prof)(g.to(torch.float64))
        row = {"reference": crossed(ref, res)}
        for est in ("sssbench", "hdrp"):
            vals = []
            for s in range(seeds):
                op = DiskSSS(prof, samples, frames=frames, seed=s, estimator=est)
                with torch.inference_mode():
                    vals.append(crossed(op(g), res))
            row[est] = sum(vals) / seeds
            row[f"{est}_se"] = (
                float(torch.tensor(vals).std(unbiased=True)) / math.sqrt(seeds)
                if seeds > 1
                else float("nan")
            )
        rows[h] = row
    return {
        "res": res,
        "samples": samples,
        "frames": frames,
        "seeds": seeds,
        "steps": rows,
        "load": os.getloadavg(),
    }


def _pct(a: float, b: float) -> float:
    return 100.0 * (a / b - 1.0) if b > 0 else float("nan")


def block(m: dict) -> str:
    """The Markdown block (verdict sentence computed from ``m``, and its table)."""
    steps = m["steps"]
    table = []
    for h, r in steps.items():
        table.append([f"{h:g}", r["reference"], r["sssbench"], r["sssbench_se"], r["hdrp"],
                      r["hdrp_se"], _pct(r["hdrp"], r["sssbench"]),
                      _pct(r["reference"], r["sssbench"])])  # fmt: skip
    stepped = [h for h in steps if h > 0]
    parts = []
    for h in stepped:
        r = steps[h]
        more = _pct(r["hdrp"], r["sssbench"])
        ref = _pct(r["reference"], r["sssbench"])
        parts.append(
            f"HDRP lets {abs(more):.0f} % {'more' if more >= 0 else 'less'} light across at a "
            f"{h:g} mm step than sssbench's estimator; the reference lets {abs(ref):.0f} % "
            f"{'more' if ref >= 0 else 'less'}"
        )
    if 0.0 in steps and stepped:  # the step's own effect: each against its no-step crossing
        top, zero = steps[stepped[-1]], steps[0.0]
        kept = {k: 100.0 * top[k] / zero[k] for k in ("hdrp", "sssbench", "reference")}
        parts.append(
            f"against its own no-step crossing, at {stepped[-1]:g} mm HDRP keeps "
            f"{kept['hdrp']:.0f} %, sssbench's estimator {kept['sssbench']:.0f} %, the "
            f"reference {kept['reference']:.0f} %"
        )
    band = [h for h in stepped if 1.0 <= h <= 2.0]
    in_claim = [h for h in band if 30.0 <= _pct(steps[h]["hdrp"], steps[h]["sssbench"]) <= 60.0]
    claim = (
        f"The issue's 30–60 % at 1–2 mm: {len(in_claim)} of the {len(band)} steps in that "
        f"range ({', '.join(f'{h:g} mm' for h in in_claim) or 'none'}) fall inside it."
        if band
        else "(quick run: no step in the issue's 1–2 mm range.)"
    )
    la = m["load"]
    heights = ", ".join(f"{h:g}" for h in steps)
    return "\n".join(
        [
            START,
            f"**Light across a depth step** (`python -m experiments.disk_crossing`: a {m['res']}² "
            f"plane, {STEP_PIXEL_MM} mm pixels, lit left half, unlit right half {heights} mm "
            f"further away; skin_deon6; {m['samples']} samples, "
            f"{m['frames']} frames, mean over {m['seeds']} seeds; crossed = light on the unlit "
            f"half per lit column, mean of the channels). {'; '.join(parts)}. {claim} "
            f"(Load average {la[0]:.2f} / {la[1]:.2f} / {la[2]:.2f}; no timing involved.)",
            "",
            md_table(
                table,
                [
                    "step mm",
                    "reference",
                    "sssbench",
                    "se",
                    "hdrp",
                    "se",
                    "hdrp vs sssbench %",
                    "reference vs sssbench %",
                ],
            ),  # fmt: skip
            END,
        ]
    )


def update_section(text: str, new_block: str) -> str:
    """``text`` (sections/disk.md) with its crossing block replaced by ``new_block``, or
    ``new_block`` inserted before the run stamp (the last ``<sub>`` line) if it has none."""
    if START in text and END in text:
        head, rest = text.split(START, 1)
        return head + new_block + rest.split(END, 1)[1]
    lines = text.rstrip("\n").split("\n")
    at = max((i for i, line in enumerate(lines) if line.startswith("<sub>")), default=len(lines))
    return "\n".join(lines[:at] + [new_block, ""] + lines[at:]) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    quick = "--quick" in argv
    torch.set_num_threads(1)  # as the experiments run (experiments.common.execute)
    text = block(measure(quick))
    path = (ROOT / "_quick" if quick else ROOT) / "sections" / "disk.md"
    if path.exists():
        path.write_text(update_section(path.read_text(), text))
    else:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

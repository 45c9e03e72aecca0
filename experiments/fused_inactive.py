"""The fused sum of Gaussians with and without the copy of its inactive pixels (issue 30).

``FusedSumOfGaussiansSSS`` writes its per-Gaussian x results at the active pixels only
(``separable_sweep(..., keep_inactive=False)``) and its y sweep reads every set's inactive
pixels from the diffuse image (``inactive_from``); before 2026-12-06 the x sweep copied the
diffuse image into every set's inactive pixels and the y sweep read them there. Both are the
same library, so ``experiments.ab_native`` (two builds, one Python) cannot time the change:
here the two schedules — the method, and :func:`copying` (the earlier one, through the same
public ``separable_sweep``) — are alternated in one process on the 1080p close-up of
``experiments.perf`` (7 taps, 2 threads), with the pre-integrated two-pass in the same rounds;
the figure is the median per-round ratio with its bootstrapped standard error
(:func:`experiments.perf.median_ratio`), and the two results are checked bitwise equal first.

    python -m experiments.fused_inactive [--rounds 21] [--processes 3]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys

import torch

from experiments.perf import CLOSE, interleaved_ms, make_scene, median_ratio
from sssbench.gbuffer import GBuffer
from sssbench.ops import FusedSumOfGaussiansSSS, PreintegratedSSS, separable_sweep
from sssbench.ops._gather_native import serial_copy
from sssbench.profiles import SumOfGaussians


def copying(op: FusedSumOfGaussiansSSS, g: GBuffer, scratch: torch.Tensor) -> torch.Tensor:
    """``op(g)`` as it ran before 2026-12-06: the x sweep writes every pixel of every set
    (the diffuse image at the inactive ones) into ``scratch``, the y sweep reads them there."""
    opts = {"follow_surface": op.follow_surface, "surface_scale": op.surface_scale}
    xs = separable_sweep(g.diffuse, op.kernels, "x", g, out=scratch, check_finite=False, **opts)
    coefficients = op.coefficients.to(g.diffuse.dtype)
    return separable_sweep(xs, op.kernels, "y", g, coefficients=coefficients,
                           out=serial_copy(g.diffuse), check_finite=False, **opts)  # fmt: skip


def one_process(rounds: int) -> tuple[float, float, float, float]:
    """(new / copying, its standard error, copying / pre-integrated, new / pre-integrated)."""
    torch.set_num_threads(2)
    skin = SumOfGaussians.from_table("skin_deon6")
    g = make_scene(CLOSE, (1080, 1920))
    op, pre = FusedSumOfGaussiansSSS(skin, 7), PreintegratedSSS(skin, 7, follow_surface="lerp")
    scratch = torch.empty((len(op.kernels), *g.diffuse.shape), dtype=g.diffuse.dtype)
    if not torch.equal(op(g), copying(op, g, scratch)):
        raise SystemExit("fused_inactive: the two schedules differ")
    t = interleaved_ms(
        {"new": lambda: op(g), "copying": lambda: copying(op, g, scratch), "pre": lambda: pre(g)},
        rounds,
    )
    ratio, se = median_ratio(t["new"], t["copying"])
    return ratio, se, median_ratio(t["copying"], t["pre"])[0], median_ratio(t["new"], t["pre"])[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=21)
    ap.add_argument("--processes", type=int, default=3)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(*one_process(args.rounds))
        return 0
    rows = []
    for i in range(args.processes):  # fresh processes: the machine drifts between them
        print(f"fused_inactive: process {i + 1}/{args.processes}", file=sys.stderr)
        cmd = [sys.executable, "-m", "experiments.fused_inactive", "--one"]
        out = subprocess.run(cmd + ["--rounds", str(args.rounds)], capture_output=True,
                             text=True, check=True)  # fmt: skip
        rows.append([float(v) for v in out.stdout.split()])
    for r in rows:
        print(f"new / copying {r[0]:.3f} ± {r[1]:.3f}; over the pre-integrated two-pass: "
              f"copying {r[2]:.2f}×, new {r[3]:.2f}×")  # fmt: skip
    mean = statistics.mean(r[0] for r in rows)
    se = statistics.stdev(r[0] for r in rows) / len(rows) ** 0.5 if len(rows) > 1 else rows[0][1]
    print(f"pooled new / copying: {mean:.3f} ± {se:.3f} ({len(rows)} processes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The fused sum of Gaussians against its earlier schedules (issue 30).

``FusedSumOfGaussiansSSS`` writes its per-Gaussian x results at the active pixels only
(``separable_sweep(..., keep_inactive=False)``), its y sweep reads every set's inactive
pixels from the diffuse image (``inactive_from``), and a new result gets the image's inactive
pixels from the x sweep's threads, row by row (``inactive_into``). The earlier schedules,
through the same public ``separable_sweep`` (``--against``):

- :func:`copying` (until the morning of 2026-12-06): the x sweep copied the diffuse image into
  every set's inactive pixels and the y sweep read them there; the new result a copy of the
  whole image on the calling thread (``serial_copy``) before the sweeps;
- :func:`serial_output` (2026-12-06, until ``inactive_into``): the method's sweeps, but the new
  result that copy of the whole image;
- :func:`small_pages` (2026-12-06, until its per-Gaussian images were put in 2 MB pages): the
  method itself with a workspace from ``torch.empty`` (4 KB pages).

All are the same library, so ``experiments.ab_native`` (two builds, one Python) cannot time
the changes: here the method and one earlier schedule are alternated in one process on the
1080p close-up of ``experiments.perf`` (7 taps, 2 threads), with the pre-integrated two-pass
in the same rounds; the figure is the median per-round ratio with its bootstrapped standard
error (:func:`experiments.perf.median_ratio`), and the two results are checked bitwise equal
first.

    python -m experiments.fused_inactive [--rounds 21] [--processes 3] [--against copying]
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
from sssbench.ops import sum_of_gaussians_fused as fused
from sssbench.ops._gather_native import serial_copy
from sssbench.profiles import SumOfGaussians


def _serial_sweeps(
    op: FusedSumOfGaussiansSSS, g: GBuffer, scratch: torch.Tensor, copies_inactive: bool
) -> torch.Tensor:
    """The method's two sweeps into a new result that is first a copy of the whole image
    (``serial_copy``); ``copies_inactive``: the x sweep also writes the image into every set's
    inactive pixels of ``scratch`` and the y sweep reads them there (else they are read from
    the image, ``inactive_from``)."""
    opts = {"follow_surface": op.follow_surface, "surface_scale": op.surface_scale}
    xs = separable_sweep(g.diffuse, op.kernels, "x", g, out=scratch, check_finite=False,
                         keep_inactive=copies_inactive, **opts)  # fmt: skip
    return separable_sweep(xs, op.kernels, "y", g, coefficients=op.coefficients.to(g.dtype),
                           out=serial_copy(g.diffuse), check_finite=False,
                           inactive_from=None if copies_inactive else g.diffuse,
                           **opts)  # fmt: skip


def copying(op: FusedSumOfGaussiansSSS, g: GBuffer, scratch: torch.Tensor) -> torch.Tensor:
    """``op(g)`` as it ran before 2026-12-06: the x sweep writes every pixel of every set
    (the diffuse image at the inactive ones) into ``scratch``, the y sweep reads them there."""
    return _serial_sweeps(op, g, scratch, copies_inactive=True)


def serial_output(op: FusedSumOfGaussiansSSS, g: GBuffer, scratch: torch.Tensor) -> torch.Tensor:
    """``op(g)`` as it ran on 2026-12-06 before ``inactive_into``: the method's two sweeps,
    into a new result that is first a copy of the whole image (``serial_copy``)."""
    return _serial_sweeps(op, g, scratch, copies_inactive=False)


def small_pages(op: FusedSumOfGaussiansSSS, g: GBuffer, scratch: torch.Tensor) -> torch.Tensor:
    """``op(g)`` as it ran on 2026-12-06 before its workspace was put in 2 MB pages
    (:func:`~sssbench.ops._pages.huge_page_empty`): the method itself with ``scratch``, a
    ``torch.empty`` tensor in 4 KB pages, as its workspace for the call."""
    saved = getattr(fused._SCRATCH, "tensor", None)
    fused._SCRATCH.tensor = scratch
    try:
        return op(g)
    finally:
        fused._SCRATCH.tensor = saved


#: the earlier schedules by name (``--against``)
EARLIER = {"copying": copying, "serial_output": serial_output, "small_pages": small_pages}


def one_process(rounds: int, against: str = "copying") -> tuple[float, float, float, float]:
    """(new / earlier, its standard error, earlier / pre-integrated, new / pre-integrated),
    ``against`` naming the earlier schedule (:data:`EARLIER`)."""
    earlier = EARLIER[against]
    torch.set_num_threads(2)
    skin = SumOfGaussians.from_table("skin_deon6")
    g = make_scene(CLOSE, (1080, 1920))
    op, pre = FusedSumOfGaussiansSSS(skin, 7), PreintegratedSSS(skin, 7, follow_surface="lerp")
    scratch = torch.empty((len(op.kernels), *g.diffuse.shape), dtype=g.diffuse.dtype)
    if not torch.equal(op(g), earlier(op, g, scratch)):
        raise SystemExit(f"fused_inactive: the method and {against} differ")
    t = interleaved_ms(
        {"new": lambda: op(g), "earlier": lambda: earlier(op, g, scratch), "pre": lambda: pre(g)},
        rounds,
    )
    ratio, se = median_ratio(t["new"], t["earlier"])
    return ratio, se, median_ratio(t["earlier"], t["pre"])[0], median_ratio(t["new"], t["pre"])[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=21)
    ap.add_argument("--processes", type=int, default=3)
    ap.add_argument("--against", choices=sorted(EARLIER), default="copying")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(*one_process(args.rounds, args.against))
        return 0
    rows = []
    for i in range(args.processes):  # fresh processes: the machine drifts between them
        print(f"fused_inactive: process {i + 1}/{args.processes}", file=sys.stderr)
        cmd = [sys.executable, "-m", "experiments.fused_inactive", "--one"]
        cmd += ["--rounds", str(args.rounds), "--against", args.against]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append([float(v) for v in out.stdout.split()])
    for r in rows:
        print(f"new / {args.against} {r[0]:.3f} ± {r[1]:.3f}; over the pre-integrated "
              f"two-pass: {args.against} {r[2]:.2f}×, new {r[3]:.2f}×")  # fmt: skip
    mean = statistics.mean(r[0] for r in rows)
    se = statistics.stdev(r[0] for r in rows) / len(rows) ** 0.5 if len(rows) > 1 else rows[0][1]
    print(f"pooled new / {args.against}: {mean:.3f} ± {se:.3f} ({len(rows)} processes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

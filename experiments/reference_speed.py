"""Wall time and peak memory of the exact reference at a realistic resolution.

Usage::

    python experiments/reference_speed.py [--size 1920x1080] [--pixel-mm 0.07]
        [--scene head_close|sphere] [--profile skin_deon6] [--threads 2]
        [--reconstruction box|bilinear]

``head_close`` is the procedural head framed on the cheek: at 1080 rows its skin pixels are
0.063–0.12 mm, i.e. ~0.07 mm at the cheek (the scene has no pixel-size parameter on this
branch, so ``--pixel-mm`` is reported, not applied, for it). ``sphere`` is moved so that the
pixel at its front is ``--pixel-mm`` and it fills the frame (radius 0.45 of the screen
height). Prints wall time (from cold: scene built first, not timed) and peak RSS
(``resource.getrusage``, the whole process).
"""

from __future__ import annotations

import argparse
import math
import resource
import time

import torch

from data_synth import make_scene
from sssbench.gbuffer import pixel_size_mm
from sssbench.ops.reference import reference_sss
from sssbench.profiles import SumOfGaussians


def build(scene: str, width: int, height: int, pixel_mm: float):
    """The benchmark scene as a float64 G-buffer."""
    if scene == "sphere":
        fov = math.radians(25.0)
        screen = pixel_mm * height  # mm at the sphere's front
        radius = 0.45 * screen
        front = screen / (2 * math.tan(fov / 2))
        return make_scene(
            "sphere",
            (height, width),
            dtype=torch.float64,
            radius=radius,
            distance=front + radius,
            background=front + 3 * radius,
        )
    return make_scene(scene, (height, width), dtype=torch.float64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--pixel-mm", type=float, default=0.07)
    ap.add_argument("--scene", default="head_close", choices=["head_close", "sphere"])
    ap.add_argument("--profile", default="skin_deon6")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reconstruction", default="box", choices=["box", "bilinear"])
    args = ap.parse_args()
    width, height = (int(s) for s in args.size.lower().split("x"))
    torch.set_num_threads(args.threads)
    g = build(args.scene, width, height, args.pixel_mm)
    mask = g.mask_or_ones() > 0
    pix = pixel_size_mm(g.depth[mask], g.fov_y, height)
    profile = SumOfGaussians.from_table(args.profile)
    print(
        f"scene {args.scene} {width}x{height}: {int(mask.sum())} surface pixels, footprint "
        f"{float(pix.min()):.4f}–{float(pix.max()):.4f} mm (median {float(pix.median()):.4f}); "
        f"profile {args.profile}, widest σ {math.sqrt(float(profile.variances.max())):.2f} mm"
    )
    t0 = time.perf_counter()
    out = reference_sss(g, profile, reconstruction=args.reconstruction)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # KiB -> GiB
    print(f"reference ({args.reconstruction}): {wall:.1f} s wall, peak RSS {peak:.2f} GiB")
    print(f"output mean {out.mean().item():.6f}, threads {torch.get_num_threads()}")


if __name__ == "__main__":
    main()

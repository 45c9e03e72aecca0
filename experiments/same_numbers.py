"""Check that a speed-up changed no stored number: run a subset of the paper benchmark with
the code of a base commit and with this tree, each from an empty cache, and compare every
stored metric (times excluded) to a relative 1e-12.

    python -m experiments.same_numbers --base main [--scene face] [--scale 0.3]
        [--resolution 128] [--methods identity,artist,...]

Not a REPORT section: a tool for changes that must not move a number (issue 30's "without
changing any stored number"). Exit status 1 and one line per differing value if any differ.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: the child: runs the subset with the code on its path, prints {label: metrics} as JSON
_CHILD = r"""
import json, sys, tempfile
from pathlib import Path
import torch
torch.set_num_threads(1)
from sssbench.app import compose_spec, preset_grid
from sssbench.run import runner
scene, scale, res, methods = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
tmp = Path(tempfile.mkdtemp())
jobs = preset_grid("paper_benchmark", f"scene={scene}", f"++scene.params.pixel_mm={scale}",
                   f"method={methods}")
out = {}
for k, job in enumerate(jobs):
    spec = compose_spec(*job, "previews=false", f"resolution=[{res},{res}]",
                        store=tmp / "runs.sqlite")
    o = runner.execute(spec, tmp / str(k), sweep_dir=tmp)
    if o.status == "skipped":
        continue
    out[runner.run_label(spec)] = {"status": o.status, "message": o.message, **o.metrics}
print("RESULT" + json.dumps(out, default=repr))
"""


def _run(code_root: Path, args: argparse.Namespace) -> dict:
    env = dict(os.environ, PYTHONPATH=str(code_root), SSSBENCH_CACHE_DIR=tempfile.mkdtemp())
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, args.scene, args.scale, str(args.resolution), args.methods],
        cwd=code_root, env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT")]
    if proc.returncode or not lines:
        raise RuntimeError(f"the run with the code of {code_root} failed:\n{proc.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT") :])


def differences(base: dict, new: dict, rtol: float = 1e-12) -> list[str]:
    """One line per run or metric that differs (times, ``*_ms``, are not compared)."""
    lines = []
    for label in sorted(set(base) | set(new)):
        a, b = base.get(label), new.get(label)
        if a is None or b is None:
            lines.append(f"{label}: only in the {'new' if a is None else 'base'} run")
            continue
        for key in sorted(set(a) | set(b)):
            if key.endswith("_ms") or key == "message":
                continue
            x, y = a.get(key), b.get(key)
            if isinstance(x, float) and isinstance(y, float):
                same = (math.isnan(x) and math.isnan(y)) or abs(x - y) <= rtol * max(
                    abs(x), abs(y), 1e-300
                )
            else:
                same = x == y
            if not same:
                lines.append(f"{label}: {key} {x!r} (base) != {y!r} (new)")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--base", default="main", help="git revision of the code to compare with")
    p.add_argument("--scene", default="face")
    p.add_argument("--scale", default="0.3", help="scene.params.pixel_mm")
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument(
        "--methods",
        default="identity,artist,disk,jimenez2012,low_rank,preintegrated,sum_of_gaussians",
    )
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="sssbench-base-") as tmp:
        archive = Path(tmp) / "base.tar"
        subprocess.run(
            ["git", "archive", "-o", str(archive), args.base], cwd=REPO, check=True
        )  # fmt: skip
        with tarfile.open(archive) as tar:
            tar.extractall(Path(tmp) / "code", filter="data")
        base = _run(Path(tmp) / "code", args)
    new = _run(REPO, args)
    diff = differences(base, new)
    print(f"{len(new)} runs ({args.scene}, {args.scale} mm/px, {args.resolution}²) against "
          f"{args.base}: {len(diff)} differences")  # fmt: skip
    for line in diff:
        print("  " + line)
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())

"""Run experiments and build the report.

    python -m experiments.run NAME [NAME ...] [--quick] [--out DIR] [--threads N]
    python -m experiments.run all [--quick]       # every experiment, then the report
    python -m experiments.run report              # only concatenate sections -> REPORT.md
    python -m experiments.run list

Each experiment writes ``<out>/sections/<name>.md`` and its figures; ``report`` calls
:func:`experiments.make_report.make_report`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

from experiments.common import Context, default_out, execute

#: experiment name -> module (in report order; see make_report.ORDER)
EXPERIMENTS = {
    "low_rank": "experiments.low_rank",
    "step_edge": "experiments.step_edge",
    "gaussian_fits": "experiments.gaussian_fits",
    "pole_fit": "experiments.pole_fit",
    "sampling": "experiments.sampling",
    "cost": "experiments.cost",
    "layers": "experiments.layers",
    "extensions": "experiments.extensions",
    "benchmark": "experiments.benchmark",
    "benchmark_1080p": "experiments.benchmark_1080p",
    "plan": "experiments.plan",
    "perf": "experiments.perf",
    "seal_speed": "experiments.seal_speed",
    "stability": "experiments.stability",
    "disk": "experiments.disk",
    "mc_profiles": "experiments.mc_profiles",
    "mc_gap": "experiments.mc_gap",
    "optimised": "experiments.optimised",
    "reference_speed": "experiments.reference_speed",
    "scaling": "experiments.scaling",
    "gl_speed": "experiments.gl_speed",
}


def run_one(name: str, ctx: Context) -> Path:
    """Run ``EXPERIMENTS[name]``, or any module ``experiments.<name>`` with a ``run(ctx)``
    (so a new experiment needs no registration to be runnable)."""
    target = EXPERIMENTS.get(name, f"experiments.{name}")
    try:
        module = importlib.import_module(target)
    except ModuleNotFoundError as exc:
        if exc.name != target:
            raise
        raise SystemExit(f"unknown experiment {name!r}; choose from {sorted(EXPERIMENTS)}") from exc
    if not callable(getattr(module, "run", None)):
        raise SystemExit(f"{target} has no run(ctx) function")
    return execute(name, module.run, ctx)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.run")
    ap.add_argument("names", nargs="+", help="experiment names, 'all', 'report' or 'list'")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    if a.names == ["list"]:
        print("\n".join(EXPERIMENTS))
        return 0
    names = list(EXPERIMENTS) if a.names == ["all"] else [n for n in a.names if n != "report"]
    failed = []
    for name in names:
        ctx = Context(name, a.quick, default_out(a.quick, a.out), a.threads)
        t = time.perf_counter()
        try:
            run_one(name, ctx)
        except Exception as exc:  # one failing experiment does not stop the others
            failed.append(name)
            print(f"{name}: FAILED after {time.perf_counter() - t:.1f} s: {exc!r}", file=sys.stderr)
            if len(names) == 1:
                raise
    if a.names == ["all"] or "report" in a.names:
        from experiments.make_report import make_report

        print(f"report -> {make_report(default_out(a.quick, a.out))}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

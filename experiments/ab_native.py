"""Two builds of the native library in one process, the operators' calls alternated between them.

    python -m experiments.ab_native --base HEAD~1          # the base: a git revision's sources
    python -m experiments.ab_native --base-dir DIR         # or a folder of native sources
    options: --processes 3  --rounds 25  --threads 2  --res 1080p|512²  --ops preintegrated,...

A change to the tap loop worth a few per cent is smaller than the machine's drift from one
process to the next (docs/numerics.md: kornia's and the operator's times move by a fifth to
2× between processes on the project's 2-core machines), so a perf run before a change and one
after cannot resolve it. Here both libraries are loaded into one process — the working tree's
(:func:`sssbench.ops.native.library`, "new") and one built from the base's sources into a
temporary folder ("base") — and every round calls each operator once with each library, the
order of the two flipped from round to round (:func:`alternated_ms`), on the 1080p (or 512²)
close-up of ``experiments.perf`` at 7 taps (the pre-integrated two-pass also at 33), and the
disk at 256² with 32 samples. The figure per operator is the median of the per-round ratios
new / base with its bootstrapped standard error (:func:`experiments.perf.median_ratio`).

That is done in ``--processes`` fresh processes (default 3), one after another, and the verdict
is on the mean of their figures ± its standard error between them (:func:`pooled`): within one
process the two libraries can differ by more than the rounds' standard error says. Measured
(2026-12-05, 2-core AMD EPYC, AVX-512): the same two builds — the same hot loops, by
objdump — gave the fused sweep 1.101 ± 0.009 new / base in one process and 1.006 ± 0.013 in
the next, the 33-tap pass 0.941 ± 0.002 and 1.010 ± 0.009. A ratio within two standard
errors of 1 is "not resolved" (:func:`ab_verdict`).

Both builds use the same compiler and flags (``native._FLAGS``); a base whose ``gather.c`` has
no ``SSS_PART`` halves compiles it whole, as one unit, beside ``disk.c`` (:func:`units_for`).
A base that lacks a symbol the working tree declares cannot be loaded, and the tool says so.
Only the libraries differ: both are called by the working tree's Python, so a change in what
the operators ask of the loop is not measured here (and a base older than the loop's argument
that such a change passes computes other values while it is timed: the fused sum of
Gaussians' ``inactive`` of 2026-12-06). Time such a change by alternating the two Python
behaviours in one process (docs/numerics.md).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

#: the operators the tool can time (``experiments.perf.methods`` names, at 7 taps unless
#: the name says otherwise), the disk included
OPS = (
    "preintegrated",
    "preintegrated@33",
    "sum_of_gaussians",
    "sum_of_gaussians_fused",
    "artist",
    "disk",
)
#: where the native sources live in the repository
NATIVE_DIR = "sssbench/ops/native"


def units_for(gather_source: str, has_disk: bool) -> tuple[tuple[str, ...], ...]:
    """The translation units (a file name and its ``-D`` flags) that build a revision's native
    library: ``gather.c``'s shared state and float32 loops where its source selects them by
    ``SSS_PART`` — split along the AVX-512 loops where it has ``SSS_AVX512_UNIT`` (the gather
    library's units, :data:`sssbench.ops.native._GATHER_UNITS`), else one unit; the float64
    loops, a library of their own since 2026-12-06, time no operator here — else ``gather.c``
    whole; ``disk.c`` where the revision has it."""
    from sssbench.ops import native

    if "SSS_AVX512_UNIT" in gather_source:  # the float32 part split along its loops
        units = tuple(u for u in native._GATHER_UNITS if u[0] == "gather.c")
    elif "SSS_PART" in gather_source:  # 2026-12-05 to 06: the float32 part one unit
        units = (("gather.c", "-DSSS_PART=1"),)
    else:
        units = (("gather.c",),)
    return units + ((("disk.c",),) if has_disk else ())


def sources_at(revision: str, dest: Path, repo: Path) -> None:
    """Write the native sources (``*.c``, ``*.h``) of ``revision`` into ``dest``."""
    listed = subprocess.run(
        ["git", "ls-tree", "--name-only", f"{revision}:{NATIVE_DIR}"],
        cwd=repo,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    names = [n for n in listed if n.endswith((".c", ".h"))]
    if "gather.c" not in names:
        raise SystemExit(f"--base {revision}: no {NATIVE_DIR}/gather.c at that revision")
    for name in names:
        text = subprocess.run(
            ["git", "show", f"{revision}:{NATIVE_DIR}/{name}"],
            cwd=repo,
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        (dest / name).write_text(text)


def build_base(src: Path, out: Path) -> Path:
    """The library of the native sources in ``src``, built into ``out`` (same compiler and
    flags as the working tree's)."""
    from sssbench.ops import native

    cc = native._compiler()
    if cc is None:
        raise SystemExit("no C compiler found ($CC, cc, gcc, clang)")
    gather = (src / "gather.c").read_text()
    units = tuple(
        (str(src / name), *flags) for name, *flags in units_for(gather, (src / "disk.c").exists())
    )
    print(f"ab_native: building the base library from {src} ({len(units)} units)", flush=True)
    native._compile_and_link(cc, units, str(out), out.parent)
    return out


def alternated_ms(
    calls: dict[str, tuple[Callable[[], object], Callable[[], object]]],
    rounds: int,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, tuple[list[float], list[float]]]:
    """ms per round of each operator's ``(base, new)`` calls by
    :func:`experiments.perf.interleaved_ms`: one untimed call of each first; then every round
    calls, operator by operator, both of its calls back to back, base first in even rounds and
    new first in odd ones (so that neither always runs on the caches the other left). Returns
    ``{operator: (base ms, new ms)}``."""
    from experiments.perf import interleaved_ms

    fns = {(key, side): pair[side] for key, pair in calls.items() for side in (0, 1)}

    def order(r: int) -> list[tuple[str, int]]:
        return [(key, side) for key in calls for side in ((0, 1) if r % 2 == 0 else (1, 0))]

    times = interleaved_ms(fns, rounds, clock, order=order)
    return {key: (times[(key, 0)], times[(key, 1)]) for key in calls}


def pooled(ratios: Sequence[float], within_se: float) -> tuple[float, float]:
    """The mean of the processes' ratios and its standard error between them
    (``stdev / sqrt(n)``); with one process, its ratio and ``within_se`` (the rounds')."""
    if len(ratios) == 1:
        return float(ratios[0]), within_se
    return statistics.fmean(ratios), statistics.stdev(ratios) / math.sqrt(len(ratios))


def ab_verdict(ratio: float, se: float) -> str:
    """``new / base`` read against its standard error: "not resolved" within two standard
    errors of 1 (or without one), else "new faster" / "new slower"."""
    if not se == se or abs(ratio - 1.0) <= 2.0 * se:  # se NaN: one round
        return "not resolved"
    return "new faster" if ratio < 1.0 else "new slower"


def _with_library(lib: object, fn: Callable[[], object]) -> Callable[[], object]:
    """``fn`` run with ``lib`` as the native library every pass uses."""
    import torch

    from sssbench.ops import native

    def call() -> object:
        native._STATE["lib"] = lib
        with torch.no_grad():
            return fn()

    return call


def operators(names: Sequence[str], res: tuple[int, int]) -> dict[str, Callable[[], object]]:
    """The calls to time, by name (:data:`OPS`): on the close-up at ``res``, the disk on the
    close-up at 256²."""
    from experiments.perf import CLOSE, DISK_SAMPLES, make_scene, methods
    from sssbench.ops import DiskSSS
    from sssbench.profiles import SumOfGaussians

    g = make_scene(CLOSE, res)
    made: dict[str, Callable[[], object]] = {}
    for name in names:
        if name == "disk":
            gd = make_scene(CLOSE, (256, 256))
            disk = DiskSSS(SumOfGaussians.from_table("skin_deon6"), samples=DISK_SAMPLES)
            made[name] = lambda disk=disk, gd=gd: disk(gd)
            continue
        method, _, taps = name.partition("@")
        table = methods(int(taps or 7))
        if method not in table:
            raise SystemExit(f"--ops: unknown operator {name!r}; choose from {', '.join(OPS)}")
        op = table[method]()
        made[name] = lambda op=op: op(g)
    return made


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m experiments.ab_native", description=__doc__)
    base = p.add_mutually_exclusive_group(required=True)
    base.add_argument("--base", help="git revision whose native sources are the base")
    base.add_argument("--base-dir", type=Path, help="folder of native sources for the base")
    base.add_argument("--child", type=Path, help=argparse.SUPPRESS)  # a built base: one process
    p.add_argument("--processes", type=int, default=3, help="fresh processes (default 3)")
    p.add_argument("--rounds", type=int, default=25, help="alternated rounds (default 25)")
    p.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    p.add_argument("--res", choices=("1080p", "512²"), default="1080p")
    p.add_argument("--ops", default=",".join(OPS), help=f"comma-separated, of {', '.join(OPS)}")
    args = p.parse_args(argv)
    if args.rounds < 2:
        p.error("--rounds: at least 2 (a standard error needs two rounds)")
    if args.threads < 1:
        p.error("--threads: at least 1")
    if args.processes < 1:
        p.error("--processes: at least 1")
    args.names = [n.strip() for n in args.ops.split(",") if n.strip()]
    unknown = [
        n
        for n in args.names
        if n.partition("@")[0] not in OPS_METHODS
        or (n.partition("@")[2] and not n.partition("@")[2].isdigit())
    ]
    if unknown or not args.names:
        p.error(f"--ops: unknown {unknown or 'none given'}; choose from {', '.join(OPS)}")
    return args


#: the operator names --ops accepts before an ``@taps``
OPS_METHODS = {n.partition("@")[0] for n in OPS}


def one_process(args: argparse.Namespace) -> dict[str, dict[str, float]]:
    """This process's figures (``--child``: the base library built at that path): per
    operator the median per-round ratio new / base, its standard error and both medians."""
    import torch

    from experiments.perf import RESOLUTIONS, median_ratio
    from sssbench.ops import native

    torch.set_num_threads(args.threads)
    new = native.library()
    if new is None:
        raise SystemExit("the working tree's native library is not available (see the warning)")
    try:
        base = native._load(args.child)
    except AttributeError as exc:
        missing = f"the base library lacks a symbol the working tree uses: {exc}"
        raise SystemExit(missing) from exc
    try:
        for lib in (base, new):  # each library on torch's OpenMP team, as the app runs
            native._STATE["lib"] = lib
            native.set_pool("openmp")
        made = operators(args.names, RESOLUTIONS[args.res])
        calls = {k: (_with_library(base, fn), _with_library(new, fn)) for k, fn in made.items()}
        times = alternated_ms(calls, args.rounds)
    finally:
        native._STATE["lib"] = new
    out = {}
    for key, (base_ms, new_ms) in times.items():
        ratio, se = median_ratio(new_ms, base_ms)
        out[key] = {
            "ratio": ratio,
            "se": se,
            "base_ms": statistics.median(base_ms),
            "new_ms": statistics.median(new_ms),
        }
    return out


def main(argv: Sequence[str] | None = None) -> int:
    from experiments.common import md_table

    args = parse(argv)
    if args.child is not None:  # one process's figures, as one JSON line
        print(json.dumps(one_process(args)), flush=True)
        return 0
    repo = Path(__file__).resolve().parents[1]
    runs: list[dict[str, dict[str, float]]] = []
    with tempfile.TemporaryDirectory(prefix="ab_native_") as tmp:
        src = Path(tmp) / "src"
        if args.base_dir is not None:
            src = args.base_dir.resolve()
        else:
            src.mkdir()
            sources_at(args.base, src, repo)
        built = build_base(src, Path(tmp) / "base.so")
        child = [sys.executable, "-m", "experiments.ab_native", "--child", str(built)]
        child += ["--rounds", str(args.rounds), "--threads", str(args.threads)]
        child += ["--res", args.res, "--ops", ",".join(args.names)]
        for i in range(args.processes):
            print(
                f"ab_native: process {i + 1}/{args.processes}: {len(args.names)} operators "
                f"× {args.rounds} rounds",
                flush=True,
            )
            done = subprocess.run(child, cwd=repo, capture_output=True, text=True)
            if done.returncode != 0:
                raise SystemExit(f"ab_native: process {i + 1} failed:\n{done.stderr[-2000:]}")
            runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    rows = []
    for key in args.names:
        ratios = [r[key]["ratio"] for r in runs]
        mean, se = pooled(ratios, runs[0][key]["se"])
        rows.append(
            (
                key,
                f"{statistics.median(r[key]['base_ms'] for r in runs):.2f}",
                f"{statistics.median(r[key]['new_ms'] for r in runs):.2f}",
                ", ".join(f"{r[key]['ratio']:.3f} ± {r[key]['se']:.3f}" for r in runs),
                f"{mean:.3f} ± {se:.3f}",
                ab_verdict(mean, se),
            )
        )
    base_name = args.base or str(args.base_dir)
    print(
        f"\nbase {base_name} against the working tree, {args.res} close-up (disk: 256²), "
        f"{args.threads} threads, wall time; per process the median per-round ratio new / base "
        f"over {args.rounds} rounds ± its bootstrapped standard error; pooled: the mean over "
        f"{len(runs)} processes ± its standard error between them\n"
    )
    headers = ["operator", "base ms", "new ms", "per process", "new / base", "verdict"]
    print(md_table(rows, headers))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The README's timings, measured: the README's top commands' main jobs from an empty cache.

Runs, each in a fresh temporary folder with an empty cache (``SSSBENCH_CACHE_DIR``: the
references, the native gather library; ``MPLCONFIGDIR``: matplotlib's font cache, as on a
fresh install):

- ``benchmark``: ``sssbench -m +experiment=benchmark`` (the first top command's main job);
- ``paper`` (``--paper``): ``sssbench -m +experiment=paper_benchmark`` (long: tens of minutes);
- ``paper_fast`` (``--paper-fast``): the same preset two jobs side by side, without the PNG
  previews (``hydra/launcher=joblib previews=false``: docs/sweeps.md says where the time goes);
- ``tests`` (``--tests``): ``python -m pytest -q`` (the second top command's main job).

and prints, for each, the wall time, the CPU time of the child processes and the machine
(CPU model, cores, load average before and after: on a shared machine the figure is an upper
bound). ``--write`` records the output in ``experiments/readme_timings.json`` and rewrites the
README's timing lines from it (the block between :data:`BEGIN` and :data:`END`,
:func:`readme_block`; ``tests/test_docs.py`` checks that they agree); ``--readme`` only rewrites
those lines from the JSON. ``--no-benchmark`` leaves the default benchmark out (e.g. to time
only the paper benchmark, on an idle machine, at merge time):

    python -m experiments.readme_timings [--paper] [--paper-fast] [--tests] [--no-benchmark]
        [--write]
    python -m experiments.readme_timings --paper --no-benchmark --write   # the paper's cold time
    python -m experiments.readme_timings --readme
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from datetime import UTC, datetime
from pathlib import Path

from sssbench import _json

REPO = Path(__file__).resolve().parents[1]
#: where ``--write`` records the latest measurement (the README quotes it)
RESULTS = Path(__file__).resolve().parent / "readme_timings.json"
#: the measured jobs: name -> the command, run in an empty folder
JOBS = {
    "benchmark": [sys.executable, "-m", "sssbench", "-m", "+experiment=benchmark"],
    "paper": [sys.executable, "-m", "sssbench", "-m", "+experiment=paper_benchmark"],
    "paper_fast": [
        *(sys.executable, "-m", "sssbench", "-m", "+experiment=paper_benchmark"),
        *("hydra/launcher=joblib", "previews=false"),
    ],
    "tests": [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(REPO / "tests")],
}


#: the README the timing lines are written into
README = REPO / "README.md"
#: the markers of the README's generated timing lines
BEGIN = "<!-- readme_timings: written by experiments/readme_timings.py from readme_timings.json -->"
END = "<!-- /readme_timings -->"
#: a load average (1 min) before the job below this is an idle machine; above, the wall time is
#: an upper bound (the load after a job is mostly its own processes, so it does not decide)
IDLE_LOAD = 0.75

#: the jobs as the README writes them
COMMANDS = {
    "benchmark": "sssbench -m +experiment=benchmark",
    "paper": "sssbench -m +experiment=paper_benchmark",
    "paper_fast": "sssbench -m +experiment=paper_benchmark hydra/launcher=joblib previews=false",
    "tests": "python -m pytest -q",
}


def cpuinfo(text: str | None = None) -> dict[str, str]:
    """The first CPU's fields in ``/proc/cpuinfo`` (``text``: its content, read when
    ``None``), ``{"model name": "AMD EPYC", "cpu family": "23", ...}``; empty where there is
    no such file."""
    if text is None:
        try:
            text = Path("/proc/cpuinfo").read_text()
        except OSError:
            return {}
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            if fields:  # the first CPU's block ends
                break
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def machine() -> dict[str, object]:
    """The machine a measurement ran on."""
    model = cpuinfo().get("model name") or platform.processor() or platform.machine()
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "system": platform.platform(terse=True),
    }


def measure(name: str, log_dir: Path | None = None) -> dict[str, object]:
    """Run job ``name`` from an empty folder and cache; its wall and CPU seconds (``log_dir``:
    also keep the job's output there, as ``<name>.log``)."""
    with tempfile.TemporaryDirectory(prefix=f"sssbench-timing-{name}-") as tmp:
        env = dict(os.environ)
        env |= {"SSSBENCH_CACHE_DIR": f"{tmp}/cache", "MPLCONFIGDIR": f"{tmp}/mpl"}
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
        load_before = os.getloadavg()
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        out = subprocess.PIPE
        proc = subprocess.run(
            JOBS[name], cwd=tmp, env=env, stdout=out, stderr=subprocess.STDOUT, text=True
        )
        wall = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        load_after = os.getloadavg()
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        (log_dir / f"{name}.log").write_text(proc.stdout)
    if proc.returncode != 0:
        print(proc.stdout[-3000:], file=sys.stderr)
    return {
        "command": COMMANDS[name],
        "machine": machine(),
        "exit_code": proc.returncode,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime, 1),
        "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in load_after],
        "measured_at": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def _conditions(r: dict[str, object], mach: dict[str, object]) -> str:
    """Where and under what load job record ``r`` was measured, and what that means."""
    before, after = r["load_before"][0], r["load_after"][0]  # type: ignore[index]
    where = (
        f"on {mach['cores']} cores ({mach['cpu']}) at load average {before:.1f} before and "
        f"{after:.1f} after"
    )
    if before < IDLE_LOAD:  # the load after a job is mostly the job's own processes
        return where + " (an idle machine before the run; the load after is the job's own)"
    return (
        where + " — a shared machine, so the wall time is an upper bound above an idle "
        "machine's; re-run the script on an idle machine for its figure"
    )


def _minutes_line(what: str, r: dict, top: dict) -> str:
    """A long job's README line from its record ``r``: ``what``, the date, the command, its wall
    and CPU minutes and :func:`_conditions` (``top``: the machine when ``r`` names none)."""
    when = str(r["measured_at"])[:10]
    return (
        f"{what} ({when}): `{r['command']}` took {r['wall_s'] / 60:.0f} min wall, "
        f"{r['cpu_s'] / 60:.0f} min CPU, {_conditions(r, r.get('machine', top))}."
    )


def readme_block(record: dict[str, object]) -> str:
    """The README's timing lines from ``record`` (the JSON), between :data:`BEGIN` and
    :data:`END`: every figure is the record's, every qualifier computed from its load."""
    top = record.get("machine", {})
    lines = [BEGIN]
    bench = record.get("benchmark")
    if isinstance(bench, dict):
        when = str(bench["measured_at"])[:10]
        lines.append(
            f"The latest record ({when}): `{bench['command']}` took {bench['wall_s']:.0f} s wall, "
            f"{bench['cpu_s']:.0f} s CPU from an empty folder and cache, "
            f"{_conditions(bench, bench.get('machine', top))}."
        )
    paper = record.get("paper")
    if isinstance(paper, dict):
        lines.append(_minutes_line("The paper benchmark from cold", paper, top))
    else:
        lines.append(
            "The paper benchmark's time from cold has not been measured by the script yet "
            "(`python -m experiments.readme_timings --paper --no-benchmark --write`, on an idle "
            "machine)."
        )
    fast = record.get("paper_fast")
    if isinstance(fast, dict):
        lines.append(_minutes_line("Two jobs side by side and no PNG previews", fast, top))
    wrap = functools.partial(
        textwrap.fill, width=100, break_long_words=False, break_on_hyphens=False
    )
    return "\n".join([BEGIN, *map(wrap, lines[1:]), END])


def write_readme(record: dict[str, object], path: Path = README) -> bool:
    """Replace the README's timing block with :func:`readme_block` of ``record``; whether the
    file changed."""
    text = path.read_text()
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"{path} has no timing block ({BEGIN!r} ... {END!r})")
    new = text[:start] + readme_block(record) + text[end + len(END) :]
    if new != text:
        path.write_text(new)
    return new != text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper", action="store_true", help="also the paper benchmark (long)")
    parser.add_argument(
        "--paper-fast",
        action="store_true",
        help="also the paper benchmark under joblib without previews (long)",
    )
    parser.add_argument("--tests", action="store_true", help="also the test suite")
    parser.add_argument(
        "--no-benchmark", action="store_true", help="leave the default benchmark out"
    )
    parser.add_argument(
        "--write", action="store_true", help=f"record into {RESULTS.name} and the README"
    )
    parser.add_argument(
        "--readme", action="store_true", help=f"only rewrite the README's lines from {RESULTS.name}"
    )
    parser.add_argument(
        "--log", type=Path, metavar="DIR", help="keep each job's output in DIR/<job>.log"
    )
    args = parser.parse_args(argv)
    if args.readme:
        changed = write_readme(_json.loads(RESULTS.read_text()))
        print(f"{README.name} {'rewritten' if changed else 'already up to date'}")
        return 0
    names = [
        *([] if args.no_benchmark else ["benchmark"]),
        *(["paper"] if args.paper else []),
        *(["paper_fast"] if args.paper_fast else []),
        *(["tests"] if args.tests else []),
    ]
    if not names:
        parser.error("nothing to time (--no-benchmark without --paper, --paper-fast or --tests)")
    results: dict[str, object] = {"machine": machine()}
    for name in names:
        print(f"timing {name} from an empty cache ...", flush=True)
        r = measure(name, args.log)
        results[name] = r
        print(
            f"{name}: {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU, exit {r['exit_code']}; "
            f"load average {r['load_before'][0]:.1f} before, {r['load_after'][0]:.1f} after "
            f"on {results['machine']['cores']} cores ({results['machine']['cpu']})",
            flush=True,
        )
    if args.write:
        old = _json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
        failed = [n for n in names if results[n]["exit_code"] != 0]  # type: ignore[index]
        if failed:  # a failed job's time is not the README's figure
            print(f"not recorded: {', '.join(failed)} failed", file=sys.stderr)
            return 1
        record = {**old, **results}
        RESULTS.write_text(_json.dumps(record, indent=2) + "\n")
        write_readme(record)
        print(f"recorded in {RESULTS} and {README.name}")
    return 0 if all(results[n]["exit_code"] == 0 for n in names) else 1


if __name__ == "__main__":
    sys.exit(main())

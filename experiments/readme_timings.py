"""The README's timings, measured: the README's top commands' main jobs from an empty cache.

Runs, each in a fresh temporary folder with an empty cache (``SSSBENCH_CACHE_DIR``: the
references, the native gather library; ``MPLCONFIGDIR``: matplotlib's font cache, as on a
fresh install):

- ``benchmark``: ``sssbench -m +experiment=benchmark`` (the first top command's main job);
- ``paper`` (``--paper``): ``sssbench -m +experiment=paper_benchmark`` (long: tens of minutes);
- ``tests`` (``--tests``): ``python -m pytest -q`` (the second top command's main job).

and prints, for each, the wall time, the CPU time of the child processes and the machine
(CPU model, cores, load average before and after: on a shared machine the figure is an upper
bound). ``--write`` records the output in ``experiments/readme_timings.json``, the file the
README's figures are copied from (``tests/test_docs.py`` checks that they agree).

    python -m experiments.readme_timings [--paper] [--tests] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import tempfile
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
    "tests": [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(REPO / "tests")],
}


#: the jobs as the README writes them
COMMANDS = {
    "benchmark": "sssbench -m +experiment=benchmark",
    "paper": "sssbench -m +experiment=paper_benchmark",
    "tests": "python -m pytest -q",
}


def machine() -> dict[str, object]:
    """The machine a measurement ran on."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "system": platform.platform(terse=True),
    }


def measure(name: str) -> dict[str, object]:
    """Run job ``name`` from an empty folder and cache; its wall and CPU seconds."""
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
    if proc.returncode != 0:
        print(proc.stdout[-3000:], file=sys.stderr)
    return {
        "command": COMMANDS[name],
        "exit_code": proc.returncode,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime, 1),
        "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in load_after],
        "measured_at": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper", action="store_true", help="also the paper benchmark (long)")
    parser.add_argument("--tests", action="store_true", help="also the test suite")
    parser.add_argument("--write", action="store_true", help=f"record into {RESULTS.name}")
    args = parser.parse_args(argv)
    names = ["benchmark", *(["paper"] if args.paper else []), *(["tests"] if args.tests else [])]
    results = {"machine": machine()}
    for name in names:
        print(f"timing {name} from an empty cache ...", flush=True)
        r = measure(name)
        results[name] = r
        print(
            f"{name}: {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU, exit {r['exit_code']}; "
            f"load average {r['load_before'][0]:.1f} before, {r['load_after'][0]:.1f} after "
            f"on {results['machine']['cores']} cores ({results['machine']['cpu']})",
            flush=True,
        )
    if args.write:
        old = _json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
        RESULTS.write_text(_json.dumps({**old, **results}, indent=2) + "\n")
        print(f"recorded in {RESULTS}")
    return 0 if all(results[n]["exit_code"] == 0 for n in names) else 1


if __name__ == "__main__":
    sys.exit(main())

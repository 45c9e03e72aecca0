"""The paper benchmark at 1080p (``+experiment=paper_benchmark_1080p``): the procedural face
and the head aimed at the cheek, at the extreme close-up (0.07 mm/px) and the portrait
(0.3 mm/px), every method and the do-nothing baseline at its default taps — from a cold
reference cache, its time stated with the load average.

    python -m experiments.run benchmark_1080p [--quick]

As :mod:`experiments.benchmark`: the references and budget limits are warmed in 2 processes
(:func:`sssbench.run.warm.warm`, progress per task), then the runs go through
:func:`sssbench.run.runner.execute` in 2 processes, each timed alone
(:func:`sssbench.run.parallel.run_parallel`, a line per scene group with an ETA); the section
is built from that run's store. ``SSSBENCH_BENCHMARK_1080P`` adds overrides to every job (a comma
replaces a sweep axis), e.g. ``"scene=face,face method=identity,preintegrated"``. It takes
long (the 1080p references: ~1.5 min each on an idle machine): run it on an idle machine.
The same sweep from the app: ``sssbench -m +experiment=paper_benchmark_1080p``.
"""

from __future__ import annotations

import sys

from experiments.benchmark import preset_section
from experiments.common import Context, Section, main

TITLE = "9b. The benchmark at 1080p: the close-up and the portrait"

#: overrides of the jobs from the environment (as ``SSSBENCH_BENCHMARK`` for the 512² one)
OVERRIDES_ENV = "SSSBENCH_BENCHMARK_1080P"

#: the ``--quick`` variant (the tests'): the preset's grid at 27x48, one repeat
QUICK = ("resolution=[27,48]", "repeats=1")


def run(ctx: Context) -> Section:
    return preset_section(ctx, "paper_benchmark_1080p", OVERRIDES_ENV, TITLE, *QUICK)


if __name__ == "__main__":
    sys.exit(main("benchmark_1080p", run))

"""experiments/ab_native.py: which units build a revision, the alternation's order, the
verdict's arithmetic and the base's sources read from git."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import pytest

from experiments import ab_native

REPO = Path(__file__).resolve().parents[2]


def test_units_follow_the_revisions_gather_source():
    split = ab_native.units_for("#if SSS_PART_F32\n", has_disk=True)
    assert split == (("gather.c", "-DSSS_PART=1"), ("disk.c",))  # the float32 part one unit
    # since 2026-12-06 that part is two units, split along its AVX-512 loops (the library's)
    split = ab_native.units_for("#if SSS_PART_F32\n#ifdef SSS_AVX512_UNIT\n", has_disk=True)
    assert split == (
        ("gather.c", "-DSSS_PART=1", "-DSSS_AVX512_UNIT=0"),
        ("gather.c", "-DSSS_PART=1", "-DSSS_AVX512_UNIT=1"),
        ("disk.c",),
    )
    # a revision from before the halves: gather.c whole (compiling it twice would define
    # every symbol twice), and no disk.c where it had none
    assert ab_native.units_for("int sss_gather_f32(void);\n", has_disk=False) == (("gather.c",),)


def test_alternation_flips_the_order_each_round_and_times_every_call():
    order: list[str] = []
    ticks = iter(range(1000))

    def clock() -> float:
        return next(ticks) / 1024  # 1/1024 s per reading: exact in binary

    def call(name: str):
        return lambda: order.append(name)

    calls = {"p": (call("p base"), call("p new")), "q": (call("q base"), call("q new"))}
    times = ab_native.alternated_ms(calls, 3, clock)
    warm, timed = order[:4], order[4:]
    assert warm == ["p base", "p new", "q base", "q new"]
    assert timed == [
        *("p base", "p new", "q base", "q new"),  # round 0: base first
        *("p new", "p base", "q new", "q base"),  # round 1: new first
        *("p base", "p new", "q base", "q new"),
    ]
    # each call between two readings of a clock that advances 1/1024 s per reading
    step = 1e3 / 1024
    assert times == {"p": ([step] * 3, [step] * 3), "q": ([step] * 3, [step] * 3)}


@pytest.mark.parametrize(
    "ratio, se, verdict",
    [
        (0.95, 0.02, "new faster"),  # 2.5 standard errors below 1
        (0.97, 0.02, "not resolved"),  # 1.5
        (1.0625, 0.03125, "not resolved"),  # exactly 2 (binary fractions): not beyond
        (1.07, 0.03125, "new slower"),
        (0.5, math.nan, "not resolved"),  # one round: no standard error
    ],
)
def test_verdict_needs_two_standard_errors(ratio, se, verdict):
    assert ab_native.ab_verdict(ratio, se) == verdict


def test_processes_pool_by_their_spread_not_by_their_rounds():
    # three processes: the mean and stdev / sqrt(3), whatever each one's rounds said
    mean, se = ab_native.pooled([1.0, 1.1, 0.9], within_se=0.001)
    assert mean == pytest.approx(1.0) and se == pytest.approx(0.1 / math.sqrt(3))
    # one process: its own figure and the rounds' standard error
    assert ab_native.pooled([1.25], within_se=0.03) == (1.25, 0.03)


def test_the_base_sources_are_the_revisions_files(tmp_path):
    if subprocess.run(["git", "-C", str(REPO), "rev-parse"], capture_output=True).returncode:
        pytest.skip("not a git checkout")
    ab_native.sources_at("HEAD", tmp_path, REPO)
    listed = subprocess.run(
        ["git", "-C", str(REPO), "ls-tree", "--name-only", "HEAD:sssbench/ops/native/"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    expected = sorted(n for n in listed if n.endswith((".c", ".h")))
    assert sorted(p.name for p in tmp_path.iterdir()) == expected
    committed = subprocess.run(
        ["git", "-C", str(REPO), "show", "HEAD:sssbench/ops/native/gather.c"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert (tmp_path / "gather.c").read_text() == committed


def test_bad_arguments_are_named():
    with pytest.raises(SystemExit):
        ab_native.parse(["--rounds", "5"])  # no base
    with pytest.raises(SystemExit):
        ab_native.parse(["--base", "HEAD", "--rounds", "1"])
    with pytest.raises(SystemExit):
        ab_native.parse(["--base", "HEAD", "--processes", "0"])
    for ops in ("kornia", "preintegrated@x", ""):
        with pytest.raises(SystemExit):
            ab_native.parse(["--base", "HEAD", "--ops", ops])
    args = ab_native.parse(["--base", "HEAD", "--ops", "artist, preintegrated@17"])
    assert args.names == ["artist", "preintegrated@17"] and args.processes == 3

"""Concatenate the section files into ``REPORT.md`` (generated; never edit it by hand).

    python -m experiments.make_report [--out DIR]      # same as: python -m experiments.run report

Sections are ``<out>/sections/<name>.md``, taken in :data:`ORDER`; any other section file
(a new experiment not yet listed) follows in alphabetical order, so adding a section needs no
change here. A section listed but missing is reported as not run.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
from pathlib import Path

from experiments.common import ROOT

#: report order: the claims of issue 6, with ``perf`` (written by the perf work) after cost
ORDER = [
    "low_rank",
    "step_edge",
    "gaussian_fits",
    "pole_fit",
    "sampling",
    "cost",
    "perf",
    "seal_speed",
    "gl_speed",
    "reference_speed",
    "scaling",
    "layers",
    "extensions",
    "benchmark",
    "benchmark_1080p",
    "plan",
    "stability",
    "disk",
    "mc_profiles",
    "mc_gap",
    "optimised",
]

HEADER = """# sssbench — reproduction report

> **Generated file — do not edit.** Built by `python -m experiments.run report` from
> `experiments/sections/*.md`, which the experiments write (`python -m experiments.run all`).
> Edit the experiment, re-run it, regenerate. See `experiments/README.md`.
"""


def _verdict(text: str) -> str:
    for line in text.splitlines():
        if line.startswith("**Verdict:"):
            return line.split("**")[1].removeprefix("Verdict:").strip().rstrip(".")
    return "–"


def _title(text: str, name: str) -> str:
    for line in text.splitlines():
        if line.startswith("## "):
            return line[3:].strip()
    return name


def make_report(out: Path = ROOT) -> Path:
    """Write ``<out>/REPORT.md`` from ``<out>/sections``; returns its path."""
    sections = out / "sections"
    present = {p.stem: p for p in sorted(sections.glob("*.md"))} if sections.is_dir() else {}
    names = [n for n in ORDER if n in present] + sorted(set(present) - set(ORDER))
    missing = [n for n in ORDER if n not in present]
    texts = {n: present[n].read_text() for n in names}
    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    lines = [HEADER, f"Assembled {stamp} from {len(names)} sections.", "", "| section | verdict |"]
    lines.append("|---|---|")
    lines += [f"| [{_title(texts[n], n)}](#{n}) | {_verdict(texts[n])} |" for n in names]
    if missing:
        lines += ["", "Not run yet: " + ", ".join(f"`{n}`" for n in missing) + "."]
    for n in names:
        lines += ["", "---", "", texts[n].rstrip()]
    path = out / "REPORT.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.make_report")
    ap.add_argument("--out", type=Path, default=ROOT)
    a = ap.parse_args(argv)
    print(make_report(a.out.resolve()))
    return 0


if __name__ == "__main__":
    sys.exit(main())

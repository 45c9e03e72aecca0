"""Shared plumbing of the experiments: arguments, timing, section and figure files.

An experiment is a module with ``TITLE`` and ``run(ctx: Context) -> Section``. :func:`main`
parses ``--quick`` / ``--out``, times ``run`` and writes ``<out>/sections/<name>.md`` (plus the
figures the experiment saved in ``<out>/figures/``). Sections link their figures as
``figures/<file>.png``: relative to ``REPORT.md``, which lives beside both folders.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

#: the experiments folder (default output root: sections/ and figures/ live here)
ROOT = Path(__file__).resolve().parent
VERDICTS = ("reproduced", "partly reproduced", "not reproduced", "not comparable", "pending")
#: largest PNG we commit (bytes)
MAX_PNG_BYTES = 200_000


@dataclass
class Context:
    """What an experiment needs to know about its invocation.

    Attributes:
        name: the experiment's name (its module name, its section file's stem).
        quick: tiny sizes, a few seconds (the tests' variant).
        out: output root; sections go to ``out/sections``, figures to ``out/figures``.
        threads: torch intra-op threads used for timings.
    """

    name: str
    quick: bool = False
    out: Path = ROOT
    threads: int = 1

    @property
    def sections(self) -> Path:
        return self.out / "sections"

    @property
    def figures(self) -> Path:
        return self.out / "figures"

    def figure(self, fig: Any, stem: str | None = None, dpi: int = 80) -> str:
        """Save a matplotlib figure as ``figures/<stem>.png`` (small), close it, return the
        Markdown link target (relative to ``REPORT.md``)."""
        import matplotlib.pyplot as plt

        self.figures.mkdir(parents=True, exist_ok=True)
        path = self.figures / f"{stem or self.name}.png"
        for d in (dpi, 64, 50):
            fig.savefig(path, dpi=d, bbox_inches="tight")
            if path.stat().st_size < MAX_PNG_BYTES:
                break
        plt.close(fig)
        return f"figures/{path.name}"


@dataclass
class Section:
    """One claim's section of the report.

    Attributes:
        title: section title (without number).
        claim: the paper's statement, with its source (Markdown).
        measured: what we measured, one paragraph (Markdown).
        verdict: one of :data:`VERDICTS`.
        reason: why (the likely reason when not reproduced; what is missing when pending).
        body: extra Markdown (tables, notes) placed after the figures.
        figures: figure link targets returned by :meth:`Context.figure`.
        data: machine-readable numbers (the tests and other sections may read them).
    """

    title: str
    claim: str
    measured: str
    verdict: str
    reason: str = ""
    body: str = ""
    figures: list[str] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")

    def markdown(self, name: str, command: str, seconds: float, quick: bool) -> str:
        parts = [
            f'<a id="{name}"></a>',
            f"## {self.title}",
            "",
            f"**Paper.** {self.claim}",
            "",
            f"**Measured.** {self.measured}",
            "",
            f"**Verdict: {self.verdict}.** {self.reason}".rstrip(),
            "",
        ]
        parts += [f"![{name}]({f})\n" for f in self.figures]
        if self.body:
            parts += [self.body.strip(), ""]
        stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
        parts.append(
            f"<sub>`{command}` — {seconds:.1f} s, torch threads {torch.get_num_threads()}, "
            f"{platform.machine()}, {'QUICK (tiny sizes, not the result)' if quick else 'full'}"
            f", {stamp}</sub>"
        )
        return "\n".join(parts) + "\n"


def md_table(rows: Sequence[Sequence[Any]], headers: Sequence[str]) -> str:
    """A GitHub Markdown table; floats to 4 significant digits."""

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            if math.isnan(v):
                return "–"
            if math.isinf(v):
                return "∞"
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def median_ms(fn: Callable[[], Any], repeats: int = 5, warmup: int = 1) -> float:
    """Median wall time of ``fn()`` in ms over ``repeats`` after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t) * 1e3)
    ts.sort()
    return ts[len(ts) // 2]


def parse_args(name: str, argv: Sequence[str] | None = None) -> Context:
    ap = argparse.ArgumentParser(prog=f"python -m experiments.{name}")
    ap.add_argument("--quick", action="store_true", help="tiny sizes (seconds): the test variant")
    ap.add_argument("--out", type=Path, default=ROOT, help="output root (sections/, figures/)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    a = ap.parse_args(argv)
    return Context(name, a.quick, a.out.resolve(), a.threads)


def execute(name: str, run: Callable[[Context], Section], ctx: Context) -> Path:
    """Run one experiment in ``ctx`` and write its section file; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    torch.set_num_threads(ctx.threads)
    ctx.sections.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    section = run(ctx)
    seconds = time.perf_counter() - t0
    command = f"python -m experiments.run {name}" + (" --quick" if ctx.quick else "")
    command += f" --threads {ctx.threads}" if ctx.threads != 1 else ""
    path = ctx.sections / f"{name}.md"
    path.write_text(section.markdown(name, command, seconds, ctx.quick))
    print(f"{name}: {section.verdict} ({seconds:.1f} s) -> {path}")
    return path


def main(name: str, run: Callable[[Context], Section], argv: Sequence[str] | None = None) -> int:
    execute(name, run, parse_args(name, argv))
    return 0


# ----------------------------------------------------------------------------- scenes
#: on-disk cache of exact references (outside the repository)
CACHE_DIR = Path.home() / ".cache" / "sssbench-experiments"


#: scene parameters the experiments override: ``pores`` defaults to 0.05 mm pixels, where the
#: exact reference's window is ~560 px wide (hours); 0.4 mm keeps it to ~70 px
SCENE_PARAMS: dict[str, dict[str, Any]] = {"pores": {"pixel_mm": 0.4}}


def scene(name: str, resolution: tuple[int, int], fields: Sequence[str] | None = None, **params):
    """``data_synth.make_scene`` in float32 with seed 0 (and :data:`SCENE_PARAMS`)."""
    import data_synth

    params = {**SCENE_PARAMS.get(name, {}), **params}
    return data_synth.make_scene(name, resolution, 0, fields=fields, **params)


def reference(name: str, resolution: tuple[int, int], profile: Any, **params) -> torch.Tensor:
    """The exact :class:`~sssbench.ops.ReferenceSSS` image of a scene (all fields), cached on
    disk by (scene, resolution, params, profile) — the reference is the expensive part."""
    import hashlib
    import json

    from sssbench.ops import ReferenceSSS
    from sssbench.ops.reference import reference_code_digest

    params = {**SCENE_PARAMS.get(name, {}), **params}
    key = json.dumps(
        [
            name,
            list(resolution),
            params,
            repr(profile),
            _profile_digest(profile),
            reference_code_digest(),
        ],
        sort_keys=True,
        default=str,
    )
    path = CACHE_DIR / f"ref_{hashlib.sha1(key.encode()).hexdigest()[:16]}.pt"
    if path.is_file():
        return torch.load(path, weights_only=True)
    g = scene(name, resolution, **params)
    with torch.inference_mode():
        img = ReferenceSSS(profile)(g)
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{time.time_ns()}.tmp")
    torch.save(img, tmp)
    tmp.replace(path)
    return img


def _profile_digest(profile: Any) -> str:
    parts = []
    for attr in ("variances", "weights", "sigma_s_prime", "sigma_a"):
        v = getattr(profile, attr, None)
        if isinstance(v, torch.Tensor):
            parts.append(",".join(f"{x:.12g}" for x in v.reshape(-1).tolist()))
    return "|".join(parts)


def errors(result: torch.Tensor, ref: torch.Tensor, g: Any) -> dict[str, float]:
    """``rel_rms`` and ``psnr`` over the SSS region (mask > 0, or everything)."""
    from sssbench.metrics import psnr, rel_rms

    mask = None if g.mask is None else (g.mask > 0).to(result.dtype)
    ref = ref.to(result.dtype)
    return {"rel_rms": rel_rms(result, ref, mask), "psnr": psnr(result, ref, mask)}


def op_available(name: str) -> bool:
    """Whether ``sssbench.ops`` has landed ``name`` yet."""
    import sssbench.ops

    return hasattr(sssbench.ops, name)

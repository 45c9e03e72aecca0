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
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

#: the experiments folder (default output root: sections/ and figures/ live here)
ROOT = Path(__file__).resolve().parent
#: a paper's claim is reproduced (or partly, or not); the project's own targets (performance,
#: stability) are "target met" / "target not met", never "reproduced"
VERDICTS = (
    "reproduced",
    "partly reproduced",
    "not reproduced",
    "not comparable",
    "pending",
    "target met",
    "target not met",
)
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

    def markdown(
        self, name: str, command: str, seconds: float, quick: bool, threads: int | None = None
    ) -> str:
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
            f"<sub>`{command}` — {seconds:.1f} s, torch threads "
            f"{threads if threads is not None else torch.get_num_threads()}, "
            f"{os.cpu_count()} cores, "
            f"{platform.machine()}, {'QUICK (tiny sizes, not the result)' if quick else 'full'}"
            f", {stamp}</sub>"
        )
        return "\n".join(parts) + "\n"


def shrink_png(path: Path, max_bytes: int = MAX_PNG_BYTES) -> Path:
    """Re-save a PNG written elsewhere (e.g. by :mod:`sssbench.report`) with a 256-colour
    palette, then at lower resolution until it is under ``max_bytes``."""
    from PIL import Image

    image = Image.open(path).convert("RGB")
    scale = 1.0
    while True:
        size = (max(1, int(image.width * scale)), max(1, int(image.height * scale)))
        image.resize(size, Image.LANCZOS).quantize(colors=256).save(path, optimize=True)
        if path.stat().st_size < max_bytes or scale < 0.3:
            return path
        scale *= 0.8


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


def timed(op: Callable[[Any], torch.Tensor], g: Any, repeats: int) -> tuple[torch.Tensor, float]:
    """Output of ``op(g)`` and the median over ``repeats`` of its summed pass times (ms;
    :func:`sssbench.ops.record_passes`), after one warm-up call."""
    from sssbench.ops import record_passes

    with torch.inference_mode():
        op(g)  # warm-up
        totals = []
        for _ in range(repeats):
            with record_passes() as recs:
                out = op(g)
            totals.append(sum(r.ms for r in recs))
    return out, statistics.median(totals)


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
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output root (default: experiments/, or experiments/_quick/ with --quick)",
    )
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    a = ap.parse_args(argv)
    return Context(name, a.quick, default_out(a.quick, a.out), a.threads)


#: where ``--quick`` runs write unless ``--out`` is given (ignored by git): quick sections are
#: not results and never overwrite the tracked report
QUICK_OUT = ROOT / "_quick"


def default_out(quick: bool, out: Path | None) -> Path:
    """``out`` if given, else :data:`ROOT` (full runs) or :data:`QUICK_OUT` (quick runs)."""
    if out is not None:
        return out.resolve()
    return QUICK_OUT if quick else ROOT


def execute(name: str, run: Callable[[Context], Section], ctx: Context) -> Path:
    """Run one experiment in ``ctx`` and write its section file; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    threads = torch.get_num_threads()
    torch.set_num_threads(ctx.threads)
    ctx.sections.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        section = run(ctx)
    finally:
        torch.set_num_threads(threads)  # restored: the caller's process is not changed
    seconds = time.perf_counter() - t0
    command = f"python -m experiments.run {name}" + (" --quick" if ctx.quick else "")
    command += f" --threads {ctx.threads}" if ctx.threads != 1 else ""
    path = ctx.sections / f"{name}.md"
    path.write_text(section.markdown(name, command, seconds, ctx.quick, ctx.threads))
    print(f"{name}: {section.verdict} ({seconds:.1f} s) -> {path}")
    return path


def main(name: str, run: Callable[[Context], Section], argv: Sequence[str] | None = None) -> int:
    execute(name, run, parse_args(name, argv))
    return 0


# ----------------------------------------------------------------------------- scenes
#: scene parameters the experiments override: ``pores`` defaults to 0.05 mm pixels, where the
#: exact reference's window is ~560 px wide (hours); 0.4 mm keeps it to ~70 px
SCENE_PARAMS: dict[str, dict[str, Any]] = {"pores": {"pixel_mm": 0.4}}


def scene(name: str, resolution: tuple[int, int], fields: Sequence[str] | None = None, **params):
    """The scene as the app builds it (:func:`sssbench.run.registry.build_scene`), float32, seed 0
    (and :data:`SCENE_PARAMS`)."""
    from sssbench.run import registry

    params = {**SCENE_PARAMS.get(name, {}), **params}
    return registry.build_scene(
        name, resolution, seed=0, fields=None if fields is None else tuple(fields), params=params
    )


def reference(
    name: str,
    resolution: tuple[int, int],
    profile: Any,
    stages: dict[str, Any] | None = None,
    **params,
) -> torch.Tensor:
    """The exact :class:`~sssbench.ops.ReferenceSSS` image of a scene (all fields) from the
    app's reference cache (:mod:`sssbench.store.refcache`, same key and directory as ``sssbench``
    runs): the reference is the expensive part. ``stages`` that change the light (e.g.
    translucency) are applied to the reference as the app applies them
    (:func:`sssbench.run.registry.build_pipeline`)."""
    from sssbench.ops import ReferenceSSS
    from sssbench.run import registry
    from sssbench.store.refcache import cached_reference, reference_key

    params = {**SCENE_PARAMS.get(name, {}), **params}
    key = reference_key(
        scene=name,
        scene_params=params,
        profile=profile,
        resolution=resolution,
        seed=0,
        dtype="float32",
        stages={k: v for k, v in (stages or {}).items() if v is not None and registry.STAGES[k][1]},
    )

    def compute() -> torch.Tensor:
        g = scene(name, resolution, **params)
        pipeline = registry.build_pipeline(
            ReferenceSSS(profile), profile, stages, for_reference=True
        )
        with torch.inference_mode():
            return pipeline.run(g).image

    return cached_reference(key, compute)[0]


def errors(result: torch.Tensor, ref: torch.Tensor, g: Any) -> dict[str, float]:
    """``rel_rms`` and ``psnr`` over the SSS region (mask > 0, or everything)."""
    from sssbench.score.metrics import psnr, rel_rms

    mask = None if g.mask is None else (g.mask > 0).to(result.dtype)
    ref = ref.to(result.dtype)
    return {"rel_rms": rel_rms(result, ref, mask), "psnr": psnr(result, ref, mask)}


def op_available(name: str) -> bool:
    """Whether ``sssbench.ops`` has landed ``name`` yet."""
    import sssbench.ops

    return hasattr(sssbench.ops, name)

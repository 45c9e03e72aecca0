"""The Hydra experiment app (DESIGN §6): ``sssbench`` and ``python -m sssbench``.

One run = one (scene, method, profile, sampling, samples) point. :func:`main` composes the
config from ``conf/`` (found next to the package, whatever the working directory), reads it
once into a plain :class:`RunSpec` (DESIGN §7: nothing below the app sees ``cfg``) and
:func:`execute` then

1. skips the point if the run store already holds it with status ``ok`` (unless ``force``);
2. builds the scene with the fields the pipeline needs, runs the pipeline ``warmup`` times
   untimed and ``repeats`` times timed (per pass: median / min / max; run time = sum of the
   pass medians);
3. loads the exact reference from the cache (``.pt`` keyed by a hash of scene, profile,
   resolution, seed, dtype) or computes and caches it;
4. computes the metrics (:mod:`sssbench.metrics`) over the SSS region (mask > 0);
5. writes ``metrics.json``, ``passes.csv``, ``point.json`` and PNG previews into the Hydra job
   directory and records the run in the store.

A run that raises is stored ``failed`` (with its message; the traceback goes to
``error.txt``), one over ``timeout_s`` is stored ``timeout``; a sweep always runs to the end
and the process exits 1 afterwards if any of its runs failed (:class:`ExitStatusCallback`).

Adding a method = one YAML file in ``conf/method/`` plus one entry in :data:`METHODS`.
"""

from __future__ import annotations

import contextlib
import csv
import importlib
import inspect
import json
import logging
import math
import os
import platform
import signal
import statistics
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import torch

from sssbench.ops.gather import BACKENDS, set_backend
from sssbench.tracking import PassStats, RunRecord, RunStore, config_hash, utc_now

log = logging.getLogger("sssbench")

__all__ = [
    "CONF_DIR",
    "METHODS",
    "PROFILE_KINDS",
    "RunSpec",
    "spec_from_cfg",
    "execute",
    "ExitStatusCallback",
    "main",
]

#: the Hydra config directory (repo root / conf), resolved from this file's location
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
#: config groups whose option names are checked before Hydra starts
GROUPS = ("method", "scene", "profile", "sampling", "experiment")

#: method name (``conf/method/<name>.yaml`` ``name:``) -> class in :mod:`sssbench.ops`.
#: The class is called as ``cls(profile, samples=..., sampling=..., **params)``, passing
#: ``samples`` / ``sampling`` only if its signature takes them.
METHODS: dict[str, str] = {
    "preintegrated": "PreintegratedSSS",
    "reference": "ReferenceSSS",
    "sum_of_gaussians": "SumOfGaussiansSSS",
    "low_rank": "LowRankSSS",
    "artist": "ArtistSSS",
    "jimenez2012": "Jimenez2012SSS",
}


def _sog_table(name: str, **params: Any) -> Any:
    from sssbench.profiles import SumOfGaussians

    if params:
        raise ValueError(f"profile kind sum_of_gaussians_table takes no params, got {params}")
    return SumOfGaussians.from_table(name)


#: profile ``kind`` (``conf/profile/*.yaml``) -> constructor ``f(name, **params)``
PROFILE_KINDS: dict[str, Callable[..., Any]] = {
    "sum_of_gaussians_table": _sog_table,
}

_DTYPES = {"float32": torch.float32, "float64": torch.float64}


# ----------------------------------------------------------------------------- the plain spec
@dataclass(frozen=True)
class RunSpec:
    """Everything one run needs, as plain values (read once from the Hydra config)."""

    scene: str
    method: str
    profile: str
    sampling: str | None
    samples: int | None
    resolution: tuple[int, int]
    seed: int = 0
    dtype: str = "float32"
    scene_params: dict[str, Any] = field(default_factory=dict)
    method_params: dict[str, Any] = field(default_factory=dict)
    profile_kind: str = "sum_of_gaussians_table"
    profile_params: dict[str, Any] = field(default_factory=dict)
    repeats: int = 5
    warmup: int = 1
    threads: int | None = None
    backend: str = "native"
    store: Path = Path("sssbench.sqlite")
    store_journal: str = "wal"
    force: bool = False
    timeout_s: float | None = None
    reference_cache: Path | None = None
    previews: bool = True

    def point(self) -> dict[str, Any]:
        """The keys that define the point (hashed for the store; run control left out)."""
        return {
            "scene": self.scene,
            "scene_params": self.scene_params,
            "method": self.method,
            "method_params": self.method_params,
            "profile": self.profile,
            "profile_kind": self.profile_kind,
            "profile_params": self.profile_params,
            "sampling": self.sampling,
            "samples": self.samples,
            "resolution": list(self.resolution),
            "seed": self.seed,
            "dtype": self.dtype,
            "threads": self.threads,
            "backend": self.backend,
        }

    def reference_key(self) -> dict[str, Any]:
        """What the reference depends on: scene, profile, resolution, seed, dtype (and the
        reference code itself, so a changed reference never comes from a stale cache)."""
        from sssbench.ops.reference import reference_code_digest

        return {
            "code": reference_code_digest(),
            "scene": self.scene,
            "scene_params": self.scene_params,
            "profile": self.profile,
            "profile_kind": self.profile_kind,
            "profile_params": self.profile_params,
            "resolution": list(self.resolution),
            "seed": self.seed,
            "dtype": self.dtype,
        }


def _method_class(name: str) -> type:
    if name not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {name!r}")
    ops = importlib.import_module("sssbench.ops")
    cls = getattr(ops, METHODS[name], None)
    if cls is None:
        raise ValueError(f"method {name!r} is not available: sssbench.ops has no {METHODS[name]}")
    return cls


def _takes(cls: type, arg: str) -> bool:
    params = inspect.signature(cls.__init__).parameters
    return arg in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def spec_from_cfg(cfg: Any) -> RunSpec:
    """Read a composed Hydra config into a :class:`RunSpec` (the only place that reads cfg)."""
    from omegaconf import OmegaConf

    c = OmegaConf.to_container(cfg, resolve=True)
    assert isinstance(c, dict)
    method = c["method"]["name"]
    cls = _method_class(method)
    takes_samples = _takes(cls, "samples")
    samples = c.get("samples") if takes_samples else None
    if samples is not None and (isinstance(samples, bool) or not isinstance(samples, int)):
        raise ValueError(f"samples must be an integer, got {samples!r}")
    sampling = c["sampling"]["name"] if _takes(cls, "sampling") else None
    res = c["resolution"]
    if isinstance(res, int):
        res = [res, res]
    if not (isinstance(res, list) and len(res) == 2 and all(isinstance(v, int) for v in res)):
        raise ValueError(f"resolution must be [H, W] (integers) or one integer, got {res!r}")
    if c["dtype"] not in _DTYPES:
        raise ValueError(f"dtype must be one of {sorted(_DTYPES)}, got {c['dtype']!r}")
    if c.get("backend", "native") not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {c.get('backend')!r}")
    for key in ("repeats", "warmup"):
        if not isinstance(c[key], int) or c[key] < (1 if key == "repeats" else 0):
            raise ValueError(f"{key} must be an integer >= {int(key == 'repeats')}, got {c[key]!r}")
    store = Path(c["store"]).expanduser().resolve()
    cache = c.get("reference_cache")
    return RunSpec(
        scene=c["scene"]["name"],
        scene_params=c["scene"].get("params") or {},
        method=method,
        method_params=c["method"].get("params") or {},
        profile=c["profile"]["name"],
        profile_kind=c["profile"].get("kind", "sum_of_gaussians_table"),
        profile_params=c["profile"].get("params") or {},
        sampling=sampling,
        samples=samples,
        resolution=(int(res[0]), int(res[1])),
        seed=int(c["seed"]),
        dtype=c["dtype"],
        repeats=c["repeats"],
        warmup=c["warmup"],
        threads=c.get("threads"),
        backend=str(c.get("backend", "native")),
        store=store,
        store_journal=c.get("store_journal", "wal"),
        force=bool(c.get("force", False)),
        timeout_s=None if c.get("timeout_s") is None else float(c["timeout_s"]),
        reference_cache=Path(cache).expanduser().resolve() if cache else None,
        previews=bool(c.get("previews", True)),
    )


# ----------------------------------------------------------------------------- building blocks
def build_profile(spec: RunSpec) -> Any:
    if spec.profile_kind not in PROFILE_KINDS:
        raise ValueError(
            f"profile kind must be one of {sorted(PROFILE_KINDS)}, got {spec.profile_kind!r}"
        )
    return PROFILE_KINDS[spec.profile_kind](spec.profile, **spec.profile_params)


def build_method(spec: RunSpec, profile: Any) -> torch.nn.Module:
    """``METHODS[spec.method](profile, samples=..., sampling=..., **params)``; a ``preset``
    param calls ``cls.preset(name, ...)`` instead, and classes whose first argument is not
    ``profile`` (parametric kernels) are built from their params alone."""
    cls = _method_class(spec.method)
    kwargs = dict(spec.method_params)
    if spec.samples is not None:
        kwargs["samples"] = spec.samples
    if spec.sampling is not None:
        kwargs["sampling"] = spec.sampling
    if "seed" not in kwargs and _takes(cls, "seed"):
        kwargs["seed"] = spec.seed  # stochastic methods (rotation) follow the run's seed
    preset = kwargs.pop("preset", None)
    if preset is not None:  # e.g. ArtistSSS.preset("production"), Jimenez2012SSS.preset(...)
        return cls.preset(preset, **kwargs)
    first = next(iter(list(inspect.signature(cls.__init__).parameters)[1:]), None)
    if first == "profile":  # methods built from the run's diffusion profile
        return cls(profile, **kwargs)
    return cls(**kwargs)  # parametric kernels (artist, 2012) carry their own profile


def _default_params(cls: type, params: dict[str, Any]) -> bool:
    """Whether every given keyword equals the constructor's default."""
    sig = inspect.signature(cls.__init__).parameters
    return all(k in sig and sig[k].default == v for k, v in params.items())


def build_scene(spec: RunSpec, fields: tuple[str, ...]) -> Any:
    import data_synth

    if spec.scene not in data_synth.SCENES:
        raise ValueError(f"scene must be one of {sorted(data_synth.SCENES)}, got {spec.scene!r}")
    return data_synth.make_scene(
        spec.scene,
        resolution=spec.resolution,
        seed=spec.seed,
        fields=fields,
        dtype=_DTYPES[spec.dtype],
        **spec.scene_params,
    )


def pass_stats(runs: list[list[Any]]) -> list[PassStats]:
    """Per-pass median / min / max over repeats (passes matched by position and name)."""
    if not runs:
        return []
    n = len(runs[0])
    for r in runs[1:]:
        if [p.name for p in r] != [p.name for p in runs[0]]:
            raise RuntimeError(
                "the pipeline ran different passes in different repeats: "
                f"{[p.name for p in runs[0]]} vs {[p.name for p in r]}"
            )
    out = []
    for i in range(n):
        ms = [r[i].ms for r in runs]
        first = runs[0][i]
        out.append(
            PassStats(
                first.name,
                first.samples,
                first.pixels,
                statistics.median(ms),
                min(ms),
                max(ms),
                len(ms),
            )
        )
    return out


class RunTimeout(Exception):
    """The run exceeded ``timeout_s``."""


@contextlib.contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Raise :class:`RunTimeout` after ``seconds`` of wall time (SIGALRM in the main thread;
    elsewhere the limit is checked when the block ends)."""
    if not seconds or seconds <= 0:
        yield
        return
    start = time.monotonic()
    use_signal = (
        hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
    )
    if use_signal:

        def handler(signum: int, frame: Any) -> None:
            raise RunTimeout(f"run exceeded timeout_s={seconds:g} s")

        previous = signal.signal(signal.SIGALRM, handler)
        signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        if use_signal:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
    if time.monotonic() - start > seconds:
        raise RunTimeout(f"run exceeded timeout_s={seconds:g} s")


def reference_image(
    spec: RunSpec, gbuffer: Any, profile: Any, cache_dir: Path
) -> tuple[torch.Tensor, bool, float]:
    """The exact reference, from the cache when possible.

    Returns:
        ``(image, cache_hit, compute_ms)`` (``compute_ms`` as stored with the cache entry).
    """
    from sssbench.ops import ReferenceSSS
    from sssbench.pipeline import Pipeline

    key = spec.reference_key()
    path = cache_dir / f"reference_{config_hash(key)}.pt"
    if path.is_file():
        try:
            entry = torch.load(path, weights_only=True)
            image = entry["image"]
            if tuple(image.shape) == tuple(gbuffer.diffuse.shape):
                log.info("reference cache hit: %s", path)
                return image.to(gbuffer.dtype), True, float(entry.get("ms", math.nan))
        except Exception as exc:  # a corrupt entry is recomputed
            log.warning("reference cache entry %s unreadable (%s); recomputing", path, exc)
    log.info("reference cache miss: computing %s", path.name)
    start = time.perf_counter()
    image = Pipeline(ReferenceSSS(profile)).run(gbuffer).image
    ms = (time.perf_counter() - start) * 1e3
    _save_reference(path, image, key, ms)
    return image, False, ms


def _save_reference(path: Path, image: torch.Tensor, key: dict[str, Any], ms: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    torch.save({"image": image.detach().cpu(), "key": json.dumps(key), "ms": ms}, tmp)
    os.replace(tmp, path)  # atomic: concurrent writers of the same key are harmless


def backend_used(backend: str) -> str:
    """The tap-loop backend a run really used: ``native`` falls back to ``torch`` without a C
    compiler (see :func:`sssbench.ops.set_backend`)."""
    from sssbench.ops import native

    return "torch" if backend == "native" and native.library() is None else backend


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in (
        "sssbench",
        "torch",
        "kornia",
        "numpy",
        "scikit-image",
        "hydra-core",
        "flip-evaluator",
        "pandas",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def write_previews(run_dir: Path, result: torch.Tensor, reference: torch.Tensor) -> list[str]:
    """``result.png``, ``reference.png`` (tone-mapped sRGB) and ``error.png`` (|error| heat map
    relative to the reference peak, magma) of the first image of the batch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image

    from sssbench.metrics import tonemap

    names = []
    for name, img in (("result", result), ("reference", reference)):
        rgb = tonemap(img[:1].double().clamp(min=0)).squeeze(0).permute(1, 2, 0).numpy()
        matplotlib.image.imsave(run_dir / f"{name}.png", rgb)
        names.append(f"{name}.png")
    err = (result[:1] - reference[:1]).abs().mean(1)[0].double()
    peak = float(reference[:1].max()) or 1.0
    rel = (err / peak).numpy()
    vmax = max(float(rel.max()), 1e-12)
    matplotlib.image.imsave(run_dir / "error.png", rel, cmap="magma", vmin=0.0, vmax=vmax)
    names.append("error.png")
    return names


# ----------------------------------------------------------------------------- one run
@dataclass
class RunOutcome:
    status: str  # ok, failed, timeout, skipped
    config_hash: str
    message: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)


def _measure(spec: RunSpec, run_dir: Path) -> tuple[dict[str, Any], list[PassStats]]:
    """Build, time, compare; return the metrics.json payload and the pass statistics."""
    from sssbench.metrics import compute_all
    from sssbench.ops import ReferenceSSS
    from sssbench.pipeline import Pipeline

    if spec.threads is not None:
        torch.set_num_threads(int(spec.threads))
    set_backend(spec.backend)
    profile = build_profile(spec)
    method = build_method(spec, profile)
    pipeline = Pipeline(method)
    ref_pipeline = Pipeline(ReferenceSSS(profile))
    fields = tuple(sorted(set(pipeline.needs) | set(ref_pipeline.needs)))
    gbuffer = build_scene(spec, fields)
    is_reference = spec.method == "reference"
    warmup, repeats = (0, 1) if is_reference else (spec.warmup, spec.repeats)
    if is_reference and (spec.warmup, spec.repeats) != (0, 1):
        log.info("method=reference is timed once (warmup 0, repeats 1)")
    with torch.inference_mode():
        for _ in range(warmup):
            pipeline.run(gbuffer)
        records = []
        for _ in range(repeats):
            out = pipeline.run(gbuffer)
            records.append(out.records)
        result = out.image
        cache_dir = spec.reference_cache or spec.store.parent / "reference_cache"
        if is_reference and _default_params(ReferenceSSS, spec.method_params):
            reference, hit = result, False
            ref_ms = sum(p.ms for p in out.records)
            _save_reference(
                cache_dir / f"reference_{config_hash(spec.reference_key())}.pt",
                result,
                spec.reference_key(),
                ref_ms,
            )
        else:
            reference, hit, ref_ms = reference_image(spec, gbuffer, profile, cache_dir)
    stats = pass_stats(records)
    mask = None
    if gbuffer.mask is not None:
        support = (gbuffer.mask > 0).to(result.dtype)
        if bool(support.reshape(support.shape[0], -1).sum(1).gt(0).all()):
            mask = support
    values = compute_all(result, reference, mask)
    time_ms = float(sum(p.ms_median for p in stats))
    payload: dict[str, Any] = {
        "scene": spec.scene,
        "method": spec.method,
        "profile": spec.profile,
        "sampling": spec.sampling,
        "samples": spec.samples,
        "passes": len(stats),
        "time_ms": time_ms,
        "pass_times": [
            {
                "name": p.name,
                "samples": p.samples,
                "pixels": p.pixels,
                "ms_median": p.ms_median,
                "ms_min": p.ms_min,
                "ms_max": p.ms_max,
            }
            for p in stats
        ],
        **values,
        "samples_per_pixel": int(sum(p.samples for p in stats)),
        "skipped_stages": [list(s) for s in out.skipped],
        "metric_region": "mask>0" if mask is not None else "all",
        "resolution": list(spec.resolution),
        "seed": spec.seed,
        "dtype": spec.dtype,
        "repeats": repeats,
        "warmup": warmup,
        "threads": torch.get_num_threads(),
        "backend": backend_used(spec.backend),
        "reference_cache_hit": hit,
        "reference_ms": ref_ms,
        "versions": versions(),
    }
    if spec.previews:
        payload["previews"] = write_previews(run_dir, result, reference)
    return payload, stats


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=str))
    os.replace(tmp, path)


def execute(spec: RunSpec, run_dir: str | Path, sweep_dir: str | Path | None = None) -> RunOutcome:
    """Run one point and record it; never raises for a failure of the run itself."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    store = RunStore(spec.store, journal_mode=spec.store_journal)
    point = spec.point()
    h = config_hash(point)
    label = "/".join(
        str(v) if v is not None else "-"
        for v in (spec.scene, spec.method, spec.profile, spec.sampling, spec.samples)
    )
    point_file = run_dir / "point.json"
    info = {"config_hash": h, "store": str(store.path), "config": point, "status": "running"}
    _write_json(point_file, info)
    if not spec.force and store.is_done(h):
        log.info("skip %s: already stored ok in %s (force=true re-runs)", label, store.path)
        _write_json(point_file, {**info, "status": "skipped"})
        return RunOutcome("skipped", h)
    started = utc_now()
    t0 = time.perf_counter()
    status, message, payload, stats = "ok", "", {}, []
    try:
        with time_limit(spec.timeout_s):
            payload, stats = _measure(spec, run_dir)
    except RunTimeout as exc:
        status, message = "timeout", str(exc)
    except Exception as exc:
        status, message = "failed", f"{type(exc).__name__}: {exc}"
        (run_dir / "error.txt").write_text(traceback.format_exc())
    wall = time.perf_counter() - t0
    metrics = {
        k: payload[k]
        for k in ("rmse", "rel_rms", "psnr", "ssim", "delta_e", "flip")
        if k in payload
    }
    if payload:
        metrics.update(
            samples_per_pixel=payload["samples_per_pixel"], reference_ms=payload["reference_ms"]
        )
        _write_json(
            run_dir / "metrics.json",
            {**payload, "status": status, "config_hash": h, "wall_s": wall},
        )
        with open(run_dir / "passes.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["name", "samples", "pixels", "ms_median", "ms_min", "ms_max", "repeats"])
            for p in stats:
                w.writerow(
                    [p.name, p.samples, p.pixels, p.ms_median, p.ms_min, p.ms_max, p.repeats]
                )
    record = RunRecord(
        config=point,
        status=status,
        metrics=metrics,
        passes=stats,
        time_ms=payload.get("time_ms"),
        error=message or None,
        info={
            k: payload[k]
            for k in (
                "threads",
                "backend",
                "versions",
                "skipped_stages",
                "reference_cache_hit",
                "metric_region",
            )
            if k in payload
        }
        | {"wall_s": wall},
        run_dir=str(run_dir.resolve()),
        sweep_dir=str(Path(sweep_dir).resolve()) if sweep_dir else None,
        started_at=started,
        finished_at=utc_now(),
    )
    store.record(record)
    _write_json(point_file, {**info, "status": status, "error": message or None})
    if status == "ok":
        log.info(
            "ok %s: %d passes, %.2f ms, rel_rms %.4g, psnr %.2f dB, flip %.4f (%.1f s)",
            label,
            len(stats),
            payload["time_ms"],
            payload["rel_rms"],
            payload["psnr"],
            payload["flip"],
            wall,
        )
    else:
        log.error("%s %s: %s (%.1f s)", status, label, message, wall)
    return RunOutcome(status, h, message, metrics)


# ----------------------------------------------------------------------------- Hydra edge
_STATE = {"failed": 0}


def task(cfg: Any) -> str:
    """The Hydra task function: one run. Failures are recorded, never raised."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    hc = HydraConfig.get()
    run_dir = Path(hc.runtime.output_dir)
    sweep_dir = Path(hc.sweep.dir).resolve() if hc.mode == RunMode.MULTIRUN else None
    try:
        spec = spec_from_cfg(cfg)
    except Exception as exc:  # a bad value in the config: record it like any failed run
        message = f"{type(exc).__name__}: {exc}"
        log.error("failed: invalid config: %s", message)
        _record_invalid(cfg, run_dir, sweep_dir, message)
        _STATE["failed"] += 1
        return "failed"
    try:
        outcome = execute(spec, run_dir, sweep_dir)
    except Exception as exc:  # e.g. the store is unwritable: report, never abort the sweep
        log.error("failed: could not run or record the point: %s: %s", type(exc).__name__, exc)
        _STATE["failed"] += 1
        return "failed"
    if outcome.status in ("failed", "timeout"):
        _STATE["failed"] += 1
    return outcome.status


def _record_invalid(cfg: Any, run_dir: Path, sweep_dir: Path | None, message: str) -> None:
    from omegaconf import OmegaConf

    try:
        config = OmegaConf.to_container(cfg, resolve=True)
        store = RunStore(Path(config["store"]).expanduser())
    except Exception:
        return
    config = {k: v for k, v in config.items() if k not in ("store", "force", "timeout_s")}
    point = {
        "scene": config.get("scene", {}).get("name"),
        "method": config.get("method", {}).get("name"),
        **config,
    }
    store.record(
        RunRecord(
            config=point,
            status="failed",
            error=message,
            run_dir=str(run_dir.resolve()),
            sweep_dir=str(sweep_dir) if sweep_dir else None,
        )
    )
    run_dir.mkdir(parents=True, exist_ok=True)
    _write_json(
        run_dir / "point.json",
        {
            "config_hash": config_hash(point),
            "store": str(store.path),
            "status": "failed",
            "error": message,
        },
    )


try:
    from hydra.experimental.callback import Callback as _HydraCallback
except ImportError:  # pragma: no cover
    _HydraCallback = object  # type: ignore[assignment,misc]


class ExitStatusCallback(_HydraCallback):
    """After a multirun: count failed / timed-out jobs from their ``point.json`` files (written
    by every launcher's jobs, local or remote) and make :func:`main` exit 1 if there are any."""

    def __init__(self) -> None:
        self._start = time.time()

    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        self._start = time.time()

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir)).resolve()
        counts: dict[str, int] = {}
        bad = []
        for p in sorted(sweep_dir.rglob("point.json")):
            if p.stat().st_mtime < self._start - 1:
                continue  # from an earlier invocation into the same directory
            try:
                status = json.loads(p.read_text()).get("status", "running")
            except (OSError, json.JSONDecodeError):
                status = "failed"
            status = "failed" if status == "running" else status  # job died mid-run
            counts[status] = counts.get(status, 0) + 1
            if status in ("failed", "timeout"):
                bad.append(p.parent.name)
        summary = ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) or "no jobs"
        log.info("sweep finished: %s (%s)", summary, sweep_dir)
        if bad:
            log.error("failed or timed-out jobs: %s", ", ".join(bad))
            _STATE["failed"] += len(bad)


def _check_overrides(argv: list[str]) -> str | None:
    """A one-line message for an unknown config-group option on the command line, else None."""
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+~")
        if key not in GROUPS or "(" in value or not value:
            continue
        available = sorted(p.stem for p in (CONF_DIR / key).glob("*.yaml"))
        for v in value.split(","):
            if v.strip() and v.strip() not in available:
                return f"unknown {key} {v.strip()!r}; available: {', '.join(available)}"
    return None


def main() -> None:
    """Console entry point of ``sssbench`` / ``python -m sssbench``."""
    import hydra

    if not (CONF_DIR / "config.yaml").is_file():
        print(
            f"sssbench: config directory not found: looked for {CONF_DIR / 'config.yaml'}",
            file=sys.stderr,
        )
        sys.exit(2)
    problem = _check_overrides(sys.argv[1:])
    if problem:
        print(f"sssbench: {problem}", file=sys.stderr)
        sys.exit(2)
    _STATE["failed"] = 0
    hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")(task)()
    if _STATE["failed"]:
        sys.exit(1)


if __name__ == "__main__":
    main()

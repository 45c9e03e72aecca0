"""The Hydra entry point (DESIGN §6): ``sssbench`` and ``python -m sssbench``.

One module because the app is one edge: the command-line checks, the Hydra composition and the
callbacks read the same config schema; splitting them would spread that schema over files.

:func:`main` checks the command line (one clear line and exit 2 for an unknown key, an empty
value, a value of the wrong type or an unknown config-group option; every value of every job of
the grid, by the run's own constructors without an image: :func:`check_values`; for every job,
that each stage switched on can run on its scene and change its image: :func:`check_stages`),
composes the config from
the package's ``conf/`` (:data:`CONF_DIR`, shipped inside the package), reads it once into a
plain :class:`~sssbench.run.spec.RunSpec` (:func:`spec_from_cfg`; DESIGN §7: nothing below the app
sees ``cfg``) and hands it to :func:`sssbench.run.runner.execute`. A sweep always runs to the end;
the process exits 1 afterwards if any of its runs failed (:class:`ExitStatusCallback`).
Hydra's check of a sweep's batch before its launch composes one job per group choices and keys
(:func:`_validate_one_per_signature`): the values are already checked for every job.

Adding a method = one YAML file in ``conf/method/`` plus one entry in
:data:`sssbench.run.registry.METHODS` (``docs/extending.md``).
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import functools
import gc
import json
import logging
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any

from sssbench import _json
from sssbench._checks import check_int, check_seed
from sssbench._console import quiet_third_party
from sssbench.run import registry
from sssbench.run.runner import execute, run_label
from sssbench.run.spec import DEFAULT_SEEDS, REFERENCES, RunSpec
from sssbench.store.tracking import RunRecord, RunStore, check_journal_mode, config_hash

log = logging.getLogger("sssbench")

__all__ = [
    "CONF_DIR",
    "GROUPS",
    "compose_spec",
    "expand_grid",
    "preset_grid",
    "preset_hydra",
    "spec_from_cfg",
    "task",
    "check_stages",
    "OBJECTIVES",
    "objectives",
    "ExitStatusCallback",
    "main",
]

#: the Hydra config directory, inside the installed package
CONF_DIR = Path(__file__).resolve().parent / "conf"
#: config groups whose option names are checked before Hydra starts
GROUPS = (
    "method",
    "scene",
    "profile",
    "sampling",
    "translucency",
    "curvature",
    "halo",
    "texturing",
    "experiment",
)
#: pipeline stage groups (each option: ``enabled`` and ``params``)
STAGE_GROUPS = tuple(registry.STAGES)
_BACKENDS = ("native", "torch", "compile", "gl")


def _version() -> str:
    try:
        return metadata.version("sssbench")
    except metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "unknown"


# ----------------------------------------------------------------------------- config -> spec
def _check_type(key: str, value: Any, kind: str) -> Any:
    """``value`` as ``kind`` (int, float, bool, int?, float?), or a ValueError naming ``key``."""
    optional = kind.endswith("?")
    kind = kind.rstrip("?")
    if value is None and optional:
        return None
    ok = {
        "int": isinstance(value, int) and not isinstance(value, bool),
        "float": isinstance(value, (int, float)) and not isinstance(value, bool),
        "bool": isinstance(value, bool),
        "str": isinstance(value, str),
    }[kind]
    if not ok:
        expected = f"{'an' if kind == 'int' else 'a'} {kind}" + (" or null" if optional else "")
        raise ValueError(f"{key} must be {expected}, got {value!r}")
    return float(value) if kind == "float" else value


#: top-level scalar keys of conf/config.yaml and their types (``?``: may be null)
SCALAR_KEYS = {
    "samples": "int?",
    "seed": "int",
    "dtype": "str",
    "repeats": "int",
    "warmup": "int",
    "threads": "int?",
    "backend": "str",
    "store": "str",
    "store_journal": "str",
    "force": "bool",
    "warm_workers": "int",
    "timeout_s": "float?",
    "reference_cache": "str?",
    "reference": "str",
    "previews": "bool",
    "budget": "bool",
    "seeds": "int",
}


def spec_from_cfg(cfg: Any, overridden: tuple[str, ...] = ()) -> RunSpec:
    """Read a composed Hydra config into a :class:`RunSpec` (the only place that reads cfg).

    Args:
        cfg: the composed config.
        overridden: top-level keys given on the command line (or by a sweep); an option the
            method does not take (``samples`` for the baseline, ``sampling`` for the low-rank
            method) that was given explicitly is recorded as ``ignored`` (in ``metrics.json``),
            never in the point: options a method does not use never split its point.
    """
    from omegaconf import OmegaConf

    c = OmegaConf.to_container(cfg, resolve=True)
    assert isinstance(c, dict)
    for key, kind in SCALAR_KEYS.items():
        if key in c:
            c[key] = _check_type(key, c[key], kind)
    method = c["method"]["name"]
    registry.method_class(method)  # a clear error for an unknown method
    samples = c.get("samples")
    if samples is not None and samples < 1:
        raise ValueError(f"samples must be an integer >= 1 (taps per pass), got {samples!r}")
    if c.get("threads") is not None and c["threads"] < 1:
        raise ValueError(f"threads must be an integer >= 1 or null, got {c['threads']!r}")
    # 0 keeps its earlier meaning, no limit (as null); a negative or NaN limit is refused
    if c.get("timeout_s") is not None and not c["timeout_s"] >= 0:
        raise ValueError(
            f"timeout_s must be seconds > 0, or 0 / null (no limit), got {c['timeout_s']}"
        )
    check_int("warm_workers", c.get("warm_workers", 0), 0)
    store = _store_path(c["store"])
    ignored: dict[str, Any] = {}
    if not registry.method_takes(method, "samples"):
        if "samples" in overridden and samples is not None:
            ignored["samples"] = samples  # recorded, not in the point
        samples = None
    sampling = c["sampling"]["name"]
    if sampling == "default":  # the method's own default placement, recorded as such
        sampling = registry.default_option(method, "sampling")
    if not registry.method_takes(method, "sampling"):
        if "sampling" in overridden and c["sampling"]["name"] != "default":
            ignored["sampling"] = c["sampling"]["name"]
        sampling = None
    res = c["resolution"]
    if isinstance(res, int) and not isinstance(res, bool):
        res = [res, res]
    if not (
        isinstance(res, list)
        and len(res) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in res)
    ):
        raise ValueError(
            f"resolution must be [H, W] (positive integers) or one integer, got {res!r}"
        )
    if c["dtype"] not in ("float32", "float64"):
        raise ValueError(f"dtype must be float32 or float64, got {c['dtype']!r}")
    if c["backend"] not in _BACKENDS:
        raise ValueError(f"backend must be one of {list(_BACKENDS)}, got {c['backend']!r}")
    for key in ("repeats", "warmup"):
        if c[key] < (1 if key == "repeats" else 0):
            raise ValueError(f"{key} must be an integer >= {int(key == 'repeats')}, got {c[key]!r}")
    scene_params = dict(c["scene"].get("params") or {})
    import data_synth

    if c["scene"]["name"] in data_synth.RETIRED_SCENES:
        raise ValueError(data_synth.RETIRED_SCENES[c["scene"]["name"]])
    if c["scene"]["name"] == registry.FILE_SCENE:
        from sssbench.io import read_gbuffer, scene_file_digest

        raw = c["scene"].get("path")
        if not raw or raw == "???":
            raise ValueError("scene=file needs scene.path=<G-buffer .exr or .npz>")
        path = Path(raw).expanduser().resolve()
        if not path.is_file():
            what = "a directory, not a file" if path.is_dir() else "no such file"
            raise ValueError(f"scene.path={raw}: {what} (a G-buffer .exr or .npz)")
        try:
            scene_params = {"path": str(path), "sha256": scene_file_digest(path)}
            size = list(read_gbuffer(path).shape[1:])
        except (OSError, ValueError, TypeError) as exc:
            raise ValueError(f"scene.path={raw}: {exc}".replace("\n", " ")) from exc
        if "resolution" in overridden and [int(v) for v in res] != size:
            raise ValueError(
                f"resolution={list(res)} was given but scene.path={raw} is {size[0]}x{size[1]}: "
                "a file scene runs at the file's size (leave resolution out, or give its size)"
            )
        res = size
    stages = {}
    for group in STAGE_GROUPS:
        entry = c.get(group) or {}
        stages[group] = dict(entry.get("params") or {}) if entry.get("enabled") else None
    reference, reference_params, mc_params = _reference_choice(c, c["scene"]["name"])
    cache = c.get("reference_cache")
    tracking = c.get("tracking") or {}
    return RunSpec(
        scene=c["scene"]["name"],
        scene_params=scene_params,
        method=method,
        method_params=c["method"].get("params") or {},
        profile=c["profile"]["name"],
        profile_kind=c["profile"].get("kind", "sum_of_gaussians_table"),
        profile_params=c["profile"].get("params") or {},
        sampling=sampling,
        samples=samples,
        stages=stages,
        ignored=ignored,
        reference_params=reference_params,
        reference=reference,
        mc_params=mc_params,
        budget=bool(c.get("budget", True)),
        seeds=check_int("seeds", c.get("seeds", DEFAULT_SEEDS), 2),
        resolution=(int(res[0]), int(res[1])),
        seed=check_seed("seed", c["seed"]),  # all its bits honoured, or refused up front
        dtype=c["dtype"],
        repeats=c["repeats"],
        warmup=c["warmup"],
        threads=c.get("threads"),
        backend=c["backend"],
        store=store,
        store_journal=check_journal_mode("store_journal", c.get("store_journal", "wal")),
        force=c.get("force", False),
        timeout_s=c.get("timeout_s"),
        reference_cache=Path(cache).expanduser().resolve() if cache else None,
        previews=c.get("previews", True),
        mlflow=_check_type("tracking.mlflow", tracking.get("mlflow", False), "bool"),
        mlflow_uri=tracking.get("mlflow_uri"),
    )


def _store_path(value: str) -> Path:
    """The run store's path, checked before any run: its folder must exist (the store file
    is created on the first run, its folder never is)."""
    path = Path(value).expanduser().resolve()
    if path.is_dir():
        raise ValueError(
            f"store={value} is a directory; give the store's file, e.g. {path}/sssbench.sqlite"
        )
    if not path.parent.is_dir():
        raise ValueError(
            f"store={value}: its folder {path.parent} does not exist (create it first)"
        )
    return path


def _reference_choice(c: dict[str, Any], scene: str) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """``(reference, reference_params, mc_params)`` of the config, checked: ``reference`` one
    of :data:`~sssbench.run.spec.REFERENCES`, Monte Carlo options (``reference_params.mc_*``)
    only with ``mc``, ``mc`` only for a scene with a Monte Carlo model."""
    from sssbench.run.spec import MC_OPTIONS

    reference = c.get("reference", "profile")
    if reference not in REFERENCES:
        raise ValueError(f"reference must be one of {list(REFERENCES)}, got {reference!r}")
    params = dict(c.get("reference_params") or {})
    mc_keys = sorted(set(params) & set(MC_OPTIONS))
    if mc_keys and reference != "mc":
        raise ValueError(f"reference_params {mc_keys} need reference=mc")
    if reference == "mc":
        from data_synth.mc_scenes import MC_SCENES

        if scene not in MC_SCENES:
            raise ValueError(
                f"reference=mc needs a scene with a Monte Carlo model ({', '.join(MC_SCENES)}); "
                f"scene {scene!r} has none"
            )
    mc = {k: params.pop(k) for k in mc_keys}
    return reference, params, mc


@functools.lru_cache(maxsize=256)
def _compose_groups(groups: tuple[str, ...]) -> Any:
    """The composed config for config-group choices ``groups`` (Hydra's compose API; cached:
    composing costs ~0.3 s, and a grid has few distinct group combinations)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=["store=sssbench.sqlite", *groups])


def _group_key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


@functools.lru_cache(maxsize=256)
def _own_package(fixed: tuple[str, ...], choice: str) -> bool:
    """Whether the group choice ``choice`` (e.g. ``method=disk``), composed with the global
    choices ``fixed`` (the ``experiment`` presets), changes nothing but its own group's node."""
    from omegaconf import OmegaConf

    key = _group_key(choice)
    base = OmegaConf.to_container(_compose_groups(fixed), resolve=False)
    alone = OmegaConf.to_container(_compose_groups((*fixed, choice)), resolve=False)
    assert isinstance(base, dict) and isinstance(alone, dict)
    base.pop(key, None)
    alone.pop(key, None)
    return base == alone


def _assembled(groups: tuple[str, ...]) -> Any:
    """A copy of the config Hydra composes for the group choices ``groups`` — one composition
    per choice, not per combination: the composition of the global choices (``experiment``)
    with each group's node taken from the composition of that choice alone. Exact because a
    choice of a group other than ``experiment`` lives in its own package (checked per choice,
    :func:`_own_package`; any other case is composed whole). A grid of 6 scenes × 7 methods
    composes 14 times instead of 42 (:func:`check_values` reads every job of a sweep)."""
    from omegaconf import OmegaConf

    keys = [_group_key(g) for g in groups]
    fixed = tuple(g for g, k in zip(groups, keys, strict=True) if k == "experiment")
    rest = [g for g, k in zip(groups, keys, strict=True) if k != "experiment"]
    whole = (
        any(g.startswith("~") for g in groups)
        or len(set(keys)) != len(keys)
        or not all(_own_package(fixed, g) for g in rest)
    )
    if whole:
        return copy.deepcopy(_compose_groups(groups))
    cfg = copy.deepcopy(_compose_groups(fixed))
    for g in rest:
        node = _compose_groups((*fixed, g))[_group_key(g)]
        cfg[_group_key(g)] = OmegaConf.to_container(node, resolve=False)
    return cfg


def compose_spec(*overrides: str, store: str | Path | None = None) -> RunSpec:
    """The :class:`RunSpec` the app would run for ``overrides`` — how the experiments and
    scripts build exactly the app's runs (same defaults, same validation).

    Config-group choices (``method=artist``, ``+experiment=...``) are composed by Hydra
    (cached per combination); other ``key=value`` overrides are applied to the composed
    config with OmegaConf (values parsed as YAML, as Hydra parses plain values)."""
    from omegaconf import OmegaConf

    groups = tuple(o for o in overrides if o.split("=", 1)[0].lstrip("+~") in GROUPS)
    values = [o for o in overrides if o not in groups]
    cfg = _assembled(groups)
    for o in [*values, *([f"store={store}"] if store is not None else [])]:
        if "=" not in o:
            raise ValueError(f"override must be key=value, got {o!r}")
        key, value = o.split("=", 1)
        OmegaConf.update(cfg, key.lstrip("+"), _parse_scalar(value), force_add=key.startswith("+"))
    keys = tuple(o.split("=", 1)[0].lstrip("+~") for o in overrides)
    return spec_from_cfg(cfg, keys)


def expand_grid(params: dict[str, str]) -> list[list[str]]:
    """The override lists of a basic-sweeper grid ``{key: "a,b,c" | "glob(*,exclude=x)"}``
    (group globs expand over the group's options in :data:`CONF_DIR`), in Hydra's order."""
    import fnmatch
    import itertools

    axes = []
    for key, value in params.items():
        value = str(value)
        if value.startswith("glob("):
            inner = value[len("glob(") : -1]
            parts = [p.strip() for p in inner.split(",")]
            include = [p for p in parts if not p.startswith("exclude=")]
            exclude = [p.split("=", 1)[1] for p in parts if p.startswith("exclude=")]
            options = [
                o
                for o in _group_options(key)
                if any(fnmatch.fnmatch(o, i) for i in include)
                and not any(fnmatch.fnmatch(o, e) for e in exclude)
            ]
        else:
            options = [v.strip() for v in _split_items(value)]  # ``[16,16],[32,32]``: 2 values
        axes.append([f"{key}={o}" for o in options])
    return [list(c) for c in itertools.product(*axes)]


def preset_hydra(preset: str) -> Any:
    """Hydra's own config (``cfg.hydra``: sweeper, launcher, callbacks) under
    ``+experiment=<preset>``."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=["store=x", f"+experiment={preset}"],
            return_hydra_config=True,
        )
    return cfg.hydra


def preset_grid(preset: str, *overrides: str) -> list[list[str]]:
    """The override lists of the jobs of ``sssbench -m +experiment=<preset> <overrides>``."""
    from omegaconf import OmegaConf

    params = OmegaConf.to_container(preset_hydra(preset).sweeper.params) or {}
    for o in overrides:
        key, value = o.split("=", 1)
        # the preset's axis of the same key, whatever its prefix (``++scene.params.pixel_mm``)
        same = [k for k in params if k.lstrip("+~") == key.lstrip("+~")]
        for k in same:
            del params[k]
        params[same[0] if same else key.lstrip("+")] = value
    return [[f"+experiment={preset}", *job] for job in expand_grid(params)]


# ----------------------------------------------------------------------------- Hydra edge
#: the progress of the command line's sweep, and the jobs :func:`check_values` composed
_STATE: dict[str, Any] = {"failed": 0, "done": 0, "total": 0, "start": 0.0, "composed": frozenset()}


def _overridden() -> tuple[str, ...]:
    from hydra.core.hydra_config import HydraConfig

    keys = []
    for o in HydraConfig.get().overrides.task:
        keys.append(o.split("=", 1)[0].lstrip("+~"))
    return tuple(keys)


#: what the app returns to a search that minimises the task's return values (Hydra's Optuna
#: sweeper, ``conf/experiment/optuna.yaml``), in the order of its ``direction`` list: the run's
#: relative RMS error against the exact reference and its time (ms, sum of the pass medians)
OBJECTIVES = ("rel_rms", "time_ms")


def objectives(store: str | Path, config_hash: str) -> tuple[float, ...] | None:
    """:data:`OBJECTIVES` of the newest ``ok`` run of ``config_hash`` in ``store`` (a point a
    search proposes again, or one stored by an earlier sweep, is skipped by the runner — which
    skips a point with any ``ok`` run — and answered from the store), ``None`` without one."""
    rows = [r for r in RunStore(Path(store)).runs(status="ok") if r["config_hash"] == config_hash]
    if not rows:
        return None
    values = {**rows[-1]["metrics"], "time_ms": rows[-1]["time_ms"]}  # oldest first
    return tuple(float(values[k]) for k in OBJECTIVES)


def _returns_objectives(hc: Any) -> bool:
    """Whether the sweeper uses the task's return value as objectives (Optuna's)."""
    return "optuna" in str(hc.sweeper.get("_target_", "")).lower()


def task(cfg: Any) -> str | tuple[float, ...]:
    """The Hydra task function: one run. Failures are recorded, never raised.

    Returns the run's status, or under a search that minimises return values (Optuna) the
    run's :data:`OBJECTIVES` (the status when the run failed: the sweeper records a failed
    trial and goes on, ``max_failure_rate`` permitting)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    quiet_third_party()  # also in a launcher's worker processes
    hc = HydraConfig.get()
    run_dir = Path(hc.runtime.output_dir)
    multirun = hc.mode == RunMode.MULTIRUN
    sweep_dir = Path(hc.sweep.dir).resolve() if multirun else None
    try:
        spec = spec_from_cfg(cfg, _overridden())
    except Exception as exc:  # a bad value in the config: record it like any failed run
        message = f"{type(exc).__name__}: {exc}"
        log.error("failed: invalid config: %s", message)
        _record_invalid(cfg, run_dir, sweep_dir, message)
        _STATE["failed"] += 1
        return "failed"
    _progress(spec, hc, multirun)
    try:
        launcher = str((hc.get("launcher") or {}).get("_target_", "")) if multirun else ""
        with _timing_slot(launcher, sweep_dir):
            outcome = execute(spec, run_dir, sweep_dir)
    except Exception as exc:  # e.g. the store is unwritable: report, never abort the sweep
        log.error("failed: could not run or record the point: %s: %s", type(exc).__name__, exc)
        _STATE["failed"] += 1
        return "failed"
    _STATE["done"] += 1
    if outcome.status in ("failed", "timeout"):
        _STATE["failed"] += 1
    if not multirun:
        print(f"sssbench: {outcome.status}; output in {run_dir.resolve()}", flush=True)
    if _returns_objectives(hc) and outcome.status in ("ok", "skipped"):
        return objectives(spec.store, outcome.config_hash) or outcome.status
    return outcome.status


#: launchers whose jobs run side by side in processes of this machine: each run's timed
#: section holds the sweep's timing lock (:func:`sssbench.run.settings.timing_slot`)
SLOT_LAUNCHERS = ("JoblibLauncher",)


def _timing_slot(launcher_target: str, sweep_dir: Path | None) -> Any:
    """The run's :func:`~sssbench.run.settings.timing_slot` on ``<sweep dir>/.timing.lock``
    under a launcher of :data:`SLOT_LAUNCHERS` (joblib: its jobs build and score side by side,
    and each run is timed while the others wait), else a no-op context."""
    import contextlib

    if sweep_dir is None or launcher_target.rsplit(".", 1)[-1] not in SLOT_LAUNCHERS:
        return contextlib.nullcontext()
    from sssbench.run.settings import timing_slot

    sweep_dir.mkdir(parents=True, exist_ok=True)
    return timing_slot(sweep_dir / ".timing.lock")


def _progress(spec: RunSpec, hc: Any, multirun: bool = True) -> None:
    """One progress line per run: ``[k/n] label`` (``[1/1]`` for a single run) and, in a
    sweep, the ETA."""
    total = _STATE["total"] if multirun else 1
    k = _STATE["done"] + 1
    if total > 1 and _STATE["done"] > 0:
        per = (time.time() - _STATE["start"]) / _STATE["done"]
        eta = f", ETA {per * (total - _STATE['done']):.0f} s"
    else:
        eta = ""
    log.info("[%d/%s] %s%s", k, total or "?", run_label(spec), eta)


def _record_invalid(cfg: Any, run_dir: Path, sweep_dir: Path | None, message: str) -> None:
    from omegaconf import OmegaConf

    try:
        config = OmegaConf.to_container(cfg, resolve=True)
        store = RunStore(Path(config["store"]).expanduser())
    except Exception:
        return
    config = {k: v for k, v in config.items() if k not in ("store", "force", "timeout_s")}
    point = {  # names first and last: the report shows the scene and method, not their dicts
        **config,
        "scene": (config.get("scene") or {}).get("name"),
        "method": (config.get("method") or {}).get("name"),
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
    (run_dir / "point.json").write_text(
        _json.dumps(
            {
                "config_hash": config_hash(point),
                "store": str(store.path),
                "status": "failed",
                "error": message,
            },
            indent=2,
            default=str,
        )
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
        _STATE["start"] = self._start
        _STATE["total"] = _sweep_size(config)
        _warm_sweep(config)
        _STATE["start"] = time.time()  # the runs' ETA counts from the first run, not the warm-up
        mirror = _sweep_mirror(config)
        if mirror is not None:  # the parent run of the sweep's runs (created once, up front)
            mirror.start_sweep(str(Path(str(config.hydra.sweep.dir)).resolve()))

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        from sssbench.store.refcache import STATS

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
        refs = f"; references: {STATS['hit']} cached, {STATS['miss']} computed"
        log.info("sweep finished: %s%s (%s)", summary, refs, sweep_dir)
        if bad:
            log.error("failed or timed-out jobs: %s", ", ".join(bad))
            _STATE["failed"] += len(bad)
        mirror = _sweep_mirror(config)
        if mirror is not None and mirror.find_sweep(str(sweep_dir)) is not None:
            mirror.end_sweep(counts)


#: a multirun of images smaller than this (pixels) is not warmed: its references take less
#: time than starting the worker processes
WARM_MIN_PIXELS = 128 * 128


def _config_store(config: Any) -> Path:
    """The store of a sweep's config in a callback (Hydra's ``runtime.cwd`` resolver may not be
    set yet when the sweep starts: it is the launch directory)."""
    import os

    from omegaconf import OmegaConf

    raw = str(OmegaConf.to_container(config, resolve=False)["store"])
    raw = raw.replace("${hydra:runtime.cwd}", os.getcwd())
    if "${" in raw:
        raw = str(config.store)
    return Path(raw).expanduser().resolve()


def sweep_jobs(config: Any) -> list[list[str]]:
    """The override lists of a basic-sweeper multirun's jobs (the preset's grid and the command
    line's swept values, the command line's other overrides in every job); ``[]`` for a search
    or when the grid cannot be expanded here (Hydra functions other than ``glob``)."""
    if "n_trials" in config.hydra.sweeper:
        return []
    params = {str(k): str(v) for k, v in dict(config.hydra.sweeper.get("params") or {}).items()}
    fixed = []
    for o in config.hydra.overrides.task:
        key, _, value = str(o).partition("=")
        if key.lstrip("+~").startswith("hydra"):
            continue
        if _swept(value):
            params[key] = value
        elif key in params:  # replaces the preset's axis (Hydra's basic sweeper: same key)
            params[key] = value
        else:
            fixed.append(str(o))
    if any("(" in v and not v.startswith("glob(") for v in params.values()):
        return []
    return [[*fixed, *job] for job in expand_grid(params)]


#: the launchers (class names) whose jobs run on this machine: a sweep under them is warmed
#: first (:func:`_warm_sweep`); a cluster launcher's jobs run elsewhere and warm nothing here
WARM_LAUNCHERS = ("BasicLauncher", "JoblibLauncher")


def warms_under(launcher_target: str) -> bool:
    """Whether a sweep under the launcher ``launcher_target`` (its ``_target_``, a dotted class
    path) is warmed before its first run: the launchers of :data:`WARM_LAUNCHERS`."""
    return launcher_target.rsplit(".", 1)[-1] in WARM_LAUNCHERS


def _warm_sweep(config: Any) -> None:
    """Warm the sweep's reference cache in ``warm_workers`` processes before its first run
    (:func:`sssbench.run.warm.warm`, as ``experiments/benchmark.py`` does): the references and
    error-budget limits are computed in parallel, then the runs. Under the launchers that run
    the jobs on this machine (:data:`WARM_LAUNCHERS`: the basic launcher, one run at a time,
    and joblib's, runs side by side — without the warm-up two of its jobs on one scene would
    both compute the scene's reference), not under a cluster's (SLURM: the jobs run on other
    nodes); for grids of images of at least :data:`WARM_MIN_PIXELS`; points already stored ok
    are left out. A failure here is reported and the sweep goes on (each run computes what it
    misses)."""
    try:
        workers = int(config.get("warm_workers", 0) or 0)
        if workers < 2 or not warms_under(str(config.hydra.launcher.get("_target_", ""))):
            return
        jobs = sweep_jobs(config)
        if len(jobs) < 2:
            return
        from hydra.initialize import get_gh_backup, restore_gh_from_backup

        log.info("reading the %d jobs of the sweep for the warm-up", len(jobs))
        store = _config_store(config)
        backup = get_gh_backup()  # composing below resets Hydra's global state: keep the sweep's
        try:
            specs = [compose_spec(*job, store=store) for job in jobs]
        finally:
            restore_gh_from_backup(backup)
        specs = [s for s in specs if s.resolution[0] * s.resolution[1] >= WARM_MIN_PIXELS]
        done = RunStore(store) if store.is_file() else None
        specs = [
            s for s in specs if s.force or done is None or not done.is_done(config_hash(s.point()))
        ]
        from sssbench.run.warm import group_by_scene, warm

        if len(group_by_scene(specs)) < 2:
            return
        log.info(
            "warming the reference cache of %d runs in %d processes (two tasks per scene)",
            len(specs),
            workers,
        )
        seconds = warm(specs, workers, progress=True)
        log.info("warm-up done in %.0f s; timing the runs one at a time", seconds)
    except Exception as exc:  # the runs compute what they miss
        log.error("warm-up skipped: %s: %s", type(exc).__name__, exc)


def _sweep_mirror(config: Any) -> Any:
    """The MLflow mirror of a sweep when ``tracking.mlflow`` is on (errors logged, not raised:
    the run store stays the source of truth)."""
    tracking = config.get("tracking") or {}
    if not tracking.get("mlflow"):
        return None
    try:
        from sssbench.store.mlflow_mirror import MlflowMirror

        store = _config_store(config)
        return MlflowMirror(tracking.get("mlflow_uri"), directory=store.parent)
    except Exception as exc:
        log.error("MLflow mirror unavailable: %s: %s", type(exc).__name__, exc)
        return None


def _sweep_size(config: Any) -> int:
    """Number of jobs of a basic-sweeper grid (0 when unknown): the preset's sweeper params
    and the command line's swept overrides (``a,b``, ``glob(...)``); a search's ``n_trials``."""
    try:
        if "n_trials" in config.hydra.sweeper:  # a search (Optuna): its number of trials
            return int(config.hydra.sweeper.n_trials)
        params = {str(k): str(v) for k, v in dict(config.hydra.sweeper.get("params") or {}).items()}
        for o in config.hydra.overrides.task:
            key, _, value = str(o).partition("=")
            if _swept(value) or key in params:
                params[key] = value
        return len(expand_grid(params))
    except Exception:
        return 0


# ----------------------------------------------------------------------------- command line
def _group_options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def _top_level_keys() -> set[str]:
    import yaml

    data = yaml.safe_load((CONF_DIR / "config.yaml").read_text()) or {}
    return {k for k in data if k != "defaults"} | set(GROUPS) | {"hydra"}


def _parse_scalar(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def check_overrides(argv: list[str]) -> str | None:
    """A one-line message for a bad command-line override, else ``None``.

    Catches: an unknown key (with the closest known keys), an empty value, a value of the
    wrong type for a scalar key of ``config.yaml`` and an unknown config-group option.
    Sweeps (``a,b``) and Hydra functions (``glob(...)``, ``range(...)``) are checked item by
    item where they are plain lists."""
    known = _top_level_keys()
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        raw_key, value = arg.split("=", 1)
        adding = raw_key.startswith("+")
        key = raw_key.lstrip("+~")
        top = key.split(".", 1)[0].split("/", 1)[0]
        if top == "hydra" or (adding and "." not in key and top not in GROUPS):
            continue
        if top not in known:
            close = difflib.get_close_matches(top, sorted(known), n=3)
            hint = f"; did you mean {' or '.join(close)}?" if close else ""
            return f"unknown key {top!r}{hint} (keys: {', '.join(sorted(known - {'hydra'}))})"
        if value.strip() == "" and not raw_key.startswith("~"):
            return f"empty value for {key}: give {key}=<value>"
        if "(" in value or value.startswith("["):
            continue
        items = [v.strip() for v in value.split(",")]
        if key in GROUPS:
            available = _group_options(key)
            for v in items:
                if v not in available:
                    close = difflib.get_close_matches(v, available, n=1)
                    hint = f"; did you mean {close[0]}?" if close else ""
                    return f"unknown {key} {v!r}{hint} (available: {', '.join(available)})"
        elif key in SCALAR_KEYS:
            for v in items:
                if v == "" or (v in ("null", "~") and SCALAR_KEYS[key].endswith("?")):
                    continue
                try:
                    _check_type(key, _parse_scalar(v), SCALAR_KEYS[key])
                except ValueError as exc:
                    return str(exc)
                if key == "reference" and v not in REFERENCES:
                    return f"reference must be one of {', '.join(REFERENCES)}, got {v!r}"
    return None


#: Hydra flags that print or inspect rather than run (no value check before them)
_INSPECT_FLAGS = ("--help", "-h", "--hydra-help", "--info", "-i", "--shell-completion", "-sc")


def _swept(value: str) -> bool:
    """Whether a command-line value sweeps (``a,b``, ``[1,2],[3,4]``, ``glob(...)``) — a list
    value (``resolution=[16,16]``) is one value."""
    return value.startswith("glob(") or len(_split_items(value)) > 1


def _split_items(value: str) -> list[str]:
    """``a,b,[1,2]`` -> ``["a", "b", "[1,2]"]``: a sweep's items (commas inside brackets kept)."""
    items, depth, cur = [], 0, ""
    for ch in value:
        depth += ch in "[{"
        depth -= ch in "]}"
        if ch == "," and depth == 0:
            items.append(cur)
            cur = ""
        else:
            cur += ch
    return [*items, cur]


def check_values(argv: list[str]) -> str | None:
    """A one-line message for a value no run could take, else ``None`` — checked before the
    first run starts, so a bad value never gets a progress line, a ``failed`` row or exit 1.

    **Every job** of the command line's grid (the full product of its swept values, and under
    ``-m`` of a preset's own grid: :func:`_grid_specs`, the walk :func:`check_stages` shares)
    is read into its :class:`RunSpec` exactly as a run reads it (:func:`compose_spec`:
    resolution, ``scene.path``, samples, dtype, threads, seeds, the store's folder, …), and
    each distinct spec is checked by the run's own constructors, building no image
    (:func:`sssbench.run.inputs.check_spec`: the scene's parameters, the profile's, the
    method's with its samples and sampling, ``reference_params``, the stages' parameters, the
    Monte Carlo options). So a bad combination (a method option another method of the grid
    does not take, a scene parameter that does not fit a resolution) is found before the first
    run too. Values Hydra computes (``range(...)``, a search's ``interval(...)``) are checked
    by each run."""
    if _inspecting(argv):
        return None
    from sssbench.run.inputs import check_spec

    problem, specs = _grid_specs(argv)
    if problem:
        return problem
    memo: dict[str, Any] = {}
    for spec in specs:
        try:
            check_spec(spec, memo)
        except (ValueError, TypeError) as exc:
            return " ".join(str(exc).split())
    return None


def _grid_specs(argv: list[str]) -> tuple[str | None, list[RunSpec]]:
    """``(problem, specs)``: the :class:`RunSpec` of every job of the command line's grid (each
    distinct spec once, in the grid's order), or the one-line error of the first job that
    cannot be read. The grid: the product of the command line's values (:func:`_axes`) and,
    under ``-m``, of a preset's (``+experiment=...``) swept keys the command line does not
    set. Cached per command line and working directory: :func:`check_values` and
    :func:`check_stages` walk the same grid once."""
    import os

    problem, specs, _ = _grid_specs_cached(tuple(argv), os.getcwd())
    return problem, specs


def composed_jobs(argv: list[str]) -> frozenset[frozenset[str]]:
    """The jobs of the command line's grid (:func:`_grid_specs`) that were composed and read
    without error, each as the set of its override strings — only jobs whose every override
    is a config-group choice (composed by Hydra itself) or a plain ``key=value`` (applied to a
    struct config, which refuses a key it does not have, as Hydra does); a job with an
    ``+key=``, ``++key=`` or ``~key`` value override is left out (``+samples=7`` reads here
    but Hydra refuses it), and so is every job after the grid's first problem."""
    import os

    if _inspecting(argv):
        return frozenset()  # check_values reads no grid for these
    return _grid_specs_cached(tuple(argv), os.getcwd())[2]


def _plain_or_group(override: str) -> bool:
    """Whether ``override`` is a config-group choice or a ``key=value`` with no prefix."""
    return _group_key(override) in GROUPS or override[:1] not in "+~"


@functools.lru_cache(maxsize=8)
def _grid_specs_cached(
    argv: tuple[str, ...], cwd: str
) -> tuple[str | None, list[RunSpec], frozenset[frozenset[str]]]:
    import itertools

    axes = _grid_axes(list(argv))
    given = any(a[0].split("=", 1)[0].lstrip("+") == "store" for a in axes)
    store = None if given else str(Path(cwd) / "sssbench.sqlite")  # the config's default
    specs: list[RunSpec] = []
    seen: set[str] = set()
    composed: set[frozenset[str]] = set()
    for job in itertools.product(*axes):
        try:
            spec = compose_spec(*job, store=store)
        except Exception as exc:
            return " ".join(str(exc).split()), [], frozenset()
        if all(_plain_or_group(o) for o in job):
            composed.add(frozenset(job))
        key = json.dumps(dataclasses.asdict(spec), sort_keys=True, default=str)
        if key not in seen:
            seen.add(key)
            specs.append(spec)
    return None, specs, frozenset(composed)


def _grid_axes(argv: list[str]) -> list[list[str]]:
    """The sweep axes of a command line (:func:`_axes`) and, under ``-m``, a preset's own
    swept keys the command line does not set (a search space — ``choice(...)``,
    ``interval(...)`` — is left to each run)."""
    axes = _axes(argv)
    presets = [a[0].split("=", 1)[1] for a in axes if a[0].split("=", 1)[0] == "+experiment"]
    if presets and ("-m" in argv or "--multirun" in argv):
        from omegaconf import OmegaConf

        swept = {a[0].split("=", 1)[0].lstrip("+") for a in axes}
        params = OmegaConf.to_container(preset_hydra(presets[0]).sweeper.get("params") or {})
        for key, value in dict(params or {}).items():
            value = str(value)
            if "(" in value and not value.startswith("glob("):
                continue  # a search space (``choice(...)``, ``interval(...)``): each run checks
            if str(key).lstrip("+") not in swept:
                axes.append([job[0] for job in expand_grid({str(key): value})])
    return axes


def _inspecting(argv: list[str]) -> bool:
    return any(a in _INSPECT_FLAGS or a.startswith("--cfg") or a == "-c" for a in argv)


def _axes(argv: list[str]) -> list[list[str]]:
    """The command line's overrides as sweep axes: ``key=a,b`` -> ``["key=a", "key=b"]``
    (``glob(...)`` expanded; other Hydra functions and deletions left out)."""
    axes: list[list[str]] = []
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        raw_key, value = arg.split("=", 1)
        key = raw_key.lstrip("+~")
        if raw_key.startswith("~") or key.split(".", 1)[0].split("/", 1)[0] == "hydra":
            continue
        if value.startswith("glob("):
            options = [job[0].split("=", 1)[1] for job in expand_grid({key: value})]
            if options:
                axes.append([f"{raw_key}={o}" for o in options])
        elif "(" in value:
            continue
        else:
            axes.append([f"{raw_key}={v}" for v in _split_items(value)])
    return axes


def check_stages(argv: list[str]) -> tuple[str | None, list[str]]:
    """Issue 28: ``(refusal, notes)`` for the stages the command line switches on, checked for
    **every** job of the grid before the first run (the full product of the swept values, and
    of a preset's own grid under ``-m``), each distinct (scene, stages, method, …) once.

    A stage switched on (``translucency=on``, ``curvature=on``, ``halo=on|lab``, …) means
    "run this stage"; every stage is off by default, and only defaults are planned away
    (docs/architecture.md §5). So, per job (:func:`sssbench.run.inputs.check_stages`):

    - a requested stage that **cannot run** on the job's scene (a field the scene lacks, no
      back light, an empty mask, a method that does not take the stage's input) or that would
      **add exactly nothing** (transmittance 0 in float64) is the refusal: one line naming the
      stage, the scene and why — ``main`` prints it and exits 2, nothing is run or stored (it
      used to fail inside the run, stored ``failed``, exit 1);
    - a requested stage the automatic plan would leave out as **negligible** (a threshold:
      at most 0.1 % of the back light, no silhouette, widths changed by at most 2 %) still
      runs — refusing it would change what ``on`` means, and the stage's cost and its small
      effect are real measurements — and gets one note line before the first run.

    The grid is the one :func:`check_values` reads (:func:`_grid_specs`, cached); a job with
    no stage switched on builds nothing here."""
    if _inspecting(argv):
        return None, []
    problem, specs = _grid_specs(argv)
    if problem:
        return problem, []
    from sssbench.run.inputs import check_stages as check_job

    notes: list[str] = []
    seen: set[str] = set()
    timing_only = ("samples", "sampling", "seeds", "threads", "backend")
    for spec in specs:
        if not any(v is not None for v in spec.stages.values()):
            continue  # no stage switched on: nothing to build
        point = {k: v for k, v in spec.point().items() if k not in timing_only}
        key = json.dumps(point, sort_keys=True, default=str)
        if key in seen:
            continue
        seen.add(key)
        try:
            notes += [n for n in check_job(spec) if n not in notes]
        except Exception as exc:
            return " ".join(str(exc).split()), []
    return None, notes


def _is_group_override(override: str) -> bool:
    """Whether ``override`` chooses a config-group option (``method=disk``,
    ``+experiment=paper_benchmark``, ``hydra/launcher=joblib``): its key is a folder of
    :data:`CONF_DIR` or one of Hydra's own groups (a key with ``/``)."""
    key = _group_key(override)
    return "/" in key or (CONF_DIR / key).is_dir()


def job_signature(overrides: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """What Hydra's composition of a job depends on beyond its values: the group choices
    whole, every other override by its key alone (``samples=13`` -> ``samples``)."""
    return tuple(
        o if _is_group_override(o) else o.split("=", 1)[0] for o in (str(x) for x in overrides)
    )


#: Hydra's own check of a sweep's batch (``Sweeper.validate_batch_is_legal``), kept by
#: :func:`_install_batch_validation`
_HYDRA_VALIDATE: list[Any] = []


#: the signature of every job :func:`check_values` composed (:func:`composed_jobs`)
_COMPOSED_SIGNATURE = ("<composed by check_values>",)


def _validate_one_per_signature(sweeper: Any, batch: Any) -> None:
    """Hydra's check of a batch before its launch, on one job per :func:`job_signature`.

    Hydra's sweeper composes every job of a batch before launching it, to catch composition
    errors early (its own comment: "can be a bit slow for large jobs"): about 80 ms a job on
    the 2-core EPYC, 23 s in the main process for the paper preset's 288 jobs before the first
    one started, with every core idle (measured 2026-12-05). Composition fails on the group
    choices and on the keys; the values are checked for every job of the grid by
    :func:`check_values` before Hydra starts. So composing one job per signature (the paper
    preset: 48, one per scene and method) catches what composing all of them did; a job's
    own composition in its launcher still composes it whole.

    A job whose overrides are those of a job :func:`check_values` composed for this command
    line (``_STATE["composed"]``, :func:`composed_jobs`: its group choices by Hydra, its plain
    values into a struct config) has had its group choices and keys checked already: all such
    jobs share one signature, so one of them is composed here, which checks what is Hydra's
    own (the launcher, ``hydra.*`` overrides: the same for every job of the batch). The main
    job's 24 jobs, each its own scene and method, compose once instead of 24 times."""
    composed = _STATE.get("composed") or frozenset()
    seen: set[tuple[str, ...]] = set()
    firsts = []
    for overrides in batch:
        job = frozenset(str(o) for o in overrides)
        signature = _COMPOSED_SIGNATURE if job in composed else job_signature(overrides)
        if signature not in seen:
            seen.add(signature)
            firsts.append(overrides)
    _HYDRA_VALIDATE[0](sweeper, firsts)


def _install_batch_validation() -> None:
    """Make Hydra's sweepers check one job per signature (:func:`_validate_one_per_signature`);
    idempotent."""
    from hydra.plugins.sweeper import Sweeper

    if not _HYDRA_VALIDATE:
        _HYDRA_VALIDATE.append(Sweeper.validate_batch_is_legal)
        Sweeper.validate_batch_is_legal = _validate_one_per_signature  # type: ignore[method-assign]


def main() -> None:
    """Console entry point of ``sssbench`` / ``python -m sssbench``."""
    import hydra

    args = sys.argv[1:]
    if "--version" in args or "-V" in args:
        print(f"sssbench {_version()}")
        return
    if not (CONF_DIR / "config.yaml").is_file():
        print(
            f"sssbench: config directory not found: looked for {CONF_DIR / 'config.yaml'}",
            file=sys.stderr,
        )
        sys.exit(2)
    quiet_third_party()
    problem = check_overrides(args) or check_values(args)
    notes: list[str] = []
    if not problem:
        problem, notes = check_stages(args)
    if problem:
        print(f"sssbench: {problem}", file=sys.stderr)
        sys.exit(2)
    for note in notes:
        print(f"sssbench: note: {note}", file=sys.stderr)
    _STATE.update(failed=0, done=0, total=0, start=time.time(), composed=composed_jobs(args))
    _install_batch_validation()
    # The heap (torch, Hydra, this package: about 440 000 tracked objects) lives until the
    # process ends: frozen, the cyclic collector's full collections skip it (the README's main
    # job ran 9 of 0.14 s each in its main process). After the sweep its cycles are collected
    # once, so that their finalizers run (an open file's flush), and the heap is frozen again:
    # the interpreter's exit then spends 0.3 s instead of 1.3 s in its own collections.
    gc.freeze()
    try:
        hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")(task)()
    finally:
        gc.collect()
        gc.freeze()
    if _STATE["failed"]:
        sys.exit(1)


if __name__ == "__main__":
    main()

"""Mirror the app's runs into MLflow (optional: ``pip install "sssbench[mlflow]"``).

The run store (:mod:`sssbench.store.tracking`) stays the source of truth; the mirror copies each
finished run into an MLflow tracking store so that sweeps can be browsed and compared in the
MLflow UI (``mlflow ui --backend-store-uri sqlite:///<dir>/mlflow.db``):

* a sweep is a parent run (:meth:`MlflowMirror.start_sweep` / :meth:`MlflowMirror.end_sweep`),
  each point a child run (:meth:`MlflowMirror.log_run`);
* the point becomes params — nested dicts flattened to dotted keys (``scene_params.z``),
  values stringified (strings as they are, everything else as JSON) and cut to MLflow's
  limits; the numeric metrics become metrics; previews and ``metrics.json`` become artifacts;
  the run's status and config hash become tags (``status``, ``config_hash``).

By default the tracking store is a local SQLite file ``<directory>/mlflow.db`` with artifacts in
``<directory>/mlflow_artifacts`` (the app passes the run store's directory), never a server.
MLflow's usage telemetry is switched off (``MLFLOW_DISABLE_TELEMETRY``) before MLflow is
imported, unless the environment already says otherwise.

``import sssbench`` and ``import sssbench.store.mlflow_mirror`` never import MLflow; constructing a
:class:`MlflowMirror` does, and without MLflow it raises one ``ImportError`` saying what to
install.
"""

from __future__ import annotations

import hashlib
import importlib.util
import numbers
import os
import re
import time
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from sssbench import _json

__all__ = [
    "MlflowMirror",
    "STATUS",
    "default_tracking_uri",
    "flatten_params",
    "numeric_metrics",
    "require_mlflow",
]

#: sssbench run status -> MLflow run status
STATUS = {"ok": "FINISHED", "failed": "FAILED", "timeout": "KILLED"}
#: MLflow's limits (``mlflow.utils.validation``; checked against them in the tests)
MAX_KEY_LENGTH = 250
MAX_PARAM_VALUE_LENGTH = 6000
MAX_TAG_VALUE_LENGTH = 8000
MAX_PARAMS_TAGS_PER_BATCH = 100
MAX_METRICS_PER_BATCH = 1000
#: characters MLflow accepts in param / metric / tag keys (others become ``_``)
_BAD_KEY_CHARS = re.compile(r"[^A-Za-z0-9_\-. /:]")
_INSTALL_HINT = 'pip install "sssbench[mlflow]"'
_SWEEP_ID_TAG = "sssbench.sweep_id"


def require_mlflow() -> None:
    """Raise the mirror's ``ImportError`` now if mlflow is not installed, without importing it
    (for the app to check its config before any run starts)."""
    try:
        found = importlib.util.find_spec("mlflow") is not None
    except (ImportError, ValueError):  # a broken or None entry in sys.modules
        found = False
    if not found:
        raise ImportError(
            f"the MLflow mirror is switched on but mlflow is not installed: {_INSTALL_HINT}"
        )


def _mlflow() -> Any:
    """The ``mlflow`` module, imported on first use with telemetry off."""
    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    try:
        import mlflow
        import mlflow.entities
        import mlflow.tracking
    except ImportError as exc:
        raise ImportError(
            f"the MLflow mirror is switched on but mlflow is not installed: {_INSTALL_HINT}"
        ) from exc
    return mlflow


def default_tracking_uri(directory: str | os.PathLike[str]) -> str:
    """``sqlite:///<directory>/mlflow.db`` (absolute path; the directory is created)."""
    path = Path(directory).expanduser().resolve()
    path.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{path / 'mlflow.db'}"


def _key(key: str) -> str:
    """A valid MLflow key: bad characters -> ``_``; a key over the length limit is cut and
    ends in 8 hex digits of its hash (so two long keys stay distinct)."""
    key = _BAD_KEY_CHARS.sub("_", str(key)) or "_"
    if len(key) > MAX_KEY_LENGTH:
        digest = hashlib.sha256(key.encode()).hexdigest()[:8]
        key = f"{key[: MAX_KEY_LENGTH - 9]}~{digest}"
    return key


def _text(value: object, limit: int) -> str:
    """``value`` as a string (strings as they are, else JSON), cut to ``limit`` characters
    ending in ``...`` when cut."""
    text = value if isinstance(value, str) else _json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def flatten_params(point: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested dicts -> dotted keys with string values, as MLflow params.

    ``{"scene": "head", "scene_params": {"z": 500}, "resolution": [64, 64]}`` gives
    ``{"scene": "head", "scene_params.z": "500", "resolution": "[64, 64]"}``. An empty dict is
    kept as ``"{}"`` (the key says the point had no such params); ``None`` is ``"null"``.
    Keys are made valid for MLflow and values cut to its length limit (:func:`_key`,
    :func:`_text`).
    """
    out: dict[str, str] = {}
    for name, value in point.items():
        key = f"{prefix}{name}"
        if isinstance(value, Mapping) and value:
            out.update(flatten_params(value, f"{key}."))
        else:
            out[_key(key)] = _text(value, MAX_PARAM_VALUE_LENGTH)
    return out


def numeric_metrics(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The real-number entries of ``metrics`` (bools, strings, lists and dicts left out) as
    floats under valid keys; NaN and inf are kept (MLflow stores them)."""
    return {
        _key(k): float(v)
        for k, v in metrics.items()
        if isinstance(v, numbers.Real) and not isinstance(v, bool)
    }


def _ms(timestamp: str | None) -> int:
    """Milliseconds since the epoch of an ISO timestamp (``tracking.utc_now``), or now."""
    if timestamp is None:
        return int(time.time() * 1000)
    return int(datetime.fromisoformat(timestamp).timestamp() * 1000)


def _chunks(items: Sequence[Any], size: int) -> Iterable[Sequence[Any]]:
    for start in range(0, len(items), size):
        yield items[start : start + size]


class MlflowMirror:
    """Copies runs into an MLflow tracking store.

    Args:
        tracking_uri: where to log (any MLflow URI: ``sqlite:///...``, ``http://host:5000``);
            ``None`` = :func:`default_tracking_uri` of ``directory``.
        experiment: MLflow experiment name (created if missing).
        directory: with ``tracking_uri=None``, the directory of ``mlflow.db`` and of the
            artifacts (``mlflow_artifacts/``); the app passes the run store's directory.
        artifact_location: artifact root of a newly created experiment; default
            ``<directory>/mlflow_artifacts`` when ``directory`` is given, else MLflow's choice
            (a server's artifact root).

    Raises:
        ImportError: mlflow is not installed (the message says ``pip install
            "sssbench[mlflow]"``).
        ValueError: neither ``tracking_uri`` nor ``directory``; the experiment is deleted.
    """

    def __init__(
        self,
        tracking_uri: str | None = None,
        experiment: str = "sssbench",
        *,
        directory: str | os.PathLike[str] | None = None,
        artifact_location: str | None = None,
    ) -> None:
        if tracking_uri is None and directory is None:
            raise ValueError(
                "MlflowMirror needs tracking_uri or directory (for sqlite:///<directory>/"
                "mlflow.db), got neither"
            )
        if not isinstance(experiment, str) or not experiment.strip():
            raise ValueError(f"experiment must be a non-empty string, got {experiment!r}")
        mlflow = _mlflow()
        self.tracking_uri = tracking_uri or default_tracking_uri(directory)  # type: ignore[arg-type]
        if artifact_location is None and directory is not None:
            artifact_dir = Path(directory).expanduser().resolve() / "mlflow_artifacts"
            artifact_location = artifact_dir.as_uri()
        self._entities = mlflow.entities
        self._exception = mlflow.exceptions.MlflowException
        self.client = mlflow.tracking.MlflowClient(tracking_uri=self.tracking_uri)
        self.experiment_id = self._experiment(experiment, artifact_location)
        self.experiment = experiment
        #: the parent run of the current sweep (set by start_sweep / find_sweep)
        self.sweep_run_id: str | None = None

    def _experiment(self, name: str, artifact_location: str | None) -> str:
        found = self.client.get_experiment_by_name(name)
        if found is None:
            try:
                return self.client.create_experiment(name, artifact_location=artifact_location)
            except self._exception:  # created meanwhile by a parallel job
                found = self.client.get_experiment_by_name(name)
                if found is None:
                    raise
        if found.lifecycle_stage != "active":
            raise ValueError(
                f"MLflow experiment {name!r} is deleted in {self.tracking_uri}; restore it "
                "(mlflow experiments restore) or choose another experiment name"
            )
        return found.experiment_id

    # ------------------------------------------------------------------ sweeps
    @staticmethod
    def _sweep_id(sweep_dir: str | os.PathLike[str]) -> str:
        return hashlib.sha256(str(Path(sweep_dir).resolve()).encode()).hexdigest()[:16]

    def start_sweep(self, sweep_dir: str | os.PathLike[str], name: str | None = None) -> str:
        """Create the parent run of a sweep (tagged with its directory); return its run id.

        Call once per sweep, before its jobs run (Hydra: ``on_multirun_start``), so that jobs
        in other processes find it with :meth:`find_sweep`.
        """
        sweep_dir = Path(sweep_dir).resolve()
        run = self.client.create_run(
            self.experiment_id,
            run_name=name or sweep_dir.name,
            tags={
                _SWEEP_ID_TAG: self._sweep_id(sweep_dir),
                "sssbench.sweep_dir": _text(str(sweep_dir), MAX_TAG_VALUE_LENGTH),
                "sssbench.kind": "sweep",
            },
        )
        self.sweep_run_id = run.info.run_id
        return self.sweep_run_id

    def find_sweep(self, sweep_dir: str | os.PathLike[str]) -> str | None:
        """The run id of the newest parent run started for ``sweep_dir`` (or ``None``); it
        becomes the default ``parent`` of :meth:`log_run`."""
        runs = self.client.search_runs(
            [self.experiment_id],
            filter_string=f"tags.`{_SWEEP_ID_TAG}` = '{self._sweep_id(sweep_dir)}'",
            order_by=["attributes.start_time DESC"],
            max_results=1,
        )
        self.sweep_run_id = runs[0].info.run_id if runs else None
        return self.sweep_run_id

    def end_sweep(self, counts: Mapping[str, int] | None = None) -> None:
        """Close the current sweep's parent run.

        Args:
            counts: runs per status (``{"ok": 7, "failed": 1}``), logged as metrics
                ``runs_<status>``; the parent ends ``FAILED`` if any run failed or timed out,
                else ``FINISHED``.
        """
        if self.sweep_run_id is None:
            raise RuntimeError("end_sweep: no sweep started (call start_sweep or find_sweep)")
        status = "FINISHED"
        if counts:
            self._log_batch(self.sweep_run_id, {f"runs_{k}": v for k, v in counts.items()}, {})
            if any(counts.get(s, 0) for s in ("failed", "timeout")):
                status = "FAILED"
        self.client.set_terminated(self.sweep_run_id, status=status)
        self.sweep_run_id = None

    # ------------------------------------------------------------------ runs
    def _log_batch(
        self,
        run_id: str,
        metrics: Mapping[str, Any],
        params: Mapping[str, str],
    ) -> None:
        e, now = self._entities, int(time.time() * 1000)
        metric_list = [e.Metric(k, v, now, 0) for k, v in numeric_metrics(metrics).items()]
        param_list = [e.Param(k, v) for k, v in params.items()]
        for chunk in _chunks(metric_list, MAX_METRICS_PER_BATCH):
            self.client.log_batch(run_id, metrics=chunk)
        for chunk in _chunks(param_list, MAX_PARAMS_TAGS_PER_BATCH):
            self.client.log_batch(run_id, params=chunk)

    def log_run(
        self,
        point: Mapping[str, Any],
        metrics: Mapping[str, Any],
        artifacts: Iterable[str | os.PathLike[str]],
        status: str,
        parent: str | None = None,
        *,
        config_hash: str | None = None,
        run_name: str | None = None,
        tags: Mapping[str, object] | None = None,
        started_at: str | None = None,
        finished_at: str | None = None,
    ) -> str:
        """Log one finished run as an MLflow run; return its run id.

        Args:
            point: the run's defining config (``RunSpec.point()``), logged as params.
            metrics: metric name -> value; the real numbers are logged (:func:`numeric_metrics`).
            artifacts: files (or directories) to upload: previews, ``metrics.json`` ...;
                every one must exist (checked before the run is created).
            status: ``ok``, ``failed`` or ``timeout`` (-> MLflow FINISHED / FAILED / KILLED);
                also the tag ``status``.
            parent: run id of the sweep's parent run; ``None`` = the mirror's current sweep
                (:meth:`start_sweep` / :meth:`find_sweep`), if any.
            config_hash: the store's config hash, tag ``config_hash``.
            run_name: MLflow run name (default: the config hash).
            tags: further tags (e.g. ``{"error": message, "run_dir": ...}``), stringified.
            started_at, finished_at: ISO UTC timestamps of the run (default: now).
        """
        if status not in STATUS:
            raise ValueError(f"status must be one of {list(STATUS)}, got {status!r}")
        paths = [Path(a) for a in artifacts]
        missing = [str(p) for p in paths if not p.exists()]
        if missing:
            raise FileNotFoundError(f"artifacts not found: {', '.join(missing)}")
        parent = parent or self.sweep_run_id
        all_tags = {"sssbench.kind": "run"}
        all_tags |= {_key(k): _text(v, MAX_TAG_VALUE_LENGTH) for k, v in (tags or {}).items()}
        all_tags["status"] = status
        if config_hash is not None:
            all_tags["config_hash"] = config_hash
        if parent is not None:
            all_tags["mlflow.parentRunId"] = parent
        run = self.client.create_run(
            self.experiment_id,
            start_time=_ms(started_at),
            run_name=run_name or config_hash,
            tags=all_tags,
        )
        run_id = run.info.run_id
        try:
            self._log_batch(run_id, metrics, flatten_params(point))
            for p in paths:
                if p.is_dir():
                    self.client.log_artifacts(run_id, str(p), artifact_path=p.name)
                else:
                    self.client.log_artifact(run_id, str(p))
        except BaseException:
            self.client.set_terminated(run_id, status="FAILED")
            raise
        self.client.set_terminated(run_id, status=STATUS[status], end_time=_ms(finished_at))
        return run_id

"""One run as plain values: :class:`RunSpec` (DESIGN §6, §7).

The app reads the Hydra config once into a :class:`RunSpec` (:func:`sssbench.app.spec_from_cfg`);
the runner, the experiments and the library take it (or its fields) and never see a config
object. :meth:`RunSpec.point` is what identifies the run in the store (its hash); it holds
exactly the values that determine the result — see ``docs/architecture.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["RunSpec", "REFERENCES", "MC_OPTIONS", "DEFAULT_SEEDS", "mc_options"]

#: what a run's error is measured against: ``profile`` (the exact integral of the diffusion
#: profile, :class:`~sssbench.ops.ReferenceSSS`) or ``mc`` (that and Monte Carlo light
#: transport, :func:`sssbench.mc.scene.scene_mc`; docs/mc.md)
REFERENCES = ("profile", "mc")
#: keys of ``reference_params`` that configure the Monte Carlo reference (``reference=mc``)
MC_OPTIONS = ("mc_photons", "mc_batches", "mc_workers", "mc_seed", "mc_material")
#: method seeds a stochastic method is evaluated with per run (bias / noise split)
DEFAULT_SEEDS = 4


@dataclass(frozen=True)
class RunSpec:
    """Everything one run needs, as plain values.

    Attributes:
        scene, scene_params: a scene name of :func:`sssbench.run.registry.scene_names` and its
            builder's keyword arguments (``pixel_mm``: mm of skin per pixel at the focus).
        method, method_params: a key of :data:`sssbench.run.registry.METHODS` and its options.
        profile, profile_kind, profile_params: the diffusion profile.
        sampling: tap placement, ``None`` for methods without one.
        samples: taps per pass, ``None`` for methods without a tap count.
        stages: pipeline stage name -> its parameters (``None`` = off); see
            :data:`sssbench.run.registry.STAGES`.
        ignored: options given explicitly that the method does not take (e.g. ``samples``
            for the baseline in a samples sweep): not passed to the method and not part of the
            point — an option a method does not use never splits it (the baseline is one point
            per scene; the second job of such a sweep finds it stored and is skipped). Recorded
            in ``metrics.json``.
        resolution: ``(H, W)`` pixels.
        reference: ``profile`` or ``mc`` (:data:`REFERENCES`); in the point only when ``mc``
            (points stored before the option existed keep their hash).
        reference_params: options of the exact reference (``tol``, ``reconstruction``).
        mc_params: options of the Monte Carlo reference (:data:`MC_OPTIONS`, given on the
            command line as ``reference_params.mc_*``); in the point with ``reference``.
        budget: compute the error budget (model / taps / screen space) of the run.
        seeds: how many method seeds a stochastic method (the disk, stochastic rotation) is
            evaluated with, its error split into bias and noise (:func:`sssbench.run.runner.
            bias_noise`); in the point only when not :data:`DEFAULT_SEEDS`, so the points of
            deterministic methods and earlier runs keep their hash.
        The rest is run control (not part of the point): repeats, warm-up, threads, backend,
        store, force, timeout, caches, previews.
    """

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
    stages: dict[str, dict[str, Any] | None] = field(default_factory=dict)
    ignored: dict[str, Any] = field(default_factory=dict)
    reference_params: dict[str, Any] = field(default_factory=dict)
    reference: str = "profile"
    mc_params: dict[str, Any] = field(default_factory=dict)
    budget: bool = True
    seeds: int = DEFAULT_SEEDS
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
    mlflow: bool = False
    mlflow_uri: str | None = None

    def point(self) -> dict[str, Any]:
        """The keys that define the point (hashed for the store; run control left out).

        ``threads`` and ``backend`` are in the point: they change the timing, which is part
        of the result."""
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
            "stages": {k: v for k, v in sorted(self.stages.items()) if v is not None},
            "reference_params": self.reference_params,
            **(
                {"reference": self.reference, "mc_params": self.mc_params}
                if self.reference != "profile"
                else {}
            ),
            **({"seeds": self.seeds} if self.seeds != DEFAULT_SEEDS else {}),
            "resolution": list(self.resolution),
            "seed": self.seed,
            "dtype": self.dtype,
            "threads": self.threads,
            "backend": self.backend,
        }


def mc_options(spec: RunSpec) -> dict[str, Any]:
    """The keyword arguments of :func:`sssbench.mc.scene.scene_mc` (and of its option check,
    :func:`~sssbench.mc.scene.check_options`) a run with ``reference=mc`` passes: its
    ``reference_params.mc_*`` (:data:`~sssbench.run.spec.MC_OPTIONS`), else the defaults (the
    measured material of the run's profile table, 8 batches, the run's seed)."""
    opts = spec.mc_params
    return {
        "material": opts.get("mc_material", spec.profile),
        "photons": opts.get("mc_photons"),
        "batches": opts.get("mc_batches", 8),
        "seed": opts.get("mc_seed", spec.seed),
        "workers": opts.get("mc_workers"),
    }

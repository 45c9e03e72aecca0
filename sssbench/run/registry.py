"""The one registry of methods, profiles, scenes and pipeline stages.

The app (:mod:`sssbench.app`), the runner (:mod:`sssbench.run.runner`), the experiments and the
library all build what a run names through these functions, so a name means the same thing
everywhere. Everything here takes plain values (DESIGN §7: no config objects below the app).

- :data:`METHODS`: method name -> :class:`MethodEntry` (the class in :mod:`sssbench.ops` and
  which constructor argument receives the run's ``samples``);
- :data:`PROFILE_KINDS`: profile kind -> constructor ``f(name, **params)``;
- scenes: every name of :data:`data_synth.SCENES`, plus ``file`` (a user's G-buffer read by
  :func:`sssbench.io.load_scene_file`, parameter ``path``);
- :data:`STAGES`: the optional pipeline stages a run can switch on (translucency, curvature,
  halo, texturing) and :func:`build_pipeline`, which composes them around a method.

Adding a method, profile, scene or stage: see ``docs/extending.md``.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

__all__ = [
    "METHODS",
    "MethodEntry",
    "PROFILE_KINDS",
    "STAGES",
    "FILE_SCENE",
    "method_class",
    "method_takes",
    "default_option",
    "build_method",
    "method_from_spec",
    "build_profile",
    "build_scene",
    "check_scene",
    "build_pipeline",
    "scene_names",
]


@dataclass(frozen=True)
class MethodEntry:
    """How a method name maps to its operator.

    Attributes:
        cls: class name in :mod:`sssbench.ops`, or ``"package.module:Class"``.
        samples_arg: the constructor argument that receives the run's ``samples`` (taps per
            pass), or ``None`` if the method has no tap count (the exact reference, the
            identity).
        uses_profile: whether the constructor's first argument is the run's diffusion profile
            (parametric kernels — the artist model, the 2012 kernel — carry their own).
        deterministic: the result is a deterministic function of the taps, so the error budget
            (docs/error_budget.md) applies; stochastic estimators (the disk) split their error
            into bias and noise instead (experiments/disk.py).
    """

    cls: str
    samples_arg: str | None = "samples"
    uses_profile: bool = True
    deterministic: bool = True


#: method name (``conf/method/<name>.yaml`` ``name:``) -> :class:`MethodEntry`
METHODS: dict[str, MethodEntry] = {
    "identity": MethodEntry("IdentitySSS", samples_arg=None, uses_profile=False),
    "preintegrated": MethodEntry("PreintegratedSSS"),
    "reference": MethodEntry("ReferenceSSS", samples_arg=None),
    "sum_of_gaussians": MethodEntry("SumOfGaussiansSSS"),
    "sum_of_gaussians_fused": MethodEntry("FusedSumOfGaussiansSSS"),
    "low_rank": MethodEntry("LowRankSSS", samples_arg="n"),
    "artist": MethodEntry("ArtistSSS", uses_profile=False),
    "jimenez2012": MethodEntry("Jimenez2012SSS", uses_profile=False),
    "disk": MethodEntry("DiskSSS", deterministic=False),
}


def _sog_table(name: str, **params: Any) -> Any:
    from sssbench.profiles import SumOfGaussians

    if params:
        raise ValueError(f"profile kind sum_of_gaussians_table takes no params, got {params}")
    return SumOfGaussians.from_table(name)


def _burley(name: str, **params: Any) -> Any:
    from sssbench.profiles.burley import burley_albedo_mfp

    return burley_albedo_mfp(name, **params)


#: profile ``kind`` (``conf/profile/*.yaml``) -> constructor ``f(name, **params)``
PROFILE_KINDS: dict[str, Callable[..., Any]] = {
    "sum_of_gaussians_table": _sog_table,
    "burley_albedo_mfp": _burley,
}

#: the scene name of a user's own G-buffer file (``scene=file scene.params.path=...``)
FILE_SCENE = "file"

_DTYPES = {"float32": torch.float32, "float64": torch.float64}


def _dtype(name: str) -> torch.dtype:
    if name not in _DTYPES:
        raise ValueError(f"dtype must be one of {sorted(_DTYPES)}, got {name!r}")
    return _DTYPES[name]


# ----------------------------------------------------------------------------- methods
def method_class(name: str) -> type:
    """The operator class of method ``name`` (a clear error for an unknown name).

    :attr:`MethodEntry.cls` is a class name in :mod:`sssbench.ops` or ``"package.module:Class"``
    (a method defined outside sssbench)."""
    if name not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {name!r}")
    target = METHODS[name].cls
    module, attr = target.split(":", 1) if ":" in target else ("sssbench.ops", target)
    cls = getattr(importlib.import_module(module), attr, None)
    if cls is None:
        raise ValueError(f"method {name!r} is not available: {module} has no {attr}")
    return cls


def method_takes(name: str, arg: str) -> bool:
    """Whether method ``name`` takes option ``arg`` (``samples`` maps to its tap argument)."""
    entry = METHODS[name] if name in METHODS else None
    if entry is None:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {name!r}")
    if arg == "samples":
        return entry.samples_arg is not None
    params = inspect.signature(method_class(name).__init__).parameters
    return arg in params


def default_option(name: str, option: str) -> Any:
    """The default of constructor option ``option`` of method ``name`` (``None`` if it has
    none): what the method uses when a run does not set it."""
    cls = method_class(name)
    params = inspect.signature(cls.__init__).parameters
    if option in params and params[option].default is not inspect.Parameter.empty:
        return params[option].default
    return None


def build_method(
    name: str,
    profile: Any,
    *,
    samples: int | None = None,
    sampling: str | None = None,
    seed: int = 0,
    params: Mapping[str, Any] | None = None,
) -> nn.Module:
    """Build method ``name``.

    Args:
        name: a key of :data:`METHODS`.
        profile: the run's diffusion profile (ignored by parametric kernels).
        samples: taps per pass (passed as the method's ``samples_arg``), or ``None`` for its
            default.
        sampling: tap placement (``uniform`` / ``power`` / ``importance``), or ``None``.
        seed: seed of stochastic options (rotation), when the method takes one.
        params: other constructor keyword arguments; ``preset`` calls ``cls.preset(...)``.

    Raises:
        ValueError: an option the method does not take (naming it and the method), or the
            same option given twice (``samples`` and its tap argument).
    """
    cls = method_class(name)
    entry = METHODS[name]
    kwargs = dict(params or {})
    accepted = inspect.signature(cls.__init__).parameters
    if samples is not None:
        if entry.samples_arg is None:
            raise ValueError(f"method {name!r} has no tap count: samples must be null")
        if entry.samples_arg != "samples" and entry.samples_arg in kwargs:
            raise ValueError(
                f"method {name!r} takes its tap count as samples (its {entry.samples_arg!r}); "
                "give one of them, not both"
            )
        kwargs[entry.samples_arg] = samples
    if sampling is not None:
        if "sampling" not in accepted:
            raise ValueError(f"method {name!r} has no sampling option: sampling must be null")
        kwargs["sampling"] = sampling
    if "seed" not in kwargs and "seed" in accepted:
        kwargs["seed"] = seed  # stochastic methods (rotation) follow the run's seed
    preset = kwargs.pop("preset", None)
    if preset is not None:  # e.g. ArtistSSS.preset("production"), Jimenez2012SSS.preset(...)
        return cls.preset(preset, **kwargs)
    unknown = sorted(set(kwargs) - set(accepted) - {"self"})
    if unknown:
        valid = sorted(k for k in accepted if k not in ("self", "profile"))
        raise ValueError(f"method {name!r} has no option(s) {unknown}; valid options are {valid}")
    return cls(profile, **kwargs) if entry.uses_profile else cls(**kwargs)


def method_from_spec(spec: Any, profile: Any, **changes: Any) -> nn.Module:
    """The method a run spec names (:class:`sssbench.run.spec.RunSpec`: its ``method``,
    ``samples``, ``sampling``, ``seed`` and ``method_params``), with ``changes`` replacing any
    of ``samples``, ``sampling``, ``seed`` or ``params`` (e.g. more taps for a converged
    limit, another seed for a noise estimate)."""
    options = {
        "samples": spec.samples,
        "sampling": spec.sampling,
        "seed": spec.seed,
        "params": spec.method_params,
    }
    unknown = set(changes) - set(options)
    if unknown:
        raise TypeError(f"changes must be among {sorted(options)}, got {sorted(unknown)}")
    return build_method(spec.method, profile, **{**options, **changes})


# ----------------------------------------------------------------------------- profiles
def build_profile(name: str, kind: str = "sum_of_gaussians_table", **params: Any) -> Any:
    """The diffusion profile ``name`` of ``kind`` (see :data:`PROFILE_KINDS`)."""
    if kind not in PROFILE_KINDS:
        raise ValueError(f"profile kind must be one of {sorted(PROFILE_KINDS)}, got {kind!r}")
    return PROFILE_KINDS[kind](name, **params)


# ----------------------------------------------------------------------------- scenes
def scene_names() -> list[str]:
    """Every scene name a run may use (the synthetic catalogue and ``file``)."""
    import data_synth

    return sorted([*data_synth.SCENES, FILE_SCENE])


def build_scene(
    name: str,
    resolution: tuple[int, int],
    *,
    seed: int = 0,
    fields: tuple[str, ...] | None = None,
    dtype: str = "float32",
    params: Mapping[str, Any] | None = None,
) -> Any:
    """The G-buffer of scene ``name``: a synthetic scene of :mod:`data_synth`, or ``file``
    (``params["path"]``: a user's EXR / ``.npz`` G-buffer; its own resolution is used and
    ``resolution`` must match it or be left to the file — see :mod:`sssbench.io`)."""
    import data_synth

    params = dict(params or {})
    if name == FILE_SCENE:
        from sssbench.io import load_scene_file

        return load_scene_file(_file_scene_path(params), fields=fields, dtype=_dtype(dtype))
    _synthetic_name(name)
    return data_synth.make_scene(
        name, resolution=resolution, seed=seed, fields=fields, dtype=_dtype(dtype), **params
    )


def check_scene(
    name: str,
    resolution: tuple[int, int],
    *,
    seed: int = 0,
    dtype: str = "float32",
    params: Mapping[str, Any] | None = None,
) -> None:
    """Check :func:`build_scene`'s arguments as it checks them, building no image (the app's
    check before the first run): a synthetic scene's own builder stops before its first image
    (:func:`data_synth.check_scene`); a file scene's path, its parameters and its digest.

    Raises:
        ValueError, TypeError: what :func:`build_scene` would raise for these arguments, naming
            the parameter.
    """
    import data_synth

    params = dict(params or {})
    if name == FILE_SCENE:
        _file_scene_path(params)
        return
    _synthetic_name(name)
    data_synth.check_scene(name, resolution, seed, dtype=_dtype(dtype), **params)


def _file_scene_path(params: dict[str, Any]) -> str:
    """The path of a file scene's ``params`` (``path``, optional ``sha256``), checked."""
    from sssbench.io import scene_file_digest

    path = params.pop("path", None)
    digest = params.pop("sha256", None)
    if not path:
        raise ValueError("scene file needs scene.path=<G-buffer .exr or .npz>")
    if params:
        raise ValueError(f"scene file takes only path (and sha256), got {sorted(params)}")
    if digest is not None and scene_file_digest(path) != digest:
        raise ValueError(f"scene file {path} changed since the run was configured (sha256)")
    return str(path)


def _synthetic_name(name: str) -> None:
    import data_synth

    if name in data_synth.RETIRED_SCENES:
        raise ValueError(data_synth.RETIRED_SCENES[name])
    if name not in data_synth.SCENES:
        raise ValueError(f"scene must be one of {scene_names()}, got {name!r}")


# ----------------------------------------------------------------------------- stages
def _translucency(profile: Any, **params: Any) -> dict[str, Any]:
    from sssbench.ops import Translucency

    return {"translucency": Translucency(profile, **params)}


def _curvature(profile: Any, **params: Any) -> dict[str, Any]:
    from sssbench.ops import CurvatureModulation

    return {"curvature": CurvatureModulation(**params)}


def _halo(profile: Any, kind: str = "bilateral", sigma: float | None = None) -> dict[str, Any]:
    return {"halo": kind, "halo_sigma": sigma}


def _texturing(profile: Any, mode: str = "post") -> dict[str, Any]:
    return {"texturing": mode}


#: stage name -> (``f(profile, **params) -> Pipeline keyword arguments``, applies to the
#: reference). A new stage on the irradiance returns ``{"irradiance": [module]}``
#: (:class:`~sssbench.ops.pipeline.Pipeline`'s ``irradiance``; docs/extending.md). Stages that
#: apply to the reference change the light it integrates (translucency adds transmitted
#: light to the irradiance; texturing applies albedo): the reference pipeline gets them too,
#: so the comparison stays like with like. The others (curvature modulation, halo reduction) are
#: screen-space approximations of what the exact reference does by itself.
STAGES: dict[str, tuple[Callable[..., dict[str, Any]], bool]] = {
    "translucency": (_translucency, True),
    "texturing": (_texturing, True),
    "curvature": (_curvature, False),
    "halo": (_halo, False),
}


def build_pipeline(
    method: nn.Module,
    profile: Any,
    stages: Mapping[str, Mapping[str, Any] | None] | None = None,
    *,
    for_reference: bool = False,
    auto: bool = True,
) -> Any:
    """``Pipeline(method, **stage options)`` for the switched-on ``stages``.

    Args:
        method: the SSS operator.
        profile: the run's profile (translucency's transmittance profile).
        stages: stage name -> its parameters (``None`` or missing = off).
        for_reference: build the reference's pipeline: only the stages that change the light
            being scattered (see :data:`STAGES`).
        auto: the pipeline's automatic plan (leave out stages the scene does not need).
    """
    from sssbench.ops.pipeline import Pipeline

    kwargs: dict[str, Any] = {}
    for name, params in (stages or {}).items():
        if name not in STAGES:
            raise ValueError(f"stage must be one of {sorted(STAGES)}, got {name!r}")
        if params is None:
            continue
        build, applies_to_reference = STAGES[name]
        if for_reference and not applies_to_reference:
            continue
        for key, value in build(profile, **dict(params)).items():
            if key == "irradiance":  # several stages may each add irradiance modules
                kwargs[key] = [*kwargs.get(key, []), *value]
            else:
                kwargs[key] = value
    return Pipeline(method, auto=auto, **kwargs)

"""Kernels optimised by gradient descent through the method's own passes (issue 18).

One module because the fit, its training scenes, its cache key and the methods' fitted
parametrisations change together (a cached fit is keyed by all of them).

Every published rule places taps without looking at the pixel grid, the irradiance
reconstruction of the gather (linear interpolation) or the depth-aware pass that applies
them (importance sampling, 000 §7; a power law, 002 appendix; uniform taps). Here a method's
kernel is *fitted* — the pre-integrated two-pass kernel's taps (000 eq. 5), the sum of
Gaussians' per-Gaussian tap sets (003 §7.3) or the 2012 kernel's strength, falloff and width
(002 eq. 1): the method (e.g. :class:`~sssbench.ops.PreintegratedSSS`, every depth-aware
option it was given) is run on a
training set of scenes at one pixel footprint, its output compared with the exact reference
(:class:`~sssbench.ops.ReferenceSSS`, the SSS stage only, cached), and the error minimised
with Adam through the differentiable gather (:func:`~sssbench.ops.separable_pass`, the torch
loop; gradcheck passes in float64). The loss is the mean over the training scenes of each
scene's rel RMS divided by the best published rule's rel RMS on that scene — a choice: the
goal is less error than the best rule on every scene, and with a plain mean of rel RMS the
scenes with large errors (a light disc on a plane) dominate the fit. Measured on the held-out
head (7 taps, 1 mm per pixel): 21 % less error than the best rule with the relative loss, 3 %
with the plain mean (which in exchange did better on the skin-patch scene, 44 % against 0 %).

Parametrisations (:mod:`sssbench.kernels.parametrise`), so that every iterate is a valid
kernel, all fitted by the one loop :func:`fit_taps` (:data:`METHOD_FITS` says which method
uses which):

- ``preintegrated`` (:class:`SymmetricTaps`): offsets symmetric and sorted (the positive half
  ``s · cumsum(softplus(u))``, mirrored, a centre tap at 0 for an odd tap count), weights per
  channel non-negative, symmetric and normalised (a softmax of mirrored logits), as the
  normalised kernel of 000 eq. 5;
- ``sum_of_gaussians`` (:class:`PerGaussianTaps`): one such tap set per blurred Gaussian of
  003 §7.3.3, each normalised on its own; variances and blend weights stay the profile's;
- ``jimenez2012`` (:class:`Jimenez2012Parameters`): the 2012 kernel's per-channel strength
  (sigmoid) and falloff (exp) and its width (a log-ratio), 002 eq. 1; its taps stay the 2012
  kernel builder's.

The fit starts from each published rule (importance, 000 §7; uniform; power, 002 appendix —
at equal taps; for the 2012 kernel its given parameters and each preset of 002 at the given
width) for a short screening run (:data:`SCREEN_STEPS`), continues from the best
screened kernel, and keeps the best iterate seen (the starts included), so the training error
never rises above the best rule's. The screening is there because the loss has local minima
(the taps' interpolation weights are piecewise linear in the offsets): measured at 9 taps and
0.3 mm per pixel with the plain mean of rel RMS, 100 steps from the power rule (the best rule
on the training set, 0.0328) stop at 0.0290, from the importance rule (0.0332) at 0.0199
(learning rate 0.05) and 0.0192 (0.15).

Backend: the native gather's backward recomputes the torch loop (see
:mod:`sssbench.ops._gather_native`), so a training step with the native forward costs a native
forward *plus* a torch forward and backward; the fit therefore runs the torch backend
directly (the two agree bitwise with ``follow_surface`` ``None`` / ``"lerp"``, see
:data:`~sssbench.ops.gather.BACKEND_AGREEMENT`). Measured on this 2-core machine shared with
other jobs: one forward + backward of the 7-tap method on a 96² scene ≈ 0.2 s with either.

Results are cached on disk (:func:`kernel_cache_dir`) under a digest of everything they
depend on (:func:`cache_key`): the package's source code, the profile's content, the method and
its options, the tap count, the footprint, the training set and the optimiser's settings — a
changed input can never be served an old kernel.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sssbench import _json
from sssbench._checks import check_choice, check_int, check_scalar, check_seed
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.parametrise import (
    Fitted,
    Jimenez2012Parameters,
    Parametrisation,
    PerGaussianTaps,
    SymmetricTaps,
)
from sssbench.kernels.sampling import OPTIMISED, SAMPLINGS
from sssbench.kernels.sources import (
    MAX_OPTIMISED_TAPS,
    check_optimised_sampling,
    register_kernel_source,
)
from sssbench.profiles.base import Profile

__all__ = [
    "OPTIMISED",
    "METHODS",
    "MAX_OPTIMISED_TAPS",
    "FOOTPRINTS",
    "TrainingScene",
    "DEFAULT_TRAINING",
    "SymmetricTaps",
    "PerGaussianTaps",
    "Jimenez2012Parameters",
    "Parametrisation",
    "Fitted",
    "MethodFit",
    "METHOD_FITS",
    "FitResult",
    "OptimisedKernel",
    "fit_taps",
    "optimise",
    "method_options",
    "use_optimised",
    "check_optimised_sampling",
    "cache_key",
    "kernel_cache_dir",
    "nearest_footprint",
    "rel_rms_loss",
    "training_loss",
    "sss_reference",
]

log = logging.getLogger("sssbench")

#: footprints (mm per pixel) kernels are fitted at when a method resolves its kernel from the
#: run's G-buffer: a log grid (ratio ≈ 1.4–1.7), a run uses the nearest (:func:`nearest_footprint`)
FOOTPRINTS = (0.05, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 5.0)
#: optimiser defaults (Adam, cosine-decayed learning rate)
DEFAULT_STEPS = 60
DEFAULT_LR = 0.15
#: steps of the screening run from each published rule (at most ``steps``)
SCREEN_STEPS = 15


# ------------------------------------------------------------------- training scenes
@dataclass(frozen=True)
class TrainingScene:
    """One training scene: ``data_synth.make_scene(name, resolution, seed, pixel_mm=p,
    **params)`` at the fit's footprint ``p``.

    Attributes:
        name: a key of ``data_synth.SCENES`` that takes ``pixel_mm``.
        resolution: ``(H, W)``; small (96²) keeps a step fast.
        seed: the scene's seed (textures, tint).
        params: other scene parameters as ``(name, value)`` pairs (hashable, ordered).
    """

    name: str
    resolution: tuple[int, int] = (96, 96)
    seed: int = 0
    params: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        check_seed("seed", self.seed)  # at construction, not when the fit builds the scene

    def build(self, pixel_mm: float) -> Any:
        """The G-buffer at ``pixel_mm`` (float32, every field the scene has)."""
        from data_synth import make_scene

        return make_scene(
            self.name, self.resolution, self.seed, pixel_mm=pixel_mm, **dict(self.params)
        )

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "resolution": list(self.resolution),
            "seed": self.seed,
            "params": {k: list(v) if isinstance(v, tuple) else v for k, v in self.params},
        }


#: the default training set: a textured face (seed 101, turned 35°), a shadow edge and a small
#: light disc on a plane — disjoint from the held-out scenes of ``experiments/optimised.py``
#: (head, sphere, pores: other geometry, other textures, other seeds)
DEFAULT_TRAINING = (
    TrainingScene("face", seed=101, params=(("yaw", 35.0),)),
    TrainingScene("step_edge", seed=0),
    TrainingScene("light_dot", seed=0, params=(("radius", 2.0),)),
)


# ------------------------------------------------------------------- the fit
def rel_rms_loss(
    result: torch.Tensor, reference: torch.Tensor, mask: torch.Tensor | None
) -> torch.Tensor:
    """Differentiable rel RMS over the SSS region, as :func:`sssbench.score.metrics.rel_rms`:
    ``√(Σ m (M − R)² / Σ m R²)`` with ``m = [mask > 0]`` (every pixel without a mask), B = 1."""
    ref = reference.to(result.dtype)
    m = torch.ones_like(result[:, :1]) if mask is None else (mask > 0).to(result.dtype)
    return _safe_sqrt((m * (result - ref) ** 2).sum() / (m * ref * ref).sum())


def _safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """``√x`` whose gradient at ``x = 0`` is 0 (a subgradient) instead of ``inf · 0 = NaN``: a
    training term that reaches exactly 0 (a scene the kernel already matches, e.g. at a coarse
    footprint) must not turn every parameter into NaN (docs/reliability.md, class 11)."""
    pos = x > 0
    return torch.where(pos, torch.where(pos, x, torch.ones_like(x)).sqrt(), torch.zeros_like(x))


def _check_finite_step(step: int, value: float, params: Sequence[torch.Tensor]) -> None:
    """Fail clearly when the loss, a gradient or a parameter of the fit is not finite (never
    keep or cache a NaN kernel)."""
    if not math.isfinite(value):
        raise ValueError(
            f"optimised-kernel fit: the training loss is {value} at step {step} (a reference "
            "or a result with no energy on its mask?); nothing is cached"
        )
    for p in params:
        if not bool(torch.isfinite(p).all()) or (
            p.grad is not None and not bool(torch.isfinite(p.grad).all())
        ):
            raise ValueError(
                f"optimised-kernel fit: a parameter or its gradient is not finite at step "
                f"{step}; nothing is cached"
            )


def training_loss(
    method: nn.Module,
    problems: Sequence[tuple[Any, torch.Tensor]],
    scales: Sequence[float] | None = None,
) -> torch.Tensor:
    """Mean over ``(gbuffer, target)`` pairs of :func:`rel_rms_loss` of ``method(gbuffer)``,
    each divided by its ``scales`` entry (default 1)."""
    scales = [1.0] * len(problems) if scales is None else scales
    if len(scales) != len(problems):
        raise ValueError(f"scales must hold {len(problems)} values, got {len(scales)}")
    pairs = zip(problems, scales, strict=True)
    terms = [rel_rms_loss(method(g), t, g.mask) / c for (g, t), c in pairs]
    return sum(terms) / len(problems)


@dataclass(frozen=True)
class FitResult:
    """What :func:`fit_taps` returns.

    Attributes:
        fitted: the best parameters seen, as a :class:`~sssbench.kernels.parametrise.Fitted`
            (float64, detached kernels and continuous parameters).
        losses: the mean training loss at every evaluated step (``losses[0]``: the init).
        best_step: the step of ``fitted``.
    """

    fitted: Fitted
    losses: list[float]
    best_step: int

    @property
    def kernel(self) -> Kernel1D:
        """The kernel of a two-pass method (``fitted.kernel``)."""
        return self.fitted.kernel


def fit_taps(
    method: nn.Module,
    problems: Sequence[tuple[Any, torch.Tensor]],
    init: Kernel1D | Parametrisation,
    *,
    steps: int = DEFAULT_STEPS,
    lr: float = DEFAULT_LR,
    scales: Sequence[float] | None = None,
) -> FitResult:
    """Fit a method's kernel to targets by Adam: THE optimiser loop of every parametrisation.

    Each step writes the parametrisation's :meth:`~Parametrisation.value` into ``method``
    (e.g. its ``kernel`` or its Gaussian ``steps``), runs ``method`` on every problem (its own
    passes, torch backend) and steps the parameters.

    Args:
        method: the module whose kernel is fitted (e.g. :class:`~sssbench.ops.PreintegratedSSS`);
            the attributes the parametrisation sets are restored afterwards.
        problems: ``(gbuffer, target (1, 3, H, W))`` pairs; the loss is the mean over them of
            :func:`rel_rms_loss` on each G-buffer's mask (:func:`training_loss`).
        init: a :class:`Parametrisation` (its parameters are the start and hold the best
            iterate afterwards), or a symmetric :class:`Kernel1D`, fitted as
            :class:`~sssbench.kernels.parametrise.SymmetricTaps` in ``method.kernel``.
        steps: Adam steps (>= 0); the learning rate decays as a half cosine to 5 % of ``lr``.
        lr: Adam's learning rate on the (unconstrained) parameters, > 0.
        scales: divisor of each problem's term (default 1), > 0.

    Returns:
        A :class:`FitResult` with the best iterate (never worse than the start).
    """
    from sssbench.ops.gather import backend

    steps = check_int("steps", steps, 0)
    lr = check_scalar("lr", lr, 0.0, low_inclusive=False)
    if not problems:
        raise ValueError("problems must hold at least one (gbuffer, target) pair")
    if isinstance(init, Kernel1D):
        init = SymmetricTaps(init)
    if not isinstance(init, Parametrisation):
        raise TypeError(f"init must be a Kernel1D or a Parametrisation, got {type(init).__name__}")
    param = init
    params = [p for p in param.parameters() if p.numel()]
    opt = torch.optim.Adam(params, lr=lr) if params else None
    saved = {name: getattr(method, name) for name in param.value()}
    losses: list[float] = []
    best: tuple[float, dict[str, torch.Tensor], int] = (math.inf, {}, 0)
    try:
        # also inside a caller's no_grad / inference_mode (a method fits on its first call)
        with backend("torch"), torch.inference_mode(False), torch.enable_grad():
            for step in range(steps + 1):
                for name, value in param.value().items():
                    setattr(method, name, value)
                loss = training_loss(method, problems, scales)
                value = float(loss.detach())
                _check_finite_step(step, value, params)
                losses.append(value)
                if value < best[0]:
                    state = {k: v.detach().clone() for k, v in param.state_dict().items()}
                    best = (value, state, step)
                if step == steps or opt is None:
                    break
                for group in opt.param_groups:  # half cosine from lr to 5 % of lr
                    group["lr"] = lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * step / steps)))
                opt.zero_grad()
                loss.backward()
                _check_finite_step(step, value, params)
                opt.step()
    finally:
        for name, value in saved.items():
            setattr(method, name, value)
    if best[1]:
        param.load_state_dict(best[1])
    return FitResult(param.fitted(), losses, best[2])


# ------------------------------------------------------------------- methods
@dataclass(frozen=True)
class MethodFit:
    """How one method's kernel is fitted.

    Attributes:
        cls: the method's class name in :mod:`sssbench.ops`.
        parametrisation: its :class:`Parametrisation` (built from a method by ``parametrise``).
        parametrise: method -> parametrisation at the method's current kernel.
        starts: ``(profile, taps, options) -> {name: method}``, the method with each published
            rule (the fit's starting points and the rules it is compared with).
        profile_of: method -> the profile its fit targets (and is keyed by).
    """

    cls: str
    parametrisation: type[Parametrisation]
    parametrise: Callable[[nn.Module], Parametrisation]
    starts: Callable[[Profile, int, dict[str, Any]], dict[str, nn.Module]]
    profile_of: Callable[[nn.Module], Profile]


def _ops_class(name: str) -> type:
    import sssbench.ops

    return getattr(sssbench.ops, name)


def _rule_starts(cls: str) -> Callable[[Profile, int, dict[str, Any]], dict[str, nn.Module]]:
    """The method with each placement rule of :data:`SAMPLINGS` (000 §7, 002 appendix)."""

    def starts(profile: Profile, taps: int, options: dict[str, Any]) -> dict[str, nn.Module]:
        return {rule: _ops_class(cls)(profile, taps, rule, **options) for rule in SAMPLINGS}

    return starts


def _jimenez2012_starts(
    profile: Profile, taps: int, options: dict[str, Any]
) -> dict[str, nn.Module]:
    """The 2012 method with its given strength / falloff and with each preset of
    :data:`~sssbench.kernels.JIMENEZ2012_PRESETS` (002 Table 1, the 2012 shader's defaults), at
    the given width: the published parameter sets (the width is a scene parameter in 002)."""
    from sssbench.kernels.jimenez2012 import JIMENEZ2012_PRESETS

    cls = _ops_class("Jimenez2012SSS")
    rest = {k: v for k, v in options.items() if k not in ("strength", "falloff")}
    sets = {"given": (options["strength"], options["falloff"])}
    for name, p in JIMENEZ2012_PRESETS.items():
        if json.dumps(_jsonable((p["strength"], p["falloff"]))) != json.dumps(
            _jsonable(sets["given"])
        ):
            sets[name] = (p["strength"], p["falloff"])
    return {name: cls(t, f, samples=taps, profile=profile, **rest) for name, (t, f) in sets.items()}


def _base_profile(method: nn.Module) -> Profile:
    from sssbench.profiles.sum_of_gaussians import SumOfGaussians

    p = method.base_profile
    return SumOfGaussians.from_table(p) if isinstance(p, str) else p


#: method name (as :data:`sssbench.run.registry.METHODS`) -> how its kernel is fitted
METHOD_FITS: dict[str, MethodFit] = {
    "preintegrated": MethodFit(
        "PreintegratedSSS", SymmetricTaps, lambda m: SymmetricTaps(m.kernel),
        _rule_starts("PreintegratedSSS"), lambda m: m.profile,
    ),
    "sum_of_gaussians": MethodFit(
        "SumOfGaussiansSSS", PerGaussianTaps, lambda m: PerGaussianTaps(m.schedule),
        _rule_starts("SumOfGaussiansSSS"), lambda m: m.profile,
    ),
    "jimenez2012": MethodFit(
        "Jimenez2012SSS", Jimenez2012Parameters, Jimenez2012Parameters, _jimenez2012_starts,
        _base_profile,
    ),
}  # fmt: skip
#: methods whose kernels can be fitted
METHODS = tuple(METHOD_FITS)


# ------------------------------------------------------------------- cache
def kernel_cache_dir() -> Path:
    """``$SSSBENCH_CACHE_DIR/kernels``, else ``~/.cache/sssbench/kernels``."""
    root = os.environ.get("SSSBENCH_CACHE_DIR")
    return (Path(root) if root else Path.home() / ".cache" / "sssbench") / "kernels"


def _jsonable(value: Any) -> Any:
    """An option as JSON (a dataclass such as a ``Stretch`` by its fields, tensors and tuples
    as lists, a profile by its content digest)."""
    from sssbench._digest import profile_digest

    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"type": type(value).__name__, **_jsonable(dataclasses.asdict(value))}
    if isinstance(value, Profile):
        return {"profile": profile_digest(value)}
    if isinstance(value, torch.Tensor):
        return value.detach().double().tolist()
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def cache_key(
    profile: Profile,
    method: str,
    taps: int,
    pixel_mm: float,
    training: Sequence[TrainingScene],
    options: Mapping[str, Any],
    steps: int,
    lr: float,
) -> dict[str, Any]:
    """Everything an optimised kernel depends on (module doc)."""
    from sssbench._digest import code_digest, profile_digest

    return {
        "kind": "optimised kernel",
        "code": code_digest(),
        "profile": profile_digest(profile),
        "method": method,
        "options": {k: _jsonable(options[k]) for k in sorted(options)},
        "taps": taps,
        "pixel_mm": pixel_mm,
        "training": [s.describe() for s in training],
        "init": "best published start after screening",
        "optimiser": {"name": "adam", "steps": steps, "lr": lr, "screen": SCREEN_STEPS},
    }


@dataclass(frozen=True)
class OptimisedKernel:
    """A fitted kernel and how it was made.

    Attributes:
        fitted: the kernels (mm, or widths for the 2012 kernel; float64) and continuous
            parameters (:class:`~sssbench.kernels.parametrise.Fitted`).
        method: the method's name (a key of :data:`METHOD_FITS`).
        pixel_mm: the footprint it was fitted at (mm per pixel).
        init_loss, loss: training loss of the best published start and of ``fitted``: the mean
            over the training scenes of the rel RMS divided by the best start's on that scene
            (1 when one start is best on every scene).
        rule_losses: the training loss of each published start (rules, or the 2012 kernel's
            parameter sets).
        start: the start the fit continued from (the best after screening).
        losses: the training loss per step.
        seconds: wall time of the fit (references, rules and steps), as stored with the entry.
        cached: loaded from the disk cache.
        key: :func:`cache_key`.
    """

    fitted: Fitted
    method: str
    pixel_mm: float
    init_loss: float
    loss: float
    rule_losses: dict[str, float]
    start: str
    losses: list[float]
    seconds: float
    cached: bool
    key: dict[str, Any] = field(repr=False)

    @property
    def kernel(self) -> Kernel1D:
        """The kernel of a two-pass method (``fitted.kernel``)."""
        return self.fitted.kernel

    @property
    def params(self) -> dict[str, Any]:
        """The fitted continuous parameters (``fitted.params``; the 2012 kernel's)."""
        return self.fitted.params


_STORED = ("init_loss", "loss", "rule_losses", "start", "losses", "seconds")


def _cache_path(key: Mapping[str, Any], cache_dir: Path | None) -> Path:
    from sssbench.store.tracking import config_hash

    return (cache_dir or kernel_cache_dir()) / f"optimised_{config_hash(dict(key))}.json"


def _load(path: Path, key: Mapping[str, Any], pixel_mm: float) -> OptimisedKernel | None:
    if not path.is_file():
        return None
    try:
        entry = _json.loads(path.read_text())
        if entry["key"] != _json.loads(_json.dumps(dict(key))):
            return None  # a hash collision: never serve another key's kernel
        stored = {name: entry[name] for name in _STORED}
        if not all(math.isfinite(v) for v in (entry["loss"], entry["init_loss"])):
            raise ValueError(f"non-finite loss {entry['loss']}")  # written before the checks
        fitted = Fitted.from_dict(entry["fitted"])
        return OptimisedKernel(fitted, key["method"], pixel_mm, **stored, cached=True,
                               key=dict(key))  # fmt: skip
    except Exception as exc:  # an unreadable entry is recomputed
        log.warning("optimised-kernel cache entry %s unreadable (%s); refitting", path, exc)
        return None


def _store(path: Path, result: OptimisedKernel) -> None:
    """Write one entry atomically (a temporary file, then ``os.replace``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    entry = {"key": result.key, "fitted": result.fitted.as_dict()}
    entry |= {name: getattr(result, name) for name in _STORED}
    tmp.write_text(_json.dumps(entry))
    os.replace(tmp, path)


def sss_reference(
    scene: TrainingScene, gbuffer: Any, profile: Profile, pixel_mm: float
) -> torch.Tensor:
    """``ReferenceSSS(profile)(gbuffer)`` for ``gbuffer = scene.build(pixel_mm)``, from the
    shared reference cache (:mod:`sssbench.store.refcache`) under its own key: the SSS stage only
    (the scattered diffuse), not a pipeline image."""
    from sssbench.ops import ReferenceSSS
    from sssbench.store.refcache import cached_reference, reference_key

    key = reference_key(
        scene=scene.name,
        scene_params={**dict(scene.params), "pixel_mm": pixel_mm},
        profile=profile,
        resolution=scene.resolution,
        seed=scene.seed,
        dtype="float32",
    )
    key["image"] = "ReferenceSSS(profile)(gbuffer): the SSS stage only"

    def compute() -> torch.Tensor:
        with torch.no_grad():
            return ReferenceSSS(profile)(gbuffer)

    return cached_reference(key, compute, shape=tuple(gbuffer.diffuse.shape))[0]


# ------------------------------------------------------------------- entry point
def method_options(method: str, options: Mapping[str, Any] | None) -> dict[str, Any]:
    """Every constructor option of ``method`` but the fit's own (``profile``, ``samples``,
    ``sampling``, ``pixel_mm``), defaults filled in, so that equal methods share one cache key.

    Raises:
        ValueError: an option the fit sets itself, an unknown option, or a required one (the
            2012 kernel's ``strength``, ``falloff``, ``width``) missing, naming it.
    """
    check_choice("method", method, METHODS)
    options = dict(options or {})
    own = {"profile", "samples", "sampling", "pixel_mm"} & set(options)
    if own:
        raise ValueError(f"options must not set {sorted(own)} (the fit's own)")
    params = inspect.signature(_ops_class(METHOD_FITS[method].cls).__init__).parameters
    names = [k for k in params if k not in ("self", "profile", "samples", "sampling", "pixel_mm")]
    unknown = sorted(set(options) - set(names))
    if unknown:
        raise ValueError(f"options of {method!r} have no {unknown}; valid: {names}")
    empty = inspect.Parameter.empty
    missing = [k for k in names if k not in options and params[k].default is empty]
    if missing:
        raise ValueError(f"options of {method!r} must give {missing} (no default)")
    return {k: options.get(k, params[k].default) for k in names}


def optimise(
    profile: Profile,
    method: str = "preintegrated",
    taps: int = 7,
    pixel_mm: float = 0.3,
    training: Sequence[TrainingScene] | None = None,
    steps: int | None = None,
    lr: float | None = None,
    *,
    options: Mapping[str, Any] | None = None,
    cache: bool = True,
    cache_dir: Path | None = None,
) -> OptimisedKernel:
    """A method's kernel fitted at one pixel footprint (module doc).

    Minimises the mean rel RMS of the method (``method`` with ``taps`` and ``options``)
    against the exact reference over ``training`` built at ``pixel_mm`` mm per pixel,
    starting from its published starts (:data:`METHOD_FITS`: the placement rules of
    :data:`SAMPLINGS`, or the 2012 kernel's given and preset parameters; screening, module
    doc). The result is valid for footprints near ``pixel_mm`` (the fit sees how the taps fall
    on pixels of that size); a method's ``sampling="optimised"`` uses the kernel fitted at the
    nearest of :data:`FOOTPRINTS` (0.05–5 mm per pixel). Cost: one forward + backward of the
    method per training scene and step (starts × ``SCREEN_STEPS`` + ``steps`` steps), plus the
    training references once (cached); ``experiments/optimised.py`` times them.

    Args:
        profile: the radial profile: the exact reference's (the target), and the method's
            (its pre-integrated kernel, its Gaussians, or the 2012 kernel's base profile,
            which must then be a :class:`~sssbench.profiles.SumOfGaussians`).
        method: one of :data:`METHODS` (``preintegrated``, ``sum_of_gaussians``,
            ``jimenez2012``).
        taps: taps per pass in ``[1, MAX_OPTIMISED_TAPS]`` (the 2012 kernel adds a centre tap
            to an even count, 002 appendix).
        pixel_mm: footprint of the training scenes, mm per pixel at their focus, > 0.
        training: scenes (default :data:`DEFAULT_TRAINING`).
        steps, lr: see :func:`fit_taps` (``None``: :data:`DEFAULT_STEPS`, :data:`DEFAULT_LR`).
        options: other keyword arguments of the method (``follow_surface``, ``rotation``,
            ``seed``, ``halo`` …; the 2012 kernel's ``strength``, ``falloff`` and ``width``,
            its starting point): the fit runs the passes the method will run.
        cache: load / store the result in ``cache_dir`` (default :func:`kernel_cache_dir`).

    Returns:
        An :class:`OptimisedKernel`.

    Example:
        >>> from sssbench.profiles import SumOfGaussians
        >>> r = optimise(SumOfGaussians.from_table("skin_deon6"), taps=7, pixel_mm=0.3)
        ... # doctest: +SKIP
        >>> r.loss <= r.init_loss  # doctest: +SKIP
        True
    """
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a sssbench Profile, got {type(profile).__name__}")
    options = method_options(method, options)
    taps = check_int("taps", taps, 1, MAX_OPTIMISED_TAPS)
    pixel_mm = check_scalar("pixel_mm", pixel_mm, 0.0, low_inclusive=False)
    steps = check_int("steps", DEFAULT_STEPS if steps is None else steps, 0)
    lr = check_scalar("lr", DEFAULT_LR if lr is None else lr, 0.0, low_inclusive=False)
    training = DEFAULT_TRAINING if training is None else training
    if isinstance(training, (str, bytes)) or not isinstance(training, (list, tuple)):
        raise TypeError(
            f"training must be a non-empty sequence of TrainingScene, got {type(training).__name__}"
        )
    training = tuple(training)
    if not training or not all(isinstance(s, TrainingScene) for s in training):
        raise TypeError("training must be a non-empty sequence of TrainingScene")
    spec = METHOD_FITS[method]
    key = cache_key(profile, method, taps, pixel_mm, training, options, steps, lr)
    path = _cache_path(key, cache_dir)
    if cache and (hit := _load(path, key, pixel_mm)) is not None:
        return hit
    start = time.perf_counter()
    with torch.inference_mode(False):  # scenes and references usable by autograd
        problems = []
        for scene in training:
            g = scene.build(pixel_mm)
            problems.append((g, sss_reference(scene, g, profile, pixel_mm).clone()))
        ops = spec.starts(profile, taps, options)
        with torch.no_grad():  # each scene's term relative to the best start there
            errs = [
                [float(rel_rms_loss(op(g), t, g.mask)) for op in ops.values()] for g, t in problems
            ]
        scales = [max(min(e), torch.finfo(torch.float32).eps) for e in errs]
        params = {name: spec.parametrise(op) for name, op in ops.items()}
        screens = {
            name: fit_taps(op, problems, params[name], steps=min(SCREEN_STEPS, steps), lr=lr,
                           scales=scales)
            for name, op in ops.items()
        }  # fmt: skip
        rule_losses = {name: fit.losses[0] for name, fit in screens.items()}
        chosen = min(screens, key=lambda name: min(screens[name].losses))
        # continues from the best screened iterate (the parametrisation holds it)
        fit = fit_taps(ops[chosen], problems, params[chosen], steps=steps, lr=lr, scales=scales)
    result = OptimisedKernel(
        fit.fitted, method, pixel_mm, min(rule_losses.values()), min(fit.losses), rule_losses,
        chosen, fit.losses, time.perf_counter() - start, False, key,
    )  # fmt: skip
    log.info(
        "optimised %s kernel (%d taps) at %.3g mm/px: training loss (rel RMS / best "
        "start's) %.4g -> %.4g (%.0f s)",
        method, taps, pixel_mm, result.init_loss, result.loss, result.seconds,
    )  # fmt: skip
    if cache:
        _store(path, result)
    return result


def nearest_footprint(pixel_mm: float) -> float:
    """The point of :data:`FOOTPRINTS` nearest to ``pixel_mm`` in log scale (a footprint
    outside 0.05–5 mm per pixel gets the nearest end, with a warning: no kernel is fitted there)."""
    pixel_mm = check_scalar("pixel_mm", pixel_mm, 0.0, low_inclusive=False)
    best = min(FOOTPRINTS, key=lambda p: abs(math.log(pixel_mm / p)))
    if not FOOTPRINTS[0] / 1.2 <= pixel_mm <= FOOTPRINTS[-1] * 1.2:
        log.warning(
            "footprint %.3g mm/px is outside the fitted range %g-%g: using the kernel fitted "
            "at %g mm/px", pixel_mm, FOOTPRINTS[0], FOOTPRINTS[-1], best,
        )  # fmt: skip
    return best


# ------------------------------------------------------------------- methods' use
def use_optimised(method: nn.Module, gbuffer: Any | None = None) -> OptimisedKernel:
    """Install into ``method`` (built with ``sampling="optimised"``) the kernel fitted at its
    footprint: its ``pixel_mm`` when set, else the footprint of ``gbuffer``
    (:func:`sssbench.score.budget.footprint_mm`, the median over the mask; B = 1) snapped to the
    nearest of :data:`FOOTPRINTS`. Fitted on first use (:func:`optimise` with the method's
    ``samples`` and ``fit_options``, then from the disk cache), memoised per footprint in
    ``method.fitted``.

    Raises:
        ValueError: no ``pixel_mm`` and a G-buffer with B != 1 (or none).
    """
    name = next(k for k, s in METHOD_FITS.items() if s.cls == type(method).__name__)
    spec = METHOD_FITS[name]
    pixel_mm = method.pixel_mm
    if pixel_mm is None:
        from sssbench.score.budget import footprint_mm

        if gbuffer is None or gbuffer.shape[0] != 1:
            raise ValueError(
                "sampling='optimised' without pixel_mm resolves the footprint per G-buffer: "
                f"give B = 1 (got {None if gbuffer is None else gbuffer.shape[0]}) or pixel_mm"
            )
        pixel_mm = nearest_footprint(footprint_mm(gbuffer))
    if pixel_mm not in method.fitted:
        method.fitted[pixel_mm] = optimise(
            spec.profile_of(method), name, method.samples, pixel_mm, options=method.fit_options
        )
    fit = method.fitted[pixel_mm]
    spec.parametrisation.install(method, fit.fitted)
    return fit


# the operators find the fitted kernels through the kernel-source registry (no import of
# this module from below: docs/architecture.md)
register_kernel_source(OPTIMISED, use_optimised)

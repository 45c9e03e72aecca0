"""A stochastic method's run: whether its result depends on its seed, and its error split
into bias and noise over several method seeds (:func:`sssbench.score.bias_noise.bias_noise`)."""

from __future__ import annotations

from typing import Any

import torch

from sssbench._checks import MAX_SEED
from sssbench.run import registry
from sssbench.run.inputs import stage_pipeline
from sssbench.run.settings import checkpoint
from sssbench.run.spec import RunSpec
from sssbench.score.bias_noise import bias_noise

__all__ = ["is_stochastic", "seed_split"]


def is_stochastic(method_name: str, method: Any) -> bool:
    """Whether a method's result depends on its seed: registered ``deterministic=False`` (the
    disk) or a separable method with stochastic rotation on (``rotation`` not ``None``)."""
    entry = registry.METHODS[method_name]
    return not entry.deterministic or getattr(method, "rotation", None) is not None


def seed_split(
    spec: RunSpec,
    method: Any,
    profile: Any,
    gbuffer: Any,
    first: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None,
) -> dict[str, float]:
    """:func:`bias_noise` of a stochastic method over ``spec.seeds`` seeds: ``first`` (the
    timed result, the run's seed ``s``) and ``s + 1 … s + K − 1`` (``s`` = the method's own
    ``seed`` option if given, else the run's seed; the scene keeps the run's seed; modulo 2³²
    for a seed in the generators' range). Empty for deterministic methods and ``seeds == 1``."""
    seeds = spec.seeds
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds must be an integer >= 1, got {seeds!r}")
    if seeds == 1 or not is_stochastic(spec.method, method):
        return {}
    base = int(spec.method_params.get("seed", spec.seed))
    images = [first]
    for k in range(1, seeds):
        params = dict(spec.method_params)
        # s + k wraps within the 32-bit seed range (docs/reliability.md, class 1): a run seed
        # of 2³² − 1 stays valid for its K − 1 further seeds
        s_k = (base + k) % (MAX_SEED + 1) if 0 <= base <= MAX_SEED else base + k
        if "seed" in params:
            params["seed"] = s_k
        other = registry.method_from_spec(spec, profile, seed=s_k, params=params)
        images.append(stage_pipeline(spec, other, profile).run(gbuffer).image)
        checkpoint()  # a process waiting to time goes first (settings.timing_slot)
    return bias_noise(images, reference, mask)

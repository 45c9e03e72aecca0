"""The screen-space methods as the app configures them, for the experiments.

``factory(profile, samples) -> nn.Module`` builds method ``name`` exactly as a ``sssbench
method=<name> samples=<n>`` run would (the app's config defaults, e.g. the 2012 kernel's
width, through :func:`sssbench.app.compose_spec` and :func:`sssbench.run.registry.build_method`),
so an experiment and a sweep never disagree on what a method is.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

from torch import nn

from sssbench.app import compose_spec
from sssbench.run import registry
from sssbench.run.spec import RunSpec

#: the screen-space methods the experiments compare (the baseline and the exact reference
#: are handled by the experiments themselves)
SCREEN_SPACE = ("preintegrated", "sum_of_gaussians", "low_rank", "artist", "jimenez2012")


@cache
def _spec(name: str) -> RunSpec:
    return compose_spec(f"method={name}")


def build(name: str, profile, samples: int | None = None) -> nn.Module:
    """Method ``name`` with the app's defaults and ``samples`` taps per pass."""
    spec = _spec(name)
    return registry.method_from_spec(
        spec, profile, samples=spec.samples if samples is None else samples
    )


def available() -> dict[str, Callable[..., nn.Module]]:
    """Method name -> ``factory(profile, samples)`` for every screen-space method."""
    return {name: (lambda p, n, _name=name: build(_name, p, n)) for name in SCREEN_SPACE}


def missing() -> list[str]:
    """Screen-space methods without an operator (none once every method has landed)."""
    return []

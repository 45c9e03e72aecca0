"""Kernel sources: where a method's taps come from when they are not built from a profile by
a placement rule — data the operators are *given*, never code they import from above.

A method built with ``sampling="optimised"`` (taps fitted through its own passes, DESIGN §8)
asks this registry for the source named ``"optimised"`` on first use; the fitting code
(:mod:`sssbench.tune.optimise`, a layer above the operators: it runs them and scores them)
registers itself here when ``sssbench`` is imported. The operators therefore never import the
fitting code, and the import graph stays free of circles (docs/architecture.md).

A source is a callable ``(method, gbuffer | None) -> fit`` that installs the kernel it
resolves into ``method`` and returns what it installed (with its losses, for the record).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sssbench._checks import check_int, check_magnitude
from sssbench.kernels.sampling import OPTIMISED

__all__ = [
    "MAX_OPTIMISED_TAPS",
    "KernelSource",
    "check_optimised_sampling",
    "kernel_source",
    "register_kernel_source",
    "use_optimised",
]

#: largest tap count fitted (a step costs about linearly in taps; beyond this the importance
#: rule's discretisation error is already small, see experiments/sections/sampling.md)
MAX_OPTIMISED_TAPS = 33

#: ``(method, gbuffer | None) -> fit``: installs a kernel into the method, returns the fit
KernelSource = Callable[[Any, Any], Any]

_SOURCES: dict[str, KernelSource] = {}


def register_kernel_source(name: str, source: KernelSource) -> None:
    """Register ``source`` under ``name`` (a later registration of the same name replaces it)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"name must be a non-empty string, got {name!r}")
    if not callable(source):
        raise TypeError(f"source must be callable, got {type(source).__name__}")
    _SOURCES[name] = source


def kernel_source(name: str) -> KernelSource:
    """The source registered under ``name``.

    Raises:
        LookupError: nothing is registered under ``name`` (names the registered ones).
    """
    try:
        return _SOURCES[name]
    except KeyError:
        known = ", ".join(sorted(_SOURCES)) or "none"
        raise LookupError(
            f"no kernel source {name!r} is registered (registered: {known}); "
            "importing sssbench registers the fitted kernels ('optimised')"
        ) from None


def use_optimised(method: Any, gbuffer: Any | None = None) -> Any:
    """Install into ``method`` (built with ``sampling="optimised"``) the kernel the
    ``"optimised"`` source resolves for it (at ``method.pixel_mm``, else at the footprint of
    ``gbuffer``) and return the fit (:func:`sssbench.tune.optimise.use_optimised`)."""
    return kernel_source(OPTIMISED)(method, gbuffer)


def check_optimised_sampling(sampling: str, samples: int, pixel_mm: float | None) -> float | None:
    """Validate a method's ``samples`` and ``pixel_mm`` against its ``sampling``: fitted
    kernels stop at :data:`MAX_OPTIMISED_TAPS`, and ``pixel_mm`` (the footprint, mm per
    pixel) is only for ``sampling="optimised"``. Returns ``pixel_mm``."""
    if sampling == OPTIMISED:
        check_int("samples (with sampling='optimised')", samples, 1, MAX_OPTIMISED_TAPS)
    if pixel_mm is None:
        return None
    if sampling != OPTIMISED:
        raise ValueError(
            f"pixel_mm is the footprint of sampling='optimised' kernels; it must be None "
            f"with sampling={sampling!r}"
        )
    return check_magnitude("pixel_mm", pixel_mm, "length")

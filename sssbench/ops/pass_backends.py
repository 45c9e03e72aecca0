"""Gather backends whose pass lives in a layer above the operators (docs/architecture.md §1).

The GL backend (:mod:`sssbench.gl`) runs a pass as a GLSL shader; it imports the operators, so
the operators must not import it. It registers its passes here when ``sssbench`` is imported:
:func:`sssbench.ops.gather.separable_pass` dispatches ``backend("gl")`` passes to it, and
:class:`sssbench.ops.DiskSSS` its whole disk pass (the disk is one gather over a 2D pattern,
not a separable pass).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sssbench._checks import check_choice

__all__ = ["PASS_BACKENDS_ABOVE", "register_pass_backend"]

#: backends whose pass lives in a layer above the operators (docs/architecture.md): the GL
#: backend (:mod:`sssbench.gl`) registers ``"gl"`` when ``sssbench`` is imported, so the
#: gather dispatches to it without importing it
PASS_BACKENDS_ABOVE = ("gl",)
_REGISTERED: dict[str, tuple[Callable[[], Any], Callable[..., Any]]] = {}
_DISK: dict[str, Callable[..., Any]] = {}


def register_pass_backend(
    name: str,
    enter: Callable[[], Any],
    run_pass: Callable[..., Any],
    disk_pass: Callable[..., Any] | None = None,
) -> None:
    """Register the passes of backend ``name`` (one of :data:`PASS_BACKENDS_ABOVE`): ``enter()``
    is called when a :func:`backend` block starts (raise there if the backend cannot run);
    ``run_pass(image, kernel, direction, gbuffer, **options) -> (out, pixels)`` runs one pass
    with :func:`separable_pass`'s semantics; ``disk_pass(method, gbuffer) -> image`` (optional)
    runs a :class:`~sssbench.ops.DiskSSS` with its ``forward``'s semantics."""
    check_choice("name", name, PASS_BACKENDS_ABOVE)
    if not (callable(enter) and callable(run_pass)):
        raise TypeError("enter and run_pass must be callable")
    if disk_pass is not None and not callable(disk_pass):
        raise TypeError("disk_pass must be callable or None")
    _REGISTERED[name] = (enter, run_pass)
    if disk_pass is not None:
        _DISK[name] = disk_pass
    else:
        _DISK.pop(name, None)


def _pass_backend(name: str) -> tuple[Callable[[], Any], Callable[..., Any]]:
    try:
        return _REGISTERED[name]
    except KeyError:
        raise RuntimeError(
            f"backend {name!r} is not registered: it registers itself when sssbench is "
            "imported (sssbench.gl)"
        ) from None


def _disk_pass_backend(name: str) -> Callable[..., Any]:
    """The disk pass registered for backend ``name`` (``RuntimeError`` naming it if none)."""
    _pass_backend(name)
    try:
        return _DISK[name]
    except KeyError:
        raise RuntimeError(f"backend {name!r} registered no disk pass (DiskSSS)") from None

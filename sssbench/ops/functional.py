"""Functional twins of the operators, in kornia's style (DESIGN §7).

``preintegrated_sss(gbuffer, profile, samples=7, ...)`` is ``PreintegratedSSS(profile,
samples=7, ...)(gbuffer)`` with **every** argument of the module, but without rebuilding the
kernel (or the SVD) on every call: modules are kept in a small least-recently-used cache keyed
by the *content* of their arguments — a profile by its tensors (so a profile changed in place
is a different key, never a stale kernel), tensors by their bytes, everything else by value.
The cached module is never handed out, so nobody can change it behind the cache's back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import torch
from torch import nn

__all__ = ["functional", "cached_module", "CACHE_SIZE"]

#: modules kept by :func:`cached_module`
CACHE_SIZE = 32
_CACHE: OrderedDict[tuple, nn.Module] = OrderedDict()


def _key(value: Any) -> Any:
    from sssbench._digest import profile_digest
    from sssbench.profiles.base import Profile

    if isinstance(value, Profile):
        return ("profile", profile_digest(value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = dataclasses.fields(value)
        return (type(value).__name__, tuple((f.name, _key(getattr(value, f.name))) for f in fields))
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous()
        return (
            "tensor",
            str(t.dtype),
            tuple(t.shape),
            hashlib.sha256(t.numpy().tobytes()).digest(),
        )
    if isinstance(value, (list, tuple)):
        return (type(value).__name__, tuple(_key(v) for v in value))
    if isinstance(value, dict):
        return ("dict", tuple(sorted((k, _key(v)) for k, v in value.items())))
    if isinstance(value, (str, int, float, bool, type(None))):
        return (type(value).__name__, value)
    raise TypeError(f"functional operators take plain values, got {type(value).__name__}")


def cached_module(cls: type[nn.Module], *args: Any, **kwargs: Any) -> nn.Module:
    """``cls(*args, **kwargs)``, built once per distinct argument content (see module doc)."""
    key = (cls, _key(args), _key(kwargs))
    module = _CACHE.get(key)
    if module is None:
        module = cls(*args, **kwargs)
        _CACHE[key] = module
        if len(_CACHE) > CACHE_SIZE:
            _CACHE.popitem(last=False)
    else:
        _CACHE.move_to_end(key)
    return module


def functional(cls: type[nn.Module], name: str) -> Callable[..., torch.Tensor]:
    """The functional twin ``name(gbuffer, *args, **kwargs)`` of operator ``cls``: the same
    arguments as ``cls(...)`` (and its signature, for help and introspection), then applied
    to ``gbuffer``; forward options (``width``, ``guide``, ``sample_weight``, ``inplace``) are
    not taken — use the module for those."""

    def twin(gbuffer: Any, *args: Any, **kwargs: Any) -> torch.Tensor:
        return cached_module(cls, *args, **kwargs)(gbuffer)

    params = list(inspect.signature(cls.__init__).parameters.values())[1:]
    gb = inspect.Parameter("gbuffer", inspect.Parameter.POSITIONAL_OR_KEYWORD)
    twin.__signature__ = inspect.Signature([gb, *params], return_annotation=torch.Tensor)
    twin.__name__ = twin.__qualname__ = name
    twin.__doc__ = (
        f"``{cls.__name__}(*args, **kwargs)(gbuffer)`` — the functional form of "
        f":class:`{cls.__name__}` (every argument of the module; the module is built once per "
        "distinct argument content and reused, see :mod:`sssbench.ops.functional`).\n\n"
        f"{cls.__doc__ or ''}"
    )
    twin.__module__ = cls.__module__
    return twin

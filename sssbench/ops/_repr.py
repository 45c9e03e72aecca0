"""``extra_repr`` of the operators: ``print(op)`` shows every setting it was built with.

:func:`options_repr` reads the constructor's parameter names and shows the attribute of the
same name when the operator keeps one (``samples=7, sampling='importance', ...``): one rule
for every operator, so a new option appears in the printout without another list to update.
"""

from __future__ import annotations

import inspect
from typing import Any

import torch

__all__ = ["options_repr"]


def _short(value: Any) -> str:
    from sssbench.profiles.base import Profile

    if isinstance(value, Profile):
        return f"{type(value).__name__}({getattr(value, 'name', '')!s})"
    if isinstance(value, torch.Tensor):
        if value.numel() <= 6:
            return "[" + ", ".join(f"{v:.4g}" for v in value.reshape(-1).tolist()) + "]"
        return f"tensor{tuple(value.shape)}"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)) and len(value) > 6:
        return f"[{len(value)} items]"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    return repr(value)


def options_repr(module: Any) -> str:
    """``name=value`` for every constructor parameter the module keeps as an attribute."""
    names = list(inspect.signature(type(module).__init__).parameters)[1:]
    parts = []
    for name in names:
        if name in module.__dict__ or hasattr(type(module), name) or name in dir(module):
            try:
                value = getattr(module, name)
            except AttributeError:
                continue
            if isinstance(value, torch.nn.Module):
                continue  # children print themselves
            parts.append(f"{name}={_short(value)}")
    return ", ".join(parts)

"""Input validation shared by every public function (DESIGN §2: check at the boundary).

Each helper raises ``ValueError`` or ``TypeError`` whose message names the argument, what was
expected and what was received. Internals trust data that passed these checks.

Half-precision policy (``docs/numerics.md``): tensors must be float32 or float64. float16 and
bfloat16 are rejected by :func:`check_tensor` with a ``TypeError`` naming the argument and
asking for float32 — a pass accumulates up to ``MAX_SAMPLES`` weighted taps, and at a unit
roundoff of 2⁻¹¹ / 2⁻⁸ a normalised kernel no longer sums to 1 to within its own tails; nothing
is cast silently. Tested in ``tests/reliability/test_half_precision.py``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

FLOAT_DTYPES = (torch.float32, torch.float64)


def check_tensor(
    name: str,
    value: object,
    *,
    ndim: int | None = None,
    channels: int | Sequence[int] | None = None,
    finite: bool = True,
) -> torch.Tensor:
    """Check that ``value`` is a float32/float64 tensor of the given rank and channel count.

    Args:
        name: argument name used in error messages.
        value: the object to check.
        ndim: required number of dimensions, or ``None`` for any.
        channels: required size of dim 1 (an int or a set of allowed sizes), or ``None``.
        finite: reject NaN and Inf (DESIGN §2: no silent NaN).

    Returns:
        The tensor, unchanged.
    """
    if not isinstance(value, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if value.dtype not in FLOAT_DTYPES:
        if value.dtype in (torch.float16, torch.bfloat16):
            raise TypeError(
                f"{name} has dtype {value.dtype}; half precision is not supported: "
                "convert to float32 (accumulation in half precision loses the kernel tails)"
            )
        raise TypeError(f"{name} must be float32 or float64, got dtype {value.dtype}")
    if ndim is not None and value.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {tuple(value.shape)}")
    if channels is not None:
        allowed = (channels,) if isinstance(channels, int) else tuple(channels)
        if value.ndim < 2 or value.shape[1] not in allowed:
            raise ValueError(
                f"{name} must have {' or '.join(map(str, allowed))} channels in dim 1, "
                f"got shape {tuple(value.shape)}"
            )
    if finite and not bool(torch.isfinite(value).all()):
        n_bad = int((~torch.isfinite(value)).sum())
        raise ValueError(f"{name} contains {n_bad} NaN or Inf values; expected finite values")
    return value


def check_range(
    name: str,
    value: torch.Tensor,
    low: float | None = None,
    high: float | None = None,
    *,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
) -> torch.Tensor:
    """Check that every element of ``value`` lies in the interval [low, high] (or open ends)."""
    if value.numel() == 0:
        return value
    _check_bounds(name, float(value.min()), float(value.max()), low, high, low_inclusive,
                  high_inclusive)  # fmt: skip
    return value


def _check_bounds(
    name: str,
    vmin: float,
    vmax: float,
    low: float | None,
    high: float | None,
    low_inclusive: bool,
    high_inclusive: bool,
) -> None:
    """Raise unless [vmin, vmax] lies in the interval (Python floats: float64 comparisons)."""
    lo_ok = low is None or (vmin >= low if low_inclusive else vmin > low)
    hi_ok = high is None or (vmax <= high if high_inclusive else vmax < high)
    if not (lo_ok and hi_ok):
        interval = _interval(low, high, low_inclusive, high_inclusive)
        raise ValueError(f"{name} must lie{interval}, got values in [{vmin:g}, {vmax:g}]")


def check_scalar(
    name: str,
    value: object,
    low: float | None = None,
    high: float | None = None,
    *,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
) -> float:
    """Check a finite real scalar in a range and return it as ``float``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        if isinstance(value, torch.Tensor) and value.numel() == 1:
            value = float(value)
        else:
            raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(
            f"{name} must be a finite number{_interval(low, high, low_inclusive, high_inclusive)}"
            f", got {value}"
        )
    # a Python float is a float64: 1e-300 does not round to 0
    _check_bounds(name, value, value, low, high, low_inclusive, high_inclusive)
    return value


def check_int(name: str, value: object, low: int | None = None, high: int | None = None) -> int:
    """Check an integer (not bool, not float) in [low, high] and return it."""
    if isinstance(value, bool) or not isinstance(value, int):
        lo = "-inf" if low is None else str(low)
        hi = "inf" if high is None else str(high)
        raise TypeError(
            f"{name} must be an integer in [{lo}, {hi}], got {type(value).__name__} {value!r}"
        )
    if (low is not None and value < low) or (high is not None and value > high):
        lo = "-inf" if low is None else str(low)
        hi = "inf" if high is None else str(high)
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value}")
    return value


def _interval(
    low: float | None, high: float | None, low_inclusive: bool, high_inclusive: bool
) -> str:
    """`` in [low, high]`` (with open ends as given), or ``""`` when unbounded."""
    if low is None and high is None:
        return ""
    lb = "[" if low_inclusive and low is not None else "("
    rb = "]" if high_inclusive and high is not None else ")"
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    return f" in {lb}{lo}, {hi}{rb}"


def check_choice(name: str, value: object, choices: Sequence[object]) -> object:
    """Check that ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value

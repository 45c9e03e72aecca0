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

#: Magnitudes accepted for physical scalars, per kind: ``(smallest non-zero, largest, unit)``.
#: Lengths run from 1 nm to 1 km (every material and scene of the papers lies decades inside),
#: variances are their squares, coefficients their reciprocals, and dimensionless factors
#: (multipliers, range σ, gains) span the same twelve decades around 1. The bounds keep every
#: derived quantity the passes form in float32 — ``x²``, ``1/x²``, ``x · pixels-per-mm``,
#: ``exp(−d²/2v)`` — inside float32's normal range (1.2e-38 … 3.4e38) instead of overflowing to
#: inf or underflowing to 0 and turning into NaN downstream (``docs/reliability.md``).
MAGNITUDES: dict[str, tuple[float, float, str]] = {
    "length": (1e-6, 1e6, "mm"),
    "variance": (1e-12, 1e12, "mm²"),
    "coefficient": (1e-6, 1e6, "mm⁻¹"),
    "factor": (1e-6, 1e6, ""),
}
#: largest seed of every API that takes one (rotation, scenes, Monte Carlo, optimised kernels):
#: the CPU ``torch.Generator`` (MT19937) keeps only the low 32 bits of its seed, so a wider seed
#: would be accepted and silently folded (``s`` and ``s + 2³²`` give the same stream). Seeds are
#: therefore refused above 2³² − 1 (``docs/reliability.md``), and the seeds derived from one
#: (per batch, worker, channel) are hashes of it (:func:`derive_seed`), never ``seed · k + i``.
MAX_SEED = 2**32 - 1


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
    v = value.detach()  # a bound is checked on the values, not recorded by autograd
    _check_bounds(name, float(v.min()), float(v.max()), low, high, low_inclusive,
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


def check_magnitude(
    name: str, value: object, kind: str, *, zero: bool = False
) -> float | torch.Tensor:
    """Check a physical scalar (or every element of a tensor) against :data:`MAGNITUDES`.

    Args:
        name: argument name used in error messages.
        value: a real number, or a float tensor (checked elementwise).
        kind: ``"length"`` (mm), ``"variance"`` (mm²), ``"coefficient"`` (mm⁻¹) or
            ``"factor"`` (dimensionless).
        zero: accept the whole of ``[0, largest]``: for quantities that may vanish (an
            absorption coefficient, a gain), which are therefore never divided by, so only
            the upper bound matters.

    Returns:
        The value as ``float`` (scalars) or the tensor, unchanged.

    Raises:
        TypeError: not a real number / float tensor.
        ValueError: NaN, ±inf, negative, 0 (unless ``zero``), or outside the kind's range; the
            message names the argument and the allowed range with its unit.
    """
    lo, hi, unit = MAGNITUDES[kind]
    lo = 0.0 if zero else lo
    allowed = f"in [{lo:g}, {hi:g}]{' ' + unit if unit else ''}"
    if isinstance(value, torch.Tensor) and value.numel() != 1:
        t = check_tensor(name, value)
        bad = (t < lo) | (t > hi) | ((t == 0) & (not zero))
        if t.numel() and bool(bad.any()):
            v = float(t[bad][0])
            raise ValueError(f"{name} must be {allowed}, got {v:g}")
        return t
    v = check_scalar(name, value)
    if not lo <= v <= hi or (v == 0 and not zero):
        raise ValueError(f"{name} must be {allowed}, got {v:g}")
    return v


def check_seed(name: str, value: object) -> int:
    """A seed as the user gave it: an integer in [0, :data:`MAX_SEED`] (2³² − 1, all of whose
    bits the generator honours), else one line naming ``name`` and the range."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(
            f"{name} must be an integer seed in [0, {MAX_SEED}], got {type(value).__name__} "
            f"{value!r}"
        )
    if not 0 <= value <= MAX_SEED:
        raise ValueError(
            f"{name} must be an integer seed in [0, {MAX_SEED}] (2^32 - 1: the generator keeps "
            f"32 bits of a seed), got {value}"
        )
    return value


def derive_seed(seed: int, *keys: object) -> int:
    """A generator seed in [0, :data:`MAX_SEED`] for the stream ``keys`` (a batch, a worker,
    a channel …) of the user's ``seed``: a 32-bit BLAKE2b hash of both, so that distinct
    ``(seed, keys)`` give unrelated streams (equal only by a 2⁻³² chance, not by arithmetic)
    instead of ``seed · k + i`` overflowing 32 bits or landing systematically on another
    seed's stream. ``seed`` must already be checked."""
    import hashlib

    text = " ".join(map(str, ("sssbench.seed", seed, *keys)))
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=4).digest(), "little")


def check_method_options(surface_scale: object, seed: object) -> None:
    """Magnitude checks of the options every separable method shares (on entry, before any
    kernel is built): ``surface_scale`` a length (scalar or per-channel ``(3,)``) or ``None``,
    ``seed`` a generator seed."""
    if surface_scale is not None:
        check_magnitude("surface_scale", surface_scale, "length")
    check_seed("seed", seed)

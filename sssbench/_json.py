"""Strict JSON for every file and column the project writes (``metrics.json``, ``point.json``,
the run store's JSON columns, the exporter's and the fitted kernels' files).

Python's :mod:`json` writes ``NaN`` and ``Infinity`` by default, which strict parsers (a
browser's ``JSON.parse``, ``jq``) reject. :func:`dumps` writes a non-finite number as ``null``
and, inside an object, states what it was in a sibling field ``<key>_nonfinite`` (``"nan"``,
``"inf"`` or ``"-inf"``; in a list the ``null`` stands alone). :func:`loads` reads it back
with the numbers restored, and reads older files that hold ``NaN`` as well.
"""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["NONFINITE_SUFFIX", "dumps", "loads", "strict"]

#: suffix of the sibling field that says what a ``null`` written for a non-finite number was
NONFINITE_SUFFIX = "_nonfinite"


def _word(x: float) -> str:
    return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")


def strict(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by ``None`` (and, in a dict, a sibling
    ``<key>_nonfinite`` naming it); tuples become lists, other values are left as they are."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        out: dict[Any, Any] = {}
        for k, v in obj.items():
            if isinstance(v, float) and not math.isfinite(v):
                out[k] = None
                out[f"{k}{NONFINITE_SUFFIX}"] = _word(v)
            else:
                out[k] = strict(v)
        return out
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    return obj


def dumps(obj: Any, **kwargs: Any) -> str:
    """:func:`json.dumps` of :func:`strict` ``(obj)`` with ``allow_nan=False`` (a non-finite
    number that slipped through, e.g. from a ``default=`` hook, raises instead of writing
    invalid JSON). Keyword arguments as :func:`json.dumps`."""
    default = kwargs.get("default")
    if default is not None:  # what default= makes of a value is made strict too

        def hook(o: Any) -> Any:
            return strict(default(o))

        kwargs["default"] = hook
    return json.dumps(strict(obj), allow_nan=False, **kwargs)


def _restore(obj: Any) -> Any:
    if isinstance(obj, dict):
        out = {k: _restore(v) for k, v in obj.items()}
        for k in [k for k in out if isinstance(k, str) and k.endswith(NONFINITE_SUFFIX)]:
            key = k[: -len(NONFINITE_SUFFIX)]
            if key in out and out[key] is None and out[k] in ("nan", "inf", "-inf"):
                out[key] = float(out.pop(k))
        return out
    if isinstance(obj, list):
        return [_restore(v) for v in obj]
    return obj


def loads(text: str | bytes) -> Any:
    """Parse JSON written by :func:`dumps` with the non-finite numbers restored (``NaN``
    literals of older files are read as well)."""
    return _restore(json.loads(text))

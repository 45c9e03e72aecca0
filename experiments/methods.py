"""The screen-space methods as ``factory(profile, samples) -> nn.Module`` for the experiments.

Each entry builds one method at a taps-per-pass count; methods not landed in
:mod:`sssbench.ops` are left out (:func:`available`).
"""

from __future__ import annotations

from collections.abc import Callable

from torch import nn

import sssbench.ops as ops

#: 002's shader-default 2012 kernel needs a width in mm (a scene parameter): 2 mm, as perf uses
JIMENEZ2012_WIDTH_MM = 2.0


def _factories() -> dict[str, tuple[str, Callable[..., nn.Module]]]:
    return {
        "preintegrated": ("PreintegratedSSS", lambda p, n: ops.PreintegratedSSS(p, n)),
        "sum_of_gaussians": ("SumOfGaussiansSSS", lambda p, n: ops.SumOfGaussiansSSS(p, n)),
        "low_rank3": (
            "LowRankSSS",
            lambda p, n: ops.LowRankSSS(p, 3, n=n, extent=4 * float(p.length_scales()[1])),
        ),
        "artist": (
            "ArtistSSS",
            lambda p, n: ops.ArtistSSS.preset("multi_layer_close_fit", n),
        ),
        "jimenez2012": (
            "Jimenez2012SSS",
            lambda p, n: ops.Jimenez2012SSS.preset("shader_default", JIMENEZ2012_WIDTH_MM, n),
        ),
    }


def available() -> dict[str, Callable[..., nn.Module]]:
    """Method name -> factory, for the methods present in :mod:`sssbench.ops`."""
    return {k: f for k, (cls, f) in _factories().items() if hasattr(ops, cls)}


def missing() -> list[str]:
    return [k for k, (cls, _) in _factories().items() if not hasattr(ops, cls)]

"""Functional twins (kornia style) and operator printouts.

A twin takes every argument of its module and gives the module's result bit for bit; it
reuses the kernel while the arguments' content is unchanged and rebuilds it when a profile
is changed in place (no stale kernel). ``print(op)`` shows the settings it was built with.
"""

from __future__ import annotations

import inspect

import pytest
import torch

import data_synth
from sssbench import ops
from sssbench.ops.functional import cached_module
from sssbench.profiles import SumOfGaussians

TWINS = {
    "preintegrated_sss": (ops.PreintegratedSSS, lambda p: (p,), {"samples": 9, "rotation": 0.1}),
    "sum_of_gaussians_sss": (ops.SumOfGaussiansSSS, lambda p: (p,), {"samples": 5}),
    "fused_sum_of_gaussians_sss": (
        ops.FusedSumOfGaussiansSSS,
        lambda p: (p,),
        {"samples": 5, "follow_surface": None},
    ),
    "low_rank_sss": (ops.LowRankSSS, lambda p: (p,), {"rank": 2, "n": 9}),
    "artist_sss": (ops.ArtistSSS, lambda p: (0.5, 0.8, 0.4, 1.5), {"samples": 5}),
    "jimenez2012_sss": (
        ops.Jimenez2012SSS,
        lambda p: ((0.48, 0.41, 0.28), (1.0, 0.37, 0.3), 3.0),
        {"samples": 9},
    ),
    "disk_sss": (ops.DiskSSS, lambda p: (p,), {"samples": 8, "seed": 3}),
}


@pytest.fixture(scope="module")
def scene():
    return data_synth.make_scene("head_cheek", (24, 24), dtype=torch.float64)


@pytest.mark.parametrize("name", sorted(TWINS))
def test_twin_takes_every_argument_and_equals_the_module(name, scene):
    cls, args, kwargs = TWINS[name]
    twin = getattr(ops, name)
    cls_params = list(inspect.signature(cls.__init__).parameters)[1:]
    assert list(inspect.signature(twin).parameters) == ["gbuffer", *cls_params]
    p = SumOfGaussians.from_table("skin_jg10")
    got = twin(scene, *args(p), **kwargs)
    torch.testing.assert_close(got, cls(*args(p), **kwargs)(scene), rtol=0, atol=0)


def test_twin_reuses_the_kernel_and_never_a_stale_one(scene):
    p = SumOfGaussians.from_table("skin_jg10")
    first = cached_module(ops.PreintegratedSSS, p, samples=7)
    assert cached_module(ops.PreintegratedSSS, p, samples=7) is first  # same content
    assert cached_module(ops.PreintegratedSSS, p, samples=9) is not first
    with torch.no_grad():
        p.variances.mul_(4.0)  # the profile changed in place: a new kernel
    rebuilt = cached_module(ops.PreintegratedSSS, p, samples=7)
    assert rebuilt is not first
    torch.testing.assert_close(
        ops.preintegrated_sss(scene, p, samples=7),
        ops.PreintegratedSSS(p, samples=7)(scene),
        rtol=0,
        atol=0,
    )


def test_every_registered_operator_prints_its_settings():
    from sssbench.app import compose_spec
    from sssbench.run import registry

    p = SumOfGaussians.from_table("skin_jg10")
    for name, entry in registry.METHODS.items():
        if name == "reference":
            continue
        samples = 5 if entry.samples_arg else None
        params = compose_spec(f"method={name}").method_params  # the app's defaults
        op = registry.build_method(name, p, samples=samples, params=params)
        text = repr(op)
        if entry.samples_arg:
            assert f"{entry.samples_arg}=5" in text, text
        assert text.startswith(type(op).__name__ + "(")
    assert "mode='sqrt'" in repr(ops.Texturing("sqrt"))
    assert "strategy='reduce_min'" in repr(ops.CurvatureModulation("reduce_min"))

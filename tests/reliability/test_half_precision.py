"""The half-precision policy (``docs/numerics.md``): float16 and bfloat16 are rejected at the
boundary with a TypeError that names the argument and says to convert to float32."""

from __future__ import annotations

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D
from sssbench.ops import PreintegratedSSS, separable_pass
from sssbench.profiles import SumOfGaussians

HALF = [torch.float16, torch.bfloat16]


def _fields(dtype=torch.float32):
    return {
        "diffuse": torch.rand(1, 3, 6, 6).to(dtype),
        "depth": torch.full((1, 1, 6, 6), 400.0).to(dtype),
        "fov_y": 0.5,
    }


def _assert_half_message(info, name, dtype):
    msg = str(info.value)
    assert name in msg and str(dtype) in msg, msg
    assert "half precision is not supported" in msg and "float32" in msg, msg


@pytest.mark.parametrize("dtype", HALF)
@pytest.mark.parametrize("field", ["diffuse", "depth", "mask", "normal", "thickness"])
def test_gbuffer_rejects_half(dtype, field):
    f = _fields()
    ch = 3 if field in ("diffuse", "normal") else 1
    f[field] = torch.full((1, ch, 6, 6), 0.5, dtype=dtype)
    with pytest.raises(TypeError) as info:
        GBuffer(**f)
    _assert_half_message(info, field, dtype)


@pytest.mark.parametrize("dtype", HALF)
def test_gbuffer_all_half_rejected(dtype):
    with pytest.raises(TypeError) as info:
        GBuffer(**_fields(dtype))
    _assert_half_message(info, "diffuse", dtype)


@pytest.mark.parametrize("dtype", HALF)
def test_separable_pass_rejects_half_image(dtype):
    g = GBuffer(**_fields())
    k = Kernel1D(torch.tensor([-1.0, 0.0, 1.0]), torch.full((3, 3), 1 / 3))
    with pytest.raises(TypeError) as info:
        separable_pass(g.diffuse.to(dtype), k, "x", g)
    _assert_half_message(info, "image", dtype)


@pytest.mark.parametrize("dtype", HALF)
def test_kernel_rejects_half(dtype):
    with pytest.raises(TypeError) as info:
        Kernel1D(torch.tensor([0.0], dtype=dtype), torch.ones(1, 3))
    _assert_half_message(info, "offsets", dtype)
    with pytest.raises(TypeError) as info:
        Kernel1D(torch.tensor([0.0]), torch.ones(1, 3, dtype=dtype))
    _assert_half_message(info, "weights", dtype)


@pytest.mark.parametrize("dtype", HALF)
def test_gbuffer_to_half_rejected_and_float32_is_the_way_back(dtype):
    g = GBuffer(**_fields(torch.float64))
    with pytest.raises(TypeError, match="half precision"):
        g.to(dtype)
    out = PreintegratedSSS(SumOfGaussians.from_table("skin_jg10"), 3)(g.to(torch.float32))
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())

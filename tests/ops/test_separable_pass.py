"""The gather primitive against an independent per-pixel loop (the 2012 shader, in numpy)."""

import math

import numpy as np
import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D
from sssbench.ops import Rotation, record_passes, separable_pass


def slow_pass(img, depth, mask, fov, offsets, weights, direction, follow=None, scale=None):
    """Per-pixel transcription of 002's SSSSBlurPS with mm units (DESIGN §4)."""
    _, _, h, w = img.shape
    out = img.copy()
    f = h / (2 * math.tan(fov / 2))
    for i in range(h):
        for j in range(w):
            m = mask[0, 0, i, j]
            if m == 0:
                continue
            step = f / depth[0, 0, i, j] * m
            acc = np.zeros(3)
            for o, wt in zip(offsets, weights, strict=True):
                p = (j if direction == "x" else i) + o * step
                n = w if direction == "x" else h
                p = min(max(p, 0.0), n - 1)
                p0 = int(math.floor(p))
                p1 = min(p0 + 1, n - 1)
                t = p - p0
                if direction == "x":
                    s = (1 - t) * img[0, :, i, p0] + t * img[0, :, i, p1]
                    z = (1 - t) * depth[0, 0, i, p0] + t * depth[0, 0, i, p1]
                else:
                    s = (1 - t) * img[0, :, p0, j] + t * img[0, :, p1, j]
                    z = (1 - t) * depth[0, 0, p0, j] + t * depth[0, 0, p1, j]
                if follow == "lerp" and o != 0:
                    a = min(abs(z - depth[0, 0, i, j]) / scale, 1.0)
                    s = s + a * (img[0, :, i, j] - s)
                acc += wt * s
            out[0, :, i, j] = acc
    return out


def make(seed=0, h=9, w=11, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(1, 3, h, w, generator=g, dtype=dtype)
    depth = 80 + 40 * torch.rand(1, 1, h, w, generator=g, dtype=dtype)
    mask = (torch.rand(1, 1, h, w, generator=g, dtype=dtype) > 0.3).to(dtype)
    mask = mask * torch.rand(1, 1, h, w, generator=g, dtype=dtype)
    return GBuffer(img, depth, 0.6, mask=mask)


KERNEL = Kernel1D(
    torch.tensor([-3.1, -1.2, 0.0, 0.7, 2.9], dtype=torch.float64),
    torch.tensor(
        [[0.1, 0.2, 0.05], [0.2, 0.2, 0.15], [0.4, 0.3, 0.6], [0.2, 0.2, 0.15], [0.1, 0.1, 0.05]],
        dtype=torch.float64,
    ),
)


@pytest.mark.parametrize("direction", ["x", "y"])
@pytest.mark.parametrize("follow", [None, "lerp"])
def test_matches_slow_per_pixel_loop(direction, follow):
    g = make()
    got = separable_pass(g.diffuse, KERNEL, direction, g, follow_surface=follow, surface_scale=7.0)
    ref = slow_pass(
        g.diffuse.numpy(),
        g.depth.numpy(),
        g.mask.numpy(),
        g.fov_y,
        KERNEL.offsets.tolist(),
        KERNEL.weights.numpy(),
        direction,
        follow,
        7.0,
    )
    np.testing.assert_allclose(got.numpy(), ref, rtol=1e-12, atol=1e-12)


def test_masked_out_pixels_are_not_computed_and_recorded():
    g = make()
    with record_passes() as rec:
        out = separable_pass(g.diffuse, KERNEL, "x", g, name="probe")
    off = g.mask == 0
    assert torch.equal(
        out.masked_select(off.expand_as(out)), g.diffuse.masked_select(off.expand_as(out))
    )
    assert rec[0].name == "probe" and rec[0].samples == 5
    assert rec[0].pixels == int((g.mask > 0).sum())


def test_normalised_kernel_keeps_a_constant_image():
    g = make(dtype=torch.float32)
    const = GBuffer(torch.full_like(g.diffuse, 0.37), g.depth, g.fov_y, mask=g.mask)
    k = KERNEL.to(torch.float32)
    k = Kernel1D(k.offsets, k.weights / k.weights.sum(0))
    out = separable_pass(const.diffuse, k, "y", const)
    assert float((out - 0.37).abs().max()) < 1e-6


def test_rotation_by_zero_equals_the_axis_pass_and_by_quarter_turn_equals_other_axis():
    g = make()
    zero = Rotation(torch.zeros_like(g.depth), radius=1.0)
    a = separable_pass(g.diffuse, KERNEL, "x", g, rotation=zero)
    b = separable_pass(g.diffuse, KERNEL, "x", g)
    torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    # turning the x axis by -90° (rows grow downward) samples along y with flipped offsets
    quarter = Rotation(torch.full_like(g.depth, -math.pi / 2), radius=1.0)
    c = separable_pass(g.diffuse, KERNEL, "x", g, rotation=quarter)
    flipped = Kernel1D(-KERNEL.offsets.flip(0), KERNEL.weights.flip(0))
    d = separable_pass(g.diffuse, flipped, "y", g)
    torch.testing.assert_close(c, d, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(
    "kw, exc, match",
    [
        (dict(direction="z"), ValueError, "direction"),
        (dict(width=0.0), ValueError, "width"),
        (dict(follow_surface="bilinear"), ValueError, "follow_surface"),
        (dict(image=torch.ones(1, 3, 2, 2, dtype=torch.float64)), ValueError, "image"),
        (dict(kernel="gauss"), TypeError, "kernel"),
    ],
)
def test_bad_arguments(kw, exc, match):
    g = make()
    args = dict(image=g.diffuse, kernel=KERNEL, direction="x", gbuffer=g)
    args.update(kw)
    with pytest.raises(exc, match=match):
        separable_pass(**args)


@pytest.mark.parametrize("follow", ["lerp", "gaussian"])
def test_per_channel_surface_scale_equals_three_scalar_passes(follow):
    g = make()
    scales = torch.tensor([2.0, 7.0, 30.0], dtype=torch.float64)
    got = separable_pass(g.diffuse, KERNEL, "x", g, follow_surface=follow, surface_scale=scales)
    for c, s in enumerate(scales.tolist()):
        one = separable_pass(g.diffuse, KERNEL, "x", g, follow_surface=follow, surface_scale=s)
        torch.testing.assert_close(got[:, c], one[:, c], rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="surface_scale"):
        separable_pass(g.diffuse, KERNEL, "x", g, follow_surface=follow, surface_scale=-scales)


def test_compiled_loop_equals_eager_loop():
    """torch.compile fuses the tap loop (issue 7); results must equal the eager loop."""
    from sssbench.ops.gather import backend

    g = make(dtype=torch.float32, h=12, w=17)
    kernel = KERNEL.to(torch.float32)
    with backend("torch"):
        eager = separable_pass(g.diffuse, kernel, "x", g, follow_surface="lerp", surface_scale=5.0)
    with backend("compile"):
        fused = separable_pass(g.diffuse, kernel, "x", g, follow_surface="lerp", surface_scale=5.0)
    torch.testing.assert_close(fused, eager, rtol=1e-5, atol=1e-6)

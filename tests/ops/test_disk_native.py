"""The disk's C sample loop (``native/disk.c``) against its specification, the torch loop
(``with gather.backend("torch")``), on every option the disk tests cover, both dtypes, both
estimators, every SIMD level; its fallbacks (other profiles, autograd, no library)."""

from __future__ import annotations

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.ops import DiskSSS, _disk_native, native
from sssbench.ops._disk_native import DISK_NATIVE_AGREEMENT
from sssbench.ops.gather import backend
from sssbench.profiles import BurleyNormalized, SumOfGaussians
from sssbench.profiles.dipole import Dipole

pytestmark = pytest.mark.skipif(native.library() is None, reason="no C compiler")

BURLEY = BurleyNormalized([1.0, 0.5, 0.3], [0.8, 0.6, 0.4])
SKIN = SumOfGaussians.from_table("skin_deon6")
FOV = 0.4


def scene(dtype, seed=0, ids=False, h=18, w=14):
    """Two images with a 15 mm depth step, a random stencil of fractional strength and (with
    ``ids``) two materials split at the middle column."""
    gen = torch.Generator().manual_seed(seed)
    e = torch.rand(2, 3, h, w, generator=gen, dtype=torch.float64)
    z = 300 + 20 * torch.rand(2, 1, h, w, generator=gen, dtype=torch.float64)
    z[..., : h // 2, :] += 15.0
    keep = torch.rand(2, 1, h, w, generator=gen, dtype=torch.float64) > 0.2
    mask = keep * torch.rand(2, 1, h, w, generator=gen, dtype=torch.float64)
    pid = None
    if ids:
        pid = (torch.arange(w) >= w // 2).long().expand(2, 1, h, w).contiguous()
    return GBuffer(e.to(dtype), z.to(dtype), FOV, mask=mask.to(dtype), profile_id=pid)


OPTIONS = [
    {},
    {"pattern": "r2"},
    {"rotation": "ign"},
    {"rotation": "blue_noise"},
    {"rotation": "none"},
    {"frames": 2},
    {"normalise": False},
    {"jitter_radius": False},
    {"fetch": "bilinear"},
    {"adaptive": (4, 32)},
    {"adaptive": (2, 16), "normalise": False, "fetch": "bilinear"},
    {"surface_area": True},
    {"fetch": "bilinear", "surface_area": True, "normalise": False},
    {"seed": 2**62 + 12345},
    {"estimator": "hdrp"},
    {"estimator": "hdrp", "rotation": "ign"},
]
CASES = [(name, p, o) for name, p in (("burley", BURLEY), ("skin", SKIN)) for o in OPTIONS] + [
    ("two", [BURLEY, SKIN], {}),
    ("two", [BURLEY, SKIN], {"cross_profile": "accept", "fetch": "bilinear"}),
    ("two", [BURLEY, SKIN], {"estimator": "hdrp"}),
]


def both(op, g):
    """(native result, its counts, torch result, its counts)."""
    a, ca = op(g), op.last_counts
    with backend("torch"):
        b, cb = op(g), op.last_counts
    return a, ca, b, cb


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("name, profile, options", CASES)
def test_native_disk_equals_the_torch_loop(name, profile, options, dtype):
    g = scene(dtype, ids=name == "two")
    kernel = DiskSSS(profile, 16, **options)
    assert _disk_native.usable_profile(kernel.kernels[0])
    a, ca, b, cb = both(kernel, g)
    assert a.dtype == b.dtype == dtype
    scale = float(b.abs().max())
    assert float((a - b).abs().max()) <= DISK_NATIVE_AGREEMENT[dtype] * scale
    if ca is not None:  # adaptive and HDRP sample counts: the same integers
        assert torch.equal(ca, cb)


LEVEL_OPTIONS = [{}, {"fetch": "bilinear", "adaptive": (4, 16)}, {"estimator": "hdrp"}]


@pytest.mark.parametrize("options", LEVEL_OPTIONS)
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_every_simd_level_gives_bitwise_the_same_result(options, dtype):
    g = scene(dtype, seed=3)
    op = DiskSSS(SKIN, 16, **options)
    levels = native.simd_levels()
    outs = []
    for level in levels:
        with native.simd(level) as used:
            assert used == level
            outs.append(op(g))
    with backend("torch"):
        ref = op(g)
    for level, out in zip(levels, outs, strict=True):
        assert torch.equal(out, outs[0]), level
        tol = DISK_NATIVE_AGREEMENT[dtype] * float(ref.abs().max())
        assert float((out - ref).abs().max()) <= tol


def test_kilometre_float32_geometry_through_the_native_loop():
    """docs/reliability.md class 3 (float64 geometry in every dtype) holds in the C loop: at
    1 km depth and 0.001 rad the float32 bilinear result is float64's to 1e-7 relative."""
    diffuse = torch.tensor(
        [[[[9.2075e-07, 6.4502e-07]], [[7.9115e-07, 1.7861e-07]], [[3.5111e-07, 5.8134e-07]]]]
    )
    g = GBuffer(diffuse=diffuse, depth=torch.tensor([[[[1e6, 1016666.6875]]]]), fov_y=0.001)
    op = DiskSSS(SKIN, samples=8, seed=0, pattern="r2", normalise=False, fetch="bilinear")
    assert _disk_native.usable_profile(op.kernels[0])
    out32, out64 = op(g), op(g.to(torch.float64))
    assert float((out32.double() - out64).abs().max() / out64.abs().max()) <= 1e-6


def test_other_profiles_run_the_torch_loop():
    """A profile whose closed form the C loop does not have (here the dipole) is
    gathered by the torch loop: the same bits as backend "torch"."""
    p = Dipole.from_material("skin1")
    op = DiskSSS(p, 8)
    assert not _disk_native.usable_profile(op.kernels[0])
    g = scene(torch.float32, seed=5)
    a, _, b, _ = both(op, g)
    assert torch.equal(a, b)


def test_gradients_run_the_torch_loop_and_are_the_torch_loops():
    """With autograd recording (diffuse requiring a gradient) the disk runs the torch loop:
    its gradient exists and is the torch backend's; the output is linear in the diffuse, so
    the gradient of sum(out * c) is checked against central differences too."""
    g = scene(torch.float64, seed=7, h=6, w=5)
    e = g.diffuse.clone().requires_grad_(True)
    op = DiskSSS(SKIN, 4)
    c = torch.rand(e.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    (op(g.replace(diffuse=e)) * c).sum().backward()
    grad = e.grad.clone()
    e.grad = None
    with backend("torch"):
        (op(g.replace(diffuse=e)) * c).sum().backward()
    assert torch.equal(grad, e.grad)
    with torch.no_grad():
        i = (0, 1, 2, 3)
        bump = torch.zeros_like(e)
        bump[i] = 1e-3
        plus = (op(g.replace(diffuse=e + bump)) * c).sum()
        minus = (op(g.replace(diffuse=e - bump)) * c).sum()
    assert float((plus - minus) / 2e-3) == pytest.approx(float(grad[i]), rel=1e-9)


def test_without_the_library_the_torch_loop_runs(monkeypatch):
    g = scene(torch.float32, seed=2)
    op = DiskSSS(BURLEY, 8)
    with backend("torch"):
        want = op(g)
    monkeypatch.setattr(native, "library", lambda: None)
    assert not _disk_native.usable(_disk_pixels(g), op.kernels[0])
    assert torch.equal(op(g), want)


def _disk_pixels(g):
    from sssbench.ops.disk import _Pixels

    return _Pixels(g)

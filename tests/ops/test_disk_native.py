"""The disk's C sample loop (``native/disk.c``, vectorised in ``native/disk_simd.h``) against
its specification, the torch loop (``with gather.backend("torch")``), on every option the disk
tests cover, both dtypes, both estimators, every SIMD level of this CPU; the vectorised exp
against the C library's; its fallbacks (other profiles, autograd, no library)."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.ops import DiskSSS, _disk_native, native
from sssbench.ops._disk_native import DISK_EXP_ULP, DISK_EXPF_REL, DISK_NATIVE_AGREEMENT
from sssbench.ops.disk import _Pixels
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


@pytest.mark.parametrize("level", native.simd_levels())
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("name, profile, options", CASES)
def test_native_disk_equals_the_torch_loop(name, profile, options, dtype, level):
    """At every level: the scalar loop, and at AVX2 / AVX-512 the vectorised loops (estimator
    "sssbench" with the point fetch, and HDRP's estimator; the bilinear fetch runs the scalar
    loop compiled there)."""
    g = scene(dtype, ids=name == "two")
    kernel = DiskSSS(profile, 16, **options)
    assert _disk_native.usable_profile(kernel.kernels[0])
    with native.simd(level) as used:
        assert used == level
        a, ca, b, cb = both(kernel, g)
    assert a.dtype == b.dtype == dtype
    scale = float(b.abs().max())
    assert float((a - b).abs().max()) <= DISK_NATIVE_AGREEMENT[dtype] * scale
    if ca is not None:  # adaptive and HDRP sample counts: the same integers
        assert torch.equal(ca, cb)


LEVEL_OPTIONS = [
    {},
    {"jitter_radius": False, "surface_area": True},
    {"fetch": "bilinear", "adaptive": (4, 16)},
    {"estimator": "hdrp"},
]


@pytest.mark.parametrize("options", LEVEL_OPTIONS)
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_vector_levels_agree_bitwise_and_every_level_with_the_torch_loop(options, dtype):
    """AVX2 and AVX-512 run the same lane-wise IEEE operations (4 or 8 pixels per vector, a
    last partial vector padded): bitwise equal; the scalar level differs from them (the
    vectorised loop's exp, addition theorem and reciprocals) within the torch bound. On a
    64 x 50 image (3200 pixels: many full vectors and a partial one per thread)."""
    g = scene(dtype, seed=3, h=64, w=50)
    op = DiskSSS(SKIN, 16, **options)
    levels = native.simd_levels()
    outs = {}
    for level in levels:
        with native.simd(level) as used:
            assert used == level
            outs[level] = op(g)
    with backend("torch"):
        ref = op(g)
    vector = [lv for lv in levels if lv != "scalar"]
    for level in vector[1:]:
        assert torch.equal(outs[level], outs[vector[0]]), level
    tol = DISK_NATIVE_AGREEMENT[dtype] * float(ref.abs().max())
    for level, out in outs.items():
        assert float((out - ref).abs().max()) <= tol, level


#: (angle phi, rotation turn, pixels per mm) at radius 1 mm whose offset ppm sin(phi + turn),
#: with sin by the addition theorem from cos / sin of phi and of turn, rounds half to even to
#: another integer than with libm's sin of the rounded sum (found by a search in Python, whose
#: math.sin is libm's and whose float operations are the C loop's): 6.5 → 6 against
#: 6.500000000000002 → 7; 6.499999999999999 → 6 against 6.500000000000006 → 7; -6.5 → -6
#: against -6.5000000000000036 → -7
NEAR_TIES = [
    (4.924751778411374, 1.9057700639797035, 12.490038987645521),
    (2.994546979776625, 3.6654974587763136, 17.662955594683233),
    (3.885326994325826, 1.5739777634038004, 8.858147800735985),
]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("phi, turn, ppm", NEAR_TIES)
def test_hdrp_vector_loop_lands_each_sample_where_libm_does(phi, turn, ppm, dtype):
    """HDRP's vectorised loop (disk_simd.h hdrp_vec_) forms sin and cos by the addition
    theorem and calls libm for a lane whose rounding to a pixel could differ: at offsets
    where the two round to different pixels its sample lands where the scalar loop's does
    (so the results agree to the exp's precision, not by a whole other pixel's colour)."""
    gen = torch.Generator().manual_seed(1)
    e = torch.rand(1, 3, 48, 48, generator=gen, dtype=torch.float64).to(dtype)
    z = (300 + torch.rand(1, 1, 48, 48, generator=gen, dtype=torch.float64)).to(dtype)
    g = GBuffer(e, z, FOV)
    kernel = DiskSSS(SKIN, 1, estimator="hdrp").kernels[0]
    ctx = _Pixels(g)
    pix = torch.tensor([24 * 48 + 24])  # a centre in the middle: every candidate inside
    f64 = torch.float64
    args = (ctx, kernel, ctx.on, pix, torch.tensor([turn], dtype=f64),
            torch.tensor([ppm], dtype=f64), torch.tensor([1.0], dtype=f64),
            torch.tensor([1.0], dtype=f64), torch.tensor([phi], dtype=f64))  # fmt: skip
    with native.simd("scalar"):
        ref = _disk_native.gather_hdrp(*args)
    # the pixel the scalar loop (libm) takes and the one the addition theorem alone would
    psi = phi + turn
    s0, c0, ct, st = math.sin(phi), math.cos(phi), math.cos(turn), math.sin(turn)
    libm = (24 + round(ppm * math.sin(psi)), 24 + round(ppm * math.cos(psi)))
    theorem = (24 + round(ppm * (s0 * ct + c0 * st)), 24 + round(ppm * (c0 * ct - s0 * st)))
    assert libm != theorem  # the case is a near tie
    # one sample: its E (to the rounding of w E / w), far from the other pixel's
    at, other = e[0, :, libm[0], libm[1]], e[0, :, theorem[0], theorem[1]]
    assert torch.allclose(ref[0][0] / ref[1][0], at, rtol=1e-6, atol=0)
    assert float((at - other).abs().max()) > 0.05
    for level in native.simd_levels()[1:]:
        with native.simd(level):
            num, den = _disk_native.gather_hdrp(*args)
        assert torch.allclose(num, ref[0], rtol=4 * DISK_EXPF_REL, atol=0), level
        assert torch.allclose(den, ref[1], rtol=4 * DISK_EXPF_REL, atol=0), level


@pytest.mark.parametrize("image_dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("d", [0.05, 0.7, 12.0])
def test_vectorised_burley_sampler_against_the_scalar_loops(d, image_dtype):
    """Burley's radial sampler vectorised (vlog_, vlog1p_, a sinh series, the disk's exp)
    against the scalar loop's libm chain at 10^6 uniform quantiles, both ends on a log scale
    and the edges (0, 1/2, the largest below 1, the smallest subnormal): the radius within
    DISK_BURLEY_R_ABS · d, the inverse density where r >= d / 10 within DISK_BURLEY_INV_REL
    (plus DISK_EXPF_REL for a float32 image), the same infinities and NaNs; AVX2 and AVX-512
    bitwise the same."""
    gen = torch.Generator().manual_seed(0)
    ends = torch.logspace(-17, -1, 2000, dtype=torch.float64)
    edges = torch.tensor([0.0, 0.5, 1 - 2**-53, 2**-1074], dtype=torch.float64)
    uniform = torch.rand(1_000_000, generator=gen, dtype=torch.float64)
    u = torch.cat([uniform, ends, 1 - ends, edges])
    r0, inv0, used = _disk_native.burley_radial(u, d, "scalar", image_dtype)
    assert used == "scalar"
    levels = [lv for lv in native.simd_levels() if lv != "scalar"]
    if not levels:
        pytest.skip("no vector level on this CPU")
    outs = {}
    for level in levels:
        r, inv, used = _disk_native.burley_radial(u, d, level, image_dtype)
        assert used == level
        outs[level] = (r, inv)
        assert float((r - r0).abs().max()) <= _disk_native.DISK_BURLEY_R_ABS * d, level
        ok = (r0 >= d / 10) & torch.isfinite(inv0) & (inv0 > 0)
        rel = _disk_native.DISK_BURLEY_INV_REL + (
            DISK_EXPF_REL if image_dtype == torch.float32 else 0.0
        )
        assert float(((inv - inv0).abs() / inv0)[ok].max()) <= rel, level
        assert torch.equal(torch.isinf(inv), torch.isinf(inv0))
        assert torch.equal(torch.isnan(inv), torch.isnan(inv0))
    for level in levels[1:]:
        assert torch.equal(outs[level][0], outs[levels[0]][0])
        assert torch.equal(outs[level][1], outs[levels[0]][1])


@pytest.mark.parametrize("level", [lv for lv in native.simd_levels() if lv != "scalar"])
@pytest.mark.parametrize("image_dtype", [torch.float64, torch.float32])
def test_vectorised_disk_exp_against_libm(level, image_dtype):
    """The vectorised loop's exp is within DISK_EXP_ULP of the C library's exp (Python's
    math.exp) for float64 images (disk_simd.h vexp_), and within DISK_EXPF_REL relative for
    float32 ones (vexpf_, float32 precision), at 10^6 uniform arguments in [-745, 0], 10^6 in
    [-30, 0] (where a weight is not negligible), 10^5 in [-1e-3, 0] and the ends (0, -0, the
    normal / subnormal boundary, below the smallest subnormal, -inf); +0 or within 2.3e-308
    where exp is subnormal; NaN stays NaN."""
    gen = torch.Generator().manual_seed(0)
    ends = [0.0, -0.0, -1e-300, -708.39, -708.4, -709.78, -745.13, -745.2, -746.0, -1e308]
    x = torch.cat([
        -745 * torch.rand(1_000_000, dtype=torch.float64, generator=gen),
        -30 * torch.rand(1_000_000, dtype=torch.float64, generator=gen),
        -1e-3 * torch.rand(100_000, dtype=torch.float64, generator=gen),
        torch.tensor([*ends, -math.inf], dtype=torch.float64),
    ])  # fmt: skip
    want = torch.tensor([math.exp(v) for v in x.tolist()], dtype=torch.float64)
    got, used = _disk_native.vexp(x, level, image_dtype)
    assert used == level
    normal = want >= torch.finfo(torch.float64).tiny
    if image_dtype == torch.float64:
        ulp = (got[normal].view(torch.int64) - want[normal].view(torch.int64)).abs()
        assert int(ulp.max()) <= DISK_EXP_ULP
    else:
        rel = ((got[normal] - want[normal]) / want[normal]).abs()
        assert float(rel.max()) <= DISK_EXPF_REL
        assert float(rel.max()) > 2.0**-30  # float32 precision, not float64's: the other exp
    assert float((got[~normal] - want[~normal]).abs().max()) < 2.3e-308
    assert (got[~normal] >= 0).all()
    nan, _ = _disk_native.vexp(torch.tensor([math.nan, -1.0]), level, image_dtype)
    assert math.isnan(float(nan[0]))
    assert float(nan[1]) == pytest.approx(math.exp(-1.0), rel=2 * DISK_EXPF_REL)


def test_disk_exp_rejects_an_unknown_image_dtype():
    with pytest.raises(ValueError, match="image_dtype"):
        _disk_native.vexp(torch.zeros(3), "scalar", torch.float16)


def test_hashed_noise_in_c_equals_the_torch_hash():
    """The C loop hashes the rotation and radial shift from disk.hash_key itself: with the
    rotation passed in as turns from disk.hash_uniform instead, the result is bitwise the
    same (the same integers, the same float64 values); a wrong key would move every
    sample."""
    from sssbench.ops import disk as disk_mod

    g = scene(torch.float64, seed=4)
    op = DiskSSS(SKIN, 16, seed=2**40 + 7)
    ctx = disk_mod._Pixels(g)
    kernel, accept, sel = op._groups(g, ctx)[0]
    pix = ctx.index[sel]
    step = 1.0 / disk_mod.pixel_size_mm(ctx.pos[pix][:, 2].double(), ctx.fov_y, ctx.h)
    u0, theta0 = disk_mod.pattern_points(op.pattern, 16)
    turn = 2 * math.pi * disk_mod.hash_uniform(pix % ctx.hw, op.seed, 1, 0)
    shift = disk_mod.hash_uniform(pix % ctx.hw, op.seed, 1, 1)
    args = (ctx, kernel, accept, pix)
    given = _disk_native.gather(*args, turn, shift, step, u0, theta0, False)
    keys = {
        "turn_key": disk_mod.hash_key(op.seed, 1, 0),
        "shift_key": disk_mod.hash_key(op.seed, 1, 1),
    }
    hashed = _disk_native.gather(*args, None, None, step, u0, theta0, False, **keys)
    for a, b in zip(given, hashed, strict=True):
        assert torch.equal(a, b)
    other = dict(keys, turn_key=keys["turn_key"] ^ 1)
    moved = _disk_native.gather(*args, None, None, step, u0, theta0, False, **other)
    assert not torch.equal(moved[0], given[0])


@pytest.mark.parametrize("level", [None, "scalar", "torch"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_sums_without_the_moments_are_the_same_bits(level, dtype):
    """``moments=False`` (the plain and the adaptive refinement calls: nobody reads the
    moments) leaves the nine moment sums out of the loop: ``Σ w E`` and ``Σ w`` are bitwise
    those of the call that forms the moments, in the vectorised and the scalar C loop and the
    torch loop, and the moments come back as ``None``."""
    from sssbench.ops import disk as disk_mod

    g = scene(dtype, seed=6, h=40, w=30)
    op = DiskSSS(SKIN, 16)
    ctx = disk_mod._Pixels(g)
    kernel, accept, sel = op._groups(g, ctx)[0]

    def both():
        full = op._gather(ctx, kernel, accept, sel, 16, 0, 0)
        lean = op._gather(ctx, kernel, accept, sel, 16, 0, 0, moments=False)
        return full, lean

    if level == "torch":
        with backend("torch"):
            full, lean = both()
    else:
        with native.simd(level):
            full, lean = both()
    assert lean[2] is None and full[2].shape == (sel.numel(), 3, 3)
    assert float(full[2].abs().sum()) > 0  # the full call did form them
    assert torch.equal(full[0], lean[0]) and torch.equal(full[1], lean[1])


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

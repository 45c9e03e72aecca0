"""The native tap loop (issue 7) against the torch loop, which is its specification.

Every case runs one ``separable_pass`` twice, once per backend, on G-buffers with random
depth, random mask strength and holes; the torch loop is vectorised torch code, the native
loop C, so agreement is between two independent implementations of the same formulas. The
native cases run at every instruction-set level of the C loop this CPU has (the ``simd``
fixture: the scalar loop, and the vectorised AVX2 and AVX-512 loops of
``native/gather_simd.h`` where supported).
"""

import math
import subprocess
import sys

import pytest
import torch

from sssbench._memo import memoised
from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D
from sssbench.ops import Stretch, native, separable_pass
from sssbench.ops._stencil import image_stencils
from sssbench.ops.gather import backend

pytestmark = pytest.mark.skipif(native.library() is None, reason="no C compiler")

#: the C loop's levels this CPU supports (the scalar one alone without the library)
LEVELS = native.simd_levels() or ("scalar",)


@pytest.fixture(params=LEVELS)
def simd(request):
    """Run the test's native passes at each supported instruction-set level."""
    with native.simd(request.param):
        yield request.param


def scene(seed=0, b=1, h=23, w=31, dtype=torch.float64, holes=True, cover=0.7):
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(b, 3, h, w, generator=g, dtype=dtype)
    # depth with smooth slopes and a discontinuity, as at a silhouette
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij"
    )
    depth = 60 + 0.8 * xx + 0.3 * yy + 25.0 * (xx > w / 2)
    depth = depth.expand(b, 1, h, w) + 3 * torch.rand(b, 1, h, w, generator=g, dtype=dtype)
    mask = torch.rand(b, 1, h, w, generator=g, dtype=dtype)
    if holes:
        mask = mask * (torch.rand(b, 1, h, w, generator=g, dtype=dtype) < cover)
    return GBuffer(img, depth.contiguous(), 0.7, mask=mask)


def kernel(taps=7, dtype=torch.float64):
    offsets = torch.linspace(-4.0, 4.0, taps, dtype=torch.float64)
    weights = torch.exp(-0.5 * offsets[:, None] ** 2 / torch.tensor([0.5, 1.5, 3.0]))
    return Kernel1D(offsets, weights / weights.sum(0))


def both(image, k, direction, g, **kw):
    with backend("torch"):
        ref = separable_pass(image, k, direction, g, **kw)
    with backend("native"):
        got = separable_pass(image, k, direction, g, **kw)
    return ref, got


def tol(dtype):
    # the bound for float32; float64 differs only by rounding of the same operations
    return dict(rtol=0, atol=1e-5) if dtype == torch.float32 else dict(rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("direction", ["x", "y"])
@pytest.mark.parametrize("cover", [0.7, 0.1], ids=["dense", "sparse"])
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"follow_surface": "lerp", "surface_scale": 4.0},
        {"follow_surface": "gaussian", "surface_scale": 2.5},
        {"follow_surface": "lerp", "surface_scale": torch.tensor([1.0, 4.0, 20.0])},
        {"follow_surface": "gaussian", "surface_scale": torch.tensor([1.0, 4.0, 20.0])},
        {"stretch": Stretch()},
        {"stretch": Stretch(ssslevel=2.0, correction=50.0, maxdd=0.5)},
        {"use_mask": False},
        {"width": 3.0},
    ],
    ids=lambda o: "-".join(f"{k}" for k in o) or "plain",
)
def test_native_equals_torch_loop(simd, dtype, direction, cover, options):
    """Dense and sparse stencils (the y pass uses wide and narrow column strips)."""
    g = scene(dtype=dtype, cover=cover)
    ref, got = both(g.diffuse, kernel(), direction, g, **options)
    torch.testing.assert_close(got, ref, **tol(dtype))
    assert not torch.equal(ref, g.diffuse)  # the case blurs something


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_equals_torch_loop_with_per_pixel_width_batch_and_no_mask(simd, dtype):
    g = scene(seed=3, b=3, dtype=dtype)
    # one image of the batch has an empty stencil: it must come back unchanged
    mask = g.mask.clone()
    mask[1] = 0
    g = g.replace(mask=mask)
    width = 0.5 + 2 * torch.rand(3, 1, 23, 31, generator=torch.Generator().manual_seed(1))
    width = width.to(dtype)
    for k in (kernel(1), kernel(7), kernel(33)):
        for direction in ("x", "y"):
            ref, got = both(g.diffuse, k, direction, g, width=width, follow_surface="lerp",
                            surface_scale=3.0)  # fmt: skip
            torch.testing.assert_close(got, ref, **tol(dtype))
            assert torch.equal(got[1], g.diffuse[1])
    no_mask = GBuffer(g.diffuse, g.depth, g.fov_y)
    ref, got = both(no_mask.diffuse, kernel(), "y", no_mask)
    torch.testing.assert_close(got, ref, **tol(dtype))


def test_native_handles_non_contiguous_inputs(simd):
    g = scene(h=20, w=26)
    wide = torch.rand(1, 3, 26, 20, dtype=torch.float64).transpose(2, 3)  # strided view
    g = g.replace(diffuse=wide)
    assert not g.diffuse.is_contiguous()
    ref, got = both(g.diffuse, kernel(), "x", g, follow_surface="lerp", surface_scale=3.0)
    torch.testing.assert_close(got, ref, **tol(torch.float64))


def test_native_pass_is_differentiable():
    """With autograd the native operator runs too; its backward (the torch loop's VJP) is
    checked against finite differences of the native forward (more in test_gather_op.py)."""
    g = scene(h=6, w=7)
    image = g.diffuse.clone().requires_grad_(True)
    k = kernel(5)
    with backend("native"):
        out = separable_pass(image, k, "x", g, follow_surface="lerp", surface_scale=4.0)
        assert out.requires_grad
        assert torch.autograd.gradcheck(
            lambda x: separable_pass(x, k, "x", g, follow_surface="lerp", surface_scale=4.0),
            (image,),
        )


def test_native_survives_an_overflowing_width():
    """float32 width 1e38: steps overflow to ±inf and 0·inf = NaN; the native loop clamps
    them into the image (NaN -> the border) instead of reading out of bounds."""
    g = scene(dtype=torch.float32)
    with backend("native"):
        out = separable_pass(g.diffuse, kernel(dtype=torch.float32), "x", g, width=1e38)
    assert torch.isfinite(out).all()


def test_without_a_compiler_the_torch_loop_runs(monkeypatch, tmp_path):
    """A machine without a C compiler warns once and falls back to the torch loop."""
    code = (
        "import warnings, torch\n"
        "from sssbench.ops import native\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        "    assert native.library() is None\n"
        "    assert native.library() is None\n"
        "print(len(w), 'native gather unavailable' in str(w[0].message))\n"
    )
    env = {
        "PATH": str(tmp_path),
        "CC": "",
        "SSSBENCH_CACHE_DIR": str(tmp_path),
        "HOME": str(tmp_path),
    }
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["1", "True"]


def test_library_is_built_into_the_cache_dir(tmp_path):
    code = (
        "from sssbench.ops import native\n"
        "assert native.library() is not None\n"
        "print(native.cache_dir())\n"
    )
    env = dict(__import__("os").environ, SSSBENCH_CACHE_DIR=str(tmp_path))
    runs = [
        subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
        for _ in range(2)
    ]  # two workers racing for the same build
    outs = [r.communicate()[0].strip() for r in runs]
    assert all(r.returncode == 0 for r in runs)
    built = list((tmp_path / "native").glob("*.so"))
    assert len(built) == 1 and outs[0] == str(tmp_path / "native")


#: rows of the "larger image" (203 wide): at 90% cover over 2 x 16384 pixels, the work the C
#: loop needs before it splits a pass over two threads (MIN_THREAD_WORK in gather_body.h)
BIG_H = 180


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("cover", [0.95, 0.12], ids=["dense", "sparse"])
def test_native_lines_windows_and_threads_on_a_larger_image(simd, dtype, cover):
    """An image large enough for two threads and many y strips (spans crossing strip edges),
    kernels from a pixel wide to wider than the image, a per-pixel width with a few huge
    values (their window is the whole line) and both follow-surface modes: each line reads
    only the window its largest step can reach, which must hold every tap."""
    g = scene(seed=5, h=BIG_H, w=203, dtype=dtype, cover=cover)
    width = 0.05 + torch.rand(1, 1, BIG_H, 203, generator=torch.Generator().manual_seed(2))
    width[0, 0, 40, 100:105] = 1e4  # taps clamp at both borders
    width = width.to(dtype)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for wide in (0.2, 3.0, 60.0):
            for direction in ("x", "y"):
                for follow in ("lerp", "gaussian"):
                    ref, got = both(g.diffuse, kernel(9), direction, g, width=width * wide,
                                    follow_surface=follow, surface_scale=3.0)  # fmt: skip
                    torch.testing.assert_close(got, ref, **tol(dtype))
    finally:
        torch.set_num_threads(threads)


@pytest.mark.parametrize("direction", ["x", "y"])
def test_native_result_independent_of_thread_count(simd, direction):
    """Lines are handed to the threads in chunks, each thread taking the next unclaimed one
    (gather_body.h, job.claim): which thread computes a line, and how many threads there are,
    must change no bit of the result (every line is computed alone). 1, 2 and 4 threads on an
    image with work for four (4 x 16384 active pixels and more), new output and in place."""
    g = scene(seed=7, h=420, w=203, dtype=torch.float32, cover=0.95)
    threads = torch.get_num_threads()
    outs = []
    try:
        for n in (1, 2, 4):
            torch.set_num_threads(n)
            new = separable_pass(g.diffuse, kernel(9), direction, g, follow_surface="lerp",
                                 surface_scale=3.0)  # fmt: skip
            img = g.diffuse.clone()
            separable_pass(img, kernel(9), direction, g, follow_surface="lerp",
                           surface_scale=3.0, inplace=True)  # fmt: skip
            outs.append((new, img))
    finally:
        torch.set_num_threads(threads)
    assert not torch.equal(outs[0][0], g.diffuse)  # the pass changed the image
    for new, img in outs[1:]:
        assert torch.equal(new, outs[0][0]) and torch.equal(img, outs[0][1])
    torch.testing.assert_close(outs[0][1], outs[0][0], rtol=0, atol=0)


def _big_pass(seed):
    g = scene(seed=seed, h=BIG_H, w=203, cover=0.9)
    return separable_pass(g.diffuse, kernel(9), "y", g, follow_surface="lerp", surface_scale=3.0)


def test_native_pool_serves_concurrent_python_threads():
    """The worker pool runs one pass at a time: a Python thread calling while another's pass
    runs starts threads of its own. Every result equals the torch loop's."""
    import threading

    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with backend("torch"):
            refs = [_big_pass(seed) for seed in range(4)]
        got = [None] * 4

        def work(i):
            for _ in range(5):
                got[i] = _big_pass(i)

        with backend("native"):
            workers = [threading.Thread(target=work, args=(i,)) for i in range(4)]
            for t in workers:
                t.start()
            for t in workers:
                t.join()
        for ref, out in zip(refs, got, strict=True):
            torch.testing.assert_close(out, ref, **tol(torch.float64))
    finally:
        torch.set_num_threads(threads)


@pytest.mark.parametrize("pool", native.POOLS)
def test_native_pool_restarts_in_a_forked_child(pool):
    """A child forked after the parent's passes ran on ``pool`` (the own pool's workers, or
    torch's OpenMP team) has no workers: its first pass runs on new threads of its own pool
    (and must not wait on the parent's). The child calls the native pass directly: torch's
    own OpenMP pool does not survive a fork, so it runs no torch computation; and
    ``native.pool()`` says so there ("own")."""
    import os
    import time

    import numpy as np

    from sssbench._memo import memo_scope
    from sssbench.ops._gather_native import native_pass

    previous = native.pool()
    native.set_pool(pool)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        g = scene(seed=1, h=BIG_H, w=203, cover=0.9)
        lib = native.library_for(g.diffuse.dtype)
        args = (g.depth, g.mask, None, None,
                torch.linspace(-4.0, 4.0, 9, dtype=torch.float64),
                torch.full((9, 3), 1 / 9, dtype=torch.float64),
                torch.full((3,), 1 / 3.0, dtype=torch.float64),
                40.0, 1.0, 0.0, 0.0, True, 1)  # fmt: skip
        parent = torch.empty_like(g.diffuse)
        n_active = int((g.mask > 0).sum())
        with memo_scope():  # the child finds the stencil's runs here, computing nothing
            assert native_pass(lib, g.diffuse, parent, args, copy=True) == n_active
            child = torch.empty_like(g.diffuse)
            pid = os.fork()
            if pid == 0:  # the child: no torch computation, exit status = verdict
                status = 2
                try:
                    native_pass(lib, g.diffuse, child, args, copy=True)
                    status = 0 if np.array_equal(child.numpy(), parent.numpy()) else 1
                    if status == 0 and native.pool() != "own":  # as pool_run's pid check
                        status = 3
                finally:
                    os._exit(status)
        deadline = time.monotonic() + 60
        while (done := os.waitpid(pid, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        if done[0] == 0:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
            pytest.fail("the forked child's pass did not finish within 60 s")
        assert os.waitstatus_to_exitcode(done[1]) == 0  # the child's result is the parent's
        assert not torch.equal(parent, g.diffuse)  # which blurred something
    finally:
        torch.set_num_threads(threads)
        native.set_pool(previous)


def _openmp_backend():
    return "parallel backend: OpenMP" in torch.__config__.parallel_info()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_passes_on_torchs_openmp_team_give_the_own_pools_bits(dtype):
    """Where torch runs on OpenMP (Linux wheels), the native passes run on torch's own team by
    default (issue 30: its workers spin after every torch operation on the cores a second pool
    needs); an x and a y pass, a fan-in sweep and the disk give the own pool's bits, at 1, 2
    and 3 threads (3 on 2 cores: a team larger than the machine)."""
    from sssbench.ops import DiskSSS, separable_sweep
    from sssbench.profiles import SumOfGaussians

    assert native.pool() == ("openmp" if _openmp_backend() else "own")
    g = scene(seed=4, h=BIG_H, w=203, cover=0.9, dtype=dtype)
    k = kernel(9)
    images = torch.rand(2, *g.diffuse.shape, dtype=dtype, generator=torch.Generator())
    coef = torch.tensor([[0.5, 0.2, 0.3], [0.5, 0.8, 0.7]], dtype=dtype)
    disk = DiskSSS(SumOfGaussians.from_table("skin_deon6"), 8)
    opts = dict(follow_surface="lerp", surface_scale=3.0)

    def outputs():
        with backend("native"):
            return [
                separable_pass(g.diffuse, k, "x", g, **opts),
                separable_pass(g.diffuse, k, "y", g, **opts),
                separable_sweep(images, [k, k], "y", g, coefficients=coef, **opts),
                disk(g),
            ]

    threads = torch.get_num_threads()
    try:
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            assert native.set_pool("own") == "own"
            own = outputs()
            assert native.set_pool("openmp") == ("openmp" if _openmp_backend() else "own")
            team = outputs()
            for a, b in zip(own, team, strict=True):
                assert torch.equal(a, b), n
    finally:
        torch.set_num_threads(threads)
        native.set_pool("openmp")


@pytest.mark.skipif(not _openmp_backend(), reason="torch does not run on OpenMP here")
def test_an_openmp_team_smaller_than_asked_still_runs_every_job():
    """OMP_THREAD_LIMIT=1 gives a team of one where a call asks for two: that one thread
    runs both jobs (pool.h: jobs t, t + n, ...; the disk's jobs are fixed halves of its
    pixels, a pass's share its lines), and the results are the own pool's two threads'. In
    a fresh interpreter (the limit is read when the runtime starts)."""
    code = """
import ctypes, sys, torch
sys.path.insert(0, {tests!r})
from test_gather_backends import scene, kernel
from sssbench.ops import DiskSSS, native, separable_pass
from sssbench.ops.gather import backend
from sssbench.profiles import SumOfGaussians
torch.set_num_threads(2)
assert native.pool() == "openmp"
g = scene(seed=6, h=180, w=203, cover=0.9)
disk = DiskSSS(SumOfGaussians.from_table("skin_deon6"), 8)
with backend("native"):
    team = [separable_pass(g.diffuse, kernel(9), "y", g), disk(g)]
    native.set_pool("own")
    own = [separable_pass(g.diffuse, kernel(9), "y", g), disk(g)]
print("equal" if all(torch.equal(a, b) for a, b in zip(team, own)) else "differ")
"""
    import os
    from pathlib import Path

    env = dict(os.environ, OMP_THREAD_LIMIT="1")
    out = subprocess.run(
        [sys.executable, "-c", code.format(tests=str(Path(__file__).parent))],
        capture_output=True, text=True, env=env, timeout=300, check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "equal"


def test_spans_are_the_runs_of_the_stencil():
    """Against a Python walk over the mask, row by row."""
    from sssbench.ops._stencil import image_spans

    g = scene(seed=7, b=2, h=9, w=13, cover=0.6)
    g.mask[1] = 0
    spans = image_spans(g.mask, (2, 9, 13))
    for bi in range(2):
        expected = []
        for r in range(9):
            c = 0
            while c < 13:
                if g.mask[bi, 0, r, c] > 0:
                    start = c
                    while c < 13 and g.mask[bi, 0, r, c] > 0:
                        c += 1
                    expected.append([r, start, c])
                c += 1
        assert spans[bi].tolist() == expected
    assert image_spans(None, (1, 3, 5))[0].tolist() == [[0, 0, 5], [1, 0, 5], [2, 0, 5]]


def test_stencil_memo_misses_after_an_in_place_write():
    g = scene()
    first = image_stencils(g.mask)
    assert image_stencils(g.mask) is first  # built once per mask
    g.mask[0, 0, :5] = 0  # in place: bumps the version counter
    again = image_stencils(g.mask)
    assert again is not first
    assert torch.equal(again[0], torch.nonzero(g.mask[0].reshape(-1) > 0).squeeze(1))
    ref, got = both(g.diffuse, kernel(), "x", g)
    torch.testing.assert_close(got, ref, **tol(torch.float64))


def test_memo_keeps_a_bounded_number_of_entries():
    from sssbench._memo import _MEMO_SIZE

    calls = []
    n = _MEMO_SIZE + 8
    ts = [torch.zeros(2) for _ in range(n)]
    for t in ts:
        memoised((t,), "probe", lambda t=t: calls.append(t) or len(calls))
    assert len(calls) == n
    assert memoised((ts[-1],), "probe", lambda: -1) == n  # recent: a hit
    assert memoised((ts[0],), "probe", lambda: -1) == -1  # evicted: recomputed


def test_memo_sees_writes_that_bump_no_version_counter():
    """An inference tensor has no version counter and ``.data`` / NumPy writes bump none: the
    memo compares contents, so each of these writes makes the next lookup compute anew (the
    value is the number of active pixels, recounted independently here)."""
    with torch.inference_mode():
        mask = torch.ones(1, 1, 4, 4)

    def count(m):
        return memoised((m,), "probe-count", lambda: int((m > 0).sum()))

    assert count(mask) == 16
    with torch.inference_mode():
        mask[0, 0, 0] = 0  # no version counter to bump
    assert count(mask) == 12
    normal = torch.ones(1, 1, 4, 4)
    assert count(normal) == 16
    normal.data[0, 0, :, 0] = 0  # .data: no version bump
    assert count(normal) == 12
    normal.numpy()[0, 0, 3] = 0  # a NumPy view
    assert count(normal) == 9


@pytest.mark.parametrize("name", ["native", "torch"])
@pytest.mark.parametrize("cover", [0.1, 0.7, None], ids=["sparse", "dense", "full"])
def test_inplace_pass_equals_the_copying_pass(simd, name, cover):
    """``inplace=True`` reads every tap before it writes: the native loop copies each row (x)
    or column strip (y) it works on first; the torch loop gathers every tap first."""
    g = scene(b=2, holes=cover is not None, cover=cover or 0.0)
    k = kernel()
    with backend(name):
        for direction in ("x", "y"):
            ref = separable_pass(
                g.diffuse, k, direction, g, follow_surface="lerp", surface_scale=3.0
            )
            work = g.diffuse.clone()
            got = separable_pass(work, k, direction, g, follow_surface="lerp", surface_scale=3.0,
                                 inplace=True)  # fmt: skip
            assert got is work
            torch.testing.assert_close(got, ref, rtol=0, atol=0)
        no_mask = GBuffer(g.diffuse, g.depth, g.fov_y)
        ref = separable_pass(no_mask.diffuse, k, "x", no_mask)
        got = separable_pass(no_mask.diffuse.clone(), k, "x", no_mask, inplace=True)
        torch.testing.assert_close(got, ref, rtol=0, atol=0)


def test_inplace_is_not_honoured_under_autograd_or_for_strided_images():
    g = scene(h=8, w=9)
    image = g.diffuse.clone().requires_grad_(True)
    out = separable_pass(image, kernel(3), "x", g, inplace=True)
    assert out is not image and out.requires_grad
    strided = g.diffuse.transpose(2, 3).contiguous().transpose(2, 3)
    before = strided.clone()
    out = separable_pass(strided, kernel(3), "x", g, inplace=True)
    assert out is not strided and torch.equal(strided, before)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_blend_on_stencil_native_equals_torch_lerp(dtype):
    """The SoG blend, out ← lerp(out, end, w) on the stencil, against torch.lerp per pixel
    (weights below and above one half take torch's two formulas); pixels off the stencil keep
    ``out``."""
    from sssbench.ops.gather import blend_on_stencil

    g = scene(seed=9, b=2, h=70, w=90, dtype=dtype, cover=0.6)
    gen = torch.Generator().manual_seed(4)
    out0 = torch.rand(2, 3, 70, 90, generator=gen, dtype=dtype)
    end = torch.rand(2, 3, 70, 90, generator=gen, dtype=dtype)
    weight = torch.tensor([0.1, 0.5, 0.93], dtype=dtype)
    on = (g.mask > 0).expand(2, 3, 70, 90)
    expected = torch.where(on, torch.lerp(out0, end, weight.view(1, 3, 1, 1)), out0)
    for name in ("native", "torch"):
        with backend(name):
            got = blend_on_stencil(out0.clone(), end, weight, g.mask)
        torch.testing.assert_close(got, expected, **tol(dtype))
        assert torch.equal(got[~on], out0[~on])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sum_of_gaussians_native_equals_torch(simd, dtype):
    """The whole 12-pass schedule (passes and blends, LOD stencils) on both backends."""
    import data_synth
    from sssbench.ops import SumOfGaussiansSSS
    from sssbench.profiles import SumOfGaussians

    g = data_synth.make_scene("head", resolution=(96, 80), dtype=dtype)
    op = SumOfGaussiansSSS(SumOfGaussians.from_table("skin_deon6"), 9, follow_surface="lerp")
    with backend("torch"):
        ref = op(g)
    with backend("native"):
        got = op(g)
    torch.testing.assert_close(got, ref, **tol(dtype))
    assert not torch.allclose(ref, g.diffuse)


@pytest.mark.parametrize("image_dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("kernel_dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("surface_scale", [1e-40, 2.5, "per-channel"])
def test_native_converts_the_kernel_itself_as_the_torch_loop(
    simd, image_dtype, kernel_dtype, surface_scale
):
    """Without autograd the C loop takes the kernel's taps as they are and converts them to the
    pass's dtype itself: offsets beyond its range clamp to its largest value (taps on the
    border), 1 / surface_scale too (1e-40 mm overflows float32). The torch loop converts them
    in torch (``_taps``, ``_inverse_scale``): the results must be bitwise equal."""
    big = 1e300 if kernel_dtype == torch.float64 else 3e38
    offsets = torch.tensor([-big, -2.5, -0.75, 0.0, 0.75, 2.5, big], dtype=kernel_dtype)
    weights = torch.rand(7, 3, generator=torch.Generator().manual_seed(3), dtype=kernel_dtype)
    k = Kernel1D(offsets, weights / weights.sum(0))
    g = scene(seed=11, b=2, dtype=image_dtype)
    # whole-mm depths: neighbours at equal depth, where 0 * an unclamped inf 1/scale is NaN
    g = GBuffer(g.diffuse, torch.round(g.depth), g.fov_y, mask=g.mask)
    if surface_scale == "per-channel":
        surface_scale = torch.tensor([0.5, 1.5, 4.0], dtype=torch.float64)
    width = torch.where(g.depth > 70, 0.0, 1.0).to(image_dtype)
    for direction in ("x", "y"):
        # a width of 0 at some pixels: an unclamped infinite offset would give inf * 0 = NaN
        ref, got = both(g.diffuse, k, direction, g, follow_surface="lerp",
                        surface_scale=surface_scale, width=width)  # fmt: skip
        assert torch.equal(got, ref)


@pytest.mark.parametrize("inplace", [False, True])
@pytest.mark.parametrize("masked", ["some", "none"])
def test_weights_beyond_the_pass_dtype_are_refused_by_both_loops(inplace, masked):
    """Weights finite in float64 but not in float32: ``ValueError`` naming ``kernel.weights``
    from either loop, also when no pixel is active (the C loop checks before it computes)
    and before anything is written."""
    k = Kernel1D(torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64),
                 torch.full((3, 3), 1e300, dtype=torch.float64))  # fmt: skip
    g = scene(seed=2, b=2, dtype=torch.float32)
    if masked == "none":
        g = GBuffer(g.diffuse, g.depth, g.fov_y, mask=torch.zeros_like(g.mask))
    image = g.diffuse.clone()
    for name in ("torch", "native"):
        with backend(name), pytest.raises(ValueError, match="kernel.weights"):
            separable_pass(image, k, "x", g, inplace=inplace)
        assert torch.equal(image, g.diffuse)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("inplace", [False, True])
def test_every_simd_level_gives_the_scalar_loops_bits(dtype, inplace):
    """The vectorised loops (issue 30) against the scalar one and the torch loop, bitwise but
    for the gaussian's exp (the vectorised loops' polynomial exp: the stated tolerance): runs of
    every length (vectors with spare lanes), smooth per-pixel widths (the x pass's consecutive
    loads, the permute / row-select fetch) with rough patches and a few huge values (lanes far
    apart: the gather fallback), the stretch, both axes, dense and sparse stencils."""
    h, w = 61, 203
    gen = torch.Generator().manual_seed(7)
    width = 0.5 + 0.3 * torch.linspace(0, 1, w, dtype=torch.float64).expand(1, 1, h, w).clone()
    width[..., 10:20, :] = 0.05 + 4 * torch.rand(1, 1, 10, w, generator=gen, dtype=torch.float64)
    width[0, 0, 30, 50:53] = 1e4
    width = width.to(dtype)
    cases = [
        {},
        {"follow_surface": "lerp", "surface_scale": torch.tensor([1.0, 4.0, 20.0])},
        {"follow_surface": "gaussian", "surface_scale": 2.0},
        {
            "stretch": Stretch(ssslevel=2.0, correction=50.0, maxdd=0.5),
            "follow_surface": "lerp",
            "surface_scale": 3.0,
        },
        {"use_mask": False},
    ]
    for cover in (0.95, 0.3):
        g = scene(seed=11, h=h, w=w, dtype=dtype, cover=cover)
        for kw in cases:
            kw = {k: (v.to(dtype) if isinstance(v, torch.Tensor) else v) for k, v in kw.items()}
            for wide in (1.0, 8.0):
                for direction in ("x", "y"):
                    args = (kernel(9), direction, g)
                    opts = dict(width=width * wide, **kw)
                    with backend("torch"):
                        ref = separable_pass(g.diffuse.clone(), *args, **opts)
                    outs = {}
                    for level in LEVELS:
                        with native.simd(level), backend("native"):
                            image = g.diffuse.clone()
                            outs[level] = separable_pass(image, *args, inplace=inplace, **opts)
                    for level, out in outs.items():
                        if kw.get("follow_surface") != "gaussian":
                            assert torch.equal(out, outs["scalar"]), (level, kw, direction)
                            assert torch.equal(out, ref), (level, kw, direction)
                        else:  # BACKEND_AGREEMENT's tolerance (the vectorised exp)
                            span = float(g.diffuse.abs().max())
                            for other in (outs["scalar"], ref):
                                err = float((out - other).abs().max()) / span
                                assert err <= (1e-6 if dtype == torch.float32 else 1e-14), err


def test_simd_level_is_capped_chosen_by_name_and_by_the_environment():
    best = native.simd_levels()[-1]
    with native.simd("avx512") as level:
        assert level == ("avx512" if "avx512" in native.simd_levels() else best)
        assert native.simd_level() == level
    assert native.simd_level() == best
    with native.simd("scalar"):
        assert native.simd_level() == "scalar"
    with pytest.raises(ValueError, match="unknown SIMD level"):
        native.set_simd("sse9")
    code = "from sssbench.ops import native; print(native.simd_level())"
    env = {**__import__("os").environ, "SSSBENCH_SIMD": "scalar"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "scalar"


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("inplace", [False, True])
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"follow_surface": "lerp", "surface_scale": 4.0},
        {"follow_surface": "gaussian", "surface_scale": torch.tensor([1.0, 4.0, 20.0])},
        {"stretch": Stretch(ssslevel=2.0, correction=50.0, maxdd=0.5)},
        {"use_mask": False},
    ],
    ids=lambda o: "-".join(f"{k}" for k in o) or "plain",
)
def test_blend_fused_into_the_pass_equals_the_pass_then_the_blend(simd, dtype, inplace, options):
    """``separable_pass(..., blend_into=(target, w))``: the native loop blends each result into
    ``target`` as it writes it (the sum of Gaussians' step, issue 30). Its specification is the
    pass followed by :func:`blend_on_stencil` on the pass's stencil: bitwise the native pass
    and the native blend run one after the other (both weights' formulas: w < 0.5 and >= 0.5),
    and within the backends' tolerance the torch loop followed by ``torch.lerp``; ``target``
    off the stencil and the pass's own result are untouched by the fusion."""
    from sssbench.ops.gather import blend_on_stencil

    weight = torch.tensor([0.2, 0.5, 0.9], dtype=dtype)
    opts = {k: (v.to(dtype) if isinstance(v, torch.Tensor) else v) for k, v in options.items()}
    for cover in (0.7, 0.1):  # wide and narrow column strips
        g = scene(seed=5, b=2, h=37, w=83, dtype=dtype, cover=cover)
        start = torch.rand(2, 3, 37, 83, generator=torch.Generator().manual_seed(8), dtype=dtype)
        stencil = g.mask if opts.get("use_mask", True) else None
        for direction in ("x", "y"):
            with backend("native"):
                image, target = g.diffuse.clone(), start.clone()
                out = separable_pass(image, kernel(), direction, g, inplace=inplace,
                                     blend_into=(target, weight), **opts)  # fmt: skip
                plain = separable_pass(g.diffuse.clone(), kernel(), direction, g, **opts)
                expected = blend_on_stencil(start.clone(), plain, weight, stencil)
            assert torch.equal(out, plain), direction
            assert torch.equal(target, expected), direction
            if stencil is not None:
                off = (stencil <= 0).expand_as(target)
                assert torch.equal(target[off], start[off])
            with backend("torch"):
                ref_target = start.clone()
                separable_pass(g.diffuse.clone(), kernel(), direction, g,
                               blend_into=(ref_target, weight), **opts)  # fmt: skip
            torch.testing.assert_close(target, ref_target, **tol(dtype))
            assert not torch.equal(target, start)


def test_blend_into_checks_its_target():
    """A target of another shape or dtype, or sharing memory with the pass's image or the
    G-buffer, is refused naming ``blend_into``; a weight that is not ``(3,)`` too."""
    g = scene(seed=2)
    w = torch.tensor([0.3, 0.3, 0.3], dtype=torch.float64)
    image = g.diffuse.clone()
    cases = [
        ((torch.zeros(1, 3, 5, 5, dtype=torch.float64), w), "shape"),
        ((g.diffuse.clone().float(), w), "dtype"),
        ((image, w), "shares memory with image"),
        ((g.diffuse.clone(), w[:2]), r"shape \(3,\)"),
    ]
    for blend_into, match in cases:
        with pytest.raises(ValueError, match=match):
            separable_pass(image, kernel(), "x", g, blend_into=blend_into)
    with pytest.raises(TypeError, match="blend_into"):
        separable_pass(image, kernel(), "x", g, blend_into=g.diffuse.clone())


@pytest.mark.parametrize("level", LEVELS)
def test_gaussian_follow_surface_exp_is_within_one_ulp(level):
    """The gaussian follow-surface factor ``exp(-d² / 2)`` of the float32 loops against the
    correctly rounded exp (float64 ``exp`` of the loop's own float32 argument, rounded): at
    most 1 ulp where the exact factor is normal. The scalar loop: the C library's ``expf`` of
    the torch loop's ``(-0.5 d) d``; the vectorised loops (issue 30): the table exp of
    ``z = |dz|² k``, ``k = (1 / surface_scale)² 4 / ln 2`` rounded once, as
    ``exp(-z ln 2 / 8)``, and where the exact factor is subnormal 0 or the smallest normal
    number (never a subnormal). The arguments run from 0 to past the smallest normal factor.
    One tap of weight 1 clamped onto the row's last pixel, colour 1: each result is the
    factor of its pixel's depth step to that pixel, bit for bit as computed."""
    import numpy as np

    n = 4001
    depth = torch.linspace(100.0, 114.5, n, dtype=torch.float32).view(1, 1, 1, n)
    g = GBuffer(torch.ones(1, 3, 1, n), depth.contiguous(), 0.7)
    inv = torch.tensor([1.0, 0.37, 2.9], dtype=torch.float64)  # 1 / surface_scale, per channel
    k = Kernel1D(torch.tensor([1e6], dtype=torch.float64), torch.ones(1, 3, dtype=torch.float64))
    with native.simd(level), backend("native"):
        out = separable_pass(g.diffuse, k, "x", g, follow_surface="gaussian",
                             surface_scale=1.0 / inv, use_mask=False)  # fmt: skip
    z = depth.view(-1).numpy()
    dz = np.abs(z[-1] - z)  # float32, as the loop
    inv32 = (1.0 / (1.0 / inv)).to(torch.float32).numpy()
    tiny = np.finfo(np.float32).tiny
    lowest, subnormal_seen = 0.0, False
    for ch in range(3):
        if level == "scalar":
            d = dz * inv32[ch]
            x = ((np.float32(-0.5) * d) * d).astype(np.float64)
        else:  # z = |dz|^2 k in units of ln 2 / 8
            k32 = np.float32(float(inv32[ch]) ** 2 * (4.0 / math.log(2.0)))
            x = -((dz * dz) * k32).astype(np.float64) * (math.log(2.0) / 8.0)
        exact = np.exp(x).astype(np.float32)
        got = out[0, ch, 0].numpy()
        normal = exact >= tiny
        ulps = np.abs(got.view(np.int32).astype(np.int64) - exact.view(np.int32))
        assert int(ulps[normal].max()) <= 1, (level, ch)
        sub = got[~normal]  # 0, or (vectorised) at most the smallest normal number
        assert bool(((sub == 0) | ((sub >= tiny) & (sub <= tiny * (1 + 2**-20)))).all())
        assert x.max() == 0
        lowest = min(lowest, float(x[normal].min()))
        subnormal_seen = subnormal_seen or bool((~normal).any())
    assert lowest < -87  # the arguments of every normal factor are covered
    assert subnormal_seen  # and arguments past them


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("direction", ["x", "y"])
def test_gaussian_factor_does_not_depend_on_the_pixels_sharing_its_vector(level, direction):
    """A pixel's gaussian follow-surface factor is a function of its own depth step only, not
    of the pixels the vectorised loop holds in the same vector (issue 30: where every lane's
    exponent is below 1/2 the float loops take a 4-operation path, ``expz_near_``, that must
    give the full ``expz_``'s bits). Image A: in every line the first 7 pixels' steps keep all
    three channels' exponents below 1/2; image B: the same, but a pixel in the same vector
    (at 8 and 16 lanes: the line's 8th in an x pass, whose vectors run along the line; the 8th
    line's in a y pass, whose vectors run across the lines) steps by 5 mm, so its vector takes
    the full path. The other pixels' results must be the same bits in both, and within 1 ulp
    of the correctly rounded factor. One tap of weight 1 clamped onto the line's last pixel,
    colour 1: each result is the factor of its pixel's depth step to that pixel."""
    import numpy as np

    lines, n = 257, 64
    gen = torch.Generator().manual_seed(3)
    inv = torch.tensor([1.0, 0.37, 2.9], dtype=torch.float64)  # 1 / surface_scale
    k_max = float(inv.max()) ** 2 * (4.0 / math.log(2.0))
    steps = torch.rand(lines, 7, generator=gen, dtype=torch.float64) * math.sqrt(0.5 / k_max)
    depth_a = torch.full((lines, n), 100.0, dtype=torch.float32)
    depth_a[:, :7] += steps.to(torch.float32)
    depth_b = depth_a.clone()
    kept = torch.ones(lines, 7, dtype=torch.bool)  # the pixels compared
    if direction == "x":
        depth_b[:, 7] += 5.0
    else:
        depth_b[7::8, :7] += 5.0
        kept[7::8] = False
    k = Kernel1D(torch.tensor([1e6], dtype=torch.float64), torch.ones(1, 3, dtype=torch.float64))

    def factors(depth: torch.Tensor) -> torch.Tensor:
        d = depth if direction == "x" else depth.t()
        d = d.contiguous().view(1, 1, *d.shape)
        g = GBuffer(torch.ones(1, 3, *d.shape[-2:]), d, 0.7)
        with native.simd(level), backend("native"):
            out = separable_pass(g.diffuse, k, direction, g, follow_surface="gaussian",
                                 surface_scale=1.0 / inv, use_mask=False)  # fmt: skip
        out = out[0] if direction == "x" else out[0].transpose(1, 2)
        return out[:, :, :7]  # (3, lines, 7)

    fa, fb = factors(depth_a), factors(depth_b)
    assert torch.equal(fa.view(torch.int32)[:, kept], fb.view(torch.int32)[:, kept])
    # every exponent of A's 7 pixels below 1/2, so each channel's vectors took the near path
    dz = (depth_a[:, :7] - depth_a[:, -1:]).abs().numpy()
    inv32 = (1.0 / (1.0 / inv)).to(torch.float32).numpy()
    for ch in range(3):
        k32 = np.float32(float(inv32[ch]) ** 2 * (4.0 / math.log(2.0)))
        z = (dz * dz) * k32
        assert float(z.max()) < 0.5 and float(z.max()) > (0.3 if ch == 2 else 0.0)
        exact = np.exp(-z.astype(np.float64) * (math.log(2.0) / 8.0)).astype(np.float32)
        if level == "scalar":
            continue  # the C library's expf of the torch loop's argument: the test above
        ulps = np.abs(fa[ch].numpy().view(np.int32).astype(np.int64) - exact.view(np.int32))
        assert int(ulps.max()) <= 1, ch


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gaussian_pass_underflow_is_flushed_and_the_callers_fp_state_restored(simd, dtype):
    """Issue 30: a gaussian pass runs with flush-to-zero (the far taps' exp(-d²/2) across a
    depth step underflows; subnormal arithmetic is slow). Every tap but the centre lands
    across a depth step of d surface scales, d swept over the range where exp(-d²/2) passes
    from normal through subnormal to 0 in the dtype, onto pixels of colour 0 (even columns)
    or from them (odd columns): the torch loop's results there are subnormal; the native
    ones are 0 there and no result is subnormal (BACKEND_AGREEMENT's tolerance holds),
    the centre tap's weight (offset 0: exp(-0) = 1, not computed) is applied bit for bit,
    and afterwards the calling thread still computes subnormals (its FP state restored)."""
    tiny = torch.finfo(dtype).tiny
    h, w = 15, 40
    lo, hi = (12.5, 15.0) if dtype == torch.float32 else (37.0, 39.0)
    step = torch.linspace(lo, hi, h, dtype=dtype).view(1, 1, h, 1)  # in surface scales
    odd = torch.arange(w) % 2 == 1
    depth = 100.0 + step * 2.0 * odd.to(dtype)  # surface scale 2.0 mm
    img = torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(1), dtype=dtype)
    img = img * odd.to(dtype)  # colour 0 on the even columns
    g = GBuffer(img, depth.contiguous(), 0.7)
    # taps at ±1 and ±3 pixels (at 100 mm depth): onto the other parity only, and the centre
    f_px = h / (2.0 * math.tan(0.35))
    off = torch.tensor([-3.0, -1.0, 0.0, 1.0, 3.0], dtype=torch.float64) * 100.0 / f_px
    wts = torch.tensor([1e-3, 0.2, 0.5, 0.2, 1e-3], dtype=torch.float64)[:, None].repeat(1, 3)
    k = Kernel1D(off, wts)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the pass on the calling thread: its FP state is the caller's
    try:
        # width = depth / 100: every pixel's step is that of 100 mm depth (taps ~on pixels)
        ref, got = both(g.diffuse, k, "x", g, follow_surface="gaussian", surface_scale=2.0,
                        use_mask=False, width=g.depth / 100.0)  # fmt: skip
        probe = torch.tensor([tiny], dtype=dtype) * 0.25
    finally:
        torch.set_num_threads(threads)
    assert 0 < float(probe) < tiny  # the caller's subnormals survive the pass
    even = ~odd
    sub = ref[..., even]
    assert bool(((sub != 0) & (sub.abs() < tiny)).any())  # the torch loop had subnormals
    assert not bool(((got != 0) & (got.abs() < tiny)).any())  # no subnormal is produced
    assert bool((got[ref.abs() < tiny] == 0).all())  # where torch's result is subnormal: 0
    err = float((got - ref).abs().max()) / float(img.abs().max())
    assert err <= (1e-6 if dtype == torch.float32 else 1e-14), err
    # odd columns away from the right border (where taps clamp onto odd pixels): the
    # centre's 0.5 · colour plus terms far below its last bit
    inner = odd & (torch.arange(w) < w - 4)
    assert torch.equal(got[..., inner], (0.5 * img)[..., inner])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(
    "options",
    [
        {"follow_surface": "lerp", "surface_scale": 3.0},
        {"follow_surface": "gaussian", "surface_scale": torch.tensor([0.5, 2.0, 9.0])},
        {"stretch": Stretch(ssslevel=2.0, correction=50.0, maxdd=0.5)},
    ],
    ids=["lerp", "gaussian", "stretch"],
)
def test_x_pass_into_a_new_image_equals_the_same_pass_in_place(simd, dtype, options):
    """Issue 30: an x pass whose output is a new image reads each row's window where it is
    (the vectorised loops; the image's last rows, whose whole-vector loads could pass its end,
    are packed as in place), copies only the inactive pixels and loads the centre pixels of a
    whole vector: the same values, so the same bits as the in-place pass (which packs every
    row) at the same level, the gaussian's exp included, and its inactive pixels are the
    input's. Runs of every length (spare lanes), rows of several runs, a wide kernel."""
    g = scene(seed=5, b=2, h=37, w=149, dtype=dtype, cover=0.6)
    opts = {k: (v.to(dtype) if isinstance(v, torch.Tensor) else v) for k, v in options.items()}
    with backend("native"):
        for k in (kernel(7), Kernel1D(kernel(9).offsets * 6, kernel(9).weights)):
            new = separable_pass(g.diffuse, k, "x", g, **opts)
            work = g.diffuse.clone()
            inplace = separable_pass(work, k, "x", g, inplace=True, **opts)
            assert inplace is work and new is not g.diffuse
            assert torch.equal(new, inplace)
            off = (g.mask <= 0).expand_as(new)
            assert torch.equal(new[off], g.diffuse[off])
            assert not torch.equal(new, g.diffuse)  # the case blurs something


def _bits(t: torch.Tensor) -> torch.Tensor:
    """``t``'s bit patterns (NaN payloads and the sign of zero included)."""
    return t.contiguous().view(torch.int32 if t.dtype == torch.float32 else torch.int64)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_simd_levels_keep_the_scalar_loops_bits_at_edge_values(dtype):
    """Issue 30's shorter vector code against the scalar loop, bitwise, where a select and one
    min instruction, or a clamp and no clamp, could differ in a bit: the lerp factor's clamp
    as one min (its max left out when no inverse scale has its sign bit set), the border
    clamp as one min, the second sample's index as an integer min, the weights broadcast as
    they are. Values: -0 and NaN in the colours and depths (the C entry takes them; the
    public pass refuses NaN depths), samples far beyond both borders and exactly on the last
    row / column, weights of -0, and inverse scales of -1 and -0 (the max kept) and of 0 and
    1e30 (left out) — the negative ones only through the C entry."""
    from sssbench.ops._gather_native import run_pass

    b, h, w = 1, 37, 71
    gen = torch.Generator().manual_seed(5)
    image = torch.rand(b, 3, h, w, generator=gen, dtype=torch.float64).to(dtype)
    image[0, :, 3, 5:40:3] = -0.0
    image[0, 1, 9, 11] = float("nan")
    depth = (50 + 10 * torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64)).to(dtype)
    depth[0, 0, 12, 20:60:4] = float("nan")
    depth[0, 0, 20, 30:34] = float("inf")
    mask = (torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64) < 0.8).to(dtype)
    # offsets (mm per width unit) reaching past both borders, and one landing exactly on the
    # last row / column from the first (f_px / depth * width * offset = n - 1 at depth 50)
    offsets = torch.tensor([-500.0, -3.0, -0.5, 0.0, 0.5, 3.0, 700.0], dtype=torch.float64)
    weights = torch.rand(7, 3, generator=gen, dtype=torch.float64)
    weights[1, 0] = weights[5, 2] = -0.0
    f_px = 50.0
    for inv in ([-1.0, -0.0, 2.0], [0.0, 1.0, 1e30], [0.25, 0.5, 4.0]):
        inv_scale = torch.tensor(inv, dtype=torch.float64)
        for axis_y in (False, True):
            n = h if axis_y else w
            edge = offsets.clone()
            edge[6] = float(n - 1)  # from pixel 0 at depth 50: exactly the last position
            for follow in (0, 1):
                args = (depth, mask, None, None, edge, weights, inv_scale, f_px, 1.0, 0.0,
                        0.0, axis_y, follow)  # fmt: skip
                outs = {}
                for level in LEVELS:
                    with native.simd(level):
                        outs[level] = run_pass(image.clone(), args, inplace=False)[0]
                for level, out in outs.items():
                    assert torch.equal(_bits(out), _bits(outs["scalar"])), (level, inv, axis_y)

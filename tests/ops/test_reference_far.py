"""The multipole method of ReferenceSSS against a brute-force surface integral on a curved,
masked surface with a depth step and a shadow edge, the kernel tens of pixels wide."""

import math

import numpy as np
import pytest
import torch
from oracles import FOV, brute_force_reference

from sssbench.gbuffer import GBuffer
from sssbench.ops.reference import reference_radius_px, reference_sss
from sssbench.profiles import SumOfGaussians

H = W = 48
PIX = 0.05  # mm per pixel at z0
#: σ = 0.06 mm (about one pixel: cell by cell) and 0.15, 0.35 mm (3 and 7 pixels: moments)
PROFILE = SumOfGaussians(
    torch.tensor([0.06, 0.15, 0.35]) ** 2,
    torch.tensor([[0.3, 0.5, 0.6], [0.3, 0.3, 0.3], [0.4, 0.2, 0.1]]),
)


def scene() -> GBuffer:
    z0 = PIX * H / (2 * math.tan(FOV / 2))
    yy, xx = torch.meshgrid(
        torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij"
    )
    depth = z0 + 0.25 * torch.sin(xx / 6.0) * torch.cos(yy / 9.0) + 0.004 * (xx - 24) ** 2
    depth = depth + 0.3 * (xx + 0.5 * yy > 40)  # a depth step inside the surface
    mask = ((xx - 23.5) ** 2 + (yy - 23.5) ** 2 < 21**2) & ((xx - 30) ** 2 + (yy - 14) ** 2 > 9)
    shade = 0.3 + 0.6 * torch.sigmoid((xx - yy) / 3.0) + 0.1 * torch.sin(yy / 4.0)
    shade = shade * torch.where(yy > 30 - 0.3 * xx, 1.0, 0.15)  # a sharp shadow edge
    rgb = torch.stack([shade, 0.8 * shade, 0.6 * shade])[None]
    return GBuffer(rgb, depth[None, None], FOV, mask=mask.double()[None, None])


def _targets(g: GBuffer, n: int) -> np.ndarray:
    on = torch.nonzero(g.mask[0, 0] > 0).numpy()
    rng = np.random.default_rng(0)
    return on[rng.choice(len(on), n, replace=False)]


def _rel_rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).mean() / (b**2).mean()))


@pytest.fixture(scope="module")
def setup():
    g = scene()
    k = reference_radius_px(g, PROFILE)
    assert k < H  # the window is not capped: every method sees the same support
    return g, k, _targets(g, 60)


@pytest.mark.parametrize("reconstruction", ["box", "bilinear"])
def test_multipole_matches_the_brute_force_surface_integral(setup, reconstruction):
    g, k, tg = setup
    want = brute_force_reference(g, PROFILE, tg, k, reconstruction)
    out = reference_sss(g, PROFILE, method="multipole", reconstruction=reconstruction)
    got = out[0][:, tg[:, 0], tg[:, 1]].numpy().T
    assert _rel_rms(got, want) < 1e-4


def test_cell_gather_matches_the_brute_force_surface_integral(setup):
    # the oracle itself against the cell-by-cell gather (closed forms / Gauss–Legendre cells)
    g, k, tg = setup
    want = brute_force_reference(g, PROFILE, tg, k, "box")
    got = reference_sss(g, PROFILE, method="gather")[0][:, tg[:, 0], tg[:, 1]].numpy().T
    assert _rel_rms(got, want) < 1e-5


def test_a_tile_whose_window_blocks_are_all_out_of_reach_gets_zero():
    # e.g. its own cells are too steep to expand and every block around lies at another depth
    from sssbench.ops._reference_far import far_field

    x = torch.rand(5, 3, dtype=torch.float64)
    out = far_field(x, x.new_zeros(0, 3), x.new_zeros(0, 4, 10), 1.0)
    assert out.shape == (5, 4) and not bool(out.any())


def _coefficients_by_reductions(p, mom, v):
    # the expansion's columns as first written (issue 30), with torch's sum(-1) over the
    # three axes: the oracle of the unrolled form, which must agree on every bit
    from sssbench.ops._reference_far import _NMOM, _Q33

    s, c = mom.shape[:2]
    qv = mom[..., 4:]
    qp = (qv[..., _Q33].view(s, c, 3, 3) * p[:, None, None, :]).sum(-1)
    out = mom.new_empty(s, c, _NMOM)
    dv = mom[..., 1:4] / v
    qpv = qp / (v * v)
    torch.sub(dv, qpv, out=out[..., 1:4])
    half_step = torch.sub(dv, qpv, alpha=0.5)
    alpha = mom[..., 0] - (half_step * p[:, None]).sum(-1)
    torch.sub(alpha, qv[..., :3].sum(-1), alpha=0.5 / v, out=out[..., 0])
    scale = torch.tensor([1.0, 1.0, 1.0, 2.0, 2.0, 2.0], dtype=mom.dtype) / (2 * v * v)
    torch.mul(qv, scale, out=out[..., 4:])
    return out.view(s, -1)


@pytest.mark.parametrize("seed", range(4))
def test_expansion_columns_are_bitwise_those_of_the_reduction_form(seed):
    from sssbench.ops._reference_far import _coefficients, _sum3

    gen = torch.Generator().manual_seed(seed)
    for s, c, v in ((1, 1, 0.3), (7, 4, 2.0), (1500, 4, 37.5), (4099, 3, 1e3)):
        scale = 10.0 ** torch.randint(-6, 6, (s, 1, 1), generator=gen)
        mom = torch.randn(s, c, 10, generator=gen, dtype=torch.float64) * scale
        p = torch.randn(s, 3, generator=gen, dtype=torch.float64) * 40.0
        assert torch.equal(_coefficients(p, mom, v), _coefficients_by_reductions(p, mom, v))
        t = torch.randn(s, c, 3, generator=gen, dtype=torch.float64) * scale
        assert torch.equal(_sum3(t), t.sum(-1))


@pytest.mark.parametrize("numpy_loop", [True, False], ids=["numpy", "torch"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_exp_in_place_within_one_ulp_of_the_c_library(dtype, numpy_loop, monkeypatch):
    """The far field's exp (NumPy's loop on the tensor's memory where it is vectorised, else
    ``torch.exp_``: both paths, whichever this CPU takes) against libm's ``exp`` (Python's
    ``math.exp``, rounded once to the dtype): at most 1 ulp where the result is normal, over
    [−700, 0] for float64 and [−87, 0] for float32 (which takes ``torch.exp_``), with 0, −0
    and −inf; the same tensor is returned, overwritten."""
    from sssbench.ops import _reference_far
    from sssbench.ops._reference_far import exp_in_place

    monkeypatch.setattr(_reference_far, "numpy_exp_vectorised", lambda: numpy_loop)

    lo = -700.0 if dtype == torch.float64 else -87.0
    x = torch.cat(
        [
            torch.linspace(lo, 0.0, 20011, dtype=torch.float64),
            -torch.rand(5000, dtype=torch.float64, generator=torch.Generator().manual_seed(3)),
            torch.tensor([0.0, -0.0, -math.inf], dtype=torch.float64),
        ]
    ).to(dtype)
    want = torch.tensor([math.exp(v) for v in x.double().tolist()], dtype=torch.float64).to(dtype)
    got = x.clone()
    assert exp_in_place(got) is got
    itype = torch.int64 if dtype == torch.float64 else torch.int32
    ulp = (got.view(itype).long() - want.view(itype).long()).abs()
    assert int(ulp.max()) <= 1
    assert float(got[-3]) == 1.0 and float(got[-2]) == 1.0 and float(got[-1]) == 0.0
    # under inference mode (the reference's workers), and a strided view through torch
    with torch.inference_mode():
        y = x.clone()
        assert torch.equal(exp_in_place(y), got)
    z = torch.stack([x, x], 1)[:, 0]
    assert not z.is_contiguous()
    assert torch.equal(exp_in_place(z), torch.exp(x))


def test_the_far_fields_exp_is_named_in_the_cache_key(monkeypatch):
    """Which library's exp the far field takes is this CPU's (NumPy's vectorised loop needs
    AVX-512: NumPy's own feature table says whether it has it), and it is part of the numeric
    libraries' line that cached images are keyed on: the other choice is another key."""
    import numpy

    from sssbench import _digest
    from sssbench.ops import _reference_far

    features = numpy._core._multiarray_umath.__cpu_features__
    assert _digest.numpy_exp_vectorised() == bool(features.get("AVX512_SKX"))
    assert _reference_far.numpy_exp_vectorised is _digest.numpy_exp_vectorised
    line = _digest.numeric_libraries()
    assert line.endswith(f" exp {_digest.far_exp()}")
    flipped = "torch" if _digest.far_exp() == "numpy" else "numpy"
    monkeypatch.setattr(_digest, "far_exp", lambda: flipped)
    assert _digest.numeric_libraries() == line.rsplit(" ", 1)[0] + f" {flipped}"


def _exact_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` with every dot product summed exactly and rounded once (``math.fsum``)."""
    return np.array(
        [[math.fsum(a[i] * b[:, j]) for j in range(b.shape[1])] for i in range(a.shape[0])]
    )


def _blas_threads() -> set[int]:
    """The thread counts of the BLAS libraries loaded (NumPy's), per threadpoolctl."""
    from threadpoolctl import threadpool_info

    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def _in_map(fn):
    """``fn()`` run as an item of ``map_threads`` (where the far field's products run)."""
    from sssbench.ops._reference_far import map_threads

    return next(iter(map_threads(lambda _: fn(), [0], 1)))


@pytest.mark.parametrize(("t", "s", "c"), [(1, 1, 1), (17, 5, 33), (48, 506, 40), (7, 1492, 3)])
def test_blas_product_against_exact_dot_products(t, s, c):
    """The far field's products (NumPy's BLAS, inside map_threads) against dot products
    summed exactly: within a few units of rounding of Σ |a_k b_k| (any summation order is);
    a transposed view, under inference mode, an operand requiring a gradient (torch's
    product, differentiable) and float32 (torch's)."""
    from sssbench.ops._reference_far import blas_product

    gen = torch.Generator().manual_seed(t * 1000 + s)
    a = torch.randn(t, s, generator=gen, dtype=torch.float64)
    b = torch.randn(c, s, generator=gen, dtype=torch.float64).t()  # a strided view
    want = _exact_product(a.numpy(), b.numpy())
    size = (a.abs() @ b.abs()).numpy()
    bound = 4 * s * np.finfo(np.float64).eps * size
    got = _in_map(lambda: blas_product(a, b))
    assert got.dtype == torch.float64 and got.shape == (t, c)
    assert np.all(np.abs(got.numpy() - want) <= bound)
    with torch.inference_mode():
        assert torch.equal(_in_map(lambda: blas_product(a, b)), got)
    a_grad = a.clone().requires_grad_(True)
    _in_map(lambda: blas_product(a_grad, b)).sum().backward()
    assert torch.allclose(a_grad.grad, b.sum(1).expand(t, s))
    got32 = _in_map(lambda: blas_product(a.float(), b.float()))
    assert got32.dtype == torch.float32
    assert np.all(np.abs(got32.double().numpy() - want) <= 4 * s * 2.0**-24 * size + bound)


def test_blas_product_runs_at_one_blas_thread():
    """OpenBLAS's product at two threads differs from its one-thread product in the last
    bits (measured at the far field's shape), so the far field takes NumPy's product only
    inside map_threads, which holds NumPy's BLAS to one thread while its items run (restored
    after): there its product is the one-thread product bitwise, whatever the limit outside;
    outside, it is torch's."""
    from threadpoolctl import threadpool_limits

    from sssbench.ops._reference_far import blas_product, map_threads

    gen = torch.Generator().manual_seed(5)
    a = torch.randn(256, 916, generator=gen, dtype=torch.float64)
    b = torch.randn(916, 40, generator=gen, dtype=torch.float64)
    with threadpool_limits(limits=1, user_api="blas"):
        one = torch.from_numpy(a.numpy() @ b.numpy())
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        got = list(map_threads(lambda _: (blas_product(a, b), _blas_threads()), range(4), 2))
        assert _blas_threads() == before  # restored
        assert torch.equal(blas_product(a, b), a @ b)  # outside: torch's
    for product, threads in got:
        assert torch.equal(product, one)
        assert threads <= {1}


def test_overlapping_maps_keep_the_blas_at_one_thread_until_the_last_ends():
    """Two maps that overlap without nesting (two callers' threads): the first to end must
    not give the other's products back their threads; the last restores the BLAS as it was."""
    from threadpoolctl import threadpool_limits

    from sssbench.ops import _reference_far as far

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        first, second = (
            far.map_threads(lambda i: i, range(2), 1),
            far.map_threads(lambda i: i, range(2), 1),
        )
        next(first)  # the first map holds the BLAS
        next(second)  # the second too
        first.close()  # the first ends: the second still runs at one thread
        assert _blas_threads() <= {1} and far._BLAS_HOLD["count"] == 1
        second.close()
        assert _blas_threads() == before and far._BLAS_HOLD["count"] == 0

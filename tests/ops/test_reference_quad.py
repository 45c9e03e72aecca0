"""The native reference quadrature (sssbench/ops/native/quad.c, issue 30): its cell sums
against the torch code's direct forms (the box rule's cell integral, the nine hat-weighted
weights contracted with the neighbours), its levels against each other, its exp against
libm, its argument checks, and the whole reference with and without it."""

import math

import numpy as np
import pytest
import torch

from sssbench.ops import _reference_quad as quad
from sssbench.ops import native
from sssbench.ops._reference_near import box_cell_sums
from sssbench.ops.reference import _sog_cell_weights, reference_sss
from sssbench.profiles import SumOfGaussians
from sssbench.profiles.sum_of_gaussians import cell_rules
from tests.ops.test_reference_far import scene

pytestmark = pytest.mark.skipif(
    not quad.available(), reason="the native reference quadrature needs a C compiler"
)


def _cells(n: int, tilted: bool, seed: int = 5):
    rng = np.random.default_rng(seed)
    dx, dy, dz = (torch.from_numpy(rng.uniform(-0.8, 0.8, n)) for _ in range(3))
    hh = torch.from_numpy(rng.uniform(0.1, 0.25, n))
    hh[::7] = 0.0  # cells off the surface: weight exactly 0
    sx = torch.from_numpy(rng.uniform(-2, 2, n)) if tilted else torch.zeros(n).double()
    sy = torch.from_numpy(rng.uniform(-2, 2, n)) if tilted else torch.zeros(n).double()
    return dx, dy, dz, hh, sx, sy


PROFILE = SumOfGaussians(
    torch.tensor([0.01, 0.1, 0.2, 0.3, 0.6]) ** 2,
    torch.from_numpy(np.random.default_rng(3).uniform(0.05, 0.5, (5, 3))),
)


@pytest.mark.parametrize("tilted", [False, True])
def test_box_cell_sums_equal_the_cell_integral_times_the_values(tilted):
    # the oracle: SumOfGaussians.cell_integral's rules as the reference's torch code sums
    # them (_sog_cell_weights), times each cell's own values; every rule kind
    n, size = 157, 300  # not a multiple of any vector width: the tail lanes
    geom = _cells(n, tilted)
    rng = np.random.default_rng(4)
    q = torch.from_numpy(rng.uniform(0, 1, (size, 3)))
    values = torch.cat([torch.ones(size, 1, dtype=torch.float64), q], 1)
    cells = torch.from_numpy(rng.integers(0, size, n))
    v = PROFILE.variances.tolist()
    rules = [cell_rules(v, near2, 0.25, tilted) for near2 in (0.0, 0.05, 0.5)]
    if tilted:
        assert {r for rule in rules for r in rule} >= {"narrow", 3, 4, 6, 7, 8, 10}
    for rule in rules:
        want_w = _sog_cell_weights(PROFILE, rule, *geom)  # (3, n)
        want = torch.cat([want_w * q[cells].t(), want_w])
        got = box_cell_sums(PROFILE, rule, torch.stack(geom), values, cells)
        torch.testing.assert_close(got, want, rtol=1e-13, atol=1e-15 * float(want.abs().max()))


@pytest.mark.parametrize("kind", ["tilted", "one_axis"])
def test_levels_agree_bitwise(kind):
    # every lane performs the same IEEE operations at every instruction-set level (the split
    # exponent's general sums, and its sums for a surface sloped along one axis)
    geom = _geometry(kind)
    size = 400
    values = torch.from_numpy(np.random.default_rng(6).uniform(0, 1, (size, 4)))
    cells = torch.from_numpy(np.random.default_rng(7).integers(0, size, 203))
    rule = cell_rules(PROFILE.variances.tolist(), 0.0, 0.25, True)
    outs = {}
    for level in quad.QUAD_LEVELS:
        with quad.quad_level(level) as used:
            outs[used] = box_cell_sums(PROFILE, rule, geom, values, cells)
    first = next(iter(outs.values()))
    assert len(outs) >= 1 and all(torch.equal(o, first) for o in outs.values())


def _geometry(kind: str, n: int = 203) -> torch.Tensor:
    """``(6, n)`` cells: ``tilted`` (both slopes in [-2, 2]), ``one_axis`` (``sy = 0``: the
    split exponent's cross factor is 1 in every lane) or ``steep`` (both slopes of 50 to 100
    mm/mm, either sign: the cross factor's exponent above QUAD_SPLIT_MAX for every Gaussian of
    PROFILE in every cell on the surface)."""
    dx, dy, dz, hh, sx, sy = _cells(n, kind != "one_axis", seed=11)
    if kind == "steep":
        rng = np.random.default_rng(12)
        sx = torch.from_numpy(rng.uniform(50, 100, n) * rng.choice([-1, 1], n))
        sy = torch.from_numpy(rng.uniform(50, 100, n) * rng.choice([-1, 1], n))
    return torch.stack([dx, dy, dz, hh, sx, sy])


def _sums_both_ways(kind: str, rows: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The native cell sums of ``_geometry(kind)`` with the split exponent where it applies
    (the default) and with one exp per node (its oracle), Gauss–Legendre rules of odd and even
    orders for the five Gaussians of PROFILE (``rows`` 1: the box's n × n rule over the cell;
    3: the bilinear reconstruction's 2·quadrant_order(n) nodes per axis)."""
    from sssbench.ops._reference_near import HAT_OFFSETS, hat_cell_sums

    geom = _geometry(kind)
    m, size = geom.shape[1], 400
    rng = np.random.default_rng(13)
    values = torch.from_numpy(rng.uniform(0, 1, (size, 4)))
    cells = torch.from_numpy(rng.integers(30, size - 30, m))
    rule = (3, 4, 7, 8, 10)
    out = []
    for on in (True, False):
        with quad.split_exponent(on):
            if rows == 1:
                out.append(box_cell_sums(PROFILE, rule, geom, values, cells))
            else:
                hat = torch.tensor([a - 20 * b for a, b in HAT_OFFSETS])
                out.append(hat_cell_sums(PROFILE, rule, *geom, values, cells, hat, native=True))
    return out[0], out[1]


@pytest.mark.parametrize("rows", [1, 3])
@pytest.mark.parametrize("kind", ["tilted", "one_axis"])
def test_split_exponent_equals_one_exp_per_node(kind, rows):
    # the product of the three factors is the node's exp in real arithmetic: equal to rounding
    split, direct = _sums_both_ways(kind, rows)
    assert not torch.equal(split, direct)  # the split sums did run: other roundings
    assert torch.isfinite(split).all()
    torch.testing.assert_close(split, direct, rtol=1e-13, atol=1e-15 * float(direct.abs().max()))


@pytest.mark.parametrize("rows", [1, 3])
def test_split_exponent_is_not_taken_where_a_factor_would_be_large(rows):
    # every vector block holds a cell whose cross factor's exponent exceeds QUAD_SPLIT_MAX:
    # one exp per node everywhere, so bitwise the oracle's sums (the split form would give
    # factors up to e^±400 here: cancellation, and overflow further out)
    split, direct = _sums_both_ways("steep", rows)
    assert torch.isfinite(direct).all() and float(direct.abs().max()) > 0
    assert torch.equal(split, direct)


def test_split_exponent_switch_is_restored():
    lib = native.quad_library()
    with quad.split_exponent(False):
        with quad.split_exponent(True):
            assert lib.quad_set_split(1) == 1
        assert lib.quad_set_split(0) == 0
    assert lib.quad_set_split(1) == 1  # the default is back


def test_exp_against_libm():
    # a few ulp where the result is normal, 0 where libm's is subnormal, NaN kept
    rng = np.random.default_rng(8)
    x = np.concatenate(
        [rng.uniform(-745, 0, 20000), rng.uniform(-1, 1e-12, 5000), [0.0, -708.0, -750.0]]
    )
    got = quad.native_exp(torch.from_numpy(x)).numpy()
    want = np.array([math.exp(t) for t in x])
    normal = want >= np.finfo(np.float64).tiny
    ulp = np.abs(got - want)[normal] / np.spacing(want[normal])
    assert ulp.max() <= quad.QUAD_EXP_ULP
    assert np.abs(got[~normal] - want[~normal]).max() < 3.4e-308
    assert math.isnan(float(quad.native_exp(torch.tensor([math.nan]))[0]))


def test_small_argument_exp_gives_the_exps_bits():
    # qexp_small (the split exponent's cross factors where every exponent is small) is qexp
    # itself there: bitwise the same at every level, up to the bound the C code uses
    # (QEXP_SMALL; ln 2 / 64 = 0.01083 is where qexp's reduction would start to round
    # 32 x / ln 2 away from 0, and beyond 0.0109 the two differ: measured)
    lib = native.quad_library()
    rng = np.random.default_rng(9)
    small = lib.quad_exp_small_bound()
    assert 0.01 <= small < math.log(2) / 64
    x = np.concatenate(
        [rng.uniform(-small, small, 100_000), 10.0 ** -rng.uniform(1.97, 300, 20_000)]
    )
    x = np.concatenate([x, -x[-20_000:], [0.0, -0.0, small, -small, 5e-324]])
    x = torch.from_numpy(x)
    for level in quad.QUAD_LEVELS:
        with quad.quad_level(level):
            want, got = torch.empty_like(x), torch.empty_like(x)
            lib.quad_exp_array(x.data_ptr(), want.data_ptr(), x.numel())
            lib.quad_exp_small_array(x.data_ptr(), got.data_ptr(), x.numel())
            assert torch.equal(got.view(torch.int64), want.view(torch.int64))


def test_bad_arguments_are_refused():
    geom = torch.stack(_cells(8, True))
    values = torch.ones(10, 4, dtype=torch.float64)
    tables = (
        torch.tensor([3]),
        torch.zeros(3, dtype=torch.float64),
        torch.zeros(3, dtype=torch.float64),
        torch.zeros(3, dtype=torch.float64),
        torch.tensor([-1.0], dtype=torch.float64),
    )
    w = torch.ones(1, 3, dtype=torch.float64)
    ok = torch.arange(8)
    hat = torch.zeros(1, dtype=torch.int64)
    assert quad.native_cell_sums(geom, None, values, ok, hat, tables, w, 1).shape == (6, 8)
    with pytest.raises(IndexError, match="rows of values"):
        quad.native_cell_sums(geom, None, values, ok + 3, hat, tables, w, 1)
    with pytest.raises(ValueError, match="rows must be 1 or 3"):
        quad.native_cell_sums(geom, None, values, ok, hat, tables, w, 2)
    big = (torch.tensor([65]), *(torch.zeros(65, dtype=torch.float64),) * 3, tables[4])
    with pytest.raises(ValueError, match="1 to 64 nodes"):
        quad.native_cell_sums(geom, None, values, ok, hat, big, w, 1)
    with pytest.raises(ValueError, match="geom must be contiguous float64"):
        quad.native_cell_sums(geom.float(), None, values, ok, hat, tables, w, 1)
    with pytest.raises(ValueError, match="level must be one of"):
        quad.quad_level("sse4")


@pytest.mark.parametrize("reconstruction", ["box", "bilinear"])
def test_reference_is_the_same_with_and_without_the_native_sums(reconstruction, monkeypatch):
    # the curved, masked scene with a depth step and a shadow edge, and the face close-up
    # with the six-Gaussian skin: the torch sums (the library switched off) are the oracle
    from data_synth import make_scene

    skin = SumOfGaussians.from_table("skin_deon6")
    narrow = SumOfGaussians(
        torch.tensor([0.01, 0.03, 0.2]) ** 2,
        torch.tensor([[0.4, 0.2, 0.1], [0.3, 0.4, 0.3], [0.3, 0.4, 0.6]]),
    )
    cases = [(scene(), narrow)]
    cases.append((make_scene("face", (24, 24), dtype=torch.float64, pixel_mm=0.1), skin))
    for g, prof in cases:
        new = reference_sss(g, prof, reconstruction=reconstruction)
        with monkeypatch.context() as m:
            m.setattr(quad, "available", lambda: False)
            old = reference_sss(g, prof, reconstruction=reconstruction)
        assert not torch.equal(new, old)  # the native path did run: another summation order
        torch.testing.assert_close(new, old, rtol=1e-13, atol=1e-15 * float(old.abs().max()))


def test_offset_fields_equal_torch_gather_and_subtraction():
    # the values torch.gather and one subtraction give, bit for bit; indices checked
    g = torch.Generator().manual_seed(9)
    fields = torch.rand(10, 900, generator=g, dtype=torch.float64) * 100
    centre = torch.arange(200, 260)
    shift = torch.tensor([0, -31, 30, 1, -1, 62])
    got = quad.offset_fields(fields, centre, shift)
    idx = (centre[None, :] + shift[:, None]).reshape(1, -1).expand(10, -1)
    want = torch.gather(fields, 1, idx).view(10, 6, 60)
    want[:3] = want[:3] - fields[:3, centre][:, None]
    assert torch.equal(got, want)
    with pytest.raises(IndexError, match="centre \\+ shift"):
        quad.offset_fields(fields, centre, torch.tensor([700]))

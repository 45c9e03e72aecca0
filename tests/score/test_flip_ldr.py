"""The torch LDR-FLIP map (``sssbench.score.flip_ldr.flip_ldr_map``) against NVIDIA's FLIP 1.7
(``flip_evaluator.evaluate``, C++), the oracle, called through
``metrics._flip_ldr_official`` (no memo).

The tolerances are measured, not derived. Synthetic images (random, smooth, saturated, tiny,
non-square; 30, 67 and 120 ppd): max |torch - FLIP 1.7| 1.6e-6, ``TOL`` = 1e-5. Renders
(7 scenes x 2 methods x 3 ppd at 128^2, measured once outside the suite): max 2.7e-5,
above 1e-5 at no more than 6 of 16384 pixels of a map, mean |difference| <= 2.2e-8;
``TOL_RENDER`` = 3e-5. The differences are last-bit differences of ``powf`` (glibc's, at most
0.82 ulp off, against the float64 value rounded once) that FLIP itself magnifies
(``HyAB ** 0.7`` of a distance of an ulp or two; the square root of the feature filters'
rounding noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sssbench.score import metrics
from sssbench.score.flip_ldr import flip_ldr_map

TOL = 1e-5
TOL_RENDER = 3e-5


def _check(
    ref: torch.Tensor, test: torch.Tensor, ppd: float = 67.0, tol: float = TOL
) -> np.ndarray:
    ours = flip_ldr_map(ref, test, ppd)
    official = metrics._flip_ldr_official(ref, test, ppd)
    assert ours.shape == official.shape == ref.shape[1:]
    assert ours.dtype == np.float32
    diff = np.abs(ours.astype(np.float64) - official)
    assert diff.max() <= tol, f"max |diff| {diff.max():.3g}"
    return ours


def _rand(shape: tuple[int, ...], seed: int) -> torch.Tensor:
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("ppd", [30.0, 67.0, 120.0])
@pytest.mark.parametrize("hw", [(48, 48), (37, 61), (5, 7), (1, 1), (1, 9), (23, 2)])
def test_random(ppd: float, hw: tuple[int, int]) -> None:
    ref = _rand((3, *hw), 1)
    _check(ref, _rand((3, *hw), 2), ppd)
    _check(ref, (ref + 0.02 * torch.randn(ref.shape, generator=torch.Generator().manual_seed(3)))
           .clamp(0, 1), ppd)  # fmt: skip


@pytest.mark.parametrize("ppd", [30.0, 67.0, 120.0])
def test_smooth_gradients(ppd: float) -> None:
    yy, xx = torch.meshgrid(torch.linspace(0, 1, 40), torch.linspace(0, 1, 70), indexing="ij")
    ref = torch.stack((xx, yy, 0.5 * (xx + yy)))
    test = torch.stack((xx**1.1, yy, 0.5 * (xx + yy) + 0.01 * torch.sin(9 * xx))).clamp(0, 1)
    _check(ref, test, ppd)


def test_identical_images_give_zero_where_flip_does() -> None:
    ref = _rand((3, 33, 47), 4)
    ours = _check(ref, ref.clone())
    official = metrics._flip_ldr_official(ref, ref.clone(), 67.0)
    assert np.array_equal(ours == 0, official == 0)
    assert (ours == 0).all()


def test_saturated_colours() -> None:
    gen = torch.Generator().manual_seed(5)
    ref = torch.randint(0, 2, (3, 30, 30), generator=gen).float()
    test = torch.randint(0, 2, (3, 30, 30), generator=gen).float()
    test[:, :10] = ref[:, :10]
    _check(ref, test)
    _check(torch.zeros(3, 12, 12), torch.ones(3, 12, 12))
    _check(torch.ones(3, 9, 9), torch.ones(3, 9, 9))


def test_float64_input_is_read_as_float32() -> None:
    ref, test = _rand((3, 20, 20), 6).double(), _rand((3, 20, 20), 7).double()
    assert np.array_equal(
        flip_ldr_map(ref, test, 67.0), flip_ldr_map(ref.float(), test.float(), 67.0)
    )


@pytest.mark.parametrize(("scene", "ppd"), [("face", 67.0), ("sphere", 67.0), ("head", 120.0)])
def test_render_of_a_method_against_its_reference(scene: str, ppd: float) -> None:
    """A scene's reference against a method's result, as the runner scores them (the sphere
    at 67 ppd and the head at 120 ppd hold the largest differences measured)."""
    from data_synth import make_scene
    from sssbench.ops import PreintegratedSSS, ReferenceSSS
    from sssbench.profiles import SumOfGaussians

    skin = SumOfGaussians.from_table("skin_jg10")
    g = make_scene(scene, (128, 128), fields=["mask"], dtype=torch.float32)
    ref = metrics._display(ReferenceSSS(skin)(g).double(), 1.0)[0]
    res = metrics._display(PreintegratedSSS(skin)(g).double(), 1.0)[0]
    ours = _check(ref, res, ppd, tol=TOL_RENDER)
    diff = np.abs(ours.astype(np.float64) - metrics._flip_ldr_official(ref, res, ppd))
    assert diff.mean() <= 1e-7 and (diff > TOL).sum() <= 16
    assert ours.max() > 0.01  # the method differs visibly somewhere


def test_flip_map_uses_the_torch_map() -> None:
    ref = _rand((1, 3, 16, 16), 8)
    res = _rand((1, 3, 16, 16), 9)
    got = metrics.flip_map(res, ref)[0]
    t_ref, t_res = (metrics._display(x.double(), 1.0)[0] for x in (ref, res))
    assert np.array_equal(got, flip_ldr_map(t_ref, t_res, 67.0))


def test_map_does_not_depend_on_torchs_threads() -> None:
    ref, test = _rand((3, 70, 90), 10), _rand((3, 70, 90), 11)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = flip_ldr_map(ref, test, 67.0)
        torch.set_num_threads(2)
        two = flip_ldr_map(ref, test, 67.0)
    finally:
        torch.set_num_threads(before)
    assert np.array_equal(one, two)


def test_strips_do_not_change_the_map(monkeypatch: pytest.MonkeyPatch) -> None:
    """The strips of rows (``_STRIP_ELEMENTS``) are a schedule, not a value: one-row-group
    strips give the whole-image map bit for bit."""
    from sssbench.score import flip_ldr

    ref, test = _rand((3, 45, 33), 12), _rand((3, 45, 33), 13)
    whole = flip_ldr_map(ref, test, 67.0)
    monkeypatch.setattr(flip_ldr, "_STRIP_ELEMENTS", 1)  # strips of 8 rows
    assert np.array_equal(flip_ldr_map(ref, test, 67.0), whole)


@pytest.mark.parametrize(
    ("ref", "test", "ppd", "exc", "name"),
    [
        (torch.rand(3, 4), torch.rand(3, 4), 67.0, ValueError, "reference"),
        (torch.rand(4, 5, 5), torch.rand(4, 5, 5), 67.0, ValueError, "reference"),
        (torch.rand(3, 5, 5), torch.rand(3, 5, 6), 67.0, ValueError, "test"),
        (torch.rand(3, 5, 5), torch.rand(3, 5, 5), 0.0, ValueError, "ppd"),
        (torch.rand(3, 5, 5), torch.rand(3, 5, 5), -3.0, ValueError, "ppd"),
        (torch.rand(3, 5, 5), torch.rand(3, 5, 5), float("nan"), ValueError, "ppd"),
        (np.zeros((3, 5, 5)), torch.rand(3, 5, 5), 67.0, TypeError, "reference"),
    ],
)
def test_bad_input(ref: object, test: object, ppd: float, exc: type, name: str) -> None:
    with pytest.raises(exc, match=name):
        flip_ldr_map(ref, test, ppd)  # type: ignore[arg-type]


def test_near_ties_are_the_values_by_a_float32_rounding_boundary() -> None:
    """``_near_ties`` flags a float64 value within 2^-40 (relative) of the midpoint between two
    adjacent float32 values, and nothing farther: midpoints built exactly from float32 pairs."""
    from sssbench.score.flip_ldr import _near_ties

    rng = np.random.default_rng(3)
    f = rng.uniform(1e-6, 300.0, 2000).astype(np.float32)
    up = np.nextafter(f, np.float32(np.inf))
    mid = (f.astype(np.float64) + up.astype(np.float64)) / 2  # exact
    for rel, expected in ((0.0, True), (2.0**-44, True), (-(2.0**-44), True), (2.0**-36, False)):
        got = _near_ties(torch.from_numpy(mid * (1 + rel)))
        assert bool(got.all()) if expected else not bool(got.any()), rel
    assert not bool(_near_ties(torch.from_numpy(f.astype(np.float64))).any())
    assert not bool(_near_ties(torch.tensor([0.0, math.inf, math.nan])).any())


@pytest.mark.parametrize("y", [2.4, 1.0 / 3.0, 0.7])
def test_pow_is_the_same_function_of_its_input_wherever_it_lies(y: float) -> None:
    """``_pow32`` near float32 rounding boundaries (found by search: the values whose float64
    power lies within 2^-40 of one) equals the C library's ``exp(y log x)`` rounded once
    (Python's ``math``), whether the value sits in a vector of a long tensor, in its tail or
    alone: torch's vectorised and one-at-a-time ``log`` / ``exp`` may differ there."""
    from sssbench.score.flip_ldr import _near_ties, _pow32

    y32 = float(np.float32(y))
    x = torch.rand(1 << 20, generator=torch.Generator().manual_seed(5)) * 0.95 + 0.05
    hits = x[_near_ties(x.double().log().mul_(y32).exp_())]
    assert hits.numel() >= 3  # the search finds some (about 1 in 2^16)
    oracle = [np.float32(math.exp(y32 * math.log(float(v)))) for v in hits]
    filler = torch.rand(61, generator=torch.Generator().manual_seed(6)) + 0.1
    for k, v in enumerate(hits.tolist()):
        for at in (0, 17, 60):  # in a vector, at its end, in the tail of 61 elements
            t = filler.clone()
            t[at] = v
            assert _pow32(t, y)[at].item() == oracle[k]
            assert _pow32(t, torch.full_like(t, y32))[at].item() == oracle[k]  # a tensor y
        assert _pow32(torch.tensor([v]), y).item() == oracle[k]


def test_pow_of_an_image_shaped_tensor_is_the_flat_ones() -> None:
    """``_pow32`` on a strided ``(2, 3, H, W)`` view (as the pipeline passes its channels) is
    the same elementwise function as on the flat values: near-ties are found by position."""
    from sssbench.score.flip_ldr import _pow32

    x = torch.rand(2, 3, 40, 50, generator=torch.Generator().manual_seed(8)) + 1e-3
    view = x.transpose(-1, -2)  # not contiguous
    y = torch.rand(view.shape, generator=torch.Generator().manual_seed(9))
    flat = _pow32(view.reshape(-1).contiguous(), y.reshape(-1).contiguous())
    assert torch.equal(_pow32(view, y).reshape(-1), flat)
    assert torch.equal(_pow32(view, 0.7).reshape(-1), _pow32(view.reshape(-1).contiguous(), 0.7))
    with pytest.raises(ValueError, match="y must have"):
        _pow32(view, y[..., :3])


def test_planes_give_the_map_bit_for_bit_and_the_official_one():
    # each image's planes alone (what a sweep memoises for its reference), then compared:
    # the same bits as flip_ldr_map, and within TOL of FLIP 1.7 itself
    from sssbench.score.flip_ldr import flip_from_planes, flip_planes

    g = torch.Generator().manual_seed(11)
    ref = torch.rand(3, 97, 130, generator=g)
    # a random pair (TOL) and a nearly equal one, where FLIP magnifies last-bit differences
    # of powf (TOL_RENDER, see the module docstring; measured 1.8e-5 here)
    pairs = ((torch.rand(3, 97, 130, generator=g), TOL), ((ref + 1e-6).clamp(0, 1), TOL_RENDER))
    for test, tol in pairs:
        for ppd in (30.0, 67.0):
            planes = torch.stack([flip_planes(ref, ppd), flip_planes(test, ppd)])
            assert planes.shape == (2, 5, 97, 130) and planes.dtype == torch.float32
            got = flip_from_planes(planes)
            assert np.array_equal(got, flip_ldr_map(ref, test, ppd))
            official = metrics._flip_ldr_official(ref, test, ppd)
            assert np.abs(got.astype(np.float64) - official).max() <= tol
    # the metric's path (the reference's planes memoised on its bits) for two tests in turn
    other = torch.rand(3, 97, 130, generator=g)
    for test in (other, other.flip(-1)):
        assert np.array_equal(metrics._flip_ldr(ref, test, 67.0), flip_ldr_map(ref, test, 67.0))


def test_planes_reject_bad_shapes():
    from sssbench.score.flip_ldr import flip_from_planes, flip_planes

    with pytest.raises(ValueError, match=r"image must have shape \(3, H, W\)"):
        flip_planes(torch.rand(4, 8, 8), 67.0)
    with pytest.raises(ValueError, match="ppd must be a finite number"):
        flip_planes(torch.rand(3, 8, 8), 0.0)
    with pytest.raises(ValueError, match=r"planes must have shape \(2, 5, H, W\)"):
        flip_from_planes(torch.rand(3, 5, 8, 8))

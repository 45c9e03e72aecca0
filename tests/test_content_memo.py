"""The memo keyed by contents (:func:`sssbench._memo.by_content`) and the scoring it serves
(the tone map and Lab values of the reference, the FLIP map, the budget's flat-plane model):
found for equal contents held by new tensors, never stale (one changed bit recomputes), the
values bit for bit those of the computation without the memo."""

import flip_evaluator
import numpy as np
import pytest
import torch

import sssbench._memo as memo
from data_synth import make_scene
from sssbench._memo import by_content
from sssbench.ops import PreintegratedSSS, SumOfGaussiansSSS
from sssbench.profiles import SumOfGaussians
from sssbench.score import metrics
from sssbench.score.budget import flat_convolution, footprint_mm, method_kernel
from sssbench.score.flip_ldr import flip_ldr_map

SKIN = SumOfGaussians.from_table("skin_jg10")


@pytest.fixture(autouse=True)
def _empty_memo():
    memo._BY_CONTENT.clear()
    yield
    memo._BY_CONTENT.clear()


def _counted(fn):
    calls = []

    def compute():
        calls.append(1)
        return fn()

    return compute, calls


def test_equal_contents_hit_a_changed_bit_recomputes():
    a = torch.arange(12, dtype=torch.float64).reshape(3, 4)
    compute, calls = _counted(lambda: a * 2)
    first = by_content((a,), "t", compute)
    again = by_content((a.clone(),), "t", compute)  # a new tensor, the same contents
    assert len(calls) == 1 and torch.equal(first, again)
    b = a.clone()
    b[1, 2] = torch.nextafter(b[1, 2], torch.tensor(1e9, dtype=torch.float64))  # one ulp
    compute_b, calls_b = _counted(lambda: b * 2)
    assert torch.equal(by_content((b,), "t", compute_b), b * 2) and len(calls_b) == 1
    a[0, 0] = 5.0  # written in place: its contents are new, so is the key
    compute_a, calls_a = _counted(lambda: a * 2)
    assert float(by_content((a,), "t", compute_a)[0, 0]) == 10.0 and len(calls_a) == 1
    # the tag and the other key tensors are part of the key
    compute_c, calls_c = _counted(lambda: a * 3)
    by_content((a,), "other", compute_c)
    by_content((a, None), "t", compute_c)
    assert len(calls_c) == 2


def test_shape_and_dtype_are_part_of_the_key():
    a = torch.arange(6, dtype=torch.int32)
    compute, calls = _counted(lambda: 1)
    by_content((a,), "t", compute)
    by_content((a.reshape(2, 3),), "t", compute)  # same bits, another shape
    by_content((a.view(torch.float32),), "t", compute)  # same bits, another dtype
    by_content((a.numpy(),), "t", compute)  # a NumPy array of the same bits: the same key
    assert len(calls) == 3


def test_values_are_handed_out_as_copies():
    a = torch.ones(4)
    out = by_content((a,), "t", lambda: (a * 2, np.full(2, 7.0)))
    out[0][0] = -1.0  # the caller writes into what it got
    out[1][0] = -1.0
    hit = by_content((a,), "t", lambda: pytest.fail("recomputed"))
    assert torch.equal(hit[0], torch.full((4,), 2.0)) and np.array_equal(hit[1], [7.0, 7.0])
    hit[0][1] = -5.0
    assert float(by_content((a,), "t", lambda: None)[0][1]) == 2.0


def test_bounded_least_recently_used_first():
    keep = torch.zeros(2)
    by_content((keep,), "keep", lambda: 0)
    for i in range(memo._BY_CONTENT_SIZE + 5):
        by_content((keep,), "keep", lambda: pytest.fail("the recently used value was dropped"))
        by_content((torch.full((2,), float(i)),), "churn", lambda i=i: i)
    assert len(memo._BY_CONTENT) == memo._BY_CONTENT_SIZE
    compute, calls = _counted(lambda: 0)
    by_content((torch.full((2,), 0.0),), "churn", compute)  # the oldest: dropped
    assert calls == [1]


def _images(seed=0, shape=(1, 3, 40, 36)):
    g = torch.Generator().manual_seed(seed)
    ref = torch.rand(shape, generator=g, dtype=torch.float64) * 2.0
    res = ref + 0.2 * torch.randn(shape, generator=g, dtype=torch.float64)  # some < 0
    mask = (torch.rand((shape[0], 1, *shape[2:]), generator=g) > 0.3).double()
    return res.float(), ref.float(), mask


def _flip_direct(res, ref):
    """FLIP as :func:`metrics.flip_map` documents it, called here without any memo: both
    images clamped at 0, Reinhard + sRGB, LDR-FLIP at 67 ppd by the torch implementation
    (``flip_ldr.flip_ldr_map``), checked here against NVIDIA's ``flip_evaluator`` within the
    documented 1e-5."""
    out = []
    for i in range(ref.shape[0]):
        a, b = (metrics.tonemap(x[i : i + 1].double().clamp(min=0))[0].float() for x in (ref, res))
        out.append(flip_ldr_map(a, b, 67.0))
    out = np.stack(out)
    assert np.abs(out - _flip_direct_official(res, ref)).max() <= 1e-5
    return out


def _flip_direct_official(res, ref):
    """:func:`_flip_direct` by NVIDIA's ``flip_evaluator.evaluate`` (C++)."""
    out = []
    for i in range(ref.shape[0]):
        a, b = (
            np.ascontiguousarray(
                metrics.tonemap(x[i : i + 1].double().clamp(min=0))[0].permute(1, 2, 0).numpy(),
                dtype=np.float32,
            )
            for x in (ref, res)
        )
        fmap, _, _ = flip_evaluator.evaluate(
            a, b, "LDR", inputsRGB=True, applyMagma=False, computeMeanError=False,
            parameters={"ppd": 67.0},
        )  # fmt: skip
        out.append(np.asarray(fmap, dtype=np.float32)[..., 0])
    return np.stack(out)


def test_flip_map_is_flip_of_the_images_bit_for_bit_hit_or_miss(monkeypatch):
    res, ref, _ = _images(shape=(2, 3, 40, 36))
    direct = _flip_direct(res, ref)
    calls = []
    real = metrics.flip_from_planes  # one call per pair of images FLIP compares
    monkeypatch.setattr(
        metrics, "flip_from_planes", lambda *a, **k: calls.append(1) or real(*a, **k)
    )
    cold = metrics.flip_map(res, ref)
    assert len(calls) == 2 and np.array_equal(cold, direct)
    warm = metrics.flip_map(res.clone(), ref.clone())  # new tensors: FLIP is not run again
    assert len(calls) == 2 and np.array_equal(warm, direct)
    warm[0, 0, 0] = 9.0  # the caller's copy
    assert np.array_equal(metrics.flip_map(res, ref), direct)
    changed = ref.clone()
    changed[1, 0, 5, 5] += 0.25  # one pixel of the reference: its image is evaluated again
    new = metrics.flip_map(res, changed)
    assert len(calls) == 3  # the first image of the batch is unchanged: its map is kept
    assert np.array_equal(new, _flip_direct(res, changed)) and not np.array_equal(new, direct)


def test_scores_with_the_memo_are_those_without_it():
    """Every metric, with the reference's tone map and Lab values kept (a second result on the
    same reference, new tensors), equals the same metric computed with an empty memo."""
    res, ref, mask = _images(seed=1)
    res2 = (res * 1.1).clamp(min=0)

    def scores(r):
        values = metrics.compute_all(r, ref.clone(), mask)
        return values | {
            "ciede2000": metrics.delta_e(r, ref.clone(), mask, formula="ciede2000"),
            "delta_e_exp2": metrics.delta_e(r, ref.clone(), mask, exposure=2.0),
            "flip_exp2": metrics.flip(r, ref.clone(), mask, exposure=2.0),
        }

    scores(res)  # keeps the reference's values
    assert len(memo._BY_CONTENT) > 0
    warm = scores(res2)
    memo._BY_CONTENT.clear()
    cold = scores(res2)
    assert warm == cold  # bit for bit (floats compared exactly)
    # a changed reference is recomputed: its ΔE is that of a cold memo on it
    ref2 = ref.clone()
    ref2[..., 3, 4] += 0.5
    warm2 = metrics.delta_e(res2, ref2, mask)
    memo._BY_CONTENT.clear()
    assert warm2 == metrics.delta_e(res2, ref2, mask) != cold["delta_e"]


def test_flat_convolution_memo_is_the_fft_bit_for_bit(monkeypatch):
    """The budget's model image: computed once for two methods with the same continuous
    kernel (the pre-integrated kernel at 7 and 13 taps), equal bit for bit to a computation
    with an empty memo; a changed light or another kernel is computed again."""
    import sssbench.score.budget as budget

    g = make_scene("light_dot", (32, 32), fields=["mask"], dtype=torch.float64)
    p = footprint_mm(g)
    calls = []
    real = budget._flat
    monkeypatch.setattr(budget, "_flat", lambda *a: calls.append(1) or real(*a))
    m7 = flat_convolution(g, method_kernel(PreintegratedSSS(SKIN, samples=7)), p)
    m13 = flat_convolution(g, method_kernel(PreintegratedSSS(SKIN, samples=13)), p)
    assert len(calls) == 1 and torch.equal(m7, m13)
    memo._BY_CONTENT.clear()
    assert torch.equal(flat_convolution(g, method_kernel(PreintegratedSSS(SKIN)), p), m7)
    assert len(calls) == 2
    artist = flat_convolution(g, method_kernel(SumOfGaussiansSSS(SKIN)), p)  # another kernel
    assert len(calls) == 3 and not torch.equal(artist, m7)
    brighter = g.replace(diffuse=g.diffuse * 1.5)  # another light
    out = flat_convolution(brighter, method_kernel(PreintegratedSSS(SKIN)), p)
    assert len(calls) == 4
    torch.testing.assert_close(out, m7 * 1.5, rtol=1e-12, atol=1e-12)  # linear in the light


def test_flip_map_does_not_depend_on_flips_threads():
    """FLIP runs on torch's thread count (``metrics._flip_threads``): its map on one thread
    is the map on two, bit for bit, and the runtime's own setting is restored after."""
    lib = metrics._flip_openmp()
    if lib is None:
        pytest.skip("this flip_evaluator build vendors no OpenMP runtime")
    res, ref, _ = _images(seed=2, shape=(1, 3, 64, 64))
    before = lib.omp_get_max_threads()
    maps = []
    for threads in (1, 2):
        with metrics._flip_threads(threads):
            assert lib.omp_get_max_threads() == threads
            maps.append(_flip_direct_official(res, ref))
        assert lib.omp_get_max_threads() == before
    assert np.array_equal(maps[0], maps[1])


@pytest.mark.parametrize(("shape", "win"), [((3, 40, 36), 7), ((3, 5, 9), 5)])
def test_ssim_is_skimages_bit_for_bit_hit_or_miss(shape, win):
    """``metrics._structural_similarity`` (the reference's window moments memoised) against
    ``skimage.metrics.structural_similarity`` itself, cold and with the reference's moments
    kept (a second result), and after one pixel of the reference changed."""
    from skimage.metrics import structural_similarity

    g = torch.Generator().manual_seed(3)
    ref = torch.rand(shape, generator=g, dtype=torch.float64)
    for k in range(2):
        res = ref + 0.1 * (k + 1) * torch.randn(shape, generator=g, dtype=torch.float64)
        for r in (ref, ref.clone()):
            value, smap = metrics._structural_similarity(r, res, win, 1.3)
            expected = structural_similarity(
                r.permute(1, 2, 0).numpy(), res.permute(1, 2, 0).numpy(), win_size=win,
                data_range=1.3, channel_axis=-1, full=True,
            )  # fmt: skip
            assert value == expected[0] and np.array_equal(smap, expected[1])
    changed = ref.clone()
    changed[1, 2, 3] += 0.5
    value, _ = metrics._structural_similarity(changed, res, win, 1.3)
    assert value == structural_similarity(
        changed.permute(1, 2, 0).numpy(), res.permute(1, 2, 0).numpy(), win_size=win,
        data_range=1.3, channel_axis=-1,
    )  # fmt: skip

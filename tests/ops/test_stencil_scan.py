"""The native loop's stencil runs, rebuilt from the mask by a C scan on every call.

Checked against a Python walk over the mask (``mask > 0`` pixel by pixel, the definition):
rows whose length straddles the scan's block of 16 (float32) / 8 (float64) pixels, NaN,
-0.0 and negative values (none of them > 0), and more runs than the first buffer holds. A
write that bumps no version counter is seen by the next call (nothing is kept across calls,
unless the mask is sealed: then the runs are kept while the seal holds, and a write to it is
caught as ``SealBroken``, never served silently).
"""

import pytest
import torch

from sssbench._memo import memo_scope
from sssbench.ops import native
from sssbench.ops._stencil import image_spans

pytestmark = pytest.mark.skipif(native.library() is None, reason="no C compiler")


def walk(mask: torch.Tensor) -> list[list[int]]:
    """Runs ``[row, first, end)`` of ``mask > 0`` of one ``(H, W)`` mask, by a Python walk."""
    h, w = mask.shape
    on = (mask > 0).tolist()
    runs = []
    for r in range(h):
        c = 0
        while c < w:
            if on[r][c]:
                start = c
                while c < w and on[r][c]:
                    c += 1
                runs.append([r, start, c])
            else:
                c += 1
    return runs


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("w", [1, 7, 8, 15, 16, 17, 33, 64, 65])
def test_runs_equal_a_walk_over_the_mask(dtype, w):
    gen = torch.Generator().manual_seed(w)
    h = 6
    mask = torch.rand(2, 1, h, w, generator=gen, dtype=dtype)
    mask[0, 0, 0] = 1.0  # a full row
    mask[0, 0, 1] = 0.0  # an empty row
    holes = torch.rand(2, 1, h, w, generator=gen) < 0.3
    mask[holes] = 0.0
    specials = torch.tensor([float("nan"), -0.0, -1.0, float("inf")], dtype=dtype)
    pick = torch.randint(0, 4, (2, 1, h, w), generator=gen)
    sprinkle = torch.rand(2, 1, h, w, generator=gen) < 0.15
    mask[sprinkle] = specials[pick[sprinkle]]
    spans = image_spans(mask, (2, h, w))
    for bi in range(2):
        assert spans[bi].dtype == torch.int64 and spans[bi].is_contiguous()
        assert spans[bi].tolist() == walk(mask[bi, 0])


def test_long_active_and_empty_stretches_across_blocks():
    """Runs starting and ending at every offset within a block, on a wide row."""
    w = 200
    mask = torch.zeros(1, 1, 40, w)
    for r in range(40):
        mask[0, 0, r, r : r + 3 + 4 * r] = 0.5  # one run of growing length
    assert image_spans(mask, (1, 40, w))[0].tolist() == walk(mask[0, 0])


def test_more_runs_than_the_first_buffer_holds():
    """Every other pixel on: 2000 runs per row, more than the 4·H + 1024 first guess."""
    mask = torch.zeros(1, 1, 3, 4000, dtype=torch.float64)
    mask[..., ::2] = 1.0
    spans = image_spans(mask, (1, 3, 4000))[0]
    assert spans.shape == (6000, 3)
    assert spans.tolist() == walk(mask[0, 0])


def test_a_write_without_version_bump_is_seen_by_the_next_call():
    """Nothing is kept across calls: a NumPy write (no version bump) between two calls."""
    mask = torch.zeros(1, 1, 4, 20)
    assert image_spans(mask, (1, 4, 20))[0].numel() == 0
    mask.numpy()[0, 0, 2, 5:9] = 1.0
    assert image_spans(mask, (1, 4, 20))[0].tolist() == [[2, 5, 9]]


def test_runs_are_shared_within_one_call_and_rebuilt_after_a_write():
    mask = torch.zeros(1, 1, 4, 20)
    mask[0, 0, 1, 3:6] = 1.0
    with memo_scope():
        first = image_spans(mask, (1, 4, 20))
        assert image_spans(mask, (1, 4, 20)) is first  # one scan per call
        mask[0, 0, 3, :2] = 1.0  # in place: a new version
        again = image_spans(mask, (1, 4, 20))
    assert again is not first
    assert again[0].tolist() == [[1, 3, 6], [3, 0, 2]]


def test_a_sealed_mask_scans_once_across_calls(monkeypatch):
    """Under a seal the runs are memoised across operator calls (one scan for the seal's
    life, counted on the C scan), equal to the walk; once the seal ends, a mask changed
    since is scanned anew (the runs kept under the seal are not served)."""
    import sssbench.ops._stencil as stencil
    from sssbench._memo import sealed

    scans = []
    real = stencil._scan
    monkeypatch.setattr(stencil, "_scan", lambda *a: scans.append(a) or real(*a))
    mask = torch.zeros(2, 1, 5, 21)
    mask[0, 0, 1, 3:9] = 1.0
    mask[1, 0, 4, 20] = 0.5
    with sealed({"mask": mask}):
        for _ in range(3):
            with memo_scope():  # a new operator call each time
                runs = image_spans(mask, (2, 5, 21))
        assert len(scans) == 2  # one per image, once
        assert [r.tolist() for r in runs] == [walk(mask[0, 0]), walk(mask[1, 0])]
    mask[0, 0, 2, :4] = 1.0  # after the seal: an ordinary tensor again
    with memo_scope():
        runs = image_spans(mask, (2, 5, 21))
    assert len(scans) == 4
    assert runs[0].tolist() == [[1, 3, 9], [2, 0, 4]]


@pytest.mark.parametrize("how", ["numpy", "inplace"])
def test_a_write_to_a_sealed_mask_is_never_served_stale(how):
    """A write to a sealed mask raises ``SealBroken``: at the next lookup when torch counts
    it (in place), else at the seal's verification (a NumPy write); runs served in between
    are the memo's, and the run that read them is invalid by the seal's contract."""
    from sssbench._memo import SealBroken, sealed

    mask = torch.zeros(1, 1, 4, 20)
    mask[0, 0, 0, 2:5] = 1.0
    with pytest.raises(SealBroken):
        with sealed({"mask": mask}):
            with memo_scope():
                assert image_spans(mask, (1, 4, 20))[0].tolist() == [[0, 2, 5]]
            if how == "numpy":
                mask.numpy()[0, 0, 3, :2] = 1.0
            else:
                mask[0, 0, 3, :2] = 1.0
            with memo_scope():
                image_spans(mask, (1, 4, 20))
    with memo_scope():  # the seal is over: the write is seen
        assert image_spans(mask, (1, 4, 20))[0].tolist() == [[0, 2, 5], [3, 0, 2]]

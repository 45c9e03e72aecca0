"""The native loop's stencil runs, rebuilt from the mask by a C scan on every call.

Checked against a Python walk over the mask (``mask > 0`` pixel by pixel, the definition):
rows whose length straddles the scan's block of 16 (float32) / 8 (float64) pixels, NaN,
-0.0 and negative values (none of them > 0), and more runs than the first buffer holds. A
write that bumps no version counter is seen by the next call (nothing is kept across calls).
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

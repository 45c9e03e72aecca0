"""The flat model's FFT convolution (``budget._flat``) on its 5-smooth grid: the values of a
direct (slow, per-pixel) convolution to float64 rounding, the grid the smallest 5-smooth
one, and the source spectrum's memo giving the bits of a cold computation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sssbench import _memo
from sssbench.score import budget


def _direct(ker: torch.Tensor, e: torch.Tensor, m: torch.Tensor, k: int) -> torch.Tensor:
    """:func:`budget.flat_convolution`'s definition summed pixel by pixel (numpy): neighbours
    ``(i + u - k, j + v - k)`` clamped to the image, weighted by the cells ``ker[c, u, v]`` and
    by the mask's support; ``S · Σ s E w / Σ s w`` lerped by the mask, copied where it is 0."""
    kc, ec, mc = ker.numpy(), e[0].numpy(), m[0, 0].numpy()
    _, h, w = ec.shape
    s = (mc > 0).astype(np.float64)
    out = ec.copy()
    for c in range(3):
        for i in range(h):
            for j in range(w):
                num = den = 0.0
                for u in range(2 * k + 1):
                    for v in range(2 * k + 1):
                        y = min(max(i + u - k, 0), h - 1)
                        x = min(max(j + v - k, 0), w - 1)
                        num += kc[c, u, v] * s[y, x] * ec[c, y, x]
                        den += kc[c, u, v] * s[y, x]
                if mc[i, j] > 0:
                    val = kc[c].sum() * num / den
                    out[c, i, j] = ec[c, i, j] + mc[i, j] * (val - ec[c, i, j])
    return torch.from_numpy(out)[None]


def _case(h: int, w: int, k: int, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    ker = torch.rand(3, 2 * k + 1, 2 * k + 1, generator=gen, dtype=torch.float64)  # asymmetric
    ker = ker / ker.sum((1, 2), keepdim=True) * torch.tensor([1.0, 0.9, 1.1]).view(3, 1, 1)
    e = torch.rand(1, 3, h, w, generator=gen, dtype=torch.float64) + 0.1
    m = torch.rand(1, 1, h, w, generator=gen, dtype=torch.float64)
    m = torch.where(m < 0.25, torch.zeros_like(m), m)  # holes: neighbours left out
    return ker, e, m


@pytest.mark.parametrize(("h", "w", "k"), [(13, 11, 3), (9, 16, 5), (7, 7, 7)])
def test_flat_is_the_direct_convolution_to_float64_rounding(h, w, k):
    """Grids (19, 17) -> (20, 18), (19, 26) -> (20, 27), (21, 21) -> (24, 24), the source
    replicate-padded to them (more than k on a side, uneven sides). Tolerance: float64's
    eps (2.2e-16) times the FFT's O(log n) growth and the positive sums' conditioning (~1),
    with room: 1e-13 relative."""
    ker, e, m = _case(h, w, k)
    assert budget._fast_shape(h + 2 * k, w + 2 * k) != (h + 2 * k, w + 2 * k)
    got = budget._flat(ker, e, m, k)
    want = _direct(ker, e, m, k)
    assert torch.allclose(got, want, rtol=1e-13, atol=0.0)
    zero = m == 0
    assert torch.equal(got[zero.expand_as(got)], e[zero.expand_as(e)])  # copied bit for bit


def test_fast_shape_is_the_smallest_5_smooth_size():
    def smooth(n: int) -> bool:
        for p in (2, 3, 5):
            while n % p == 0:
                n //= p
        return n == 1

    for n in (1, 7, 19, 554, 778, 912, 1446, 1534):
        fast = budget._fast_shape(n, n)[0]
        assert fast >= n and smooth(fast)
        assert not any(smooth(x) for x in range(n, fast))
    assert budget._fast_shape(912, 554) == (960, 576)


def test_source_spectrum_memo_gives_the_cold_bits():
    """Two kernels of different radii (k = 1 and 2, both on the 45² grid of a 40² image) on
    one light and mask: the second reads the memoised source spectrum and gets the bits it
    gets with the memo emptied, and the direct convolution's values."""
    ker, e, m = _case(40, 40, 2, seed=1)
    small = _case(40, 40, 1, seed=2)[0]
    assert budget._fast_shape(42, 42) == budget._fast_shape(44, 44) == (45, 45)
    _memo._BY_CONTENT.clear()
    budget._flat(small, e, m, 1)
    warm = budget._flat(ker, e.clone(), m.clone(), 2)
    _memo._BY_CONTENT.clear()
    cold = budget._flat(ker, e, m, 2)
    assert torch.equal(warm, cold)
    assert torch.allclose(warm, _direct(ker, e, m, 2), rtol=1e-13, atol=0.0)
    other = e.clone()
    other[0, 0, 5, 5] += 1.0  # a new light: a new spectrum, not a stale one
    assert not torch.equal(budget._flat(ker, other, m, 2), cold)

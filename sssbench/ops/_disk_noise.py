"""A blue-noise rank mask (void-and-cluster, Ulichney 1993) for the disk's per-pixel rotation.

Engines rotate their SSS samples per pixel with a tiled blue-noise texture (HDRP, UE5): its
error is pushed to high spatial frequencies, which the eye and a later blur forgive.
:func:`blue_noise_mask` builds a ``T × T`` toroidal mask with Ulichney's algorithm (Gaussian
energy filter of σ = 1.5 pixels, computed on the torus), deterministic in ``seed``: every rank
``0 … T²−1`` appears once, so ``(rank + ½) / T²`` is a uniform stratified value per pixel.
"""

from __future__ import annotations

from functools import cache

import numpy as np

__all__ = ["blue_noise_mask"]

#: σ of the energy filter in pixels (Ulichney 1993 recommends 1.5)
_SIGMA = 1.5


def _kernel(t: int) -> np.ndarray:
    """Toroidal Gaussian ``exp(−d²/2σ²)`` centred at (0, 0), ``(t, t)``."""
    d = np.minimum(np.arange(t), t - np.arange(t)).astype(np.float64)
    return np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2 * _SIGMA**2))


@cache
def blue_noise_mask(t: int = 32, seed: int = 0) -> np.ndarray:
    """The ``(t, t)`` int64 rank mask (a permutation of ``0 … t²−1``); memoised (a pure
    function of its arguments)."""
    ker = _kernel(t)
    n = t * t

    def energy(pattern: np.ndarray) -> np.ndarray:
        return np.real(np.fft.ifft2(np.fft.fft2(pattern) * np.fft.fft2(ker)))

    def add(e: np.ndarray, i: int, sign: float) -> None:
        e += sign * np.roll(ker, (i // t, i % t), (0, 1))

    rng = np.random.default_rng(seed)
    initial = np.zeros((t, t))
    initial.flat[rng.choice(n, n // 10, replace=False)] = 1.0
    e = energy(initial)
    for _ in range(10 * n):  # relax the initial pattern: move the tightest cluster to the void
        cluster = int(np.argmax(np.where(initial == 1, e, -np.inf)))
        initial.flat[cluster] = 0.0
        add(e, cluster, -1.0)
        void = int(np.argmin(np.where(initial == 0, e, np.inf)))
        initial.flat[void] = 1.0
        add(e, void, 1.0)
        if void == cluster:
            break
    ranks = np.zeros(n, dtype=np.int64)
    ones = int(initial.sum())
    # phase 1: rank the initial ones by removing the tightest cluster
    pattern, e = initial.copy(), energy(initial)
    for rank in range(ones - 1, -1, -1):
        cluster = int(np.argmax(np.where(pattern == 1, e, -np.inf)))
        pattern.flat[cluster] = 0.0
        add(e, cluster, -1.0)
        ranks[cluster] = rank
    # phase 2: fill the largest voids up to half
    pattern, e = initial.copy(), energy(initial)
    for rank in range(ones, n // 2):
        void = int(np.argmin(np.where(pattern == 0, e, np.inf)))
        pattern.flat[void] = 1.0
        add(e, void, 1.0)
        ranks[void] = rank
    # phase 3: the zeros are the minority: fill their tightest clusters
    e = energy(1.0 - pattern)
    for rank in range(n // 2, n):
        cluster = int(np.argmax(np.where(pattern == 0, e, -np.inf)))
        pattern.flat[cluster] = 1.0
        add(e, cluster, -1.0)
        ranks[cluster] = rank
    return ranks.reshape(t, t)

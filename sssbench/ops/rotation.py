"""Seeded per-pixel angles for stochastic kernel rotation (000 §6)."""

from __future__ import annotations

import math

import torch

from sssbench._checks import check_scalar, check_seed
from sssbench.gbuffer import GBuffer
from sssbench.ops.gather import Rotation

__all__ = ["random_rotation", "DEFAULT_ROTATION_RADIUS", "CLOSE_UP_ROTATION_RADIUS"]

#: 000 §6: taps closer than 10% of the kernel size are rotated
DEFAULT_ROTATION_RADIUS = 0.1
#: 000 Fig. 9: 30% for extreme close-ups
CLOSE_UP_ROTATION_RADIUS = 0.3


def random_rotation(
    gbuffer: GBuffer, radius: float = DEFAULT_ROTATION_RADIUS, seed: int = 0
) -> Rotation:
    """Uniform random angles in [0, π) per pixel, reproducible from ``seed``.

    A kernel symmetric about its centre is unchanged by a half turn, so [0, π) covers every
    distinct orientation. Both passes of a method must use the same :class:`Rotation` so that
    the two axes stay perpendicular at each pixel.

    Args:
        gbuffer: gives the shape, dtype and device.
        radius: fraction of the kernel extent within which taps are rotated, in [0, 1].
        seed: integer seed of a dedicated ``torch.Generator`` (same seed, same angles).

    Returns:
        A :class:`~sssbench.ops.gather.Rotation` with angles ``(B, 1, H, W)``.
    """
    radius = check_scalar("radius", radius, 0.0, 1.0)
    seed = check_seed("seed", seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    b, h, w = gbuffer.shape
    angles = torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64) * math.pi
    return Rotation(angles.to(device=gbuffer.device, dtype=gbuffer.dtype), radius)

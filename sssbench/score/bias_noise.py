"""A stochastic method's error over several seeds, split into bias and noise."""

from __future__ import annotations

import torch

from sssbench.score.metrics import rel_rms

__all__ = ["bias_noise"]


def bias_noise(
    images: list[torch.Tensor], reference: torch.Tensor, mask: torch.Tensor | None = None
) -> dict[str, float]:
    """A stochastic method's error over ``K = len(images)`` seeds, split into bias and noise.

    All relative to the reference's RMS over the mask (as :func:`sssbench.score.metrics.rel_rms`),
    per image of the batch, then averaged over it:

    - ``rel_rms``: the mean over seeds of each seed's rel RMS error;
    - ``noise_rel_rms``: the RMS over pixels and channels of the standard deviation across
      seeds (unbiased, ``K − 1``), i.e. one frame's noise;
    - ``bias_rel_rms``: the rel RMS error of the seed mean, whose square still holds
      ``noise² / K`` of averaged noise, removed: ``√max(err(mean)² − noise² / K, 0)``
      (unbiased for ``bias²``; clamped at 0 when the noise hides the bias).

    For a large image each seed's squared error is ``≈ bias² + noise²``.

    Args:
        images: ``K >= 2`` results ``(B, 3, H, W)`` of the same method with different seeds.
        reference: ``(B, 3, H, W)``.
        mask: ``(B, 1, H, W)`` region (> 0) or ``None`` for all pixels.

    Returns:
        ``{"rel_rms", "bias_rel_rms", "noise_rel_rms", "seeds"}``.
    """
    if len(images) < 2:
        raise ValueError(f"images must hold >= 2 seeds' results, got {len(images)}")
    k = len(images)
    stack = torch.stack([im.double() for im in images])  # (K, B, C, H, W)
    ref = reference.double()
    m = None if mask is None else (mask > 0).double()

    def mean_px(v: torch.Tensor) -> torch.Tensor:  # (B, C, H, W) -> (B,), over the mask
        if m is None:
            return v.flatten(1).mean(1)
        return (v * m).flatten(1).sum(1) / (m.flatten(1).sum(1) * v.shape[1])

    ref_rms = mean_px(ref**2).sqrt()
    noise = mean_px(stack.var(0)).sqrt() / ref_rms
    err_mean = mean_px((stack.mean(0) - ref) ** 2).sqrt() / ref_rms
    bias = (err_mean**2 - noise**2 / k).clamp_min(0.0).sqrt()
    per_seed = [rel_rms(im, ref, None if m is None else m) for im in stack]
    return {
        "rel_rms": sum(per_seed) / k,
        "bias_rel_rms": float(bias.mean()),
        "noise_rel_rms": float(noise.mean()),
        "seeds": k,
    }

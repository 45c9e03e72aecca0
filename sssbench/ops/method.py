"""The base of every separable method: the options all of them share (DESIGN §4).

A method = a kernel (built once) + a schedule of :func:`~sssbench.ops.separable_pass` calls.
What every method accepts the same way lives here once: stochastic rotation (000 §6, one
seeded :class:`Rotation` for all passes of a call), follow-surface, and the per-call inputs of
the pipeline's options — a per-pixel width multiplier (curvature modulation, 004 §3.3.3) and a
bilateral ``guide`` + ``sample_weight`` (halo reduction, 004 §3.3).
"""

from __future__ import annotations

import torch
from torch import nn

from sssbench.gbuffer import GBuffer
from sssbench.ops.gather import SampleWeight
from sssbench.ops.rotation import random_rotation

__all__ = ["SeparableMethod"]


class SeparableMethod(nn.Module):
    """Base class: subclasses set the attributes below in ``__init__`` and implement
    :meth:`scatter`.

    Attributes:
        follow_surface: ``None``, ``"lerp"`` or ``"gaussian"`` (see ``separable_pass``).
        surface_scale: mm (float or per-channel ``(3,)``), used with ``follow_surface``.
        rotation: stochastic rotation radius fraction, or ``None``.
        seed: rotation seed.
    """

    needs: tuple[str, ...] = ("mask",)
    follow_surface: str | None = None
    surface_scale: float | torch.Tensor | None = None
    rotation: float | None = None
    seed: int = 0

    def pass_options(
        self,
        gbuffer: GBuffer,
        width: torch.Tensor | None = None,
        guide: torch.Tensor | None = None,
        sample_weight: SampleWeight | None = None,
    ) -> dict[str, object]:
        """Keyword arguments for every ``separable_pass`` of one call."""
        if not isinstance(gbuffer, GBuffer):
            raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
        rot = None if self.rotation is None else random_rotation(gbuffer, self.rotation, self.seed)
        return dict(
            follow_surface=self.follow_surface,
            surface_scale=self.surface_scale,
            rotation=rot,
            width=1.0 if width is None else width,
            guide=guide,
            sample_weight=sample_weight,
            check_finite=False,  # gbuffer.diffuse was validated; later images are pass outputs
        )

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        """The method's pass schedule over ``gbuffer.diffuse`` with ``options``."""
        raise NotImplementedError

    def forward(
        self,
        gbuffer: GBuffer,
        *,
        width: torch.Tensor | None = None,
        guide: torch.Tensor | None = None,
        sample_weight: SampleWeight | None = None,
    ) -> torch.Tensor:
        """Scattered diffuse ``(B, 3, H, W)``.

        Args:
            gbuffer: the G-buffer.
            width: per-pixel kernel-width multiplier ``(B, 1, H, W)`` (curvature modulation).
            guide: ``(B, G, H, W)`` guide image of ``sample_weight`` (halo reduction).
            sample_weight: bilateral weight function (see ``separable_pass``).
        """
        return self.scatter(gbuffer, self.pass_options(gbuffer, width, guide, sample_weight))

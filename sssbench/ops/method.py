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

from sssbench._checks import check_choice, check_scalar
from sssbench._memo import memo_scope
from sssbench.gbuffer import GBuffer
from sssbench.ops._repr import options_repr
from sssbench.ops.gather import FOLLOW_SURFACE, SampleWeight, check_writable
from sssbench.ops.rotation import random_rotation

__all__ = ["SeparableMethod"]

#: G-buffer fields a method may read while it overwrites ``diffuse`` in place
_READ_FIELDS = ("depth", "mask", "albedo", "specular", "normal", "thickness", "light_dir")


class SeparableMethod(nn.Module):
    """Base class: subclasses set the attributes below in ``__init__`` and implement
    :meth:`scatter`.

    Attributes:
        scatters_in_place: the schedule can overwrite its input image pass after pass (a
            horizontal then a vertical pass): with ``forward(inplace=True)`` it then writes
            only the stencil's pixels. Others compute as usual and copy their result in.
        follow_surface: ``None``, ``"lerp"`` or ``"gaussian"`` (see ``separable_pass``).
        surface_scale: mm (float or per-channel ``(3,)``), used with ``follow_surface``.
        rotation: stochastic rotation radius fraction, or ``None``.
        seed: rotation seed.
    """

    extra_repr = options_repr

    needs: tuple[str, ...] = ("mask",)
    #: why the method cannot take a ``sample_weight`` (halo reduction), or ``None`` when it can:
    #: :meth:`pass_options` then refuses one with this reason
    no_sample_weight: str | None = None
    scatters_in_place: bool = False
    follow_surface: str | None = None
    surface_scale: float | torch.Tensor | None = None
    rotation: float | None = None
    seed: int = 0

    def set_options(
        self,
        follow_surface: str | None,
        surface_scale: float | None,
        rotation: float | None,
        seed: int,
        *,
        default_scale: float | torch.Tensor,
    ) -> None:
        """Validate and store the shared options (subclasses call this in ``__init__``).

        Args:
            follow_surface: ``None``, ``"lerp"`` or ``"gaussian"``.
            surface_scale: mm, > 0, or ``None`` for ``default_scale`` (the method's own
                material scale, e.g. the profile's widest length or σ_max of 000 eq. 7).
            rotation: radius fraction in [0, 1] or ``None``.
            seed: rotation seed.
            default_scale: see ``surface_scale``.
        """
        check_choice("follow_surface", follow_surface, FOLLOW_SURFACE)
        if rotation is not None:
            check_scalar("rotation", rotation, 0.0, 1.0)
        self.follow_surface = follow_surface
        self.surface_scale = (
            default_scale
            if surface_scale is None
            else check_scalar("surface_scale", surface_scale, 0.0, low_inclusive=False)
        )
        self.rotation = rotation
        self.seed = seed

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
        if sample_weight is not None and self.no_sample_weight is not None:
            raise ValueError(f"sample_weight (halo reduction) {self.no_sample_weight}")
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
        inplace: bool = False,
    ) -> torch.Tensor:
        """Scattered diffuse ``(B, 3, H, W)``.

        Args:
            gbuffer: the G-buffer.
            width: per-pixel kernel-width multiplier ``(B, 1, H, W)`` (curvature modulation).
            guide: ``(B, G, H, W)`` guide image of ``sample_weight`` (halo reduction).
            sample_weight: bilateral weight function (see ``separable_pass``).
            inplace: write the result into ``gbuffer.diffuse`` and return it, as a renderer's
                SSS pass overwrites its lit-diffuse target under the stencil (002 §4, 003
                §7.3.1): a method that :attr:`scatters_in_place` then touches only the
                stencil's pixels and makes no full-image copy, so its time follows the
                covered pixels. ``gbuffer.diffuse`` no longer holds the input afterwards.
                Not with autograd recording ``gbuffer.diffuse``, nor when ``gbuffer.diffuse``
                shares memory with another field, ``width`` or ``guide``, or with itself (an
                expanded view), or is an inference tensor outside inference mode
                (``ValueError`` naming them, :func:`~sssbench.ops.gather.check_writable`).
        """
        if inplace and torch.is_grad_enabled() and gbuffer.diffuse.requires_grad:
            raise ValueError(
                "inplace=True overwrites gbuffer.diffuse, which autograd records (it requires "
                "grad): call without inplace, or under torch.no_grad()"
            )
        if inplace:
            fields = {f"gbuffer.{name}": getattr(gbuffer, name) for name in _READ_FIELDS}
            check_writable("gbuffer.diffuse", gbuffer.diffuse,
                           {**fields, "width": width, "guide": guide})  # fmt: skip
        with memo_scope():  # stencils are verified once per call (sssbench._memo)
            options = self.pass_options(gbuffer, width, guide, sample_weight)
            if inplace and self.scatters_in_place:
                options["inplace"] = True
            out = self.scatter(gbuffer, options)
        if inplace and out is not gbuffer.diffuse:
            out = gbuffer.diffuse.copy_(out)
        return out

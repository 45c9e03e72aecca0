"""The do-nothing baseline: the diffuse image unchanged, zero passes.

Every ranking of SSS methods needs the answer to "is this better than not blurring at all?"
(a method whose error exceeds the unblurred input's is worse than doing nothing). The
baseline is an operator like the others so the pipeline, the run store and the reports treat
it as one more method: it records no pass (its cost is zero) and scores the input's error.
"""

from __future__ import annotations

import torch
from torch import nn

from sssbench.gbuffer import GBuffer
from sssbench.ops._repr import options_repr
from sssbench.profiles.base import Profile

__all__ = ["IdentitySSS"]


class IdentitySSS(nn.Module):
    """Subsurface scattering left out: ``forward(gbuffer) = gbuffer.diffuse``.

    The call signature is the methods' (:class:`~sssbench.ops.SeparableMethod`), so
    ``Pipeline(IdentitySSS())`` runs with every option (curvature width, halo weights,
    ``inplace``), all of which it ignores; it runs no :func:`~sssbench.ops.separable_pass`,
    so a pipeline records no SSS pass for it.

    Args:
        profile: accepted and ignored, so the app can build it like the methods built from
            the run's profile (``IdentitySSS(profile)``); ``None`` or a
            :class:`~sssbench.profiles.Profile`.

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``, the tensor ``gbuffer.diffuse`` itself (no copy:
          doing nothing costs nothing; do not modify the result in place if the G-buffer is
          still needed).

    Example:
        >>> g = GBuffer(torch.rand(1, 3, 4, 4), torch.full((1, 1, 4, 4), 300.0), 0.4)
        >>> IdentitySSS()(g) is g.diffuse
        True
    """

    extra_repr = options_repr

    #: G-buffer fields the operator reads (none beyond diffuse)
    needs: tuple[str, ...] = ()

    def __init__(self, profile: Profile | None = None) -> None:
        super().__init__()
        if profile is not None and not isinstance(profile, Profile):
            raise TypeError(
                f"profile must be a sssbench Profile or None, got {type(profile).__name__}"
            )
        self.profile = profile

    def forward(self, gbuffer: GBuffer, **options: object) -> torch.Tensor:
        """``gbuffer.diffuse`` unchanged; ``options`` (a method's ``width``, ``guide``,
        ``sample_weight``, ``inplace``) are accepted and ignored."""
        if not isinstance(gbuffer, GBuffer):
            raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
        return gbuffer.diffuse

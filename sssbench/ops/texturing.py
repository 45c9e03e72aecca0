"""Texturing modes: where the diffuse colour map enters relative to the blur (001 §5.3).

- ``"pre"``: pre-scatter texturing, scatter ``albedo · E`` (the colour bleeds with the light;
  003 and 002 blur the textured diffuse buffer);
- ``"post"``: post-scatter texturing, scatter ``E`` then multiply by ``albedo`` (keeps texture
  detail sharp);
- ``"sqrt"``: 001 §5.3 after Weyrich et al.: the colour map is a thin absorbing layer crossed
  once on entry and once on exit, ``√albedo · scatter(√albedo · E)`` ("two absorptions of
  √diffuseColor give the desired skin tone").

On an unblurred pixel all three give ``albedo · E``. Specular is added after scattering and
texturing (001 §5.4: ``Image += sum of specular term of lights``), by the pipeline.

The two halves, :func:`texture_before` and :func:`texture_after`, are elementwise and computed
only where ``mask > 0``; the blur method in between never sees the mode, so every method gets
every mode.
"""

from __future__ import annotations

import torch
from torch import nn

from sssbench._checks import check_choice, check_tensor
from sssbench.gbuffer import GBuffer
from sssbench.ops._repr import options_repr
from sssbench.ops._stencil import active_pixels, apply_on_active
from sssbench.ops.timing import timed_pass

__all__ = ["TEXTURING_MODES", "Texturing", "texture_before", "texture_after"]

TEXTURING_MODES = ("pre", "post", "sqrt")


def _factor(albedo: torch.Tensor, mode: str, before: bool) -> torch.Tensor | None:
    """The albedo factor applied on one side of the blur, or ``None`` for none."""
    if mode == "sqrt":
        return albedo.sqrt()  # 001 §5.3: √albedo on entry and on exit
    if (mode == "pre") == before:
        return albedo
    return None


def _check(image: torch.Tensor, gbuffer: GBuffer, mode: str) -> None:
    check_choice("mode", mode, TEXTURING_MODES)
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    check_tensor("image", image, ndim=4, channels=3)
    if image.shape != gbuffer.diffuse.shape:
        raise ValueError(
            f"image must have the G-buffer's shape {tuple(gbuffer.diffuse.shape)}, "
            f"got {tuple(image.shape)}"
        )
    if gbuffer.albedo is None:
        raise ValueError("texturing needs gbuffer.albedo (B, 3, H, W), got None")


def _apply(image: torch.Tensor, gbuffer: GBuffer, factor: torch.Tensor | None) -> torch.Tensor:
    if factor is None:
        return image
    active = active_pixels(gbuffer.mask, gbuffer.depth.numel())
    return apply_on_active(lambda x, a: x * a, image, [image, factor], active)


def texture_before(image: torch.Tensor, gbuffer: GBuffer, mode: str) -> torch.Tensor:
    """The texturing applied before the blur: ``albedo·E`` (pre), ``E`` (post),
    ``√albedo·E`` (sqrt) (001 §5.3), where ``mask > 0``.

    Args:
        image: ``(B, 3, H, W)`` irradiance to be scattered.
        gbuffer: supplies ``albedo`` (required) and ``mask`` (stencil).
        mode: ``"pre"``, ``"post"`` or ``"sqrt"``.

    Returns:
        ``(B, 3, H, W)``; pixels with ``mask == 0`` are ``image``.

    Shape:
        - image, output: ``(B, 3, H, W)``

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 2, 2), torch.ones(1, 1, 2, 2), 0.5,
        ...             albedo=torch.full((1, 3, 2, 2), 0.25))
        >>> texture_before(g.diffuse, g, "sqrt")[0, :, 0, 0].tolist()
        [0.5, 0.5, 0.5]
    """
    _check(image, gbuffer, mode)
    return _apply(image, gbuffer, _factor(gbuffer.albedo, mode, before=True))


def texture_after(image: torch.Tensor, gbuffer: GBuffer, mode: str) -> torch.Tensor:
    """The texturing applied after the blur: identity (pre), ``× albedo`` (post),
    ``× √albedo`` (sqrt) (001 §5.3), where ``mask > 0``.

    Args:
        image: ``(B, 3, H, W)`` scattered radiance.
        gbuffer: supplies ``albedo`` (required) and ``mask`` (stencil).
        mode: ``"pre"``, ``"post"`` or ``"sqrt"``.

    Returns:
        ``(B, 3, H, W)``; pixels with ``mask == 0`` are ``image``.

    Shape:
        - image, output: ``(B, 3, H, W)``

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 2, 2), torch.ones(1, 1, 2, 2), 0.5,
        ...             albedo=torch.full((1, 3, 2, 2), 0.25))
        >>> texture_after(texture_before(g.diffuse, g, "sqrt"), g, "sqrt")[0, 0, 0, 0].item()
        0.25
    """
    _check(image, gbuffer, mode)
    return _apply(image, gbuffer, _factor(gbuffer.albedo, mode, before=False))


class Texturing(nn.Module):
    """The two halves of a texturing mode as a module; each half that does work records a pass
    (``texturing.before`` / ``texturing.after``, 1 sample, the stencilled pixel count).

    Args:
        mode: ``"pre"``, ``"post"`` or ``"sqrt"`` (001 §5.3).

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 2, 2), torch.ones(1, 1, 2, 2), 0.5,
        ...             albedo=torch.full((1, 3, 2, 2), 0.25))
        >>> t = Texturing("post")
        >>> t.after(t.before(g.diffuse, g), g)[0, 0, 0, 0].item()
        0.25
    """

    extra_repr = options_repr

    needs = ("albedo", "mask")

    def __init__(self, mode: str = "post") -> None:
        super().__init__()
        check_choice("mode", mode, TEXTURING_MODES)
        self.mode = mode

    def _timed(self, side: str, image: torch.Tensor, gbuffer: GBuffer) -> torch.Tensor:
        before = side == "before"
        _check(image, gbuffer, self.mode)
        factor = _factor(gbuffer.albedo, self.mode, before)
        if factor is None:
            return image
        n = gbuffer.depth.numel() if gbuffer.mask is None else int((gbuffer.mask > 0).sum())
        with timed_pass(f"texturing.{side}", 1, n):
            return _apply(image, gbuffer, factor)

    def runs(self, side: str) -> bool:
        """Whether ``side`` (``"before"`` / ``"after"``) does any work in this mode."""
        check_choice("side", side, ("before", "after"))
        return self.mode == "sqrt" or (self.mode == "pre") == (side == "before")

    def before(self, image: torch.Tensor, gbuffer: GBuffer) -> torch.Tensor:
        """:func:`texture_before`, timed."""
        return self._timed("before", image, gbuffer)

    def after(self, image: torch.Tensor, gbuffer: GBuffer) -> torch.Tensor:
        """:func:`texture_after`, timed."""
        return self._timed("after", image, gbuffer)

    def forward(self, image: torch.Tensor, gbuffer: GBuffer) -> torch.Tensor:
        """Both halves without a blur in between: ``albedo · image`` where ``mask > 0``."""
        return self.after(self.before(image, gbuffer), gbuffer)

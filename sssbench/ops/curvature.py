"""Screen-space curvature and curvature modulation of the kernel width (004 §3.3.3).

004 computes the curvature "in screen space, using the normals of the neighbouring pixels, to
obtain the oriented gradient in each x and y axis", smooths it by mean blurring, and modulates
the scattering with it in three ways; here the modulation is a per-pixel multiplier of the
kernel width, passed as ``width=`` to :func:`~sssbench.ops.separable_pass`.

Curvature (1/mm): the view-space normal map's spatial gradient
(:func:`kornia.filters.spatial_gradient`, central differences, per pixel) divided by the pixel
footprint ``2 z tan(fov_y/2)/H`` mm (DESIGN §2). Two readings (a documented choice; 004 only
says "the magnitude of the variation"):

- ``"divergence"`` (default): ``κ = ½ (∂n_x/∂x + ∂n_y/∂y)``, the screen-projected mean
  curvature: exactly ``1/R`` on a sphere seen orthographically, anywhere inside its silhouette
  (positive on convex shapes, negative on concave ones; the modulation uses ``|κ|``);
- ``"magnitude"``: ``κ = ½ (‖∂n/∂x‖ + ‖∂n/∂y‖)``, what 004 describes; on a sphere it grows like
  ``1/(R cos θ)`` toward the contour, the effect 004 reports ("the screen space curvature is
  higher at the contours").

Differences across a depth discontinuity do not measure a surface: pixels whose neighbour
differs in depth by more than ``edge_ratio`` footprints are treated as flat before smoothing,
and pixels with ``mask == 0`` do not contribute to the smoothed value of their neighbours.
"""

from __future__ import annotations

import kornia
import torch
from torch import nn

from sssbench._checks import check_choice, check_int, check_magnitude, check_scalar
from sssbench.gbuffer import GBuffer, pixel_size_mm
from sssbench.ops._repr import options_repr
from sssbench.ops.timing import timed_pass

__all__ = [
    "CURVATURE_MODES",
    "CURVATURE_STRATEGIES",
    "screen_space_curvature",
    "curvature_width",
    "CurvatureModulation",
]

CURVATURE_MODES = ("divergence", "magnitude")
#: 004 §3.3.3, in its order: increase with curvature; reduce at low curvature; reduce at low
#: curvature down to a minimum
CURVATURE_STRATEGIES = ("increase", "reduce", "reduce_min")
#: largest box-filter side (pixels): the filter allocates ``smooth²`` weights
MAX_SMOOTH = 1025


def _check_curvature_options(mode: str, smooth: int, edge_ratio: float) -> tuple[int, float]:
    """Validated ``(smooth, edge_ratio)`` of :func:`screen_space_curvature`."""
    check_choice("mode", mode, CURVATURE_MODES)
    smooth = check_int("smooth", smooth, 1, MAX_SMOOTH)
    if smooth % 2 == 0:
        raise ValueError(f"smooth must be odd (a centred box filter), got {smooth}")
    return smooth, check_magnitude("edge_ratio", edge_ratio, "factor")


def _check_width_options(
    strategy: str, reference: float, gain: float, minimum: float
) -> tuple[float, float, float]:
    """Validated ``(reference, gain, minimum)`` of :func:`curvature_width`."""
    check_choice("strategy", strategy, CURVATURE_STRATEGIES)
    return (
        check_magnitude("reference", reference, "coefficient"),
        check_magnitude("gain", gain, "factor", zero=True),
        check_scalar("minimum", minimum, 0.0, 1.0),
    )


def screen_space_curvature(
    gbuffer: GBuffer,
    *,
    mode: str = "divergence",
    smooth: int = 5,
    edge_ratio: float = 4.0,
) -> torch.Tensor:
    """Screen-space curvature of the normal map in 1/mm (004 §3.3.3).

    Args:
        gbuffer: needs ``normal`` (view space, +z toward the camera), ``depth``, ``fov_y``;
            uses ``mask``.
        mode: ``"divergence"`` (signed mean curvature) or ``"magnitude"`` (004's magnitude of
            the normal variation, >= 0), see the module docstring.
        smooth: side of the mean (box) filter in pixels, odd, in [1, MAX_SMOOTH] (1 = no
            smoothing); 004 smooths to avoid high-frequency discontinuities.
        edge_ratio: a neighbour more than ``edge_ratio`` pixel footprints away in depth is
            across a silhouette; the gradient there is set to 0.

    Returns:
        ``(B, 1, H, W)`` curvature in 1/mm (0 where ``mask == 0``).

    Shape:
        - output: ``(B, 1, H, W)``

    Example:
        >>> from data_synth import make_scene
        >>> g = make_scene("sphere", (64, 64), dtype=torch.float64, radius=70.0)
        >>> k = screen_space_curvature(g)
        >>> round(float(k[0, 0, 32, 32]) * 70.0, 1)
        1.0
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if gbuffer.normal is None:
        raise ValueError("curvature needs gbuffer.normal (B, 3, H, W), got None")
    smooth, edge_ratio = _check_curvature_options(mode, smooth, edge_ratio)

    _, h, _ = gbuffer.shape
    foot = pixel_size_mm(gbuffer.depth, gbuffer.fov_y, h)  # mm per pixel
    # (B, 3, 2, H, W): ∂/∂col, ∂/∂row per normal component, per pixel (normalized: unit slope
    # answers 1); replicate border
    grad = kornia.filters.spatial_gradient(gbuffer.normal, mode="diff", order=1, normalized=True)
    dz = kornia.filters.spatial_gradient(gbuffer.depth, mode="diff", order=1, normalized=True)
    surface = (dz[:, 0].abs() <= edge_ratio * foot).to(foot.dtype)  # (B, 2, H, W), per axis
    grad = grad * surface[:, None]
    if mode == "divergence":
        # rows grow downward, view-space y upward: ∂n_y/∂y = −∂n_y/∂row
        kappa = 0.5 * (grad[:, 0:1, 0] - grad[:, 1:2, 1]) / foot
    else:
        mag = grad.norm(dim=1)  # (B, 2, H, W): ‖∂n/∂col‖, ‖∂n/∂row‖
        kappa = 0.5 * mag.sum(1, keepdim=True) / foot
    weight = gbuffer.mask_or_ones().gt(0).to(kappa.dtype)
    kappa = kappa * weight
    if smooth > 1:  # 004 §3.3.3: mean blurring, normalised over the stencil
        num = kornia.filters.box_blur(kappa, smooth, border_type="replicate")
        den = kornia.filters.box_blur(weight, smooth, border_type="replicate")
        kappa = torch.where(weight > 0, num / den.clamp_min(1e-12), 0.0)
    return kappa


def curvature_width(
    curvature: torch.Tensor,
    strategy: str = "reduce_min",
    *,
    reference: float = 0.05,
    gain: float = 1.0,
    minimum: float = 0.5,
) -> torch.Tensor:
    """Per-pixel kernel-width multiplier from curvature (004 §3.3.3's three strategies).

    With the normalised curvature ``c = clamp(|κ| / reference, 0, 1)``:

    - ``"increase"``: ``1 + gain · c`` (wider where curved; 004: poor, it widens contours);
    - ``"reduce"``: ``c`` (unchanged at high curvature, no scattering at zero curvature; 004:
      breaks flat skin);
    - ``"reduce_min"``: ``minimum + (1 − minimum) c`` (004: the good one).

    Args:
        curvature: ``(B, 1, H, W)`` in 1/mm (:func:`screen_space_curvature`).
        strategy: one of :data:`CURVATURE_STRATEGIES`.
        reference: curvature (1/mm, > 0) that counts as "high": ``1/reference`` is the radius
            (mm) from which the width is no longer reduced (default 0.05 ↔ 20 mm, a nose).
        gain: extra width at high curvature for ``"increase"`` (>= 0).
        minimum: floor in [0, 1] for ``"reduce_min"``.

    Returns:
        ``(B, 1, H, W)`` multiplier >= 0.

    Example:
        >>> curvature_width(torch.tensor([0.0, 0.025, 1.0]).view(1, 1, 1, 3)).flatten().tolist()
        [0.5, 0.75, 1.0]
    """
    reference, gain, minimum = _check_width_options(strategy, reference, gain, minimum)
    c = (curvature.abs() / reference).clamp(0.0, 1.0)
    if strategy == "increase":
        return 1.0 + gain * c
    if strategy == "reduce":
        return c
    return minimum + (1.0 - minimum) * c


class CurvatureModulation(nn.Module):
    """Curvature → kernel-width multiplier (004 §3.3.3), ``forward(gbuffer) -> (B, 1, H, W)``;
    records one pass ``curvature`` (the gradient stencil plus the ``smooth``² box).

    Args:
        strategy: ``"increase"``, ``"reduce"`` or ``"reduce_min"`` (:func:`curvature_width`).
        reference: curvature (1/mm) that counts as high.
        gain: for ``"increase"``.
        minimum: for ``"reduce_min"``.
        mode: ``"divergence"`` or ``"magnitude"`` (:func:`screen_space_curvature`).
        smooth: box-filter side in pixels (odd).

    Example:
        >>> from data_synth import make_scene
        >>> g = make_scene("sphere", (32, 32), dtype=torch.float64)
        >>> CurvatureModulation("reduce_min")(g).shape
        torch.Size([1, 1, 32, 32])
    """

    extra_repr = options_repr

    needs = ("normal", "mask")

    def __init__(
        self,
        strategy: str = "reduce_min",
        *,
        reference: float = 0.05,
        gain: float = 1.0,
        minimum: float = 0.5,
        mode: str = "divergence",
        smooth: int = 5,
    ) -> None:
        super().__init__()
        self.reference, self.gain, self.minimum = _check_width_options(
            strategy, reference, gain, minimum
        )
        self.smooth, _ = _check_curvature_options(mode, smooth, 4.0)
        self.strategy = strategy
        self.mode = mode

    def forward(self, gbuffer: GBuffer) -> torch.Tensor:
        b, h, w = gbuffer.shape
        with timed_pass("curvature", 4 + self.smooth**2, b * h * w):
            kappa = screen_space_curvature(gbuffer, mode=self.mode, smooth=self.smooth)
            return curvature_width(
                kappa, self.strategy, reference=self.reference, gain=self.gain, minimum=self.minimum
            )

"""``Kernel1D``: a discretised 1D kernel as data (DESIGN §3)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from sssbench._checks import check_magnitude, check_tensor

__all__ = ["Kernel1D"]


@dataclass(frozen=True)
class Kernel1D:
    """Taps of a 1D convolution kernel.

    Args:
        offsets: ``(K,)`` tap positions in mm, sorted ascending (non-decreasing).
        weights: ``(K, 3)`` per-channel tap weights. Normalised kernels sum to 1 per channel;
            SVD components may carry negative weights.

    A method's kernel is plain data so it can be printed, plotted, saved and compared; the
    gather pass (:func:`sssbench.ops.separable_pass`) turns mm into pixels per pixel.

    Example:
        >>> k = Kernel1D(torch.tensor([-1.0, 0.0, 1.0]), torch.full((3, 3), 1 / 3))
        >>> len(k), k.extent
        (3, 1.0)
    """

    offsets: torch.Tensor
    weights: torch.Tensor

    def __post_init__(self) -> None:
        check_tensor("offsets", self.offsets, ndim=1)
        check_tensor("weights", self.weights, ndim=2)
        k = self.offsets.shape[0]
        if k < 1:
            raise ValueError("offsets must hold at least one tap, got shape (0,)")
        if self.weights.shape != (k, 3):
            raise ValueError(
                f"weights must have shape ({k}, 3) to match offsets, "
                f"got {tuple(self.weights.shape)}"
            )
        if k > 1 and bool((self.offsets[1:] < self.offsets[:-1]).any()):
            raise ValueError(f"offsets must be sorted ascending, got {self.offsets.tolist()}")

    def __len__(self) -> int:
        return int(self.offsets.shape[0])

    @property
    def extent(self) -> float:
        """Largest |offset| in mm."""
        return float(self.offsets.abs().max())

    def sum(self) -> torch.Tensor:
        """Per-channel weight sum, ``(3,)``."""
        return self.weights.sum(0)

    def to(self, dtype: torch.dtype) -> Kernel1D:
        return Kernel1D(self.offsets.to(dtype), self.weights.to(dtype))

    def scaled(self, factor: float) -> Kernel1D:
        """The same taps with offsets multiplied by ``factor`` (in [1e-6, 1e6]), e.g. a width
        in mm."""
        factor = check_magnitude("factor", factor, "factor")
        return Kernel1D(self.offsets * factor, self.weights)

    def as_dict(self) -> dict[str, list]:
        return {"offsets": self.offsets.tolist(), "weights": self.weights.tolist()}

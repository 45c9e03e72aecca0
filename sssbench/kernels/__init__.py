"""Discretisation of profiles into 1D taps (DESIGN §1, second layer)."""

from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.preintegrated import preintegrated, profile_taps
from sssbench.kernels.sampling import MAX_SAMPLES, SAMPLINGS, inverse_cdf, tap_positions

__all__ = [
    "Kernel1D",
    "preintegrated",
    "profile_taps",
    "tap_positions",
    "inverse_cdf",
    "SAMPLINGS",
    "MAX_SAMPLES",
]

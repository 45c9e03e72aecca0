"""Discretisation of profiles into 1D taps (DESIGN §1, second layer)."""

from sssbench.kernels.artist import (
    ARTIST_PRESETS,
    ArtistParams,
    artist,
    artist_preset,
    artist_sigmas,
)
from sssbench.kernels.guided import GuidedFactor, guide_function, guided, guided_factor
from sssbench.kernels.jimenez2012 import JIMENEZ2012_PRESETS, jimenez2012, jimenez2012_preset
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.kernels.low_rank import LowRankKernel, low_rank, reconstruct, singular_energy
from sssbench.kernels.matrix import MAX_MATRIX_SIZE, cell_centres, kernel_matrix
from sssbench.kernels.preintegrated import preintegrated, profile_taps
from sssbench.kernels.sampling import (
    MAX_SAMPLES,
    SAMPLINGS,
    gaussian_mixture_cdf,
    gaussian_mixture_interval,
    interval_weights,
    inverse_cdf,
    tap_positions,
)

__all__ = [
    "Kernel1D",
    "preintegrated",
    "profile_taps",
    "tap_positions",
    "inverse_cdf",
    "SAMPLINGS",
    "MAX_SAMPLES",
    "interval_weights",
    "gaussian_mixture_interval",
    "gaussian_mixture_cdf",
    "kernel_matrix",
    "cell_centres",
    "MAX_MATRIX_SIZE",
    "low_rank",
    "LowRankKernel",
    "reconstruct",
    "singular_energy",
    "artist",
    "artist_preset",
    "artist_sigmas",
    "ArtistParams",
    "ARTIST_PRESETS",
    "jimenez2012",
    "jimenez2012_preset",
    "JIMENEZ2012_PRESETS",
    "guided",
    "guided_factor",
    "guide_function",
    "GuidedFactor",
]

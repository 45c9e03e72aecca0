"""Radial diffusion profiles R(r) per RGB channel (DESIGN §1, first layer)."""

from sssbench.profiles.base import Profile
from sssbench.profiles.burley import BurleyNormalized
from sssbench.profiles.dipole import MATERIALS, Dipole
from sssbench.profiles.empirical import empirical_dipole_fit, empirical_pole_fit
from sssbench.profiles.fit import FitResult, fit_sum_of_gaussians, rel_rms_power
from sssbench.profiles.layers import Layer, compose_layers, fit_powers_of_gaussian
from sssbench.profiles.sum_of_gaussians import SOG_TABLES, SumOfGaussians

__all__ = [
    "Profile",
    "SumOfGaussians",
    "SOG_TABLES",
    "Dipole",
    "MATERIALS",
    "BurleyNormalized",
    "empirical_dipole_fit",
    "empirical_pole_fit",
    "FitResult",
    "fit_sum_of_gaussians",
    "rel_rms_power",
    "Layer",
    "compose_layers",
    "fit_powers_of_gaussian",
]

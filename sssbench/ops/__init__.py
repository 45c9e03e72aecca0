"""Torch operators on a G-buffer (DESIGN §1, third layer): the one gather pass, the
methods built from it, and the extensions (translucency, curvature, halo, texturing)."""

from sssbench.ops import native
from sssbench.ops.artist import ArtistSSS, artist_sss
from sssbench.ops.curvature import (
    CURVATURE_MODES,
    CURVATURE_STRATEGIES,
    CurvatureModulation,
    curvature_width,
    screen_space_curvature,
)
from sssbench.ops.disk import DiskSSS, disk_sss
from sssbench.ops.gather import (
    BACKENDS,
    FOLLOW_SURFACE,
    Rotation,
    Stretch,
    backend,
    get_backend,
    separable_pass,
    separable_sweep,
)
from sssbench.ops.halo import HALO_KINDS, halo_guide, halo_weight, lab_guide, range_weight
from sssbench.ops.identity import IdentitySSS
from sssbench.ops.jimenez2012 import Jimenez2012SSS, jimenez2012_sss
from sssbench.ops.low_rank import LowRankSSS, low_rank_sss
from sssbench.ops.method import SeparableMethod
from sssbench.ops.preintegrated import PreintegratedSSS, preintegrated_sss, two_pass
from sssbench.ops.reference import ReferenceSSS, reference_sss
from sssbench.ops.rotation import random_rotation
from sssbench.ops.sum_of_gaussians import (
    SoGStep,
    SumOfGaussiansSSS,
    blend_weights,
    incremental_variances,
    jg10_stretch,
    sum_of_gaussians_sss,
)
from sssbench.ops.sum_of_gaussians_fused import (
    FusedSumOfGaussiansSSS,
    fused_sum_of_gaussians_sss,
)
from sssbench.ops.texturing import TEXTURING_MODES, Texturing, texture_after, texture_before
from sssbench.ops.timing import PassRecord, record_passes
from sssbench.ops.translucency import (
    TRANSLUCENCY_FORMS,
    Translucency,
    back_light,
    translucency,
    transmittance,
)

__all__ = [
    "DiskSSS",
    "disk_sss",
    "SeparableMethod",
    "separable_pass",
    "separable_sweep",
    "backend",
    "get_backend",
    "BACKENDS",
    "native",
    "Stretch",
    "Rotation",
    "FOLLOW_SURFACE",
    "two_pass",
    "PreintegratedSSS",
    "preintegrated_sss",
    "ArtistSSS",
    "artist_sss",
    "Jimenez2012SSS",
    "jimenez2012_sss",
    "LowRankSSS",
    "low_rank_sss",
    "ReferenceSSS",
    "IdentitySSS",
    "reference_sss",
    "random_rotation",
    "SumOfGaussiansSSS",
    "sum_of_gaussians_sss",
    "blend_weights",
    "incremental_variances",
    "jg10_stretch",
    "SoGStep",
    "FusedSumOfGaussiansSSS",
    "fused_sum_of_gaussians_sss",
    "PassRecord",
    "record_passes",
    "Translucency",
    "translucency",
    "transmittance",
    "back_light",
    "TRANSLUCENCY_FORMS",
    "CurvatureModulation",
    "screen_space_curvature",
    "curvature_width",
    "CURVATURE_MODES",
    "CURVATURE_STRATEGIES",
    "HALO_KINDS",
    "halo_guide",
    "lab_guide",
    "range_weight",
    "halo_weight",
    "Texturing",
    "texture_before",
    "texture_after",
    "TEXTURING_MODES",
]

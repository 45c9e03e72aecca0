"""Torch operators on a G-buffer (DESIGN §1, third layer): the one gather pass and the
methods built from it."""

from sssbench.ops.gather import FOLLOW_SURFACE, Rotation, Stretch, separable_pass
from sssbench.ops.preintegrated import PreintegratedSSS, preintegrated_sss, two_pass
from sssbench.ops.reference import ReferenceSSS, reference_sss
from sssbench.ops.rotation import random_rotation
from sssbench.ops.timing import PassRecord, record_passes

__all__ = [
    "separable_pass",
    "Stretch",
    "Rotation",
    "FOLLOW_SURFACE",
    "two_pass",
    "PreintegratedSSS",
    "preintegrated_sss",
    "ReferenceSSS",
    "reference_sss",
    "random_rotation",
    "PassRecord",
    "record_passes",
]

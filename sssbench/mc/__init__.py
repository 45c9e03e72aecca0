"""Monte Carlo light transport: physical ground truth for the diffusion profiles.

* :mod:`~sssbench.mc.walk` — vectorised random walk in a homogeneous slab or half-space
  (isotropic or Henyey–Greenstein scattering, index-matched or smooth dielectric boundary):
  :func:`total_reflectance`, :func:`slab`, :func:`walk`.
* :mod:`~sssbench.mc.searchlight` — pencil-beam radial profiles of the measured materials
  (:func:`searchlight`), cached on disk.
* :mod:`~sssbench.mc.hfunction` — Chandrasekhar's H-function, the half-space oracle.
* :mod:`~sssbench.mc.boundary` — exact dielectric Fresnel reflectance.

See ``docs/mc.md``.
"""

from sssbench.mc.boundary import fresnel_dielectric, normal_specular
from sssbench.mc.hfunction import h_function, h_function_integral, halfspace_reflectance
from sssbench.mc.searchlight import SearchlightResult, searchlight, searchlight_result
from sssbench.mc.walk import WalkTally, slab, total_reflectance, walk

__all__ = [
    "walk",
    "WalkTally",
    "total_reflectance",
    "slab",
    "searchlight",
    "searchlight_result",
    "SearchlightResult",
    "h_function",
    "h_function_integral",
    "halfspace_reflectance",
    "fresnel_dielectric",
    "normal_specular",
]

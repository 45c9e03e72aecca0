"""Synthetic scenes for sssbench: procedural G-buffers in millimetres (DESIGN §1, §5).

``make_scene(name, resolution, seed, fields=..., dtype=..., **params)`` builds one scene as a
:class:`~sssbench.gbuffer.GBuffer` (:func:`check_scene`: the same checks of its arguments,
no image built); :data:`SCENES` maps each name to its :class:`SceneSpec`
(builder, the optional fields it provides, parameter defaults). Every scene takes ``pixel_mm``,
the skin footprint of one pixel at its focus (:mod:`data_synth.scale`, :data:`SCALES`);
:func:`pixel_footprint_mm` reads it back from a G-buffer.

Modules: :mod:`~data_synth.scenes` (the catalogue and builders), :mod:`~data_synth.render`
(tracing, shading, shadows, thickness), :mod:`~data_synth.geometry` (rays and convex
primitives), :mod:`~data_synth.mc_scenes` (the backlit slab and the scenes' analytic
models for Monte Carlo), :mod:`~data_synth.head` (the ellipsoid head),
:mod:`~data_synth.face` (the implicit face), :mod:`~data_synth.scale` (physical scale),
:mod:`~data_synth.textures` (image textures).
"""

# the Monte Carlo scenes' module registers its builder (backlit_slab) in SCENES; it reads the
# catalogue's helpers, the catalogue never imports it (one direction: mc_scenes -> scenes)
from data_synth import mc_scenes as _mc_scenes  # noqa: E402, F401
from data_synth.face import FACE_PARTS
from data_synth.head import HEAD_HEIGHT_MM, head_object
from data_synth.render import OPTIONAL_FIELDS
from data_synth.scale import SCALES, focus_depth, pixel_footprint_mm
from data_synth.scenes import (
    DEFAULT_FOV_Y,
    DEFAULT_RESOLUTION,
    HEAD_PIXEL_MM,
    HEAD_SCENES,
    RETIRED_SCENES,
    SCENES,
    FaceBuild,
    SceneSpec,
    check_scene,
    face_parts,
    make_scene,
)

__all__ = [
    "DEFAULT_FOV_Y",
    "DEFAULT_RESOLUTION",
    "FACE_PARTS",
    "FaceBuild",
    "HEAD_HEIGHT_MM",
    "HEAD_PIXEL_MM",
    "HEAD_SCENES",
    "OPTIONAL_FIELDS",
    "RETIRED_SCENES",
    "SCALES",
    "SCENES",
    "SceneSpec",
    "check_scene",
    "face_parts",
    "focus_depth",
    "head_object",
    "make_scene",
    "pixel_footprint_mm",
]

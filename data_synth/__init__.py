"""Synthetic scenes for sssbench: procedural G-buffers in millimetres (DESIGN §1, §5).

``make_scene(name, resolution, seed, fields=..., dtype=..., **params)`` builds one scene as a
:class:`~sssbench.gbuffer.GBuffer`; :data:`SCENES` maps each name to its :class:`SceneSpec`
(builder, the optional fields it provides, parameter defaults). Shared ray/solid geometry and
lighting live in :mod:`data_synth.geometry`.
"""

from data_synth.scenes import (
    DEFAULT_FOV_Y,
    DEFAULT_RESOLUTION,
    HEAD_HEIGHT_MM,
    OPTIONAL_FIELDS,
    SCENES,
    SceneSpec,
    head_object,
    make_scene,
)

__all__ = [
    "DEFAULT_FOV_Y",
    "DEFAULT_RESOLUTION",
    "HEAD_HEIGHT_MM",
    "OPTIONAL_FIELDS",
    "SCENES",
    "SceneSpec",
    "head_object",
    "make_scene",
]

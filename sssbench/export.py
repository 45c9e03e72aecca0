"""``sssbench-export-kernel``: a method's 1D kernels as JSON or as HLSL / GLSL arrays.

One module because every format (HLSL, GLSL, JSON, GLSL passes) writes the same kernels and
constants in the same order; the contract a user pastes against is stated once, here.

A separable method's taps (:class:`~sssbench.kernels.Kernel1D`) are what a renderer needs to
reproduce it: this module collects every kernel a method's passes use (:func:`method_kernels`,
each named after its passes), writes them for a shader (:func:`shader_source`) or as JSON
(:func:`kernels_json`, read back exactly by :func:`load_kernels`), and is the console script::

    sssbench-export-kernel method=preintegrated profile=skin_deon6 samples=7 \\
        sampling=importance --format hlsl --out kernel.hlsl

The method is composed exactly as the app composes a run (:func:`sssbench.app.compose_spec`,
:func:`sssbench.run.registry.build_method`), so the defaults are the app's.

Shader conventions (transcribed from the separable SSS shader ``SSSSBlurPS``, 002 appendix,
the shader of ``SeparableSSS.h``):

- one ``float4`` per tap: ``rgb`` the per-channel weight, ``w`` (``.a``) the offset;
- the centre tap (offset 0) comes first: the shader weights the unshifted centre colour by
  ``kernel[0].rgb`` and loops over ``i = 1 .. N-1`` for the shifted taps (the kernel builder of
  ``SeparableSSS.h`` moves the 0 offset to the front the same way); the other taps follow in
  ascending order. A kernel without a centre tap (an even tap count) keeps ascending order and
  says so in the file: such a kernel needs a loop over all taps (004 Fig. 3.6);
- offset units: the shader steps ``kernel[i].a * sssWidth * (distToProjWindow / depth) / 3``
  texture coordinates ("divide by 3 as the kernels range from -3 to 3", 002 appendix). A
  texture coordinate spans the whole projection window, twice its half-height, so a tap lands
  ``w · sssWidth · 2/3`` world units away along the vertical axis (the mapping
  :func:`sssbench.kernels.jimenez2012` documents). The file therefore writes
  ``w = 1.5 · offset_mm / sss_width_mm`` and names the ``sssWidth`` (mm) to set. The default
  ``sss_width_mm``: the 2012 method's own ``width`` (then ``w`` is exactly the 2012 kernel
  builder's offset, range ±2, or ±3 above 20 taps); otherwise half the largest offset in mm,
  so the widest tap sits at ``|w| = 3``, the listing's range. ``--sss-width 1.5`` writes
  ``w`` in mm. If the scene's world unit is not the mm, multiply ``sssWidth`` by the world
  units per mm.

Everything else the measured image depends on (:func:`method_constants`, written by the
command line next to the taps in every format):

- follow-surface: ``#define SSSS_FOLLOW_SURFACE_FACTOR <x>`` (1/mm) **replaces
  ``300.0 * distanceToProjectionWindow * sssWidth``** in ``SeparableSSS.h``'s follow-surface
  line, for **linear depth in mm**: ``s = saturate(SSSS_FOLLOW_SURFACE_FACTOR * abs(depthM -
  depth))``. It is ``1 / surface_scale`` (the method's depth step of full replacement); a depth
  buffer in another unit multiplies it by the mm per depth unit. A per-channel scale (the
  artist model) writes a ``float3`` / ``vec3`` and the lerp becomes per channel (the line's
  ``s`` declared ``float3`` / ``vec3``: the header says so, :func:`_factor_comment`). With
  ``SSSS_FOLLOW_SURFACE 2`` (000 eq. 7, the artist model's default) the factor is ``1 /
  σ_max`` and the tap weight is multiplied by ``exp(-0.5 · (factor · |Δz|)²)`` instead;
- the mask: ``SSSS_STRENGTH_SOURCE`` is the G-buffer mask, 0 = not computed (the stencil,
  002's ``initStencil`` ``discard``), otherwise it multiplies ``finalStep``; and
  ``SSSS_SKIPPED_PIXELS``, the render targets' rule: where a pass computes no pixel its target
  must hold that pass's input (the torch passes leave it there, and the next pass's taps read
  it);
- the JG10 stretch (003 §7.3.1): ``SSSS_STRETCH_SSSLEVEL``, ``_CORRECTION`` (px), ``_MAXDD``
  (mm/px), the step divided by ``depth + correction · min(|∂depth/∂axis|, maxdd)``;
- stochastic rotation (000 §6): ``SSSS_ROTATION_RADIUS``;
- the sum of Gaussians: its pass schedule, the blend factors ``w'`` (``kernel_sog<i>_blend``)
  and the LOD (``SSSS_LOD_THRESHOLD`` px, each step's ``σ`` as ``KERNEL_SOG<i>_SIGMA``, and
  the line that adds it to ``SSSSBlurPS``); the SVD rank-N terms' schedule (in
  ``SSSSBlurPS``: the x pass without the stencil's discard);
- several kernels in one file: the two lines that select one for ``SSSSBlurPS``
  (:func:`_selection_lines`).

Tested where users run them: tests/gl/test_export_gl.py, test_export_hlsl.py and
test_export_schedules.py paste these files into the paper's ``SSSSBlurPS`` (GLSL port; HLSL
through glslang and SPIRV-Cross), follow the header and compare with the torch operator.

``--format glsl-pass`` writes complete GLSL 330 fragment shaders, one per kernel (the pass with
the kernel and these constants baked in, :func:`sssbench.gl.shaders.pass_source`): the very
source the GL backend (:mod:`sssbench.gl`) compiles and runs for the method; several passes are
separated by ``// ==== sssbench pass <name> ====`` lines (:func:`split_passes`).

The JSON file keeps each :class:`Kernel1D` exactly (offsets in the kernel's own unit, and
``unit_mm``, the mm per offset unit: 1 for every method but the 2012 one, whose offsets are in
widths); :func:`load_kernels` reads it back bit for bit.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sssbench import _json
from sssbench._checks import check_choice, check_magnitude
from sssbench.gl.shaders import shader_order
from sssbench.kernels.kernel1d import Kernel1D

__all__ = [
    "FORMATS",
    "NamedKernel",
    "method_kernels",
    "shader_order",
    "shader_source",
    "kernels_json",
    "load_kernels",
    "build_from_overrides",
    "method_constants",
    "Constant",
    "pass_sources",
    "split_passes",
    "main",
]

#: output formats of the console script
FORMATS = ("hlsl", "glsl", "json", "glsl-pass")
#: the line before each pass of a ``glsl-pass`` file
PASS_MARK = "// ==== sssbench pass {name} ===="
#: printf format of every number in the shader arrays: 9 significant digits round-trip a
#: float32 exactly (and leave a float64 within 5e-9 relative)
NUMBER = "%.9g"
#: the shader's kernel range (002 appendix: "the kernels range from -3 to 3")
SHADER_RANGE = 3.0
#: world units per unit of ``w · sssWidth`` (see the module doc: ``/3`` in texture
#: coordinates, which span 2 half-heights of the projection window)
_WORLD_PER_W = 2.0 / 3.0
_JSON_FORMAT = "sssbench-kernels/1"


@dataclass(frozen=True)
class NamedKernel:
    """One kernel of a method, named after the passes that apply it.

    Attributes:
        name: the pass name without its axis (``preintegrated``, ``sog2``) or with it when
            the two axes differ (``low_rank0.x``, ``low_rank0.y``).
        kernel: the taps (offsets in units of ``unit_mm`` mm, weights ``(K, 3)``).
        unit_mm: mm per offset unit (1, or the 2012 method's ``width``).
        extras: per-channel constants the shader needs beside the taps, e.g. the sum of
            Gaussians' blend factor ``w'_i`` (003 §7.3.3) as ``{"blend": [r, g, b]}``.
    """

    name: str
    kernel: Kernel1D
    unit_mm: float = 1.0
    extras: dict[str, list[float]] = field(default_factory=dict)

    @property
    def offsets_mm(self) -> torch.Tensor:
        """``(K,)`` float64 offsets in mm."""
        return self.kernel.offsets.double() * self.unit_mm


# ----------------------------------------------------------------------------- collecting
def method_kernels(method: nn.Module, name: str | None = None) -> list[NamedKernel]:
    """Every 1D kernel the passes of ``method`` apply, in pass order.

    - pre-integrated, artist, 2012 and any other :class:`~sssbench.ops.SeparableMethod`
      whose ``kernel`` is a :class:`Kernel1D`: one kernel, both axes (named after the method);
    - sum of Gaussians: one kernel per blurred Gaussian step ``sog<i>`` (the increment's
      taps, 003 §7.3.3) with its blend factor; the unblurred first step has no pass and no
      kernel;
    - SVD rank-N: per term ``low_rank<i>.x`` (horizontal) and ``low_rank<i>.y`` (vertical).

    Args:
        method: the operator (e.g. from :func:`sssbench.run.registry.build_method`).
        name: the method's name in messages (default: its class name).

    Raises:
        ValueError: a method without separable 1D kernels (the exact reference, the identity,
            the 2D disk), naming it and why.
    """
    from sssbench.ops import Jimenez2012SSS, LowRankSSS, SeparableMethod, SumOfGaussiansSSS

    kind = type(method).__name__
    if isinstance(method, SumOfGaussiansSSS) and method.steps is not None:  # None: not fitted
        return [
            NamedKernel(f"sog{i}", s.kernel, extras={"blend": s.blend.double().tolist()})
            for i, s in enumerate(method.steps)
            if s.kernel is not None
        ]
    if isinstance(method, LowRankSSS):
        out = []
        for i, (h, v) in enumerate(method.kernel.terms):
            out += [NamedKernel(f"low_rank{i}.x", h), NamedKernel(f"low_rank{i}.y", v)]
        return out
    kernel = getattr(method, "kernel", None)
    if isinstance(method, SeparableMethod) and isinstance(kernel, Kernel1D):
        # the 2012 kernel's offsets are in widths; its passes run at width = `width` mm
        unit = float(method.width) if isinstance(method, Jimenez2012SSS) else 1.0
        name = re.sub(r"(?<!^)(?=[A-Z])", "_", kind.removesuffix("SSS")).lower()
        return [NamedKernel(name, kernel, unit)]
    if getattr(method, "sampling", None) == "optimised" and kernel is None:
        raise ValueError(
            f"method {kind} with sampling='optimised' fits its taps at a pixel footprint on "
            "first use: give it one, e.g. +method.params.pixel_mm=0.3"
        )
    why = {
        "ReferenceSSS": "it integrates the full 2D profile per pixel (the exact reference)",
        "IdentitySSS": "it does nothing (the do-nothing baseline)",
        "DiskSSS": "it samples a 2D disk per pixel in one gather pass",
    }.get(kind, "it is not a separable method with Kernel1D taps")
    raise ValueError(
        f"method {name or kind} has no separable kernel to export: {why}; the separable "
        "methods are "
        "preintegrated, sum_of_gaussians, low_rank, artist and jimenez2012"
    )


def default_sss_width(kernels: Sequence[NamedKernel], method: nn.Module | None = None) -> float:
    """The ``sssWidth`` (mm) written by default: the 2012 method's ``width``, else half the
    largest offset in mm, so the widest tap is at ``|w| = 3`` (the shader's range)."""
    from sssbench.ops import Jimenez2012SSS

    if isinstance(method, Jimenez2012SSS):
        return float(method.width)
    extent = max(float(k.offsets_mm.abs().max()) for k in kernels)
    return 1.5 * extent / SHADER_RANGE if extent > 0 else 1.5  # |w| = 1.5 · extent / sssWidth


# ----------------------------------------------------------------------------- writing
def _identifier(name: str, single: bool) -> str:
    return "kernel" if single else "kernel_" + re.sub(r"[^0-9A-Za-z_]", "_", name)


def _num(x: float) -> str:
    return NUMBER % x


def shader_source(
    kernels: Sequence[NamedKernel],
    language: str,
    sss_width_mm: float,
    *,
    header: str = "",
    constants: Sequence[Constant] = (),
) -> str:
    """HLSL or GLSL source: per kernel, ``<N>`` taps as ``float4(r, g, b, w)`` (HLSL
    ``float4 kernel[] = {...};``, as in ``SeparableSSS.h``) or ``vec4`` (GLSL
    ``const vec4 kernel[N] = vec4[N](...);``), centre tap first (:func:`shader_order`), ``w``
    the offset in the shader's units for ``sssWidth = sss_width_mm`` (module doc). One
    kernel is named ``kernel``; several ``kernel_<name>``, each with its ``*_N_SAMPLES``
    define and its extras (``float3`` / ``vec3`` constants). ``constants``
    (:func:`method_constants`) are written after the header as ``#define`` lines with their
    comments."""
    language = str(check_choice("language", language, ("hlsl", "glsl")))
    sss_width_mm = check_magnitude("sss_width_mm", sss_width_mm, "length")
    if not kernels:
        raise ValueError("kernels must hold at least one NamedKernel, got none")
    vec4, vec3 = ("float4", "float3") if language == "hlsl" else ("vec4", "vec3")
    scale = 1.0 / (_WORLD_PER_W * sss_width_mm)  # w per mm
    lines = [f"// {line}" if line else "//" for line in header.splitlines()]
    lines += [
        f"// {len(kernels)} kernel(s); {vec4}(r, g, b, w): per-channel weights and the offset",
        f"// w = 1.5 * offset_mm / sssWidth with sssWidth = {_num(sss_width_mm)} mm: the pass",
        "// steps w * sssWidth * distToProjWindow / depth * dir / 3 texture units (SSSSBlurPS).",
        "// sssWidth and the linear depth share one unit: with depth in metres pass",
        f"// sssWidth = {_num(sss_width_mm / 1000.0)}, and the constants below in mm or 1/mm alike",
        "// (the follow-surface factor times 1000).",
        *(
            [
                "// float4 kernel[] = {...} as in SeparableSSS.h; outside an effect file make it",
                "// static const (a plain global is a uniform: its initialiser is not applied).",
            ]
            if language == "hlsl"
            else []
        ),
        "",
    ]
    if constants:
        lines += _constant_lines(constants, vec3) + [""]
    single = len(kernels) == 1
    if not single:
        lines += _selection_lines(_identifier(kernels[0].name, single)) + [""]
    for nk in kernels:
        ident = _identifier(nk.name, single)
        order, centred = shader_order(nk.kernel)
        w = (nk.offsets_mm * scale).tolist()
        weights = nk.kernel.weights.double().tolist()
        n = len(order)
        lines.append(f"// {nk.name}: {n} taps, offsets {_num(nk.unit_mm)} mm per kernel unit")
        if not centred:
            lines.append("// no centre tap: loop over all taps (i = 0 .. N-1), not from 1")
        lines.append(f"#define {ident.upper()}_N_SAMPLES {n}")
        for key, values in nk.extras.items():
            args = ", ".join(_num(v) for v in values)
            const = "static const" if language == "hlsl" else "const"
            lines.append(f"{const} {vec3} {ident}_{key} = {vec3}({args});")
        taps = [f"{vec4}({', '.join(_num(v) for v in (*weights[j], w[j]))})" for j in order]
        body = ",\n".join(f"    {t}" for t in taps)
        if language == "hlsl":
            lines.append(f"float4 {ident}[] = {{\n{body}\n}};")
        else:
            lines.append(f"const vec4 {ident}[{n}] = vec4[{n}](\n{body}\n);")
        lines.append("")
    return "\n".join(lines)


def _selection_lines(ident: str) -> list[str]:
    """The header's words on running one kernel of a file of several through ``SSSSBlurPS``,
    which reads ``kernel`` and ``SSSS_N_SAMPLES`` (002 appendix), with ``ident`` (the first
    kernel's identifier) as the example; tested by pasting each kernel so."""
    return [
        "// several kernels: SSSSBlurPS reads kernel and SSSS_N_SAMPLES, so compile one shader",
        "// per kernel, this file followed by two lines naming it, e.g. for the first:",
        f"//   #define kernel {ident}",
        f"//   #define SSSS_N_SAMPLES {ident.upper()}_N_SAMPLES",
    ]


@dataclass(frozen=True)
class Constant:
    """A constant the measured result used, written next to the taps.

    Attributes:
        name: the ``#define`` name (``SSSS_FOLLOW_SURFACE_FACTOR``) or, with ``value`` ``None``,
            a comment-only entry.
        value: a number, three per-channel numbers, or ``None``.
        comment: what it means (one or more lines).
    """

    name: str
    value: float | int | tuple[float, float, float] | None
    comment: str = ""

    def as_json(self) -> dict[str, Any]:
        v = list(self.value) if isinstance(self.value, tuple) else self.value
        return {"name": self.name, "value": v, "comment": self.comment}


def _factor_comment(mode: int, per_channel: bool) -> str:
    """The header's words on ``SSSS_FOLLOW_SURFACE_FACTOR`` for follow-surface ``mode`` (1 the
    lerp, 2 000 eq. 7) and a factor per channel or not: what to put where in ``SSSSBlurPS``.
    A per-channel factor with the paper's ``float s`` would keep its first channel only (HLSL
    truncates a vector assigned to a scalar with a warning, GLSL refuses it), so the comment
    names the declaration to change."""
    if mode == 2:
        d = "float3 / vec3 d, per channel" if per_channel else "float d"
        return (
            "1/mm: 1 / surface_scale (000 eq. 7's 1 / sigma_max), for LINEAR depth in mm (depth\n"
            "in another unit: times mm per unit). SSSSBlurPS has no eq. 7 line: in its\n"
            "accumulation weight each tap by exp(-0.5 * d * d), d = FACTOR * abs(depthM -\n"
            f"depth) ({d});\nits SSSS_FOLLOW_SURFACE == 1 lerp is then not compiled"
        )
    text = (
        "1/mm: replaces `300.0 * distanceToProjectionWindow * sssWidth` in SSSSBlurPS's\n"
        "follow-surface line, for LINEAR depth in mm: s = saturate(FACTOR * abs(depthM -\n"
        "depth)); = 1 / surface_scale (depth in another unit: times mm per unit)"
    )
    if per_channel:
        text += (
            "\nper channel: declare that line's s as float3 / vec3 (the paper's float s keeps\n"
            "the first channel only: HLSL truncates it with a warning, GLSL refuses it)"
        )
    return text


def _constant_lines(constants: Sequence[Constant], vec3: str) -> list[str]:
    lines = ["// constants the measured result used (sssbench docs/gl.md, 'the export contract'):"]
    for c in constants:
        lines += [f"// {line}" for line in c.comment.splitlines()]
        if c.value is None:
            continue
        if isinstance(c.value, tuple):
            value = f"{vec3}({', '.join(_num(v) for v in c.value)})"
        elif isinstance(c.value, int) and not isinstance(c.value, bool):
            value = str(c.value)
        else:
            value = _num(float(c.value))
        lines.append(f"#define {c.name} {value}")
    return lines


def _f32(x: float) -> float:
    """``x`` as the float32 the passes compute with."""
    return float(torch.tensor(x, dtype=torch.float64).to(torch.float32))


def method_constants(method: nn.Module) -> list[Constant]:
    """Every constant besides the taps that ``method``'s measured image depends on (module doc):
    the follow-surface mode and factor, the mask semantics, the stretch, the rotation, the sum
    of Gaussians' schedule, blend factors and LOD, the rank-N schedule."""
    from sssbench.gl._run import _follow_factor
    from sssbench.ops import LowRankSSS, SeparableMethod, SumOfGaussiansSSS

    out: list[Constant] = []
    if not isinstance(method, SeparableMethod):
        return out
    mode = {None: 0, "lerp": 1, "gaussian": 2}[method.follow_surface]
    out.append(
        Constant(
            "SSSS_FOLLOW_SURFACE",
            mode,
            "follow-surface: 0 off; 1 SeparableSSS.h's lerp back to colorM (002 appendix);\n"
            "2 000 eq. 7: tap weight *= exp(-0.5 * (SSSS_FOLLOW_SURFACE_FACTOR * |dz|)^2)",
        )
    )
    if mode:
        factor = _follow_factor(method.surface_scale)
        value: float | tuple[float, float, float] = factor[0]
        per_channel = len(set(factor)) > 1
        if per_channel:
            value = factor
        out.append(
            Constant("SSSS_FOLLOW_SURFACE_FACTOR", value, _factor_comment(mode, per_channel))
        )
    out.append(
        Constant(
            "SSSS_STRENGTH_SOURCE_IS_MASK",
            1,
            "SSSS_STRENGTH_SOURCE = the G-buffer mask: 0 = pixel not computed (stencil,\n"
            "initStencil discard: the input is kept), else finalStep *= mask (003 s' = s * alpha)",
        )
    )
    out.append(
        Constant(
            "SSSS_SKIPPED_PIXELS",
            None,
            "render targets: where a pass computes no pixel (the stencil's discard, the LOD)\n"
            "its target must already hold that pass's input, which the next pass's taps read:\n"
            "copy the input into the target first (a target cleared to black darkens the\n"
            "pixels beside a stencil edge on one surface: far off, tested)",
        )
    )
    if method.rotation is not None:
        out.append(
            Constant(
                "SSSS_ROTATION_RADIUS",
                _f32(method.rotation),
                "000 §6: taps with |offset| <= radius * (largest |offset|) are turned by a\n"
                f"per-pixel angle in [0, pi) (seed {method.seed}), fetched bilinearly; the angles\n"
                "are sssbench.ops.random_rotation(gbuffer, radius, seed)'s: a\n"
                "renderer's own noise gives an image of the same statistics, not this one\n"
                "pixel for pixel",
            )
        )
    if isinstance(method, SumOfGaussiansSSS):
        st = method.stretch
        out.append(
            Constant(
                "SSSS_STRETCH",
                int(st is not None),
                "JG10 stretch (003 §7.3.1): step *= ssslevel * depth / (depth +\n"
                "correction * min(|d depth / d axis|, maxdd)) (central difference); in\n"
                "SSSSBlurPS finalStep times that factor, d depth / d axis per pixel along the\n"
                "pass's axis: (depth[i+1] - depth[i-1]) / 2, one-sided at the image's first\n"
                "and last pixel (depth[1] - depth[0], depth[n-1] - depth[n-2])",
            )
        )
        if st is not None:
            out += [
                Constant("SSSS_STRETCH_SSSLEVEL", _f32(st.ssslevel), "ssslevel (1 = physical)"),
                Constant("SSSS_STRETCH_CORRECTION", _f32(st.correction), "correction, px"),
                Constant("SSSS_STRETCH_MAXDD", _f32(st.maxdd), "maxdd, mm of depth per px"),
            ]
        out.append(
            Constant(
                "SSSS_LOD",
                int(method.lod),
                "003 §7.3.2: a step's passes skip pixels where sigma * ssslevel *\n"
                "focalPx / depth * mask < SSSS_LOD_THRESHOLD (focalPx = H / (2 tan(fov/2)))",
            )
        )
        out.append(Constant("SSSS_LOD_THRESHOLD", _f32(method.lod_threshold), "px"))
        steps = [] if method.steps is None else method.steps
        if method.lod:
            out.append(
                Constant(
                    "SSSS_LOD_IN_SSSSBLURPS",
                    None,
                    "in SSSSBlurPS, after its scale line (scale = distToProjWindow / depthM;\n"
                    "H the target's height in pixels, ssslevel SSSS_STRETCH_SSSLEVEL, 1\n"
                    "without the stretch, sigma the step's KERNEL_SOG<i>_SIGMA):\n"
                    "  if (sigma * ssslevel * 0.5 * H * scale * SSSS_STRENGTH_SOURCE <\n"
                    "      SSSS_LOD_THRESHOLD) discard;\n"
                    "and the step's blend only where its pass ran (the same test)",
                )
            )
        for i, step in enumerate(steps):
            if step.kernel is not None:
                sigma = _num(step.increment**0.5)
                comment = f"mm: step sog{i}'s sigma (the LOD's width)"
                out.append(Constant(f"KERNEL_SOG{i}_SIGMA", float(sigma), comment))
        sched = [
            "pass schedule (003 §7.3.3, Fig. 7.6): RTF = RT1 = the input; for each step in",
            "order: x pass RT1 -> RT2, y pass RT2 -> RT1, then RTF = RT1 * w' + RTF * (1 - w')",
            "(blend factor w' = kernel_<step>_blend, Listing 7.2) where the step's pass ran:",
        ]
        for i, step in enumerate(steps):
            if step.kernel is None:
                sched.append(f"  sog{i}: unblurred first Gaussian (w' = 1): no pass")
            else:
                sched.append(
                    f"  sog{i}: sigma {_num(step.increment**0.5)} mm (LOD), taps kernel_sog{i}"
                )
        out.append(Constant("SSSS_SCHEDULE", None, "\n".join(sched)))
    if isinstance(method, LowRankSSS):
        out.append(
            Constant(
                "SSSS_SCHEDULE",
                None,
                "pass schedule (000 eq. 2): result = sum over terms i of the y pass\n"
                "(kernel_low_rank<i>_y) of the x pass (kernel_low_rank<i>_x); the x\n"
                "pass writes input * sum(x weights) at pixels with mask 0; pixels\n"
                "with mask 0 keep the input in the result. In SSSSBlurPS: each x pass with\n"
                "initStencil false and no stencil test (at mask 0 its step is 0, finalStep\n"
                "*= mask, so it writes input * sum(x weights) there; a discard instead is far\n"
                "off, tested), each y pass summed into one target (blend ONE, ONE), then\n"
                "the input where the mask is 0",
            )
        )
    return out


def pass_sources(method: nn.Module, kernels: Sequence[NamedKernel]) -> dict[str, str]:
    """Complete GLSL 330 fragment shaders, one per kernel: the sources the GL backend compiles
    for ``method`` (:func:`sssbench.gl.shaders.pass_source`), keyed by kernel name."""
    from sssbench.gl._run import pass_spec
    from sssbench.ops import LowRankSSS, SumOfGaussiansSSS

    out: dict[str, str] = {}
    for nk in kernels:
        opts: dict[str, Any] = dict(
            follow_surface=method.follow_surface, surface_scale=method.surface_scale,
            width=nk.unit_mm,
            rotation_radius=None if method.rotation is None
            else float(method.rotation) * nk.kernel.extent,
        )  # fmt: skip
        if isinstance(method, SumOfGaussiansSSS):
            step = method.steps[int(nk.name[3:])]
            level = 1.0 if method.stretch is None else float(method.stretch.ssslevel)
            opts["stretch"] = method.stretch
            if method.lod:
                opts["lod"] = (math.sqrt(step.increment) * level, method.lod_threshold)
        if isinstance(method, LowRankSSS) and nk.name.endswith(".x"):
            opts["inactive_scale"] = tuple(
                float(v) for v in nk.kernel.sum().to(torch.float32).tolist()
            )
        axis = "y" if nk.name.endswith(".y") else "x"
        header = [f"sssbench pass {nk.name}: {len(nk.kernel)} taps"]
        if "blend" in nk.extras:
            header.append(
                "then blend into the result with w' = "
                + ", ".join(_num(v) for v in nk.extras["blend"])
                + " (003 Listing 7.2)"
            )
        if isinstance(method, LowRankSSS):
            header.append(f"the {axis} pass of a rank-N term (000 eq. 2): terms are summed")
        out[nk.name] = pass_spec(nk.kernel, axis, **opts).source(tuple(header))
    return out


def split_passes(text: str) -> dict[str, str]:
    """The pass sources of a ``glsl-pass`` file, keyed by kernel name (one pass: its kernel's
    name; each starts at ``#version``, the header comments before it dropped)."""
    marks = list(re.finditer(r"^// ==== sssbench pass (\S+) ====$", text, re.M))
    if not marks:
        raise ValueError("text has no '// ==== sssbench pass <name> ====' line")
    out = {}
    for m, nxt in zip(marks, [*marks[1:], None], strict=True):
        body = text[m.end() : None if nxt is None else nxt.start()]
        start = body.find("#version")
        if start < 0:
            raise ValueError(f"pass {m.group(1)} has no #version line")
        out[m.group(1)] = body[start:].rstrip() + "\n"
    return out


def _dtype_name(t: torch.Tensor) -> str:
    return str(t.dtype).removeprefix("torch.")


def kernels_json(
    kernels: Sequence[NamedKernel], sss_width_mm: float, *, meta: dict[str, Any] | None = None
) -> str:
    """The kernels as JSON: per kernel its name, ``unit_mm``, offsets and ``(K, 3)`` weights
    exactly as the :class:`Kernel1D` holds them (ascending), extras, plus the shader's
    ``sss_width_mm`` and the centre-first tap order (``shader_order``)."""
    sss_width_mm = check_magnitude("sss_width_mm", sss_width_mm, "length")
    payload = {
        "format": _JSON_FORMAT,
        **(meta or {}),
        "sss_width_mm": sss_width_mm,
        "kernels": [
            {
                "name": nk.name,
                "unit_mm": nk.unit_mm,
                "offsets_dtype": _dtype_name(nk.kernel.offsets),
                "weights_dtype": _dtype_name(nk.kernel.weights),
                "offsets": nk.kernel.offsets.tolist(),
                "weights": nk.kernel.weights.tolist(),
                "shader_order": shader_order(nk.kernel)[0],
                "extras": nk.extras,
            }
            for nk in kernels
        ],
    }
    return _json.dumps(payload, indent=1) + "\n"


def load_kernels(source: str | Path) -> list[NamedKernel]:
    """The kernels of a JSON file written by :func:`kernels_json` (a path, or the text)."""
    text = Path(source).read_text() if isinstance(source, Path) else source
    try:
        payload = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"source must be sssbench kernel JSON, got invalid JSON: {exc}") from None
    if not isinstance(payload, dict) or payload.get("format") != _JSON_FORMAT:
        raise ValueError(f"source must be sssbench kernel JSON (format {_JSON_FORMAT!r})")
    out = []
    for k in payload["kernels"]:
        kernel = Kernel1D(
            torch.tensor(k["offsets"], dtype=getattr(torch, k["offsets_dtype"])),
            torch.tensor(k["weights"], dtype=getattr(torch, k["weights_dtype"])),
        )
        out.append(NamedKernel(k["name"], kernel, float(k["unit_mm"]), dict(k.get("extras", {}))))
    return out


# ----------------------------------------------------------------------------- command line
def build_from_overrides(overrides: Sequence[str]) -> tuple[nn.Module, Any]:
    """The method (and its spec) the app would run for ``overrides`` (``method=...``,
    ``profile=...``, ``samples=...``, ``sampling=...``, ``method.params.x=...``)."""
    from sssbench.app import check_overrides, compose_spec
    from sssbench.run import registry

    problem = check_overrides(list(overrides))
    if problem:
        raise ValueError(problem)
    spec = compose_spec(*overrides)
    profile = registry.build_profile(spec.profile, spec.profile_kind, **spec.profile_params)
    return registry.method_from_spec(spec, profile), spec


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sssbench-export-kernel",
        description="Write a method's 1D kernels as an HLSL / GLSL array (float4(r, g, b, w), "
        "centre tap first, as the separable SSS shader reads them) or as JSON.",
        epilog="example: sssbench-export-kernel method=preintegrated profile=skin_deon6 "
        "samples=7 sampling=importance --format hlsl --out kernel.hlsl",
    )
    p.add_argument("overrides", nargs="*", help="the app's key=value overrides")
    p.add_argument("--format", default="hlsl", help=f"one of {', '.join(FORMATS)}")
    p.add_argument("--out", default=None, help="output file (default: standard output)")
    p.add_argument(
        "--sss-width",
        type=float,
        default=None,
        help="the shader's sssWidth in mm (w = 1.5 * offset_mm / sssWidth); default: the 2012 "
        "method's width, else half the largest offset (|w| <= 3); 1.5 writes w in mm",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Console entry point of ``sssbench-export-kernel``; exit 2 with one line on bad input."""
    args = _parser().parse_args(argv)
    try:
        fmt = str(check_choice("--format", args.format, FORMATS))
        if args.sss_width is not None:
            check_magnitude("--sss-width", args.sss_width, "length")
        method, spec = build_from_overrides(args.overrides)
        kernels = method_kernels(method, spec.method)
        if not kernels:
            raise ValueError(f"method {spec.method} uses no blurred pass with these options")
        width = args.sss_width or default_sss_width(kernels, method)
        from sssbench.run.registry import METHODS

        meta = {
            "method": spec.method,
            # parametric kernels (artist, 2012) carry their own profile
            "profile": spec.profile if METHODS[spec.method].uses_profile else None,
            "samples": spec.samples,
            "sampling": spec.sampling,
            "method_params": spec.method_params,
        }
        constants = method_constants(method)
        header = "sssbench-export-kernel " + " ".join(
            f"{k}={json.dumps(v)}" for k, v in meta.items()
        )
        if fmt == "json":
            meta["constants"] = [c.as_json() for c in constants]
            text = kernels_json(kernels, width, meta=meta)
        elif fmt == "glsl-pass":
            parts = [f"// {header}",
                     "// complete GLSL 330 fragment shaders, one per kernel, as sssbench's GL",
                     "// backend compiles them (docs/gl.md): uniforms colorTex (RGBA32F), depthTex",
                     "// (R32F linear depth, mm), strengthTex (R32F mask), axis (0 x, 1 y),",
                     "// focalPx = H / (2 tan(fov_y / 2))", ""]  # fmt: skip
            for name, src in pass_sources(method, kernels).items():
                parts += [PASS_MARK.format(name=name), src]
            text = "\n".join(parts)
        else:
            text = shader_source(kernels, fmt, width, header=header, constants=constants)
    except (ValueError, TypeError) as exc:
        print(f"sssbench-export-kernel: {exc}", file=sys.stderr)
        return 2
    if args.out is None:
        sys.stdout.write(text)
    else:
        try:
            Path(args.out).write_text(text)
        except OSError as exc:  # an unwritable --out: one line, no traceback
            why = exc.strerror or type(exc).__name__
            print(f"sssbench-export-kernel: --out {args.out}: cannot write ({why})",
                  file=sys.stderr)  # fmt: skip
            return 2
        print(f"sssbench-export-kernel: {len(kernels)} kernel(s) written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

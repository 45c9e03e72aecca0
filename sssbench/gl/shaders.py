"""GLSL 330 sources of the GL backend: the blur pass, the sum of Gaussians' blend and the rank-N
composite, written here after the papers' shaders (no third-party shader text is vendored).

The blur pass is ``SSSSBlurPS`` of ``SeparableSSS.h`` (002 appendix) with the semantics of
sssbench's gather primitive (:mod:`sssbench.ops._gather_torch`, the specification), line by
line:

=====================================================  ========================================
002 appendix ``SSSSBlurPS``                            this pass
=====================================================  ========================================
``colorM = SSSSSamplePoint(colorTex, texcoord)``       ``texelFetch`` of the pixel
``if (SSSS_STRENGTH_SOURCE == 0.0) discard``           mask 0: the pixel is copied through
``scale = distToProjWindow / depthM``                  ``focalPx / depthM`` (pixels per mm,
                                                       ``focalPx = H / (2 tan(fov/2))``)
``finalStep = sssWidth * scale * dir``                 ``step = SSSS_WIDTH * focalPx / depth``
``finalStep *= SSSS_STRENGTH_SOURCE``                  ``step *= mask`` (003 §7.3.1 s' = s·α)
``finalStep *= 1.0 / 3.0``                             taps in mm per ``SSSS_WIDTH`` (no /3)
``colorBlurred.rgb *= kernel[0].rgb``                  the same: centre tap first
``offset = texcoord + kernel[i].a * finalStep``        ``p = pixel + kernel[i].a * step``
``SSSSSample(colorTex, offset)`` (linear, clamp)       :func:`fetch_linear`: clamp to
                                                       ``[0, n-1]``, lerp of the two texels
``s = saturate(300 * distToProjWindow * sssWidth *     ``s = saturate(SSSS_FOLLOW_SURFACE_FACTOR
|depthM - depth|)``; ``lerp(color, colorM, s)``        * |Δz|)``, the factor ``1 / surface_scale``
=====================================================  ========================================

and the options of the gather primitive: the JG10 stretch in the step's denominator (003
§7.3.1, ``d + correction · min(|∂d/∂axis|, maxdd)``), 000 eq. 7's Gaussian depth factor
(``follow_surface="gaussian"``), stochastic rotation of the inner taps (000 §6, bilinear
fetch along the turned axis), a per-pixel width texture (curvature, 004 §3.3.3) and the sum of
Gaussians' depth LOD (003 §7.3.2).

Fetches: the colour and depth of a tap are the texture unit's ``GL_LINEAR`` / ``CLAMP_TO_EDGE``
sample, computed from two ``texelFetch`` in float32 (:data:`FETCH_LINEAR`): a GPU's filter
unit interpolates with 8 bits of sub-texel weight (D3D / GL allow it), which alone would put a
pass 1e-3 away from the torch loop; computed here it is the same float operations as the
torch loop (``p0 = floor(p)``, ``f = p - p0``, ``a + f (b - a)``). ``hardware_filter=True``
uses ``texture()`` with ``GL_LINEAR`` instead, as ``SSSSBlurPS`` does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from sssbench.kernels.kernel1d import Kernel1D

__all__ = [
    "shader_order",
    "VERTEX",
    "PassShader",
    "pass_source",
    "BLEND_SOURCE",
    "COMPOSITE_SOURCE",
    "FOLLOW_MODES",
]

#: ``follow_surface`` -> ``SSSS_FOLLOW_SURFACE`` value
FOLLOW_MODES = {None: 0, "lerp": 1, "gaussian": 2}

#: a full-screen triangle from ``gl_VertexID`` (no vertex buffer)
VERTEX = """#version 330
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"""

#: GLSL number format: 9 significant digits round-trip a float32 exactly
_NUM = "%.9g"


def _num(x: float) -> str:
    s = _NUM % float(x)
    if not math.isfinite(float(x)):
        raise ValueError(f"shader constant must be finite, got {x}")
    return s if any(c in s for c in ".eE") else s + ".0"


@dataclass(frozen=True)
class PassShader:
    """Everything baked into one blur pass's source: the taps and every constant the result
    depends on (the per-frame values ``axis`` and ``focalPx`` stay uniforms).

    Attributes:
        taps: ``(r, g, b, offset)`` per tap in the shader's order (centre first when
            ``centre_first``); offset in kernel units (``width`` mm each).
        centre_first: ``taps[0]`` is the offset-0 tap, weighted on the unshifted centre colour.
        rotated: per tap, whether stochastic rotation turns it (000 §6; ``()``: no rotation).
        follow: ``SSSS_FOLLOW_SURFACE``: 0 none, 1 the 2012 lerp, 2 000 eq. 7's Gaussian.
        follow_factor: ``1 / surface_scale`` per channel (1/mm), ``SSSS_FOLLOW_SURFACE_FACTOR``.
        width: mm per kernel offset unit (002's ``sssWidth`` in these units).
        stretch: ``(ssslevel, correction px, maxdd mm/px)`` of the JG10 stretch (003 §7.3.1),
            or ``None``.
        width_texture: the width is a per-pixel texture (``widthTex``) times ``width``.
        lod: ``(σ · ssslevel mm, threshold px)`` of the sum of Gaussians' depth LOD (003
            §7.3.2), or ``None``.
        inactive_scale: colour factor written at a pixel not computed (1: copied through).
        hardware_filter: fetch taps with ``texture()`` / ``GL_LINEAR`` (SSSSBlurPS) instead of
            the float32 lerp of two texels.
    """

    taps: tuple[tuple[float, float, float, float], ...]
    centre_first: bool = True
    rotated: tuple[bool, ...] = ()
    follow: int = 0
    follow_factor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    width: float = 1.0
    stretch: tuple[float, float, float] | None = None
    width_texture: bool = False
    lod: tuple[float, float] | None = None
    inactive_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    hardware_filter: bool = False


def _vec3(v: Sequence[float]) -> str:
    return f"vec3({', '.join(_num(x) for x in v)})"


def pass_source(spec: PassShader, header: Sequence[str] = ()) -> str:
    """The complete GLSL 330 fragment shader of one blur pass (one kernel, either axis).

    Uniforms (set per frame by :mod:`sssbench.gl`; a renderer sets them the same way):

    - ``colorTex`` RGBA32F, the image; ``depthTex`` R32F linear depth in mm; ``strengthTex``
      R32F mask (stencil and strength, 002 ``SSSS_STRENGTH_SOURCE``); ``widthTex`` R32F
      per-pixel width multiplier (``SSSS_WIDTH_TEXTURE``); ``rotationTex`` RG32F
      ``(cos, sin)`` of each pixel's rotation angle (``SSSS_ROTATION``);
    - ``axis`` 0 horizontal, 1 vertical; ``focalPx`` = ``H / (2 tan(fov_y / 2))``, pixels per
      mm at 1 mm depth: 002's ``distToProjWindow`` in pixels.

    Baked ``#define``: ``SSSS_WIDTH`` (mm per kernel unit), ``SSSS_FOLLOW_SURFACE_FACTOR``
    (vec3, 1/mm: ``1 / surface_scale``, the number replacing ``300 * distToProjWindow *
    sssWidth`` in the lerp, or ``1 / σ_max`` of 000 eq. 7), the stretch's
    ``SSSS_STRETCH_SSSLEVEL`` / ``_CORRECTION`` / ``_MAXDD``, the LOD's ``SSSS_LOD_SIGMA`` /
    ``SSSS_LOD_THRESHOLD`` and ``SSSS_INACTIVE_SCALE``.
    """
    n = len(spec.taps)
    if n == 0:
        raise ValueError("a pass needs at least one tap")
    taps = ",\n".join(f"    vec4({', '.join(_num(v) for v in t)})" for t in spec.taps)
    rot = spec.rotated if spec.rotated else (False,) * n
    if len(rot) != n:
        raise ValueError(f"rotated must have one flag per tap ({n}), got {len(rot)}")
    rot_rows = ", ".join("true" if r else "false" for r in rot)
    first = 1 if spec.centre_first else 0
    st = spec.stretch or (1.0, 0.0, 0.0)
    lod = spec.lod or (0.0, 0.0)
    lines = [
        "#version 330",
        *(f"// {h}" if h else "//" for h in header),
        f"#define SSSS_N_SAMPLES {n}",
        f"#define SSSS_CENTRE_FIRST {first}",
        f"#define SSSS_WIDTH {_num(spec.width)}",
        f"#define SSSS_FOLLOW_SURFACE {spec.follow}",
        f"#define SSSS_FOLLOW_SURFACE_FACTOR {_vec3(spec.follow_factor)}",
        f"#define SSSS_STRETCH {int(spec.stretch is not None)}",
        f"#define SSSS_STRETCH_SSSLEVEL {_num(st[0])}",
        f"#define SSSS_STRETCH_CORRECTION {_num(st[1])}",
        f"#define SSSS_STRETCH_MAXDD {_num(st[2])}",
        f"#define SSSS_WIDTH_TEXTURE {int(spec.width_texture)}",
        f"#define SSSS_ROTATION {int(any(rot))}",
        f"#define SSSS_LOD {int(spec.lod is not None)}",
        f"#define SSSS_LOD_SIGMA {_num(lod[0])}",
        f"#define SSSS_LOD_THRESHOLD {_num(lod[1])}",
        f"#define SSSS_INACTIVE_SCALE {_vec3(spec.inactive_scale)}",
        f"#define SSSS_HARDWARE_FILTER {int(spec.hardware_filter)}",
        "// kernel[i] = vec4(r, g, b, offset): per-channel weights, offset in kernel units",
        "// (SSSS_WIDTH mm each); centre tap first (SeparableSSS.h order)",
        f"const vec4 kernel[SSSS_N_SAMPLES] = vec4[SSSS_N_SAMPLES](\n{taps}\n);",
        f"const bool rotatedTap[SSSS_N_SAMPLES] = bool[SSSS_N_SAMPLES]({rot_rows});",
        _PASS_BODY,
    ]
    return "\n".join(lines)


_PASS_BODY = r"""
uniform sampler2D colorTex;     // RGBA32F irradiance (002 §4: linear space)
uniform sampler2D depthTex;     // R32F linear depth, mm
uniform sampler2D strengthTex;  // R32F SSSS_STRENGTH_SOURCE: stencil (0) and strength
uniform sampler2D widthTex;     // R32F per-pixel width multiplier (SSSS_WIDTH_TEXTURE)
uniform sampler2D rotationTex;  // RG32F (cos, sin) of the rotation angle (SSSS_ROTATION)
uniform int axis;               // 0: horizontal pass, 1: vertical pass
uniform float focalPx;          // H / (2 tan(fov_y / 2)): px per mm at 1 mm depth
out vec4 fragColor;

const float FLT_BIG = 3.4028234e38;

// one texel of tex along the pass axis at integer position i (row or column)
vec4 texelAxis(sampler2D tex, ivec2 pix, int i) {
    return texelFetch(tex, axis == 0 ? ivec2(i, pix.y) : ivec2(pix.x, i), 0);
}

// GL_LINEAR with CLAMP_TO_EDGE along the axis at pixel-centre position p (002: SSSSSample),
// in float32: clamp to [0, n-1], lerp of the two texels (the torch loop's operations)
void fetchLinear(ivec2 pix, float p, int n, out vec3 rgb, out float z) {
    p = clamp(p, 0.0, float(n - 1));
    float p0 = floor(p);
    float f = p - p0;
    int i0 = int(p0);
    int i1 = min(i0 + 1, n - 1);
#if SSSS_HARDWARE_FILTER
    vec2 size = vec2(textureSize(colorTex, 0));
    vec2 uv = axis == 0 ? vec2(p + 0.5, float(pix.y) + 0.5) : vec2(float(pix.x) + 0.5, p + 0.5);
    uv /= size;
    rgb = texture(colorTex, uv).rgb;
    z = texture(depthTex, uv).r;
#else
    vec3 a = texelAxis(colorTex, pix, i0).rgb;
    vec3 b = texelAxis(colorTex, pix, i1).rgb;
    rgb = a + f * (b - a);
    float za = texelAxis(depthTex, pix, i0).r;
    float zb = texelAxis(depthTex, pix, i1).r;
    z = za + f * (zb - za);
#endif
}

// bilinear fetch at (row, col), clamped (rotated taps, 000 §6)
void fetchBilinear(float row, float col, ivec2 size, out vec3 rgb, out float z) {
    row = clamp(row, 0.0, float(size.y - 1));
    col = clamp(col, 0.0, float(size.x - 1));
    float r0f = floor(row), c0f = floor(col);
    float fr = row - r0f, fc = col - c0f;
    int r0 = int(r0f), c0 = int(c0f);
    int r1 = min(r0 + 1, size.y - 1), c1 = min(c0 + 1, size.x - 1);
    float w00 = (1.0 - fr) * (1.0 - fc), w01 = (1.0 - fr) * fc;
    float w10 = fr * (1.0 - fc), w11 = fr * fc;
    rgb = w00 * texelFetch(colorTex, ivec2(c0, r0), 0).rgb
        + w01 * texelFetch(colorTex, ivec2(c1, r0), 0).rgb
        + w10 * texelFetch(colorTex, ivec2(c0, r1), 0).rgb
        + w11 * texelFetch(colorTex, ivec2(c1, r1), 0).rgb;
    z = w00 * texelFetch(depthTex, ivec2(c0, r0), 0).r
      + w01 * texelFetch(depthTex, ivec2(c1, r0), 0).r
      + w10 * texelFetch(depthTex, ivec2(c0, r1), 0).r
      + w11 * texelFetch(depthTex, ivec2(c1, r1), 0).r;
}

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(colorTex, 0);
    int n = axis == 0 ? size.x : size.y;
    // Fetch color of current pixel (002: SSSSSamplePoint):
    vec3 colorM = texelFetch(colorTex, pix, 0).rgb;
    float depthM = texelFetch(depthTex, pix, 0).r;
    float strength = texelFetch(strengthTex, pix, 0).r;
    bool isActive = strength > 0.0;  // 002: initStencil, discard where the strength is 0
#if SSSS_STRETCH
    float level = SSSS_STRETCH_SSSLEVEL;
#else
    float level = 1.0;
#endif
#if SSSS_LOD
    // 003 §7.3.2: skip a Gaussian narrower than SSSS_LOD_THRESHOLD pixels here (camera-facing)
    isActive = isActive
        && SSSS_LOD_SIGMA * focalPx / depthM * strength >= SSSS_LOD_THRESHOLD;
#endif
    if (!isActive) {
        fragColor = vec4(colorM * SSSS_INACTIVE_SCALE, 1.0);
        return;
    }
    // pixels per kernel unit: 002 scale = distToProjWindow / depthM, in pixels; 003 §7.3.1
    // stretch s = ssslevel / (d + correction * min(|ddx d|, maxdd)) (central difference)
    float denom = depthM;
#if SSSS_STRETCH
    int i = axis == 0 ? pix.x : pix.y;
    float dd = i == 0 ? texelAxis(depthTex, pix, 1).r - depthM
             : i == n - 1 ? depthM - texelAxis(depthTex, pix, n - 2).r
             : (texelAxis(depthTex, pix, i + 1).r - texelAxis(depthTex, pix, i - 1).r) / 2.0;
    denom = depthM + SSSS_STRETCH_CORRECTION * min(abs(dd), SSSS_STRETCH_MAXDD);
#endif
    float width = SSSS_WIDTH;
#if SSSS_WIDTH_TEXTURE
    width = texelFetch(widthTex, pix, 0).r * SSSS_WIDTH;
#endif
    // finalStep = sssWidth * scale; finalStep *= SSSS_STRENGTH_SOURCE (002 appendix)
    float step = min(focalPx * level / denom * width * strength, FLT_BIG);
    float pos = float(axis == 0 ? pix.x : pix.y);
#if SSSS_ROTATION
    vec2 cs = texelFetch(rotationTex, pix, 0).rg;
    // the x pass turns (1, 0) by the angle, the y pass turns (0, 1) by the same angle
    vec2 dirRC = axis == 0 ? vec2(cs.y, cs.x) : vec2(cs.x, -cs.y);  // (drow, dcol)
#endif
    // Accumulate the center sample (002: colorBlurred.rgb *= kernel[0].rgb):
    vec3 colorBlurred = vec3(0.0);
#if SSSS_CENTRE_FIRST
    colorBlurred = colorM * kernel[0].rgb;
#endif
    for (int k = SSSS_CENTRE_FIRST; k < SSSS_N_SAMPLES; k++) {
        float o = kernel[k].a * step;
        vec3 color;
        float depth;
#if SSSS_ROTATION
        if (rotatedTap[k]) {
            o = clamp(o, -FLT_BIG, FLT_BIG);
            fetchBilinear(float(pix.y) + o * dirRC.x, float(pix.x) + o * dirRC.y, size,
                          color, depth);
        } else
#endif
        fetchLinear(pix, pos + o, n, color, depth);
        vec3 weight = kernel[k].rgb;
        vec3 dz = abs(depth - depthM) * SSSS_FOLLOW_SURFACE_FACTOR;
#if SSSS_FOLLOW_SURFACE == 1
        // 002: if the difference in depth is huge, we lerp color back to colorM
        color = color + clamp(dz, 0.0, 1.0) * (colorM - color);
#elif SSSS_FOLLOW_SURFACE == 2
        // 000 eq. 7: the depth correction factor exp(-dz^2 / 2 sigma_max^2)
        weight = weight * exp(-0.5 * dz * dz);
#endif
        colorBlurred += weight * color;
    }
    fragColor = vec4(colorBlurred, 1.0);
}
"""

#: the sum of Gaussians' blend (003 §7.3.3, Listing 7.2): the blurred Gaussian is written with
#: the blend state ``src · w' + dst · (1 − w')`` (``GL_CONSTANT_COLOR``,
#: ``GL_ONE_MINUS_CONSTANT_COLOR``, blend colour ``w'``) onto the result, at the pixels the
#: Gaussian's pass computed (stencil and LOD; elsewhere ``discard`` leaves the result)
BLEND_SOURCE = """#version 330
uniform sampler2D colorTex;     // the blurred Gaussian (RT1)
uniform sampler2D depthTex;
uniform sampler2D strengthTex;
uniform int useLod;
uniform float lodWidth;         // sigma * ssslevel * focalPx
uniform float lodThreshold;
out vec4 fragColor;
void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    float strength = texelFetch(strengthTex, pix, 0).r;
    bool isActive = strength > 0.0;
    if (useLod != 0)  // 003 §7.3.2, as in the pass
        isActive = isActive
            && lodWidth / texelFetch(depthTex, pix, 0).r * strength >= lodThreshold;
    if (!isActive) discard;
    fragColor = vec4(texelFetch(colorTex, pix, 0).rgb, 1.0);
}
"""

#: the rank-N result (000 eq. 2): the summed terms where the stencil is set, the input elsewhere
COMPOSITE_SOURCE = """#version 330
uniform sampler2D colorTex;     // the input image
uniform sampler2D sumTex;       // sum over the terms of their vertical passes
uniform sampler2D strengthTex;
out vec4 fragColor;
void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    bool isActive = texelFetch(strengthTex, pix, 0).r > 0.0;
    vec3 rgb = isActive ? texelFetch(sumTex, pix, 0).rgb : texelFetch(colorTex, pix, 0).rgb;
    fragColor = vec4(rgb, 1.0);
}
"""


#: an offset within this fraction of the kernel's extent counts as the centre tap
_CENTRE_TOL = 1e-9


def shader_order(kernel: Kernel1D) -> tuple[list[int], bool]:
    """Tap indices in the shader's order and whether the first is the centre tap.

    The tap with offset 0 (to ``1e-9`` of the extent: placement rules may leave a rounding
    residue like 5.6e-16 mm) comes first, the others follow ascending (002 appendix,
    ``SeparableSSS.h``'s kernel builder); without a centre tap the order stays ascending."""
    offsets = kernel.offsets.double()
    k = len(kernel)
    i = int(offsets.abs().argmin())
    if float(offsets[i].abs()) <= _CENTRE_TOL * kernel.extent:
        return [i, *[j for j in range(k) if j != i]], True
    return list(range(k)), False

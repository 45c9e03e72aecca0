"""GLSL 400 (float64 geometry) or GLSL 330 (float32 fallback) source of the disk
(:class:`~sssbench.ops.DiskSSS`) as one fragment shader, both
estimators, written after the published formulas (no third-party shader text is vendored).

One draw per frame computes, per pixel, the estimate of the module doc of
:mod:`sssbench.ops.disk` (the specification; its torch loop is what the tests compare with).
``estimator="hdrp"`` follows Unity HDRP's ``SubsurfaceScattering.compute``
(Unity-Technologies/Graphics, ``Runtime/Material/SubsurfaceScattering/``), line by line:

========================================================  =====================================
HDRP ``SubsurfaceScattering.compute`` / ``.hlsl``        this shader (``DISK_HDRP 1``)
========================================================  =====================================
``pixelsPerMm = rcp(max(0.0001, unitsPerPixel))`` (in     ``ppm = 1 / max(0.1 mm,
its units: 1 unit = 1 m)                                  pixel_size(z))``
``sampleCount = min(π (filterRadius · pixelsPerMm)² /     ``n = min(floor(π (R_f ppm)² / 4),
SSS_PIXELS_PER_SAMPLE, sampleBudget)``                    DISK_N_SAMPLES)``
``Golden2dSeq(i, n)``: ``(i/n + 0.5/n, frac(i ·           ``u = (i + ½)/n``, ``ψ = 2π
rcp(GOLDEN_RATIO)))`` (core ``Fibonacci.hlsl``)           goldenFrac(i) + 2π rotation``
``SampleBurleyDiffusionProfile(u, d, r, rcpPdf)``         :func:`sampleBurleyPolar` (HDRP's
(``DiffusionProfile.hlsl``)                               Cardano form), or the table
``position = pixelCoord + round(vec · pixelsPerMm)``      ``roundEven`` (round half to even)
``r3D = sqrt(r² + (linearDepth − centreDepth)²)``         the same, mm
``EvalBurleyDiffusionProfile(r3D, S) · rcpPdf``           :func:`polarProfile` · ``rcpPdf``
``totalIrradiance / max(totalWeight, FLT_MIN)``           the same
========================================================  =====================================

The default ``estimator="sssbench"`` is Golubev 2018's gather with the weight ``R(d) / pdf``
at the 3D distance ``d`` (``sssbench.ops.disk`` module doc): the pattern ``(u_i, θ_i)`` of
:func:`~sssbench.ops.disk.pattern_points` as a texture (float64 on the CPU, ``θ_i`` reduced
mod 2π), the radius from Burley's inverse CDF (``x = 2 sinh(asinh(2(1 − u))/3)``,
``r = −3d ln x``; Christensen & Burley 2015) or from the tabulated inverse CDF of any other
profile, the sample's view position on the ray through its screen position at the fetched
depth, ``w = R(d) / pdf / ‖R‖₁``.

Per-pixel random numbers: the torch disk hashes a 63-bit seed with 64-bit integer arithmetic;
like an engine's noise texture, the rotation (turns) and the radial shift of every pixel and
frame are computed on the CPU by the operator's own function
(:meth:`~sssbench.ops.DiskSSS.noise`) and uploaded (``noiseTex``); the shader never hashes.
HDRP's golden-ratio angle ``2π frac(i/φ)`` is the torch loop's double (float64 geometry) or,
in the float32 fallback, computed in 32-bit fixed point (``i · 2654435769u``, ``2³²/φ``
rounded: exact modulo 2³²), so it does not lose the fraction to float32 as ``i`` grows.

Precision (``DiskShader.fp64``): the torch disk forms a sample's geometry (quantile, radius,
angle, offset, the pixel it rounds to, bilinear fractions, 3D distance, weight) in float64
whatever the image dtype, and so does this shader by default (``#version 400``, doubles): in
the torch loop's order of operations, from exact doubles — per-sample pattern values and
HDRP's angles, per-pixel rotation and radial shift, the tabulated CDF — uploaded as two
32-bit words each (``packDouble2x32``), every constant written as the very double torch uses
(``LF`` literals), and ``exp`` / ``log`` / ``sin`` / ``cos`` / the cube root, which GLSL has
only for floats, in double (:func:`double_math_source`; Newton steps for the roots). Only
colours and depths are float32, as in torch. A sample then lands in the same pixel as in
torch unless it lies within ~1e-15 of its offset of a pixel boundary, and the weights round
to the same float32: on llvmpipe most images are bitwise equal to torch's, the others within
float32 rounding (the frames' blend order; measured in ``tests/gl/test_gl_disk.py``,
docs/gl.md).
The fallback for a driver without doubles (``fp64=False``, ``#version 330``, chosen
explicitly with :func:`sssbench.gl.set_disk_geometry`) forms the geometry in float32: a
sample within float32 rounding of a pixel boundary (1e-7 of its offset) can land on the
neighbour, which changes that pixel by that one sample's share (docs/gl.md states the
tolerance).

Uniforms: ``colorTex`` RGBA32F irradiance, ``depthTex`` R32F linear depth (mm),
``strengthTex`` R32F mask (stencil and strength), ``areaTex`` R32F pixel surface areas (mm²),
``profileTex`` R32F per-pixel profile index (a list of profiles: one draw per profile),
``pixelMmPerMm`` (and, float64, ``pixelMmPerMmD``) = ``2 tan(fov_y/2) / H`` (mm per pixel at
1 mm depth), ``tanHalfFov`` and ``frameWeight`` (``1 / frames``: each frame's draw is summed
into the target by additive blending). Float64 geometry: ``noiseTex`` RGBA32UI (rotation,
shift), ``patternTex`` RGBA32UI ``(u_i, θ_i)`` or HDRP's ``(2π frac(i/φ), 0)`` in rows of
:data:`PATTERN_ROW` texels, ``radialTex`` RGBA32UI per node ``(c_k, r_k)``, each value a
double. Float32 fallback: ``noiseTex`` RGBA32F (rotation, shift as a hi/lo pair),
``patternTex`` RGBA32F ``(u_i, θ_i/2π, 1 − u_i as hi/lo)``, ``radialTex`` RGBA32F per node
``(c_k, 1 − c_k, r_k, dr/dc)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from sssbench.gl.disk_shader64 import BODY64, double_constants, double_math_source
from sssbench.gl.shaders import _num, _vec3

__all__ = ["DiskShader", "disk_source", "double_math_source", "PATTERN_ROW", "SOG_MAX"]

#: texels per row of the pattern texture (``samples`` up to 65536 fit in 16 rows)
PATTERN_ROW = 4096
#: most Gaussians a sum-of-Gaussians profile may have in the shader (its constants arrays)
SOG_MAX = 64


@dataclass(frozen=True)
class DiskShader:
    """Everything baked into the disk's source (per-frame values stay uniforms / textures).

    Attributes:
        hdrp: ``estimator="hdrp"`` (HDRP's pass) instead of ``"sssbench"``.
        samples: samples per pixel (``"hdrp"``: the budget).
        normalise, jitter, bilinear, surface_area: the operator's options (``"sssbench"``).
        radial_table: ``None`` for Burley's closed-form sampler with ``sampled_d`` (mm), else
            the number of tabulated intervals in ``radialTex``.
        sampled_d: Burley ``d`` (mm) of the sampled (widest) channel.
        burley_d: per channel Burley ``d`` (mm) for the weights, or ``None``.
        sog: per Gaussian ``(1 / 2v, (w / (2π v ‖R‖₁))_rgb)`` of a sum of Gaussians, or
            ``()`` (then ``burley_d`` is set).
        filter_radius: HDRP's filter radius ``R_f`` (mm; 0.997 quantile).
        min_pixel_mm: HDRP's floor on a pixel's footprint (mm).
        pixels_per_sample: HDRP's ``SSS_PIXELS_PER_SAMPLE``.
        fp64: form each sample's geometry in float64 as the torch disk does (GLSL 400:
            ``#version 400``); ``False``: the float32 geometry of a
            GLSL 330 driver without doubles.
        per_pixel: the operator has a list of profiles: this draw scatters the pixels whose
            ``profile_id`` is ``profile_index`` (the others are left to their profile's draw).
        profile_index: the profile of this draw (``per_pixel``).
        cross_accept: ``cross_profile="accept"``: a sample on another profile's pixel is
            accepted (``"reject"``: rejected like a stencil miss).
    """

    hdrp: bool
    samples: int
    normalise: bool = True
    jitter: bool = True
    bilinear: bool = False
    surface_area: bool = False
    radial_table: int | None = None
    sampled_d: float = 1.0
    burley_d: tuple[float, float, float] | None = None
    sog: tuple[tuple[float, tuple[float, float, float]], ...] = ()
    filter_radius: float = 0.0
    min_pixel_mm: float = 0.1
    pixels_per_sample: int = 4
    fp64: bool = False
    per_pixel: bool = False
    profile_index: int = 0
    cross_accept: bool = False


def disk_source(spec: DiskShader, header: Sequence[str] = ()) -> str:
    """The complete fragment shader of one disk draw (module doc): GLSL 400 with the float64
    geometry (``spec.fp64``), else GLSL 330 with the float32 geometry."""
    if spec.burley_d is None and not spec.sog:
        raise ValueError("a disk shader needs a Burley d or sum-of-Gaussians constants")
    if len(spec.sog) > SOG_MAX:
        raise ValueError(f"at most {SOG_MAX} Gaussians, got {len(spec.sog)}")
    n_sog = max(len(spec.sog), 1)
    sog = spec.sog or ((0.0, (0.0, 0.0, 0.0)),)
    b = ", ".join(_num(g[0]) for g in sog)
    a = ", ".join(_vec3(g[1]) for g in sog)
    lines = [
        "#version 400" if spec.fp64 else "#version 330",
        *(f"// {h}" if h else "//" for h in header),
        f"#define DISK_FP64 {int(spec.fp64)}",
        f"#define DISK_PER_PIXEL {int(spec.per_pixel)}",
        f"#define DISK_PROFILE_INDEX {int(spec.profile_index)}",
        f"#define DISK_CROSS_ACCEPT {int(spec.cross_accept)}",
        f"#define DISK_HDRP {int(spec.hdrp)}",
        f"#define DISK_N_SAMPLES {int(spec.samples)}",
        f"#define DISK_NORMALISE {int(spec.normalise)}",
        f"#define DISK_JITTER {int(spec.jitter)}",
        f"#define DISK_BILINEAR {int(spec.bilinear)}",
        f"#define DISK_SURFACE_AREA {int(spec.surface_area)}",
        f"#define DISK_RADIAL_TABLE {int(spec.radial_table is not None)}",
        f"#define DISK_RADIAL_INTERVALS {int(spec.radial_table or 1)}",
        f"#define DISK_SAMPLED_D {_num(spec.sampled_d)}",
        f"#define DISK_PROFILE_BURLEY {int(spec.burley_d is not None)}",
        f"#define DISK_BURLEY_D {_vec3(spec.burley_d or (1.0, 1.0, 1.0))}",
        f"#define DISK_SOG_N {n_sog}",
        f"#define HDRP_FILTER_RADIUS {_num(spec.filter_radius)}",
        f"#define HDRP_MIN_PIXEL_MM {_num(spec.min_pixel_mm)}",
        f"#define SSS_PIXELS_PER_SAMPLE {_num(spec.pixels_per_sample)}",
        f"#define PATTERN_ROW {PATTERN_ROW}",
        f"#define PI {_num(math.pi)}",
        "// sum of Gaussians: R(r) / ||R||_1 = sum_k sogA[k] exp(-r^2 sogB[k]) (001 eq. 6-7),",
        "// sogB = 1 / (2 v_k), sogA = w_k / (2 pi v_k ||R||_1) per channel",
        f"const float sogB[DISK_SOG_N] = float[DISK_SOG_N]({b});",
        f"const vec3 sogA[DISK_SOG_N] = vec3[DISK_SOG_N]({a});",
    ]
    if spec.fp64:
        lines += double_constants(spec, sog)
    lines += [_BODY, BODY64 if spec.fp64 else _BODY32, _MAIN]
    return "\n".join(lines)


_BODY = r"""
uniform sampler2D colorTex;     // RGBA32F irradiance
uniform sampler2D depthTex;     // R32F linear depth, mm
uniform sampler2D strengthTex;  // R32F mask: stencil (0) and strength
uniform sampler2D profileTex;   // R32F per-pixel profile index (DISK_PER_PIXEL)
#if DISK_FP64
// exact doubles, each as its two 32-bit words (packDouble2x32): GLContext.texture_f64
uniform usampler2D noiseTex;    // RGBA32UI (rotation turns, radial shift): DiskSSS.noise
uniform usampler2D patternTex;  // RGBA32UI (u_i, theta_i rad) (sssbench) / (2 pi frac(i/phi), 0)
uniform usampler2D radialTex;   // RGBA32UI per node (c_k, r_k) of the tabulated sampler
uniform double pixelMmPerMmD;   // 2 tan(fov_y / 2) / H as the double gbuffer.pixel_size_mm uses
#else
uniform sampler2D noiseTex;     // RGBA32F (rotation turns, shift hi, shift lo, 0): DiskSSS.noise
uniform sampler2D patternTex;   // RGBA32F (u_i, theta_i turns, 1 - u_i hi, lo) (sssbench)
uniform sampler2D radialTex;    // RGBA32F per node (c_k, 1 - c_k, r_k, dr/dc on [k, k+1])
#endif
uniform sampler2D areaTex;      // R32F pixel surface area, mm^2 (surface_area)
uniform float pixelMmPerMm;     // 2 tan(fov_y / 2) / H: pixel_size_mm at 1 mm depth
uniform float tanHalfFov;       // tan(fov_y / 2)
uniform float frameWeight;      // 1 / frames (frames are summed by additive blending)
out vec4 fragColor;

const float TWO_PI = 2.0 * PI;
const float FLT_MIN = 1.17549435e-38;   // HDRP: max(totalWeight, FLT_MIN)
const float FLT_BIG = 3.4028234e38;
const float NO_WEIGHT = 1e-30;          // disk.py _NO_WEIGHT: a total weight of no sample

// the profile of pixel p (DiskSSS._groups: gbuffer.profile_id)
int profileOf(ivec2 p) { return int(texelFetch(profileTex, p, 0).r); }

// may a sample land on pixel p: on the stencil and, with a list of profiles and
// cross_profile="reject", of this draw's profile (DiskSSS._groups)
bool accepted(ivec2 p) {
    bool on = texelFetch(strengthTex, p, 0).r > 0.0;
#if DISK_PER_PIXEL && !DISK_CROSS_ACCEPT
    on = on && profileOf(p) == DISK_PROFILE_INDEX;
#endif
    return on;
}

"""

_BODY32 = r"""
// ================================================================ float32 geometry (GLSL 330)
// ---------------------------------------------------------------- radial sampling
// Burley's radial CDF F(r) = 1 - e^{-r/d}/4 - 3 e^{-r/3d}/4 inverted (Christensen & Burley
// 2015): x = e^{-r/3d} solves x^3 + 3x - 4v = 0, v = 1 - u. The torch sampler writes
// Cardano's root as 2 sinh(asinh(2v) / 3); in float32 asinh(2v) = log(2v + sqrt(1 + 4v^2))
// loses the digits of a small v (a tail sample), so the root is taken in HDRP's form
// (below): x = 4v / c. Area density F'(r) / (2 pi r), F'(r) = (x^3 + x) / (4d)
void sampleBurleyArea(float v, out float r, out float rcpPdfArea) {
    float d = DISK_SAMPLED_D;
    float g = 1.0 + 4.0 * v * (2.0 * v + sqrt(1.0 + 4.0 * v * v));
    float n = pow(g, -1.0 / 3.0);
    float c = 1.0 + g * n * n + n;
    float x = 4.0 * v / c;
    r = 3.0 * d * log(c / (4.0 * v));
    float dens = (x * x * x + x) / (4.0 * d);
    rcpPdfArea = TWO_PI * r / dens;
}

// HDRP DiffusionProfile.hlsl SampleBurleyDiffusionProfile (Cardano's root written with
// g = 1 + 4v (2v + sqrt(1 + 4v^2)), v = 1 - u): r = 3d ln(c / 4v), c = 1 + g^{1/3} + g^{-1/3};
// rcpPdf (polar) = 8 pi d c^3 / (4v (c^2 + 16 v^2))
void sampleBurleyPolar(float v, out float r, out float rcpPdf) {
    float d = DISK_SAMPLED_D;
    float g = 1.0 + 4.0 * v * (2.0 * v + sqrt(1.0 + 4.0 * v * v));
    float n = pow(g, -1.0 / 3.0);
    float c = 1.0 + g * n * n + n;
    r = 3.0 * d * log(c / (4.0 * v));
    rcpPdf = 8.0 * PI * d * (c * c * c / (4.0 * v * (c * c + 16.0 * v * v)));
}

// tabulated inverse CDF (_disk_radial.TabulatedRadial): the interval k with c_k <= u (the
// last such: searchsorted right - 1), r = r_k + (u - c_k) dr/dc, at most r_k+1; the density
// is the piecewise-linear CDF's, so 1/pdf_area = 2 pi r dr/dc and 1/pdf_polar = 2 pi dr/dc.
// u is given with its complement v = 1 - u (both exact to float32): in the upper half the
// search and the difference use 1 - c_k and v, which float32 keeps where c_k and u are ~1
void sampleTable(float u, float v, out float r, out float drdc) {
    bool upper = u >= 0.5;
    int lo = 0, hi = DISK_RADIAL_INTERVALS - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) / 2;
        vec4 t = texelFetch(radialTex, ivec2(mid, 0), 0);
        if (upper ? t.g >= v : t.r <= u) lo = mid; else hi = mid - 1;
    }
    vec4 t = texelFetch(radialTex, ivec2(lo, 0), 0);
    float rNext = texelFetch(radialTex, ivec2(lo + 1, 0), 0).b;
    drdc = t.a;
    r = min(t.b + (upper ? t.g - v : u - t.r) * drdc, rNext);
}

// ---------------------------------------------------------------- the profile
// R(r) / ||R||_1 per channel: Burley R = A (e^{-r/d} + e^{-r/3d}) / (8 pi d r), r clamped to
// 1e-6 d (BurleyNormalized.evaluate), or the sum of Gaussians
vec3 profileOverTotal(float r) {
#if DISK_PROFILE_BURLEY
    vec3 d = DISK_BURLEY_D;
    vec3 rr = max(vec3(r), 1e-6 * d);
    return (exp(-rr / d) + exp(-rr / (3.0 * d))) / (8.0 * PI * d * rr);
#else
    vec3 s = vec3(0.0);
    for (int k = 0; k < DISK_SOG_N; k++) s += sogA[k] * exp(-r * r * sogB[k]);
    return s;
#endif
}

// the profile in polar measure over its total, r R(r) / ||R||_1: HDRP's
// EvalBurleyDiffusionProfile(r, S) = S / (8 pi) (e^{-S r / 3} + e^{-S r}), S = 1/d
vec3 polarProfile(float r) {
#if DISK_PROFILE_BURLEY
    vec3 d = DISK_BURLEY_D;
    return (exp(-r / (3.0 * d)) + exp(-r / d)) / (8.0 * PI * d);
#else
    return r * profileOverTotal(r);
#endif
}

// HDRP Golden2dSeq: frac(i / golden ratio), here in 32-bit fixed point (2^32 / phi rounded;
// the product wraps modulo 2^32, i.e. keeps exactly the fraction)
float goldenFrac(int i) {
    return float(uint(i) * 2654435769u) * (1.0 / 4294967296.0);
}

// ---------------------------------------------------------------- estimator="hdrp"
// HDRP SubsurfaceScattering.compute EvaluateSss / EvaluateSample (SSS_USE_TANGENT_PLANE 0,
// bilateral filter on: r3D from the depth difference)
vec3 evaluateHdrp(ivec2 pix, ivec2 size, vec3 colorM, float depthM, float turn) {
    float ppm = 1.0 / max(HDRP_MIN_PIXEL_MM, depthM * pixelMmPerMm);
    float disk = HDRP_FILTER_RADIUS * ppm;
    int n = min(int(floor(PI * disk * disk / SSS_PIXELS_PER_SAMPLE)), DISK_N_SAMPLES);
    if (n == 0) return colorM;  // fewer than one sample: no filtering
    vec3 num = vec3(0.0), den = vec3(0.0);
    for (int i = 0; i < n; i++) {
        float u = (float(i) + 0.5) / float(n);  // Golden2dSeq: fixed, no radial jitter
        float v = (float(n - i) - 0.5) / float(n);
        float r, rcpPdf;
#if DISK_RADIAL_TABLE
        float drdc;
        sampleTable(u, v, r, drdc);
        rcpPdf = TWO_PI * drdc;
#else
        sampleBurleyPolar(v, r, rcpPdf);
#endif
        float psi = TWO_PI * fract(goldenFrac(i) + turn);  // Golden2dSeq angle + rotation
        // position = pixelCoord + round(vec * pixelsPerMm), rows downward
        vec2 offset = ppm * r * vec2(cos(psi), sin(psi));
        ivec2 p = pix + ivec2(roundEven(offset));
        bool inside = all(greaterThanEqual(p, ivec2(0))) && all(lessThan(p, size));
        ivec2 q = clamp(p, ivec2(0), size - 1);
        float dz = texelFetch(depthTex, q, 0).r - depthM;
        float r3D = sqrt(r * r + dz * dz);
        vec3 w = polarProfile(r3D) * rcpPdf;
        w *= (inside && accepted(q)) ? 1.0 : 0.0;
        num += w * texelFetch(colorTex, q, 0).rgb;
        den += w;
    }
    return num / max(den, vec3(FLT_MIN));
}

// ---------------------------------------------------------------- estimator="sssbench"
// fetch at the offset (drow, dcol) pixels: irradiance, depth difference to the centre,
// acceptance and surface area (DiskSSS _Pixels.fetch; clamp to edge)
void fetchPoint(ivec2 pix, ivec2 size, float drow, float dcol, float depthM,
                out vec3 rgb, out float dz, out float ok, out float area) {
    ivec2 q = clamp(pix + ivec2(int(floor(dcol + 0.5)), int(floor(drow + 0.5))),
                    ivec2(0), size - 1);
    rgb = texelFetch(colorTex, q, 0).rgb;
    dz = texelFetch(depthTex, q, 0).r - depthM;
    ok = accepted(q) ? 1.0 : 0.0;
    area = texelFetch(areaTex, q, 0).r;
}

void fetchBilinear(ivec2 pix, ivec2 size, float drow, float dcol, float depthM,
                   out vec3 rgb, out float dz, out float ok, out float area) {
    float fr0 = floor(drow), fc0 = floor(dcol);
    float fr = drow - fr0, fc = dcol - fc0;
    ivec2 c0 = pix + ivec2(int(fc0), int(fr0));
    ivec2 lo = clamp(c0, ivec2(0), size - 1), hi = clamp(c0 + 1, ivec2(0), size - 1);
    ivec2 q[4] = ivec2[4](lo, ivec2(hi.x, lo.y), ivec2(lo.x, hi.y), hi);
    float wt[4] = float[4]((1.0 - fr) * (1.0 - fc), (1.0 - fr) * fc, fr * (1.0 - fc), fr * fc);
    rgb = vec3(0.0);
    dz = 0.0;
    area = 0.0;
    float total = 0.0;
    for (int k = 0; k < 4; k++) {
        float w = accepted(q[k]) ? wt[k] : 0.0;
        rgb += w * texelFetch(colorTex, q[k], 0).rgb;
        dz += w * (texelFetch(depthTex, q[k], 0).r - depthM);
        area += w * texelFetch(areaTex, q[k], 0).r;
        total += w;
    }
    ok = total > 0.0 ? 1.0 : 0.0;
    float safe = total > 0.0 ? total : 1.0;
    rgb /= safe;
    area /= safe;
    // all corners off the stencil: rejected; its depth is the first corner's
    dz = total > 0.0 ? dz / safe : texelFetch(depthTex, q[0], 0).r - depthM;
}

// the radial quantile u = frac(u_i + shift) and its complement v = 1 - u, each to float32
// precision: shift and 1 - u_i come as (hi, lo) float pairs, and the differences of nearly
// equal terms are exact (Sterbenz), so v keeps its digits where u is within 1e-5 of 1
void quantile(vec4 pat, vec4 noise, out float u, out float v) {
#if DISK_JITTER
    float d = (noise.y - pat.z) + (noise.z - pat.w);  // shift - (1 - u_i)
    if (d < 0.0) {          // u_i + shift < 1
        u = pat.x + (noise.y + noise.z);
        v = -d;
    } else {                // wrapped: u = u_i + shift - 1
        u = d;
        v = pat.z + ((1.0 - noise.y) - noise.z);
    }
#else
    u = pat.x;
    v = pat.z + pat.w;
#endif
}

vec3 evaluateSssbench(ivec2 pix, ivec2 size, vec3 colorM, float depthM, vec4 noise) {
    float pixelMm = depthM * pixelMmPerMm;   // pixel_size_mm at the centre
    float stepPx = 1.0 / pixelMm;            // pixels per mm
    // the centre's view position (gbuffer.view_positions)
    float halfH = 0.5 * float(size.y);
    float xM = (float(pix.x) + 0.5 - 0.5 * float(size.x)) / halfH * depthM * tanHalfFov;
    float yM = (halfH - float(pix.y) - 0.5) / halfH * depthM * tanHalfFov;
    vec3 num = vec3(0.0), den = vec3(0.0);
    for (int i = 0; i < DISK_N_SAMPLES; i++) {
        vec4 pat = texelFetch(patternTex, ivec2(i % PATTERN_ROW, i / PATTERN_ROW), 0);
        float u, v;
        quantile(pat, noise, u, v);  // Cranley-Patterson shift of the quantile (jitter_radius)
        float r, rcpPdfArea;
#if DISK_RADIAL_TABLE
        float drdc;
        sampleTable(u, v, r, drdc);
        rcpPdfArea = TWO_PI * r * drdc;
#else
        sampleBurleyArea(v, r, rcpPdfArea);
#endif
        float theta = TWO_PI * fract(pat.y + noise.x);  // theta_i + 2 pi rotation
        float dcol = r * cos(theta) * stepPx;
        float drow = -r * sin(theta) * stepPx;  // screen y is up, rows go down
        vec3 rgb;
        float dz, ok, area;
#if DISK_BILINEAR
        fetchBilinear(pix, size, drow, dcol, depthM, rgb, dz, ok, area);
#else
        fetchPoint(pix, size, drow, dcol, depthM, rgb, dz, ok, area);
#endif
        // x_i - x_p = x_p dz / z_p + offset * pixel_size(z_p + dz), in differences
        float lateral = (depthM + dz) * pixelMmPerMm;
        float dx = xM * (dz / depthM) + dcol * lateral;
        float dy = yM * (dz / depthM) - drow * lateral;
        float dist = sqrt(dx * dx + dy * dy + dz * dz);
        vec3 w = profileOverTotal(dist) * min(rcpPdfArea, FLT_BIG);  // R(d) / pdf / ||R||_1
#if DISK_SURFACE_AREA
        w *= area / (pixelMm * pixelMm);     // surface area over the disk plane's pixel area
#endif
        w *= ok;
        num += w * rgb;
        den += w;
    }
#if DISK_NORMALISE
    bvec3 safe = greaterThan(den, vec3(NO_WEIGHT));
    return mix(colorM, num / mix(vec3(1.0), den, safe), safe);
#else
    return num / float(DISK_N_SAMPLES);
#endif
}

"""

_MAIN = r"""
void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(colorTex, 0);
#if DISK_PER_PIXEL
    if (profileOf(pix) != DISK_PROFILE_INDEX) discard;  // its own profile's draw computes it
#endif
    vec3 colorM = texelFetch(colorTex, pix, 0).rgb;
    float strength = texelFetch(strengthTex, pix, 0).r;
    if (!(strength > 0.0)) {  // off the stencil: copied through
        fragColor = vec4(colorM * frameWeight, 1.0);
        return;
    }
    float depthM = texelFetch(depthTex, pix, 0).r;
#if DISK_FP64
    uvec4 nz = texelFetch(noiseTex, pix, 0);
    double phase = packDouble2x32(nz.xy), shift = packDouble2x32(nz.zw);
#if DISK_HDRP
    vec3 scattered = evaluateHdrp64(pix, size, colorM, depthM, phase);
#else
    vec3 scattered = evaluateSssbench64(pix, size, colorM, depthM, phase, shift);
#endif
#else
    vec4 noise = texelFetch(noiseTex, pix, 0);
#if DISK_HDRP
    vec3 scattered = evaluateHdrp(pix, size, colorM, depthM, noise.x);
#else
    vec3 scattered = evaluateSssbench(pix, size, colorM, depthM, noise);
#endif
#endif
    // strength: lerp(E, scattered, mask); this frame's share of the average over frames
    fragColor = vec4((colorM + strength * (scattered - colorM)) * frameWeight, 1.0);
}
"""

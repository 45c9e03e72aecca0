"""The float64 sample geometry of the disk shader (:mod:`sssbench.gl.disk_shader`, GLSL 400):
double constants written as the very doubles torch uses, GLSL's missing double ``exp`` /
``log`` / ``sin`` / ``cos`` (:func:`double_math_source`), and the two estimators' loops with
every sample's geometry in double, in the torch disk's order of operations
(``DiskSSS._gather``, ``DiskSSS._gather_hdrp``, the samplers of ``ops/_disk_radial.py``;
docs/gl.md "Sample geometry"). The shared declarations, the float32 fallback and ``main`` are in
:mod:`sssbench.gl.disk_shader`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["double_constants", "double_math_source", "BODY64"]


def _dnum(x: float) -> str:
    """A GLSL double literal that is exactly the Python float ``x`` (``repr``: the shortest
    string that reads back to the same double)."""
    if not math.isfinite(float(x)):
        raise ValueError(f"shader constant must be finite, got {x}")
    s = repr(float(x))
    return (s if any(c in s for c in ".eE") else s + ".0") + "LF"


def _dvec3(v: Sequence[float]) -> str:
    return f"dvec3({', '.join(_dnum(x) for x in v)})"


def double_constants(spec, sog) -> list[str]:
    """The float64 block's constants of a :class:`~sssbench.gl.disk_shader.DiskShader`
    ``spec`` (``sog``: its sum-of-Gaussians constants, padded), each the very double the torch
    disk uses (``_dnum``), and the double math (:func:`double_math_source`)."""
    b = ", ".join(_dnum(g[0]) for g in sog)
    a = ", ".join(_dvec3(g[1]) for g in sog)
    return [
        "// float64 geometry (DISK_FP64): the torch disk's constants as exact doubles",
        f"const double PI_D = {_dnum(math.pi)};",
        f"const double TWO_PI_D = {_dnum(2 * math.pi)};",
        f"const double EIGHT_PI_D = {_dnum(8 * math.pi)};",
        f"const double SAMPLED_D = {_dnum(spec.sampled_d)};",
        f"const double BURLEY_R_SCALE = {_dnum(-3.0 * spec.sampled_d)};  // -3 d",
        f"const double BURLEY_RCP_SCALE = {_dnum(8.0 * math.pi * spec.sampled_d)};  // 8 pi d",
        f"const dvec3 BURLEY_D_D = {_dvec3(spec.burley_d or (1.0, 1.0, 1.0))};",
        f"const double HDRP_FILTER_RADIUS_D = {_dnum(spec.filter_radius)};",
        f"const double HDRP_MIN_PIXEL_MM_D = {_dnum(spec.min_pixel_mm)};",
        f"const double SSS_PIXELS_PER_SAMPLE_D = {_dnum(spec.pixels_per_sample)};",
        f"const double sogBD[DISK_SOG_N] = double[DISK_SOG_N]({b});",
        f"const dvec3 sogAD[DISK_SOG_N] = dvec3[DISK_SOG_N]({a});",
        double_math_source(),
    ]


def double_math_source() -> str:
    """GLSL 400 ``expD``, ``logD`` and ``sinCosD`` on doubles (GLSL's ``exp``, ``log``,
    ``sin``, ``cos`` and ``pow`` take only floats): range reduction (fdlibm's two- and
    three-part ``ln 2`` and ``π/2``) and Taylor series to below double rounding. Checked
    against Python's ``math`` to a few ulp in ``tests/gl/test_gl_disk.py``."""
    fact = math.factorial
    sin_c = ", ".join(_dnum((-1) ** (j + 1) / fact(2 * j + 3)) for j in range(10))
    cos_c = ", ".join(_dnum((-1) ** j / fact(2 * j + 4)) for j in range(10))
    return "\n".join([
        "// Taylor coefficients: sin t = t + t^3 sum_j SIN_C[j] t^2j, (-1)^(j+1) / (2j+3)!;",
        "// cos t = 1 - t^2/2 + t^4 sum_j COS_C[j] t^2j, (-1)^j / (2j+4)!",
        f"const double SIN_C[10] = double[10]({sin_c});",
        f"const double COS_C[10] = double[10]({cos_c});",
        _MATH_CONSTS + _MATH_FUNCS,
    ])  # fmt: skip


_MATH_CONSTS = """
const double LN2_HI = 6.93147180369123816490e-01LF; // ln 2 in two parts (fdlibm): k LN2_HI
const double LN2_LO = 1.90821492927058770002e-10LF; // is exact for |k| < 2^20
const double PIO2_1 = 1.57079632673412561417e+00LF; // pi/2 in three 33-bit parts (fdlibm)
const double PIO2_2 = 6.07710050630396597660e-11LF;
const double PIO2_3 = 2.02226624871116645580e-21LF;

"""

_MATH_FUNCS = """
// e^x for x <= 709: x = k ln2 + t, |t| <= ln2 / 2, e^t by Horner to t^14 (error < 1e-17);
// below -708 (no normal double) 0: a weight there is 0 in float32 long before
double expD(double x) {
    if (x < -708.0LF) return 0.0LF;
    double k = roundEven(min(x, 709.0LF) * 1.44269504088896338700LF);
    double t = (x - k * LN2_HI) - k * LN2_LO;
    double p = 1.0LF;
    for (int j = 14; j >= 1; j--) p = 1.0LF + t * p / double(j);
    return ldexp(p, int(k));
}

// ln x for a normal x > 0: x = m 2^e, m in [1/sqrt 2, sqrt 2), ln m = 2 atanh(s),
// s = (m - 1)/(m + 1), |s| <= 0.172: the odd series to s^25 (error < 1e-19)
double logD(double x) {
    int e;
    double m = frexp(x, e);
    if (m < 0.70710678118654752440LF) { m *= 2.0LF; e -= 1; }
    double s = (m - 1.0LF) / (m + 1.0LF);
    double s2 = s * s;
    double p = 1.0LF / 25.0LF;
    for (int k = 11; k >= 0; k--) p = 1.0LF / double(2 * k + 1) + s2 * p;
    return double(e) * LN2_HI + (double(e) * LN2_LO + 2.0LF * s * p);
}

// sin x and cos x: x = k pi/2 + t (Cody-Waite, exact for |k| < 2^20), |t| <= pi/4: Taylor
// to t^21 and t^22 (error < 1e-22)
void sinCosD(double x, out double sn, out double cs) {
    double k = roundEven(x * 0.63661977236758134308LF);
    double t = ((x - k * PIO2_1) - k * PIO2_2) - k * PIO2_3;
    double t2 = t * t;
    double ps = SIN_C[9], pc = COS_C[9];
    for (int j = 8; j >= 0; j--) { ps = SIN_C[j] + t2 * ps; pc = COS_C[j] + t2 * pc; }
    double s = t + t * t2 * ps;
    double c = 1.0LF + t2 * (-0.5LF + t2 * pc);
    int q = int(k) & 3;
    sn = q == 0 ? s : q == 1 ? c : q == 2 ? -s : -c;
    cs = q == 0 ? c : q == 1 ? -s : q == 2 ? -c : s;
}
"""


#: the float64 geometry's functions and the estimators' loops (``evaluateHdrp64``,
#: ``evaluateSssbench64``), after the shared declarations of the disk shader
BODY64 = r"""
// ================================================================ float64 geometry (GLSL 400)
// Each sample's geometry in double, in the torch disk's order of operations (DiskSSS._gather,
// _gather_hdrp, the samplers of _disk_radial): quantile, radius, angle, offset in pixels, the
// pixel it rounds to, bilinear fractions, depth difference, 3D distance and weight. Colours
// and depths stay float32 textures, as the torch disk reads them. GLSL has no double exp,
// log, sin, cos or pow: they are written below (range reduction + Taylor series, ~1 ulp);
// which pixel a sample lands in then differs from torch's only for a sample within ~1e-15
// of its own offset of a pixel boundary, where float32 put ~1e-7.

const double DBL_TINY = 2.2250738585072014e-308LF;  // torch.finfo(float64).tiny

double fetchDouble(usampler2D t, int i, bool second) {
    uvec4 w = texelFetch(t, ivec2(i % PATTERN_ROW, i / PATTERN_ROW), 0);
    return packDouble2x32(second ? w.zw : w.xy);
}

// ---------------------------------------------------------------- radial sampling, float64
// _disk_radial.burley_radius: x = e^{-r/3d} is the real root of x^3 + 3x - 4v = 0, v = 1 - u
// (torch: 2 sinh(asinh(2v)/3)); here Newton's method in double from the float32 root in
// HDRP's form (4v / c), quadratic: three steps reach double rounding. r = -3d ln x;
// BurleyRadial.sample: 1/pdf_area = 2 pi r / ((e^{-r/d} + e^{-r/3d}) / 4d)
void sampleBurleyAreaD(double u, out double r, out double rcpPdfArea) {
    double v = 1.0LF - u;
    float vf = float(v);
    float g = 1.0 + 4.0 * vf * (2.0 * vf + sqrt(1.0 + 4.0 * vf * vf));
    float n = pow(g, -1.0 / 3.0);
    double x = double(4.0 * vf / (1.0 + g * n * n + n));
    for (int k = 0; k < 3; k++) x -= (x * x * x + 3.0LF * x - 4.0LF * v) / (3.0LF * x * x + 3.0LF);
    r = BURLEY_R_SCALE * logD(max(x, DBL_TINY));
    double dens = (expD(-r / SAMPLED_D) + expD(-r / (3.0LF * SAMPLED_D))) / (4.0LF * SAMPLED_D);
    rcpPdfArea = TWO_PI_D * r / dens;
}

// _disk_radial.hdrp_burley_sample (HDRP SampleBurleyDiffusionProfile) in double: v = 1 - u,
// g = 1 + 4v (2v + sqrt(1 + 4v^2)), n = g^{-1/3} (Newton on g n^3 = 1 from float32's pow),
// c = 1 + g n^2 + n, r = 3d ln(c / 4v), 1/pdf_polar = 8 pi d c^3 / (4v (c^2 + 16 v^2))
void sampleBurleyPolarD(double u, out double r, out double rcpPdf) {
    double v = 1.0LF - u;
    double g = 1.0LF + 4.0LF * v * (2.0LF * v + sqrt(1.0LF + 4.0LF * v * v));
    double n = double(pow(float(g), -1.0 / 3.0));
    for (int k = 0; k < 3; k++) n += n * (1.0LF - g * n * n * n) / 3.0LF;
    double c = 1.0LF + g * n * n + n;
    r = 3.0LF * SAMPLED_D * logD(c / (4.0LF * v));
    rcpPdf = BURLEY_RCP_SCALE * (c * c * c / (4.0LF * v * (c * c + 16.0LF * v * v)));
}

// TabulatedRadial.sample in double: k the last node with c_k <= u (searchsorted right - 1,
// at most the last interval), slope = (c_{k+1} - c_k) / (r_{k+1} - r_k) (at least tiny),
// r = min(r_k + (u - c_k) / slope, r_{k+1})
void sampleTableD(double u, out double r, out double slope) {
    int lo = 0, hi = DISK_RADIAL_INTERVALS;
    while (lo < hi) {
        int mid = (lo + hi + 1) / 2;
        if (packDouble2x32(texelFetch(radialTex, ivec2(mid, 0), 0).xy) <= u) lo = mid;
        else hi = mid - 1;
    }
    int k = min(lo, DISK_RADIAL_INTERVALS - 1);
    uvec4 n0 = texelFetch(radialTex, ivec2(k, 0), 0);
    uvec4 n1 = texelFetch(radialTex, ivec2(k + 1, 0), 0);
    double c0 = packDouble2x32(n0.xy), r0 = packDouble2x32(n0.zw);
    double c1 = packDouble2x32(n1.xy), r1 = packDouble2x32(n1.zw);
    slope = max((c1 - c0) / (r1 - r0), DBL_TINY);
    r = min(r0 + (u - c0) / slope, r1);
}

// ---------------------------------------------------------------- the profile, float64
// R(r) / ||R||_1 (BurleyNormalized.evaluate: r clamped to 1e-6 d; SumOfGaussians.evaluate)
dvec3 profileOverTotalD(double r) {
    dvec3 s;
#if DISK_PROFILE_BURLEY
    for (int c = 0; c < 3; c++) {
        double d = BURLEY_D_D[c];
        double rr = max(r, 1e-6LF * d);
        s[c] = (expD(-rr / d) + expD(-rr / (3.0LF * d))) / (EIGHT_PI_D * d * rr);
    }
#else
    s = dvec3(0.0LF);
    for (int k = 0; k < DISK_SOG_N; k++) s += sogAD[k] * expD(-r * r * sogBD[k]);
#endif
    return s;
}

// r R(r) / ||R||_1 (_Kernel.polar): HDRP's EvalBurleyDiffusionProfile for Burley
dvec3 polarProfileD(double r) {
#if DISK_PROFILE_BURLEY
    dvec3 s;
    for (int c = 0; c < 3; c++) {
        double d = BURLEY_D_D[c];
        s[c] = (expD(-r / (3.0LF * d)) + expD(-r / d)) / (EIGHT_PI_D * d);
    }
    return s;
#else
    return r * profileOverTotalD(r);
#endif
}

// ---------------------------------------------------------------- estimator="hdrp", float64
// DiskSSS._gather_hdrp / _hdrp_counts in double
vec3 evaluateHdrp64(ivec2 pix, ivec2 size, vec3 colorM, float depthM, double phase) {
    double zc = double(depthM);
    double ppm = 1.0LF / max(zc * pixelMmPerMmD, HDRP_MIN_PIXEL_MM_D);
    double rf = HDRP_FILTER_RADIUS_D * ppm;
    double area = PI_D * (rf * rf);
    int n = int(min(floor(area / SSS_PIXELS_PER_SAMPLE_D), double(DISK_N_SAMPLES)));
    if (n == 0) return colorM;  // fewer than one sample: no filtering
    double turn = TWO_PI_D * phase;
    vec3 num = vec3(0.0), den = vec3(0.0);
    for (int i = 0; i < n; i++) {
        double u = (double(i) + 0.5LF) / double(n);  // fixed: no radial jitter
        double r, rcpPdf;
#if DISK_RADIAL_TABLE
        double slope;
        sampleTableD(u, r, slope);
        rcpPdf = TWO_PI_D * r / slope / r;
#else
        sampleBurleyPolarD(u, r, rcpPdf);
#endif
        double psi = fetchDouble(patternTex, i, false) + turn;  // 2 pi frac(i/phi) + rotation
        double sn, cs;
        sinCosD(psi, sn, cs);
        precise double oc = ppm * r * cs;
        precise double orow = ppm * r * sn;
        ivec2 p = pix + ivec2(int(roundEven(oc)), int(roundEven(orow)));  // half to even
        bool inside = all(greaterThanEqual(p, ivec2(0))) && all(lessThan(p, size));
        ivec2 q = clamp(p, ivec2(0), size - 1);
        double dz = double(texelFetch(depthTex, q, 0).r - depthM);
        double r3D = sqrt(r * r + dz * dz);
        vec3 w = vec3(polarProfileD(r3D) * rcpPdf);
        w *= (inside && accepted(q)) ? 1.0 : 0.0;
        num += w * texelFetch(colorTex, q, 0).rgb;
        den += w;
    }
    return num / max(den, vec3(FLT_MIN));
}

// ---------------------------------------------------------------- estimator="sssbench", float64
// _Pixels.fetch in double: the pixel a point fetch lands in, a bilinear fetch's fractions and
// weights; depth differences formed in float32 (as torch: depth[j] - z_c), then double
void fetchPointD(ivec2 pix, ivec2 size, double drow, double dcol, float depthM,
                 out vec3 rgb, out double dz, out float ok, out float area) {
    ivec2 q = clamp(pix + ivec2(int(floor(dcol + 0.5LF)), int(floor(drow + 0.5LF))),
                    ivec2(0), size - 1);
    rgb = texelFetch(colorTex, q, 0).rgb;
    dz = double(texelFetch(depthTex, q, 0).r - depthM);
    ok = accepted(q) ? 1.0 : 0.0;
    area = texelFetch(areaTex, q, 0).r;
}

void fetchBilinearD(ivec2 pix, ivec2 size, double drow, double dcol, float depthM,
                    out vec3 rgb, out double dz, out float ok, out float area) {
    double fr0 = floor(drow), fc0 = floor(dcol);
    double fr = drow - fr0, fc = dcol - fc0;
    ivec2 c0 = pix + ivec2(int(fc0), int(fr0));
    ivec2 lo = clamp(c0, ivec2(0), size - 1), hi = clamp(c0 + 1, ivec2(0), size - 1);
    ivec2 q[4] = ivec2[4](lo, ivec2(hi.x, lo.y), ivec2(lo.x, hi.y), hi);
    double wt[4] = double[4]((1.0LF - fr) * (1.0LF - fc), (1.0LF - fr) * fc,
                             fr * (1.0LF - fc), fr * fc);
    rgb = vec3(0.0);
    dz = 0.0LF;
    double areaD = 0.0LF, total = 0.0LF;
    for (int k = 0; k < 4; k++) {
        double w = accepted(q[k]) ? wt[k] : 0.0LF;
        rgb += vec3(w * dvec3(texelFetch(colorTex, q[k], 0).rgb));  // per corner, then float32
        dz += w * double(texelFetch(depthTex, q[k], 0).r - depthM);
        areaD += w * double(texelFetch(areaTex, q[k], 0).r);
        total += w;
    }
    ok = total > 0.0LF ? 1.0 : 0.0;
    double safe = total > 0.0LF ? total : 1.0LF;
    rgb /= float(safe);
    area = float(areaD / safe);
    // all corners off the stencil: rejected; its depth is the first corner's
    dz = total > 0.0LF ? dz / safe : double(texelFetch(depthTex, q[0], 0).r - depthM);
}

vec3 evaluateSssbench64(ivec2 pix, ivec2 size, vec3 colorM, float depthM, double phase,
                        double shift) {
    double zc = double(depthM);
    double pixelMm = zc * pixelMmPerMmD;   // pixel_size_mm at the centre, float64
    double stepPx = 1.0LF / pixelMm;       // pixels per mm
    // the centre's view position as gbuffer.view_positions forms it (float32)
    float halfH = 0.5 * float(size.y);
    double xM = double((float(pix.x) + 0.5 - 0.5 * float(size.x)) / halfH * depthM * tanHalfFov);
    double yM = double((halfH - float(pix.y) - 0.5) / halfH * depthM * tanHalfFov);
    double turn = TWO_PI_D * phase;
    vec3 num = vec3(0.0), den = vec3(0.0);
    for (int i = 0; i < DISK_N_SAMPLES; i++) {
#if DISK_JITTER
        double u = fract(fetchDouble(patternTex, i, false) + shift);  // Cranley-Patterson
#else
        double u = fetchDouble(patternTex, i, false);
#endif
        double r, rcpPdfArea;
#if DISK_RADIAL_TABLE
        double slope;
        sampleTableD(u, r, slope);
        rcpPdfArea = TWO_PI_D * r / slope;
#else
        sampleBurleyAreaD(u, r, rcpPdfArea);
#endif
        double theta = fetchDouble(patternTex, i, true) + turn;  // theta_i + 2 pi rotation
        double sn, cs;
        sinCosD(theta, sn, cs);
        precise double dcol = r * cs * stepPx;
        precise double drow = -r * sn * stepPx;  // screen y is up, rows go down
        vec3 rgb;
        double dz;
        float ok, area;
#if DISK_BILINEAR
        fetchBilinearD(pix, size, drow, dcol, depthM, rgb, dz, ok, area);
#else
        fetchPointD(pix, size, drow, dcol, depthM, rgb, dz, ok, area);
#endif
        // x_i - x_p = x_p dz / z_p + offset * pixel_size(z_p + dz), in differences
        double lateral = (zc + dz) * pixelMmPerMmD;
        double dx = xM * (dz / zc) + dcol * lateral;
        double dy = yM * (dz / zc) - drow * lateral;
        double dist = sqrt(dx * dx + dy * dy + dz * dz);
        dvec3 wD = profileOverTotalD(dist) * rcpPdfArea;  // R(d) / pdf / ||R||_1
#if DISK_SURFACE_AREA
        wD *= double(area) / (pixelMm * pixelMm);  // surface area over the disk plane's
#endif
        vec3 w = vec3(wD) * ok;
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

/* Native sample loop of the importance-sampled disk (sssbench.ops.disk.DiskSSS), float32 and
 * float64 images, both estimators. Built into the same library as gather.c (a translation
 * unit of its own, compiled beside gather.c's two halves, sssbench/ops/native/__init__.py)
 * and called through ctypes by sssbench/ops/_disk_native.py; the torch loops DiskSSS._gather and
 * DiskSSS._gather_hdrp are the specification and the fallback.
 *
 * Per centre pixel the loop runs the samples in the torch loop's order and performs its float
 * operations in its order: every sample's geometry (radius, inverse density, angle, sub-pixel
 * offset, interpolated depth difference, 3D distance, weight) in double whatever the image's
 * dtype, colours and the sums in the image's dtype. What differs from the torch loop is the
 * elementary functions (libm's exp, log, sin, cos, sinh, asinh against torch's vectorised
 * SLEEF ones: each within 1 ulp) and, for a sum of Gaussians, the order of the sum over the
 * Gaussians (torch: a BLAS matrix product); tests/ops/test_disk_native.py measures the effect.
 *
 * The per-pixel noise (rotation, radial shift) is computed by the torch code and passed in, or
 * for the 63-bit-seeded hash hashed here from the torch code's 32-bit keys (disk.hash_key;
 * disk_hash_uniform below: the same integer hash, the same float64 values).
 *
 * SIMD: the loops are compiled three times, for the baseline x86-64, AVX2 and AVX-512F,
 * through target attributes (no -march), and a call uses the level sss_get_simd() (gather.c)
 * reports, as the separable passes do. At AVX2 and AVX-512 the default path (estimator
 * "sssbench", point fetch) and HDRP's estimator (since 2026-12-06) run loops vectorised across
 * pixels (disk_simd.h: disk_vec_ and hdrp_vec_, their few-ulp differences to these scalar
 * loops listed there); the bilinear fetch runs the scalar loop at every level.
 * -ffp-contract=off: no fused multiply-add anywhere, so AVX2 and AVX-512 agree bitwise. */
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pool.h"

int sss_get_simd(void); /* gather.c: 0 scalar, 1 AVX2, 2 AVX-512F */
int sss_simd_best(void); /* gather.c: the widest level the CPU supports */

/* One call's arguments (mirrored by _disk_native.DiskArgs; field order matters). Image arrays
 * are in the image's dtype, everything else double or int64. For estimator="hdrp" `step` is
 * HDRP's pixels per mm, `u0` the radii, `rcp` the inverse polar densities and `theta0` the
 * angles of the n samples. */
typedef struct {
    const void *area;      /* (N,) surface area (mm^2), or NULL (then packed's area is 0) */
    const void *packed;    /* (N, 8) the pixels' (r, g, b, z, accept, area, x, y): irradiance,
                              view position (mm), 1 / 0 may a sample land here, surface area
                              (mm^2): the centre's reads and the fetches, one line each */
    const int64_t *pix;    /* (M,) the centre pixels (flat indices into the batch) */
    const double *turn;    /* (M,) 2 pi x the rotation (radians) */
    const double *shift;   /* (M,) the radial Cranley-Patterson shift, or NULL (none) */
    const double *step;    /* (M,) pixels per mm at the centre */
    const double *u0;      /* (n,) radial quantiles (hdrp: radii, mm) */
    const double *theta0;  /* (n,) angles (radians) */
    const double *rcp;     /* (n,) hdrp: inverse polar densities; else NULL */
    void *num, *den;       /* (M, 3) outputs in the image dtype */
    void *mom;             /* (M, 3, 3) output or NULL */
    const double *tab_r;   /* tabulated sampler: (nodes,) radii */
    const double *tab_cdf; /* (nodes,) CDF */
    const int64_t *guide;  /* (guide_n + 1,) count of CDF values <= b / guide_n, minus 1 */
    const double *prof_a;  /* Burley: d (3,); sum of Gaussians: variances (K,) */
    const double *prof_b;  /* Burley: albedo (3,); sum of Gaussians: weights (K, 3) */
    const double *total;   /* (3,) the profile's total per channel */
    double sampler_d;      /* Burley sampler: d of the sampled channel (mm) */
    double per_mm;         /* pixel size per mm of depth: 2 tan(fov_y / 2) / H */
    double eps;            /* Burley: the radius floor's factor (profiles/burley.py _EPS) */
    int64_t m, n, h, w, hw, nodes, guide_n, n_gauss;
    int32_t sampler_kind; /* 0: tabulated, 1: Burley closed form */
    int32_t profile_kind; /* 0: sum of Gaussians, 1: Burley */
    int32_t bilinear, threads;
    /* >= 0: the rotation (turn = NULL) / radial shift (shift = NULL) hashed here from the
     * pixel, as disk.hash_uniform does with this 32-bit key (disk_hash_uniform) */
    int64_t turn_key, shift_key;
} disk_args;

/* disk.hash_uniform: lowbias32 (Wellons) of (the pixel's index in its image) ^ key, / 2^32 */
static inline double disk_hash_uniform(uint64_t pixel, int64_t key) {
    uint32_t x = (uint32_t)(pixel ^ (uint64_t)key);
    x ^= x >> 16;
    x *= 0x7FEB352Du;
    x ^= x >> 15;
    x *= 0x846CA68Bu;
    x ^= x >> 16;
    return (double)x / 4294967296.0;
}

/* whether the samples' radii are jittered (a radial shift per pixel) */
static inline int disk_jitter(const disk_args *a) { return a->shift != NULL || a->shift_key >= 0; }

/* the rotation (2 pi x turns, radians) and the radial shift (or 0) of centre q (pixel pix):
 * passed in, or hashed from the keys; 2 pi as the torch code rounds it (2 * math.pi) */
static inline void disk_noise(const disk_args *a, int64_t q, int64_t pix, double *turn,
                              double *shift) {
    const uint64_t in_image = (uint64_t)(pix % a->hw);
    *turn = a->turn ? a->turn[q] : 6.283185307179586 * disk_hash_uniform(in_image, a->turn_key);
    *shift = a->shift       ? a->shift[q]
             : a->shift_key >= 0 ? disk_hash_uniform(in_image, a->shift_key)
                                 : 0.0;
}

#define TWO_PI (2.0 * 3.141592653589793)
#define EIGHT_PI (8.0 * 3.141592653589793)
#define TINY64 2.2250738585072014e-308 /* torch.finfo(torch.float64).tiny */
/* below it exp(x) rounds to +0 (ln 2^-1075 = -745.133...): skipped, not computed — libm's
 * underflow path costs ~100x a normal exp and the far samples of a narrow Gaussian all take it */
#define EXP_ZERO (-745.2)
/* exp(x), +0 without the call below EXP_ZERO (the same value) */
static inline __attribute__((always_inline)) double exp_(double x) {
    return x < EXP_ZERO ? 0.0 : exp(x);
}

/* the profile R_c(d) per channel (mm^-2), in the torch formulas' order of operations */
static inline __attribute__((always_inline)) void profile_eval(const disk_args *a, double d,
                                                                double out[3]) {
    if (a->profile_kind == 1) { /* profiles/burley.py BurleyNormalized.evaluate */
        for (int c = 0; c < 3; ++c) {
            const double dc = a->prof_a[c];
            const double floor_ = a->eps * dc;
            const double rr = d > floor_ || d != d ? d : floor_; /* torch.maximum */
            out[c] = a->prof_b[c] * (exp_(-rr / dc) + exp_(-rr / (3.0 * dc))) / (EIGHT_PI * dc * rr);
        }
        return;
    }
    /* profiles/sum_of_gaussians.py evaluate, 001 eq. 7: sum_k w_kc exp(-d^2 / 2v_k) / (2 pi v_k) */
    out[0] = out[1] = out[2] = 0.0;
    const double d2 = -(d * d);
    for (int64_t k = 0; k < a->n_gauss; ++k) {
        const double v = a->prof_a[k];
        const double x = d2 / (2.0 * v);
        if (x < EXP_ZERO) continue; /* exp(x) is +0: the term adds (+-)0, the sum is unchanged */
        const double g = exp(x) / (TWO_PI * v);
        for (int c = 0; c < 3; ++c) out[c] += g * a->prof_b[3 * k + c];
    }
}

/* (r, 1/pdf_area) of the quantile u: _disk_radial.BurleyRadial.sample / TabulatedRadial.sample */
static inline __attribute__((always_inline)) double radial_sample(const disk_args *a, double u,
                                                                   double *inv_pdf) {
    if (a->sampler_kind == 1) {
        const double d = a->sampler_d;
        double x = 2.0 * sinh(asinh(2.0 * (1.0 - u)) / 3.0);
        x = x < TINY64 ? TINY64 : x; /* clamp_min (x >= 0 here) */
        const double r = -3.0 * d * log(x);
        const double dens = (exp_(-r / d) + exp_(-r / (3.0 * d))) / (4.0 * d);
        *inv_pdf = TWO_PI * r / dens;
        return r;
    }
    /* searchsorted(cdf, u, right=True) - 1, clamped to [0, nodes - 2]: the guide table bounds
     * the count of CDF values <= u between those of the bucket's two edges (guide_n a power of
     * two, so u * guide_n and the edges are exact) and a binary search finds it */
    const int64_t nodes = a->nodes;
    int64_t b = (int64_t)(u * (double)a->guide_n);
    b = b < 0 ? 0 : (b >= a->guide_n ? a->guide_n - 1 : b);
    int64_t lo = a->guide[b] + 1, hi = a->guide[b + 1] + 1; /* counts: lo <= count <= hi */
    if (!(u >= 0.0 && u < 1.0)) lo = 0, hi = nodes;          /* outside [0, 1): full search */
    while (lo < hi) { /* first index with cdf > u, in [lo, hi] */
        const int64_t mid = lo + (hi - lo) / 2;
        if (a->tab_cdf[mid] <= u)
            lo = mid + 1;
        else
            hi = mid;
    }
    int64_t k = lo - 1;
    k = k < 0 ? 0 : (k > nodes - 2 ? nodes - 2 : k);
    const double c0 = a->tab_cdf[k], c1 = a->tab_cdf[k + 1];
    const double r0 = a->tab_r[k], r1 = a->tab_r[k + 1];
    double slope = (c1 - c0) / (r1 - r0);
    slope = slope > TINY64 || slope != slope ? slope : TINY64;
    double r = r0 + (u - c0) / slope;
    r = r < r1 || r != r ? r : r1; /* torch.minimum */
    *inv_pdf = TWO_PI * r / slope;
    return r;
}

/* samples positioned (and their pixels prefetched) ahead of their fetches */
enum { DISK_CHUNK = 16 };

/* 2^(j/32) of the vectorised exp (disk_simd.h vexp_): sss_exp2_32, shared with quad.c */
#include "exp2_32.h"

/* what the vectorised loop (disk_simd.h) computes once per call: per sample, per node of the
 * tabulated sampler, per Gaussian or channel of the profile (disk_consts_make) */
typedef struct {
    double *cos0, *sin0;    /* (n,) cos / sin of the pattern's angles */
    double *r, *inv_pdf;    /* (n,) without radial jitter: the samples' radii, 1 / pdf_area */
    double *inv_slope;      /* (nodes - 1,) tabulated sampler: 1 / the slope (c1 - c0) / (r1 - r0),
                               clamped as radial_sample does */
    double *inv_2v, *coef;  /* Gaussians: (K,) 1 / (2 v_k), (K, 3) w_kc / (2 pi v_k total_c);
                               Burley: coef (3,) albedo_c / (8 pi d_c total_c) */
    double floor_[3], inv_d[3], inv_3d[3]; /* Burley: eps d_c, 1 / d_c, 1 / (3 d_c) */
    void *block;            /* the one allocation holding the arrays */
} disk_consts;

/* the pixels [p0, p1) of one call, split over threads */
typedef struct {
    const disk_args *a;
    const disk_consts *k; /* the vectorised loop's constants, or NULL (the scalar loop) */
    int64_t p0, p1;
} disk_job;

#if (defined(__x86_64__) || defined(_M_X64)) && defined(__GNUC__)
#define DISK_SIMD 1
#include <immintrin.h>
/* the vectorised loop's gathers, rounding, square root and any-lane test per instruction set
 * (disk_simd.h): index vectors are int64 element offsets */
#define VGATHER_F64_AVX512(base, idx) _mm512_i64gather_pd((__m512i)(idx), (base), 8)
#define VGATHER_I64_AVX512(base, idx) \
    _mm512_i64gather_epi64((__m512i)(idx), (const long long *)(base), 8)
#define VGATHER_F32S_AVX512(base, idx) _mm512_i64gather_ps((__m512i)(idx), (base), 4)
#define VGATHER_F64S_AVX512(base, idx) _mm512_i64gather_pd((__m512i)(idx), (base), 8)
#define VFLOOR_AVX512(x) \
    ((__typeof__(x))_mm512_roundscale_pd((__m512d)(x), _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC))
#define VTRUNC_AVX512(x) \
    ((__typeof__(x))_mm512_roundscale_pd((__m512d)(x), _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC))
/* nearbyint: to the nearest integer, half to even (the default rounding mode's) */
#define VRINT_AVX512(x) \
    ((__typeof__(x))_mm512_roundscale_pd((__m512d)(x), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC))
#define VSQRT_AVX512(x) ((__typeof__(x))_mm512_sqrt_pd((__m512d)(x)))
#define VANY_AVX512(m) (_mm512_test_epi64_mask((__m512i)(m), (__m512i)(m)) != 0)
#define VGATHER_F64_AVX2(base, idx) _mm256_i64gather_pd((base), (__m256i)(idx), 8)
#define VGATHER_I64_AVX2(base, idx) \
    _mm256_i64gather_epi64((const long long *)(base), (__m256i)(idx), 8)
#define VGATHER_F32S_AVX2(base, idx) _mm256_i64gather_ps((base), (__m256i)(idx), 4)
#define VGATHER_F64S_AVX2(base, idx) _mm256_i64gather_pd((base), (__m256i)(idx), 8)
#define VFLOOR_AVX2(x) \
    ((__typeof__(x))_mm256_round_pd((__m256d)(x), _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC))
#define VTRUNC_AVX2(x) \
    ((__typeof__(x))_mm256_round_pd((__m256d)(x), _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC))
#define VRINT_AVX2(x) \
    ((__typeof__(x))_mm256_round_pd((__m256d)(x), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC))
#define VSQRT_AVX2(x) ((__typeof__(x))_mm256_sqrt_pd((__m256d)(x)))
#define VANY_AVX2(m) (_mm256_movemask_pd((__m256d)(m)) != 0)
/* 2^(j/32) of the vectorised exp (vexp_, disk_simd.h), j = n32 mod 32 per lane (n32: VW int32
 * lanes): AVX2 by a gather from sss_exp2_32; AVX-512 from the same table held in four
 * registers, by two two-source permutes (bits 0-3 of j) and a blend (bit 4), with no memory
 * access per lane. The same table entries: the levels agree bitwise. Measured on the 512²
 * close-up (32 samples, skin_deon6), the disk's call 7 % faster than with the gather: its
 * exps' gathers (six per sample) wait on memory; the permutes do not. */
#define VEXP2_32_AVX2(n32) \
    _mm256_i64gather_pd(sss_exp2_32, _mm256_cvtepi32_epi64((__m128i)((n32) & 31)), 8)
/* 2^(j/8), j = 0..7 (VW int32 lanes), as floats for the float32-precision exp (vexpf_,
 * disk_simd.h): the float32 roundings of exp2_32.h's 2^(4j/32), by two in-lane permutes and a
 * blend on bit 2 (AVX2, four lanes) or one permute (AVX-512, eight): the same entries, so the
 * levels agree bitwise */
#define SSS_EXP2_8F                                                                          \
    {(float)sss_exp2_32[0],  (float)sss_exp2_32[4],  (float)sss_exp2_32[8],                  \
     (float)sss_exp2_32[12], (float)sss_exp2_32[16], (float)sss_exp2_32[20],                 \
     (float)sss_exp2_32[24], (float)sss_exp2_32[28]}
#define VEXP2_8F_AVX2(j)                                                          \
    ({                                                                            \
        const float t_[8] = SSS_EXP2_8F;                                          \
        const __m128 lo_ = _mm_permutevar_ps(_mm_loadu_ps(t_), (__m128i)(j));     \
        const __m128 hi_ = _mm_permutevar_ps(_mm_loadu_ps(t_ + 4), (__m128i)(j)); \
        _mm_blendv_ps(lo_, hi_, (__m128)_mm_slli_epi32((__m128i)(j), 29));        \
    })
#define VEXP2_8F_AVX512(j)                                                \
    ({                                                                    \
        const float t_[8] = SSS_EXP2_8F;                                  \
        _mm256_permutevar8x32_ps(_mm256_loadu_ps(t_), (__m256i)(j));      \
    })
#define VEXP2_32_AVX512(n32)                                                                  \
    ({                                                                                        \
        const __m512i j_ = _mm512_cvtepi32_epi64((__m256i)(n32));                             \
        const __m512d lo_ = _mm512_permutex2var_pd(_mm512_load_pd(sss_exp2_32), j_,        \
                                                   _mm512_load_pd(sss_exp2_32 + 8));        \
        const __m512d hi_ = _mm512_permutex2var_pd(_mm512_load_pd(sss_exp2_32 + 16), j_,   \
                                                   _mm512_load_pd(sss_exp2_32 + 24));       \
        _mm512_mask_blend_pd(_mm512_test_epi64_mask(j_, _mm512_set1_epi64(16)), lo_, hi_); \
    })
#else
#define DISK_SIMD 0
#endif

#define SCALAR float
#define SUFFIX f32
#define VGATHER_S_AVX512 VGATHER_F32S_AVX512
#define VGATHER_S_AVX2 VGATHER_F32S_AVX2
#include "disk_body.h"
#undef SCALAR
#undef SUFFIX
#undef VGATHER_S_AVX512
#undef VGATHER_S_AVX2
#define SCALAR double
#define SUFFIX f64
#define VGATHER_S_AVX512 VGATHER_F64S_AVX512
#define VGATHER_S_AVX2 VGATHER_F64S_AVX2
#include "disk_body.h"
#undef SCALAR
#undef SUFFIX
#undef VGATHER_S_AVX512
#undef VGATHER_S_AVX2

/* the vectorised loop's per-call constants (disk_consts); 0 when out of memory (the caller
 * then runs the scalar loop) */
static int disk_consts_make(const disk_args *a, disk_consts *k) {
    const int64_t n = a->n > 0 ? a->n : 0, g = a->n_gauss > 0 ? a->n_gauss : 0;
    const int64_t nodes = a->sampler_kind == 0 && a->nodes > 1 ? a->nodes : 1;
    double *m = malloc(sizeof(double) * (size_t)(4 * n + nodes + 4 * g + 3 + 1));
    if (!m) return 0;
    k->block = m;
    k->cos0 = m, k->sin0 = m + n, k->r = m + 2 * n, k->inv_pdf = m + 3 * n;
    k->inv_slope = m + 4 * n, k->inv_2v = k->inv_slope + nodes, k->coef = k->inv_2v + g;
    for (int64_t i = 0; i < n; ++i) {
        k->cos0[i] = cos(a->theta0[i]), k->sin0[i] = sin(a->theta0[i]);
        if (!disk_jitter(a)) k->r[i] = radial_sample(a, a->u0[i], &k->inv_pdf[i]);
    }
    if (a->sampler_kind == 0)
        for (int64_t j = 0; j + 1 < a->nodes; ++j) { /* radial_sample's slope */
            const double s = (a->tab_cdf[j + 1] - a->tab_cdf[j]) / (a->tab_r[j + 1] - a->tab_r[j]);
            k->inv_slope[j] = 1.0 / (s > TINY64 || s != s ? s : TINY64);
        }
    if (a->profile_kind == 1) { /* 002 eq. 3 (profiles/burley.py), over the channel's total */
        for (int c = 0; c < 3; ++c) {
            const double dc = a->prof_a[c];
            k->floor_[c] = a->eps * dc, k->inv_d[c] = 1.0 / dc, k->inv_3d[c] = 1.0 / (3.0 * dc);
            k->coef[c] = a->prof_b[c] / (EIGHT_PI * dc) / a->total[c];
        }
    } else { /* 001 eq. 7: w_kc / (2 pi v_k), over the channel's total */
        for (int64_t j = 0; j < g; ++j) {
            const double v = a->prof_a[j];
            k->inv_2v[j] = 1.0 / (2.0 * v);
            for (int c = 0; c < 3; ++c)
                k->coef[3 * j + c] = a->prof_b[3 * j + c] / (TWO_PI * v) / a->total[c];
        }
    }
    return 1;
}

enum { DISK_MAX_THREADS = 64, DISK_MIN_WORK = 1 << 16 };

/* split the centre pixels over the threads (each at least DISK_MIN_WORK pixel-samples) and run */
static void disk_split(const disk_args *a, const disk_consts *k, void *(*run)(void *)) {
    int threads = a->threads < 1 ? 1 : (a->threads > DISK_MAX_THREADS ? DISK_MAX_THREADS : a->threads);
    const int64_t work = a->m * (a->n > 0 ? a->n : 1);
    if (work < (int64_t)DISK_MIN_WORK * threads)
        threads = work < 2 * (int64_t)DISK_MIN_WORK ? 1 : (int)(work / DISK_MIN_WORK);
    disk_job jobs[DISK_MAX_THREADS];
    for (int t = 0; t < threads; ++t)
        jobs[t] = (disk_job){a, k, a->m * t / threads, a->m * (t + 1) / threads};
    pool_run(run, (char *)jobs, sizeof jobs[0], threads);
}

/* estimator "sssbench": at the AVX2 and AVX-512 levels the point fetch runs the vectorised
 * loop (disk_simd.h), the bilinear fetch and the scalar level the scalar loop */
#define DISK_ENTRY(name, fn)                                                            \
    void name(const disk_args *a) {                                                     \
        const int level = sss_get_simd();                                               \
        disk_consts k;                                                                  \
        if (DISK_SIMD && level >= 1 && !a->bilinear && disk_consts_make(a, &k)) {       \
            disk_split(a, &k, level >= 2 ? fn##_avx512 : fn##_avx2);                    \
            free(k.block);                                                              \
            return;                                                                     \
        }                                                                               \
        disk_split(a, NULL, level >= 2 ? fn##_avx512 : level == 1 ? fn##_avx2 : fn##_scalar); \
    }
#define HDRP_ENTRY(name, fn)                                                                \
    void name(const disk_args *a) {                                                         \
        const int level = sss_get_simd();                                                   \
        disk_split(a, NULL, level >= 2 ? fn##_avx512 : level == 1 ? fn##_avx2 : fn##_scalar); \
    }

DISK_ENTRY(sss_disk_f32, disk_run_f32)
DISK_ENTRY(sss_disk_f64, disk_run_f64)
HDRP_ENTRY(sss_disk_hdrp_f32, hdrp_run_f32)
HDRP_ENTRY(sss_disk_hdrp_f64, hdrp_run_f64)

/* Burley's sampler (radial_sample, sampler_kind 1, d mm) at n quantiles u: radii r and
 * inverse area densities inv, by the vectorised loop's burley_radial_ for images of float32
 * (f32 != 0) or float64 at `level` (1 AVX2, 2 AVX-512F, capped at the CPU's; 0: the scalar
 * loop's, libm): for its test against the scalar loop. Returns the level used. */
int sss_disk_burley_radial(double d, const double *u, double *r, double *inv, int64_t n,
                           int level, int f32) {
    const int best = sss_get_simd() >= 0 ? sss_simd_best() : 0;
    level = level > best ? best : (level < 0 ? 0 : level);
    disk_args a;
    memset(&a, 0, sizeof a);
    a.sampler_kind = 1, a.sampler_d = d;
#if DISK_SIMD
    if (level >= 2)
        return (f32 ? burley_radial_array_f32_avx512
                    : burley_radial_array_f64_avx512)(&a, u, r, inv, n), 2;
    if (level == 1)
        return (f32 ? burley_radial_array_f32_avx2
                    : burley_radial_array_f64_avx2)(&a, u, r, inv, n), 1;
#endif
    for (int64_t i = 0; i < n; ++i) r[i] = radial_sample(&a, u[i], &inv[i]);
    return 0;
}

/* y = exp(x) for n doubles by the vectorised loop's exp for images of float32 (f32 != 0,
 * vexpf_) or float64 (vexp_) at `level` (1 AVX2, 2 AVX-512F, capped at the CPU's; 0: libm's
 * exp): for its test against libm. Returns the level used. */
int sss_disk_vexp(const double *x, double *y, int64_t n, int level, int f32) {
    const int best = sss_get_simd() >= 0 ? sss_simd_best() : 0;
    level = level > best ? best : (level < 0 ? 0 : level);
#if DISK_SIMD
    if (level >= 2) return (f32 ? vexp_array_f32_avx512 : vexp_array_f64_avx512)(x, y, n), 2;
    if (level == 1) return (f32 ? vexp_array_f32_avx2 : vexp_array_f64_avx2)(x, y, n), 1;
#endif
    for (int64_t i = 0; i < n; ++i) y[i] = exp(x[i]);
    return 0;
}

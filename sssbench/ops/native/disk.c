/* Native sample loop of the importance-sampled disk (sssbench.ops.disk.DiskSSS), float32 and
 * float64 images, both estimators. Built into the same library as gather.c (a second
 * translation unit of the same compiler command, sssbench/ops/native/__init__.py) and called
 * through ctypes by sssbench/ops/_disk_native.py; the torch loops DiskSSS._gather and
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
 * The per-pixel noise (rotation, radial shift: the 63-bit-seeded hash, interleaved gradient
 * noise, blue noise) is computed by the torch code and passed in: identical by construction.
 *
 * SIMD: the loop is compiled three times, for the baseline x86-64, AVX2 and AVX-512F, through
 * target attributes (no -march), and a call uses the level sss_get_simd() (gather.c) reports,
 * as the separable passes do. The arithmetic is the same sequence of IEEE operations at every
 * level (-ffp-contract=off: no fused multiply-add), so the levels agree bitwise. */
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pool.h"

int sss_get_simd(void); /* gather.c: 0 scalar, 1 AVX2, 2 AVX-512F */

/* One call's arguments (mirrored by _disk_native.DiskArgs; field order matters). Image arrays
 * are in the image's dtype, everything else double or int64. For estimator="hdrp" `step` is
 * HDRP's pixels per mm, `u0` the radii, `rcp` the inverse polar densities and `theta0` the
 * angles of the n samples. */
typedef struct {
    const void *rgb;       /* (N, 3) channels-last irradiance of the batch */
    const void *pos;       /* (N, 3) view positions (mm) */
    const void *accept;    /* (N,) 1 / 0: may a sample land here */
    const void *area;      /* (N,) surface area (mm^2), or NULL */
    const void *packed;    /* (N, 8) the pixels' (r, g, b, z, accept, area, 0, 0): the fetch */
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
} disk_args;

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

/* the pixels [p0, p1) of one call, split over threads */
typedef struct {
    const disk_args *a;
    int64_t p0, p1;
} disk_job;

#define SCALAR float
#define SUFFIX f32
#include "disk_body.h"
#undef SCALAR
#undef SUFFIX
#define SCALAR double
#define SUFFIX f64
#include "disk_body.h"
#undef SCALAR
#undef SUFFIX

enum { DISK_MAX_THREADS = 64, DISK_MIN_WORK = 1 << 16 };

/* split the centre pixels over the threads (each at least DISK_MIN_WORK pixel-samples) and run */
static void disk_split(const disk_args *a, void *(*run)(void *)) {
    int threads = a->threads < 1 ? 1 : (a->threads > DISK_MAX_THREADS ? DISK_MAX_THREADS : a->threads);
    const int64_t work = a->m * (a->n > 0 ? a->n : 1);
    if (work < (int64_t)DISK_MIN_WORK * threads)
        threads = work < 2 * (int64_t)DISK_MIN_WORK ? 1 : (int)(work / DISK_MIN_WORK);
    disk_job jobs[DISK_MAX_THREADS];
    for (int t = 0; t < threads; ++t)
        jobs[t] = (disk_job){a, a->m * t / threads, a->m * (t + 1) / threads};
    pool_run(run, (char *)jobs, sizeof jobs[0], threads);
}

#define DISK_ENTRY(name, fn)                                                     \
    void name(const disk_args *a) {                                              \
        const int level = sss_get_simd();                                        \
        disk_split(a, level >= 2 ? fn##_avx512 : level == 1 ? fn##_avx2 : fn##_scalar); \
    }

DISK_ENTRY(sss_disk_f32, disk_run_f32)
DISK_ENTRY(sss_disk_f64, disk_run_f64)
DISK_ENTRY(sss_disk_hdrp_f32, hdrp_run_f32)
DISK_ENTRY(sss_disk_hdrp_f64, hdrp_run_f64)

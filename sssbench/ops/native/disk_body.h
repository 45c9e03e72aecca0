/* The disk's sample loops for one image dtype (SCALAR, SUFFIX): included twice by disk.c.
 * Each line cites the torch loop it follows (sssbench/ops/disk.py: DiskSSS._gather,
 * _Pixels.fetch, DiskSSS._gather_hdrp). */
#define DCAT_(a, b) a##_##b
#define DCAT(a, b) DCAT_(a, b)

/* _Pixels.fetch: irradiance (image dtype), depth difference to the centre (double), acceptance
 * and surface area of the sample at offset (drow, dcol) pixels from centre (row, col) */
static inline __attribute__((always_inline)) SCALAR DCAT(fetch, SUFFIX)(
    const disk_args *a, int64_t base, int64_t row, int64_t col, SCALAR z_c, double drow,
    double dcol, SCALAR rgb[3], double *dz, double *area) {
    /* the packed pixels (r, g, b, z, accept, area, -, -): one cache line per fetched pixel */
    const SCALAR *px = (const SCALAR *)a->packed;
    const int has_area = a->area != NULL;
    const int64_t h = a->h, w = a->w;
    if (!a->bilinear) { /* the pixel containing the sample, clamped to the edge */
        int64_t ri = row + (int64_t)floor(drow + 0.5), ci = col + (int64_t)floor(dcol + 0.5);
        ri = ri < 0 ? 0 : (ri > h - 1 ? h - 1 : ri);
        ci = ci < 0 ? 0 : (ci > w - 1 ? w - 1 : ci);
        const int64_t j = base + ri * w + ci;
        const SCALAR *q = px + 8 * j;
        rgb[0] = q[0], rgb[1] = q[1], rgb[2] = q[2];
        *dz = (double)(SCALAR)(q[3] - z_c);
        if (has_area) *area = (double)q[5];
        return q[4];
    }
    /* bilinear: the four corners, weight x acceptance, renormalised; the offset's integer and
     * fractional parts from the offset itself */
    const double fr0 = floor(drow), fc0 = floor(dcol);
    const double fr = drow - fr0, fc = dcol - fc0;
    const int64_t r0 = row + (int64_t)fr0, c0 = col + (int64_t)fc0;
    const int64_t rows[2] = {r0 < 0 ? 0 : (r0 > h - 1 ? h - 1 : r0),
                             r0 + 1 < 0 ? 0 : (r0 + 1 > h - 1 ? h - 1 : r0 + 1)};
    const int64_t cols[2] = {c0 < 0 ? 0 : (c0 > w - 1 ? w - 1 : c0),
                             c0 + 1 < 0 ? 0 : (c0 + 1 > w - 1 ? w - 1 : c0 + 1)};
    const double wts[4] = {(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc};
    SCALAR sum[3] = {0, 0, 0};
    double dzs = 0.0, total = 0.0, areas = 0.0;
    int64_t nearest = 0;
    for (int q = 0; q < 4; ++q) {
        const int64_t j = base + rows[q >> 1] * w + cols[q & 1];
        if (q == 0) nearest = j;
        const SCALAR *pj = px + 8 * j;
        const double wt = wts[q] * (double)pj[4];
        for (int c = 0; c < 3; ++c) sum[c] += (SCALAR)(wt * (double)pj[c]);
        dzs += wt * (double)(SCALAR)(pj[3] - z_c);
        if (has_area) areas += wt * (double)pj[5];
        total += wt;
    }
    const double safe = total > 0 ? total : 1.0;
    *dz = total > 0 ? dzs / safe : (double)(SCALAR)(px[8 * nearest + 3] - z_c);
    if (has_area) *area = areas / safe;
    for (int c = 0; c < 3; ++c) rgb[c] = sum[c] / (SCALAR)safe;
    return total > 0 ? (SCALAR)1 : (SCALAR)0;
}

/* DiskSSS._gather: sum w E, sum w and the second moments over the n samples of the pixels
 * [p0, p1) */
static inline __attribute__((always_inline)) void DCAT(disk_pixels, SUFFIX)(const disk_args *a,
                                                                            int64_t p0,
                                                                            int64_t p1) {
    const SCALAR *centre = (const SCALAR *)a->packed;
    SCALAR *num = (SCALAR *)a->num, *den = (SCALAR *)a->den, *mom = (SCALAR *)a->mom;
    for (int64_t p = p0; p < p1; ++p) {
        const int64_t pix = a->pix[p];
        const int64_t base = pix - pix % a->hw, rem = pix % a->hw;
        const int64_t row = rem / a->w, col = rem % a->w;
        const SCALAR z_cs = centre[8 * pix + 3];
        const double x_c = (double)centre[8 * pix + 6], y_c = (double)centre[8 * pix + 7];
        const double z_c = (double)z_cs, step = a->step[p];
        double turn, shift;
        disk_noise(a, p, pix, &turn, &shift);
        const int jitter = disk_jitter(a);
        /* the area factor's denominator: pixel_size_mm(z_c) ** 2 */
        const double psz = z_c * a->per_mm, psz2 = psz * psz;
        SCALAR s_num[3] = {0, 0, 0}, s_den[3] = {0, 0, 0}, s_mom[9] = {0};
        /* in chunks: first every sample's position (prefetching the pixel it lands on, so
         * that the chunk's cache misses overlap), then the fetches and weights; the same
         * operations as one sample at a time */
        double c_inv[DISK_CHUNK], c_dcol[DISK_CHUNK], c_drow[DISK_CHUNK];
        const SCALAR *px = (const SCALAR *)a->packed;
        for (int64_t i0 = 0; i0 < a->n; i0 += DISK_CHUNK) {
            const int64_t cnt = a->n - i0 < DISK_CHUNK ? a->n - i0 : DISK_CHUNK;
            for (int64_t t = 0; t < cnt; ++t) {
                double u = a->u0[i0 + t];
                if (jitter) {
                    u = u + shift;
                    u = u - trunc(u); /* torch.frac */
                }
                const double r = radial_sample(a, u, &c_inv[t]);
                const double theta = a->theta0[i0 + t] + turn;
                c_dcol[t] = r * cos(theta) * step;
                c_drow[t] = -r * sin(theta) * step; /* screen y is up, rows go down */
                int64_t ri = row + (int64_t)floor(c_drow[t] + 0.5);
                int64_t ci = col + (int64_t)floor(c_dcol[t] + 0.5);
                ri = ri < 0 ? 0 : (ri > a->h - 1 ? a->h - 1 : ri);
                ci = ci < 0 ? 0 : (ci > a->w - 1 ? a->w - 1 : ci);
                __builtin_prefetch(px + 8 * (base + ri * a->w + ci));
            }
            for (int64_t t = 0; t < cnt; ++t) {
            const double inv_pdf = c_inv[t], dcol = c_dcol[t], drow = c_drow[t];
            SCALAR rgb[3];
            double dz, area = 0.0;
            const SCALAR ok = DCAT(fetch, SUFFIX)(a, base, row, col, z_cs, drow, dcol, rgb, &dz,
                                                 &area);
            const double lateral = (z_c + dz) * a->per_mm;
            const double dx = x_c * (dz / z_c) + dcol * lateral;
            const double dy = y_c * (dz / z_c) - drow * lateral;
            const double dist = sqrt(dx * dx + dy * dy + dz * dz);
            double prof[3];
            profile_eval(a, dist, prof);
            const double fac = a->area ? area / psz2 : 1.0;
            for (int c = 0; c < 3; ++c) {
                double wd = prof[c] * inv_pdf / a->total[c];
                if (a->area) wd = wd * fac;
                const SCALAR wc = (SCALAR)wd * ok;
                const SCALAR f = wc * rgb[c];
                s_num[c] += f;
                s_den[c] += wc;
                if (mom) {
                    s_mom[3 * c] += f * f;
                    s_mom[3 * c + 1] += wc * f;
                    s_mom[3 * c + 2] += wc * wc;
                }
            }
            }
        }
        for (int c = 0; c < 3; ++c) num[3 * p + c] = s_num[c], den[3 * p + c] = s_den[c];
        if (mom)
            for (int c = 0; c < 9; ++c) mom[9 * p + c] = s_mom[c];
    }
}

/* DiskSSS._gather_hdrp: sum w E and sum w over HDRP's n samples of the pixels [p0, p1) */
static inline __attribute__((always_inline)) void DCAT(hdrp_pixels, SUFFIX)(const disk_args *a,
                                                                            int64_t p0,
                                                                            int64_t p1) {
    const SCALAR *px = (const SCALAR *)a->packed;
    SCALAR *num = (SCALAR *)a->num, *den = (SCALAR *)a->den;
    const int64_t h = a->h, w = a->w;
    for (int64_t p = p0; p < p1; ++p) {
        const int64_t pix = a->pix[p];
        const int64_t base = pix - pix % a->hw, rem = pix % a->hw;
        const int64_t row = rem / w, col = rem % w;
        const SCALAR z_c = px[8 * pix + 3];
        const double ppm = a->step[p], turn = a->turn[p];
        SCALAR s_num[3] = {0, 0, 0}, s_den[3] = {0, 0, 0};
        for (int64_t k = 0; k < a->n; ++k) {
            const double rk = a->u0[k];
            const double psi = a->theta0[k] + turn;
            const int64_t rs = row + (int64_t)nearbyint(ppm * rk * sin(psi)); /* half to even */
            const int64_t cs = col + (int64_t)nearbyint(ppm * rk * cos(psi));
            const int inside = rs >= 0 && rs < h && cs >= 0 && cs < w;
            const int64_t j = base + (rs < 0 ? 0 : (rs > h - 1 ? h - 1 : rs)) * w +
                              (cs < 0 ? 0 : (cs > w - 1 ? w - 1 : cs));
            const SCALAR *q = px + 8 * j;
            const double dz = (double)(SCALAR)(q[3] - z_c);
            const double r3 = sqrt(rk * rk + dz * dz);
            double pol[3];
            if (a->profile_kind == 1) { /* _Kernel.polar: HDRP's EvalBurley, S/(8 pi) (...) */
                for (int c = 0; c < 3; ++c) {
                    const double dc = a->prof_a[c];
                    pol[c] = (exp_(-r3 / (3.0 * dc)) + exp_(-r3 / dc)) / (EIGHT_PI * dc);
                }
            } else { /* r R_c(r) / total_c */
                double prof[3];
                profile_eval(a, r3, prof);
                for (int c = 0; c < 3; ++c) pol[c] = r3 * prof[c] / a->total[c];
            }
            const SCALAR gate = (SCALAR)inside * q[4];
            for (int c = 0; c < 3; ++c) {
                const SCALAR wc = (SCALAR)(pol[c] * a->rcp[k]) * gate;
                s_num[c] += wc * q[c];
                s_den[c] += wc;
            }
        }
        for (int c = 0; c < 3; ++c) num[3 * p + c] = s_num[c], den[3 * p + c] = s_den[c];
    }
}

/* the vectorised loop (disk_simd.h) for AVX2 and AVX-512F */
#if DISK_SIMD
#define ISA avx2
#define ISA_TARGET "avx2,fma"
#define VW 4
#define VGATHER_F64 VGATHER_F64_AVX2
#define VGATHER_I64 VGATHER_I64_AVX2
#define VGATHER_S VGATHER_S_AVX2
#define VFLOOR VFLOOR_AVX2
#define VTRUNC VTRUNC_AVX2
#define VRINT VRINT_AVX2
#define VSQRT VSQRT_AVX2
#define VANY VANY_AVX2
#define VEXP2_32 VEXP2_32_AVX2
#define VEXP2_8F VEXP2_8F_AVX2
#include "disk_simd.h" /* undefines the level's macros at its end */
#define ISA avx512
#define ISA_TARGET "avx512f"
#define VW 8
#define VGATHER_F64 VGATHER_F64_AVX512
#define VGATHER_I64 VGATHER_I64_AVX512
#define VGATHER_S VGATHER_S_AVX512
#define VFLOOR VFLOOR_AVX512
#define VTRUNC VTRUNC_AVX512
#define VRINT VRINT_AVX512
#define VSQRT VSQRT_AVX512
#define VANY VANY_AVX512
#define VEXP2_32 VEXP2_32_AVX512
#define VEXP2_8F VEXP2_8F_AVX512
#include "disk_simd.h" /* undefines the level's macros at its end */
/* a job's vectorised loop at level isa: 1 when it ran, 0 when the job needs the scalar loop
 * (estimator "sssbench": a job without constants, disk.c DISK_ENTRY) */
#define DISK_VEC(isa, job) \
    ((job)->k ? (DCAT(DCAT(disk_vec_, SUFFIX), isa)((job)->a, (job)->k, (job)->p0, (job)->p1), 1) : 0)
#define HDRP_VEC(isa, job) (DCAT(DCAT(hdrp_vec_, SUFFIX), isa)((job)->a, (job)->p0, (job)->p1), 1)
#else
#define DISK_VEC(isa, job) 0
#define HDRP_VEC(isa, job) 0
#endif

/* the thread entry points at the three instruction-set levels (disk.c header): at AVX2 and
 * AVX-512 the vectorised loop VEC where it runs the job (see DISK_VEC), else the scalar one */
#define DISK_LEVELS(kernel, runner, VEC)                                                 \
    static void *DCAT(runner, scalar)(void *arg) {                                      \
        const disk_job *job = (const disk_job *)arg;                                    \
        kernel(job->a, job->p0, job->p1);                                               \
        return NULL;                                                                    \
    }                                                                                   \
    __attribute__((target("avx2,fma"))) static void *DCAT(runner, avx2)(void *arg) {    \
        const disk_job *job = (const disk_job *)arg;                                    \
        if (!VEC(avx2, job)) kernel(job->a, job->p0, job->p1);                          \
        return NULL;                                                                    \
    }                                                                                   \
    __attribute__((target("avx512f"))) static void *DCAT(runner, avx512)(void *arg) {   \
        const disk_job *job = (const disk_job *)arg;                                    \
        if (!VEC(avx512, job)) kernel(job->a, job->p0, job->p1);                        \
        return NULL;                                                                    \
    }

DISK_LEVELS(DCAT(disk_pixels, SUFFIX), DCAT(disk_run, SUFFIX), DISK_VEC)
DISK_LEVELS(DCAT(hdrp_pixels, SUFFIX), DCAT(hdrp_run, SUFFIX), HDRP_VEC)
#undef DISK_LEVELS
#undef DISK_VEC
#undef HDRP_VEC
#undef DCAT
#undef DCAT_

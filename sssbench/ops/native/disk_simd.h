/* The disk's vectorised sample loop (estimator "sssbench", point fetch) for one image dtype
 * (SCALAR, SUFFIX) and one instruction set: included by disk_body.h once per set, with ISA
 * naming it, ISA_TARGET its target attribute, VW the pixels per vector (double lanes: 4 for
 * AVX2, 8 for AVX-512F), and the set's gathers, rounding and square root (disk.c). The
 * dispatch is the separable passes' (sss_get_simd, gather.c; disk.c DISK_ENTRY).
 *
 * One vector holds VW consecutive centre pixels (consecutive entries of the pixel list: on
 * one row, mostly, so their samples land near each other); every sample of the pattern is
 * taken for all VW pixels at once. What the scalar loop (disk_pixels_, disk_body.h) computes
 * per pixel and sample is split into
 *   - per call: each sample's (cos theta0, sin theta0), and without radial jitter its radius
 *     and inverse density (radial_sample, once); the profile's constants (1 / (2 v_k),
 *     w_kc / (2 pi v_k total_c) for a sum of Gaussians; 1 / d_c, 1 / (3 d_c),
 *     albedo_c / (8 pi d_c total_c) for Burley);
 *   - per pixel: cos and sin of its rotation (libm), its position, step, row and column;
 *   - per sample and pixel, in double lanes: the jittered radius (the tabulated sampler's
 *     guide table and binary search by gathers; Burley's closed form by burley_radial_,
 *     vectorised since 2026-12-06), the angle by the addition theorem cos(theta0 + t) =
 *     cos theta0 cos t - sin theta0 sin t (and likewise sin), the offset, the fetched pixel
 *     (hardware gathers of the packed (r, g, b, z, accept, area) rows), the 3D distance and
 *     the profile, whose exp
 *     is vexp_ below for a float64 image and vexpf_ (float32 precision) for a float32 one;
 *     the sums in the image dtype in the scalar loop's order.
 * The differences to the scalar loop (and so to the torch loop) are the addition theorem
 * (an absolute error of the unit offset below 3e-16 against libm's cos / sin of the rounded
 * sum theta0 + t: the same size as that rounding), vexp_'s or vexpf_'s error, Burley's sampler
 * (_disk_native.DISK_BURLEY_R_ABS), and products by
 * reciprocals computed once in place of divisions (1 ulp each): a few ulp of each float64
 * weight, measured against the torch loop by tests/ops/test_disk_native.py
 * (_disk_native.DISK_NATIVE_AGREEMENT). All VW lanes run the same IEEE operations (no FMA:
 * -ffp-contract=off), so AVX2 and AVX-512 agree bitwise. */

#define DV(name) DCAT(DCAT(name, SUFFIX), ISA)
#define DV_FN static inline __attribute__((always_inline, target(ISA_TARGET)))

typedef double DV(vd_) __attribute__((vector_size(VW * 8)));
typedef int64_t DV(vl_) __attribute__((vector_size(VW * 8)));
typedef int32_t DV(vi_) __attribute__((vector_size(VW * 4)));
typedef SCALAR DV(vs_) __attribute__((vector_size(VW * sizeof(SCALAR))));

/* the set's gathers (disk.c) as this file's vector types */
#define GF64(base, idx) ((DV(vd_))VGATHER_F64(base, idx))
#define GI64(base, idx) ((DV(vl_))VGATHER_I64(base, idx))
#define GS(base, idx) ((DV(vs_))VGATHER_S(base, idx))

/* lane-wise m ? a : b (m: all-ones / all-zeros 64-bit lanes) */
#define DSEL(m, a, b) \
    ((__typeof__(a))((((DV(vl_))(a)) & (m)) | (((DV(vl_))(b)) & ~(m))))

/* What vexp_ and vexpf_ below share. Their reduction: x clamped to >= -746 (also -inf; NaN
 * stays NaN), k = round(x m / ln 2) for m = 32 or 8 table steps per octave, by truncating
 * x m / ln 2 - 1/2 (< 0: trunc = round), as int32 lanes (|k| < 2^16) and as doubles. */
DV_FN DV(vi_) DV(exp_reduce_)(DV(vd_) * x, double m_over_ln2, DV(vd_) * kf) {
    const DV(vd_) zero = {0};
    *x = DSEL(*x > zero - 746.0, *x, zero - 746.0);
    const DV(vi_) k = __builtin_convertvector(*x * m_over_ln2 - 0.5, DV(vi_));
    *kf = __builtin_convertvector(k, DV(vd_));
    return k;
}

/* Their result: p 2^n, n = k >> shift (k = m n + j), 2^n built in a double's exponent bits and
 * +0 where it would be subnormal (x < -708.4: an absolute error below 2.3e-308); x0's NaN
 * lanes as they are (the scalar loop's exp). */
DV_FN DV(vd_) DV(exp_scale_)(DV(vd_) p, DV(vi_) k, int shift, DV(vd_) x0) {
    typedef DV(vl_) vl;
    const DV(vd_) zero = {0};
    const DV(vi_) biased = (k >> shift) + 1023; /* > 0: 2^n is normal */
    const vl e = __builtin_convertvector(biased, vl) << 52;
    const vl normal = __builtin_convertvector(biased > 0, vl);
    return DSEL(x0 != x0, x0, p * DSEL(normal, (DV(vd_))e, zero));
}

/* exp(x) for x <= 0 in every lane (NaN stays NaN), the scheme of exp2_32.h: 32 n + j by
 * truncating 32 x / ln 2 - 1/2 (< 0), 2^(j/32) by VEXP2_32 (a gather on AVX2, permutes of the
 * table in registers on AVX-512), 2^n built in the exponent bits; +0 where 2^n is subnormal
 * (x < -708.4: an absolute error below 2.3e-308 against libm's subnormal results). About 25
 * vector operations and one gather (AVX2) or three permutes and a blend (AVX-512). Measured
 * against libm's exp (tests/ops/test_disk_native.py, test_vectorised_disk_exp_against_libm):
 * within DISK_EXP_ULP (_disk_native.py) where the result is normal. */
DV_FN DV(vd_) DV(vexp_)(DV(vd_) x) {
    typedef DV(vd_) vd;
#ifdef DISK_PROF_NOEXP
    return x * 0.5;
#endif
    const vd x0 = x;
    vd nf;
    const DV(vi_) n32 = DV(exp_reduce_)(&x, SSS_32_OVER_LN2, &nf);
    const vd r = (x - nf * SSS_LN2_32_HI) - nf * SSS_LN2_32_LO;
    const vd q = SSS_EXPM1_DEG6(r);
    const vd tab = (vd)VEXP2_32(n32); /* 2^((n32 mod 32) / 32) */
    return DV(exp_scale_)(tab + tab * q, n32, 5, x0);
}

/* exp(x) for x <= 0 in every lane (NaN stays NaN) to float32 precision, for float32 images
 * (issue 30): their weights are rounded to float32 (wc below), so vexp_'s 1 double ulp buys
 * nothing there, and on AVX2 its gather and 25 double operations were half the disk's time
 * (512² close-up, skin_deon6, 32 samples: 967 ms of C CPU time, 473 with an exp that
 * returns x / 2). A choice: the reduction stays in double (8 x / ln 2 and r = x - n8 ln 2 / 8,
 * |r| <= ln 2 / 16: the argument is not rounded to float32, which would cost |x| 2^-24 of
 * relative error, 4e-6 at x = -70), the rest in float32 lanes (half the width of the double
 * ones: one 128-bit operation each on AVX2): e^r - 1 by its Taylor polynomial of degree 4
 * (truncation below 1.3e-9 relative), 2^(j/8) (j = n8 mod 8) from the float32 roundings of
 * exp2_32.h's table by permutes in registers (VEXP2_8F, disk.c: no memory access per lane),
 * and 2^n (n = n8 >> 3) built in a double's exponent bits as vexp_ does (+0 where it would be
 * subnormal, x < -708.4). No fused multiply-adds, the same lane-wise operations at every
 * level: AVX2 and AVX-512 agree bitwise. Its error against libm's exp, relative, is
 * DISK_EXPF_REL (_disk_native.py), measured by tests/ops/test_disk_native.py. */
typedef float DV(vf_) __attribute__((vector_size(VW * 4)));
DV_FN DV(vd_) DV(vexpf_)(DV(vd_) x) {
    typedef DV(vf_) vf;
    const DV(vd_) x0 = x;
    DV(vd_) nf;
    const DV(vi_) n8 = DV(exp_reduce_)(&x, SSS_8_OVER_LN2, &nf);
    /* |n8| < 8700: n8 ln 2 / 8 within 6e-14 of exact, a relative error of the result alike */
    const vf r = __builtin_convertvector(x - nf * SSS_LN2_8, vf);
    const vf q = r * (1.0f + r * (0.5f + r * (1.0f / 6 + r * (1.0f / 24)))); /* e^r - 1 */
    const vf tab = (vf)VEXP2_8F(n8 & 7);                                        /* 2^(j/8) */
    return DV(exp_scale_)(__builtin_convertvector(tab + tab * q, DV(vd_)), n8, 3, x0);
}

/* the exp of the profile's weights: to float32 precision for a float32 image (vexpf_), to
 * double precision for a float64 one (vexp_) */
DV_FN DV(vd_) DV(wexp_)(DV(vd_) x) { return sizeof(SCALAR) == 4 ? DV(vexpf_)(x) : DV(vexp_)(x); }

/* the exp of n doubles through wexp_ (a tail shorter than VW padded with 0): for the test of
 * its error against libm (sss_disk_vexp, disk.c) */
__attribute__((target(ISA_TARGET), unused)) static void DV(vexp_array)(const double *x, double *y,
                                                                int64_t n) {
    typedef DV(vd_) vd;
    for (int64_t i = 0; i < n; i += VW) {
        vd v = {0};
        const int64_t k = n - i < VW ? n - i : VW;
        for (int64_t l = 0; l < k; ++l) v[l] = x[i + l];
        v = DV(wexp_)(v);
        for (int64_t l = 0; l < k; ++l) y[i + l] = v[l];
    }
}

/* the point fetch's pixel index (flat, in the batch) for offsets (drow, dcol) pixels from
 * (row, col): _Pixels.fetch "point", the nearest pixel clamped to the image (row + floor(
 * drow + 0.5) formed in double: exact for offsets below 2^52 pixels; NaN clamps to 0 as the
 * scalar loop's integer conversion does) */
DV_FN DV(vl_) DV(pixel_)(DV(vd_) row, DV(vd_) col, DV(vl_) base, DV(vd_) drow, DV(vd_) dcol,
                         double hmax, double wmax, int64_t w) {
    typedef DV(vd_) vd;
    typedef DV(vl_) vl;
    typedef DV(vi_) vi;
    const vd zero = {0};
    vd ri = row + VFLOOR(drow + 0.5), ci = col + VFLOOR(dcol + 0.5);
    ri = DSEL(ri > zero, ri, zero), ci = DSEL(ci > zero, ci, zero); /* NaN: 0 */
    ri = DSEL(ri < hmax, ri, zero + hmax), ci = DSEL(ci < wmax, ci, zero + wmax);
    const vl r64 = __builtin_convertvector(__builtin_convertvector(ri, vi), vl);
    const vl c64 = __builtin_convertvector(__builtin_convertvector(ci, vi), vl);
    return base + r64 * w + c64;
}

/* log(x) for x > 0 normal in every lane (NaN stays NaN): x = 2^e m with m in [sqrt(1/2),
 * sqrt(2)) from the bits, log m = 2 atanh(f), f = (m - 1) / (m + 1) (m - 1 exact, |f| <=
 * 0.1716), by its series to f^23 (truncation below 1e-18 relative), plus e ln 2 in two parts
 * (the high part with trailing zero bits: e ln2_hi exact). Within a few ulp of libm's log
 * (tests/ops/test_disk_native.py, through the disk against the torch loop). */
DV_FN DV(vd_) DV(vlog_)(DV(vd_) x) {
    typedef DV(vd_) vd;
    typedef DV(vl_) vl;
    const vd zero = {0};
    const vl bits = (vl)x;
    vl e = ((bits >> 52) & 0x7FF) - 1023;
    vl mb = (bits & 0x000FFFFFFFFFFFFFLL) | 0x3FF0000000000000LL; /* m in [1, 2) */
    const vl big = (vd)mb > zero + 1.4142135623730951;               /* m > sqrt 2: m / 2 */
    mb = DSEL(big, mb - 0x0010000000000000LL, mb);
    e = DSEL(big, e + 1, e);
    const vd m = (vd)mb, f = (m - 1.0) / (m + 1.0), s = f * f;
    vd p = zero + 1.0 / 23;
    p = p * s + 1.0 / 21, p = p * s + 1.0 / 19, p = p * s + 1.0 / 17, p = p * s + 1.0 / 15;
    p = p * s + 1.0 / 13, p = p * s + 1.0 / 11, p = p * s + 1.0 / 9, p = p * s + 1.0 / 7;
    p = p * s + 1.0 / 5, p = p * s + 1.0 / 3;
    const vd ef = __builtin_convertvector(e, vd);
    const vd lo = ef * 1.9082149292705877e-10 + (f + f); /* the low part of ln 2, and 2f */
    const vd r = ef * 0.6931471803691238 + ((f + f) * (p * s) + lo);
    return DSEL(x != x, x, r);
}

/* log(1 + a) for a >= 0 in every lane: vlog_ of w = 1 + a, corrected by the rounding of w,
 * log1p(a) ~ log(w) - ((w - 1) - a) / w (a below 2^-53: w = 1 and the result a) */
DV_FN DV(vd_) DV(vlog1p_)(DV(vd_) a) {
    const DV(vd_) w = a + 1.0;
    return DV(vlog_)(w) - ((w - 1.0) - a) / w;
}

/* Burley's sampler (radial_sample, sampler_kind 1: _disk_radial.BurleyRadial.sample) for
 * every lane: x = 2 sinh(asinh(2 (1 - u)) / 3), r = -3 d log(max(x, tiny)), the density
 * (e^(-r/d) + e^(-r/(3d))) / (4 d) and 1 / pdf = 2 pi r / density, in the scalar loop's
 * order, with asinh(y) = log1p(y + y^2 / (1 + sqrt(1 + y^2))) (no cancellation as y -> 0),
 * sinh(z) for z in [0, asinh(2) / 3 = 0.482] by its odd Taylor series to z^17 (truncation below
 * 1e-19 relative) and vlog_ / wexp_ instead of libm: a few ulp from the scalar loop's radius
 * (issue 30: with libm lane by lane the sampler was 82 % of the disk's time with a Burley
 * profile, 512² close-up, 32 samples). */
DV_FN DV(vd_) DV(burley_radial_)(const disk_args *a, DV(vd_) u, DV(vd_) * inv) {
    typedef DV(vd_) vd;
    const vd zero = {0};
    const double d = a->sampler_d;
    const vd y = 2.0 * (1.0 - u);
    const vd t = DV(vlog1p_)(y + y * y / (1.0 + VSQRT(1.0 + y * y))); /* asinh(y) */
    const vd z = t / 3.0, z2 = z * z;
    vd q = zero + 1.0 / 355687428096000.0; /* 1 / 17! */
    q = q * z2 + 1.0 / 1307674368000.0, q = q * z2 + 1.0 / 6227020800.0;
    q = q * z2 + 1.0 / 39916800.0, q = q * z2 + 1.0 / 362880.0, q = q * z2 + 1.0 / 5040.0;
    q = q * z2 + 1.0 / 120.0, q = q * z2 + 1.0 / 6.0;
    vd x = 2.0 * (z + z * (z2 * q)); /* 2 sinh(z) */
    x = DSEL(x < TINY64, zero + TINY64, x); /* clamp_min (NaN stays) */
    const vd r = -3.0 * d * DV(vlog_)(x);
    const vd dens = (DV(wexp_)(-r / d) + DV(wexp_)(-r / (3.0 * d))) / (4.0 * d);
    *inv = TWO_PI * r / dens;
    return r;
}

/* burley_radial_ of n quantiles u (a tail shorter than VW padded with 1/2): for the test of
 * its radii and inverse densities against the scalar loop's (sss_disk_burley_radial, disk.c) */
__attribute__((target(ISA_TARGET), unused)) static void DV(burley_radial_array)(
    const disk_args *a, const double *u, double *r, double *inv, int64_t n) {
    typedef DV(vd_) vd;
    for (int64_t i = 0; i < n; i += VW) {
        vd v = {0}, ip;
        const int64_t k = n - i < VW ? n - i : VW;
        for (int64_t l = 0; l < VW; ++l) v[l] = l < k ? u[i + l] : 0.5;
        v = DV(burley_radial_)(a, v, &ip);
        for (int64_t l = 0; l < k; ++l) r[i + l] = v[l], inv[i + l] = ip[l];
    }
}

/* the radii and inverse area densities of the samples u (radial_sample lane-wise): the
 * tabulated sampler's search by gathers from the guide table (int64), the CDF and the
 * radii; the divisions by the node's slope as products by its reciprocal (kc->inv_slope,
 * once per call); Burley's closed form by burley_radial_ */
DV_FN DV(vd_) DV(radial_)(const disk_args *a, const disk_consts *kc, DV(vd_) u, DV(vd_) * inv) {
    typedef DV(vd_) vd;
    typedef DV(vl_) vl;
    typedef DV(vi_) vi;
    const vd zero = {0};
    if (a->sampler_kind == 1) return DV(burley_radial_)(a, u, inv); /* Burley's closed form */
    const int64_t nodes = a->nodes, gn = a->guide_n;
    const vl izero = {0}, one = izero + 1;
    vd bd = u * (double)gn;
    bd = DSEL(bd > zero, bd, zero);
    bd = DSEL(bd < (double)(gn - 1), bd, zero + (double)(gn - 1)); /* NaN: 0 */
    const vl b = __builtin_convertvector(__builtin_convertvector(bd, vi), vl);
    vl lo = GI64(a->guide, b) + 1, hi = GI64(a->guide + 1, b) + 1;
    const vl inside = (u >= zero) & (u < zero + 1.0);
    lo = DSEL(inside, lo, izero), hi = DSEL(inside, hi, izero + nodes);
    for (vl act = lo < hi; VANY(act); act = lo < hi) { /* first index with cdf > u */
        const vl mid = lo + ((hi - lo) >> 1);
        const vl idx = DSEL(act, mid, izero); /* settled lanes read cdf[0] (unused) */
        const vl le = GF64(a->tab_cdf, idx) <= u;
        lo = DSEL(act & le, mid + one, lo);
        hi = DSEL(act & ~le, mid, hi);
    }
    vl k = lo - one;
    k = DSEL(k > izero, k, izero);
    k = DSEL(k < izero + (nodes - 2), k, izero + (nodes - 2));
    const vd c0 = GF64(a->tab_cdf, k), r0 = GF64(a->tab_r, k);
    const vd r1 = GF64(a->tab_r + 1, k), s = GF64(kc->inv_slope, k);
    const vd du = u - c0;
    vd r = r0 + DSEL(du != zero, du * s, zero); /* 0 x inf: 0 (the scalar loop's 0 / tiny) */
    r = DSEL((r < r1) | (r != r), r, r1); /* torch.minimum */
    *inv = TWO_PI * r * s;
    return r;
}

/* DiskSSS._gather (point fetch) for the centre pixels [p0, p1), VW at a time (a last vector
 * shorter than VW repeats its last pixel in the spare lanes: computed, not written) */
__attribute__((target(ISA_TARGET))) static void DV(disk_vec_)(const disk_args *a,
                                                               const disk_consts *k, int64_t p0,
                                                               int64_t p1) {
    typedef DV(vd_) vd;
    typedef DV(vl_) vl;
    typedef DV(vs_) vs;
    const SCALAR *px = (const SCALAR *)a->packed;
    SCALAR *num = (SCALAR *)a->num, *den = (SCALAR *)a->den, *mom = (SCALAR *)a->mom;
    const int64_t w = a->w;
    const double hmax = (double)(a->h - 1), wmax = (double)(a->w - 1), per_mm = a->per_mm;
    const int has_area = a->area != NULL, jitter = disk_jitter(a);
    const vd zero = {0};
    for (int64_t p = p0; p < p1; p += VW) {
        const int64_t cnt = p1 - p < VW ? p1 - p : VW;
        vd row, col, x_c, y_c, z_c, inv_zc, step, ct, st, shift = zero, inv_psz2 = zero;
        vl base;
        vs z_cs;
        for (int l = 0; l < VW; ++l) { /* per pixel (disk_pixels_, disk_body.h) */
            const int64_t q = p + (l < cnt ? l : cnt - 1), pix = a->pix[q];
            const int64_t rem = pix % a->hw;
            base[l] = pix - rem;
            row[l] = (double)(rem / w), col[l] = (double)(rem % w);
            z_cs[l] = px[8 * pix + 3];
            x_c[l] = (double)px[8 * pix + 6], y_c[l] = (double)px[8 * pix + 7];
            z_c[l] = (double)z_cs[l];
            step[l] = a->step[q];
            double turn;
            disk_noise(a, q, pix, &turn, &shift[l]);
            ct[l] = cos(turn), st[l] = sin(turn);
            const double psz = z_c[l] * per_mm;
            inv_psz2[l] = 1.0 / (psz * psz);
            inv_zc[l] = 1.0 / z_c[l];
        }
        vs s_num[3] = {{0}}, s_den[3] = {{0}}, s_mom[9] = {{0}};
        /* in chunks of DISK_CHUNK samples: first their offsets and pixels (each lane's pixel
         * prefetched: the chunk's cache misses overlap), then the fetches and weights */
        vd c_inv[DISK_CHUNK], c_dcol[DISK_CHUNK], c_drow[DISK_CHUNK];
        vl c_j8[DISK_CHUNK];
        for (int64_t i0 = 0; i0 < a->n; i0 += DISK_CHUNK) {
            const int64_t chunk = a->n - i0 < DISK_CHUNK ? a->n - i0 : DISK_CHUNK;
            for (int64_t t = 0; t < chunk; ++t) {
                const int64_t i = i0 + t;
                vd r, inv_pdf;
                if (jitter) {
                    vd u = a->u0[i] + shift;
                    u = u - VTRUNC(u); /* torch.frac */
                    r = DV(radial_)(a, k, u, &inv_pdf);
                } else {
                    r = zero + k->r[i], inv_pdf = zero + k->inv_pdf[i];
                }
                /* cos / sin (theta0_i + turn) by the addition theorem (header) */
                const vd cs = k->cos0[i] * ct - k->sin0[i] * st;
                const vd sn = k->sin0[i] * ct + k->cos0[i] * st;
                c_inv[t] = inv_pdf;
                c_dcol[t] = r * cs * step;
                c_drow[t] = -r * sn * step; /* screen y is up, rows go down */
                c_j8[t] = DV(pixel_)(row, col, base, c_drow[t], c_dcol[t], hmax, wmax, w) << 3;
#ifdef DISK_PROF_CENTRE
                c_j8[t] = (base + __builtin_convertvector(row, vl) * w +
                           __builtin_convertvector(col, vl)) << 3;
#endif
                for (int l = 0; l < VW; ++l) __builtin_prefetch(px + c_j8[t][l]);
            }
            for (int64_t t = 0; t < chunk; ++t) {
            const vd inv_pdf = c_inv[t], dcol = c_dcol[t], drow = c_drow[t];
            const vl j8 = c_j8[t];
            const vs ok = GS(px + 4, j8);
            const vd dz = __builtin_convertvector(GS(px + 3, j8) - z_cs, vd);
            const vd rel = dz * inv_zc;
            const vd lateral = (z_c + dz) * per_mm;
            const vd dx = x_c * rel + dcol * lateral;
            const vd dy = y_c * rel - drow * lateral;
            const vd dist = VSQRT(dx * dx + dy * dy + dz * dz);
            vd wd[3] = {zero, zero, zero};
            if (a->profile_kind == 1) { /* Burley (profile_eval) */
                for (int c = 0; c < 3; ++c) {
                    const vd fl = zero + k->floor_[c];
                    const vd rr = DSEL((dist > fl) | (dist != dist), dist, fl);
                    const vd e = DV(wexp_)(-rr * k->inv_d[c]) + DV(wexp_)(-rr * k->inv_3d[c]);
                    wd[c] = k->coef[c] * e / rr;
                }
            } else { /* sum of Gaussians: the narrow ones vanish far out (no exp where every
                        lane's argument is below EXP_ZERO: there exp is +0) */
                const vd d2 = -(dist * dist);
                for (int64_t g = 0; g < a->n_gauss; ++g) {
                    const vd x = d2 * k->inv_2v[g];
                    if (!VANY(~(x < zero + EXP_ZERO))) continue; /* (NaN: computed) */
                    const vd e = DV(wexp_)(x);
                    for (int c = 0; c < 3; ++c) wd[c] += e * k->coef[3 * g + c];
                }
            }
            const vd fac = has_area ? __builtin_convertvector(GS(px + 5, j8), vd) *
                                          inv_psz2
                                    : zero;
            for (int c = 0; c < 3; ++c) {
                vd wdc = wd[c] * inv_pdf;
                if (has_area) wdc = wdc * fac;
                const vs wc = __builtin_convertvector(wdc, vs) * ok;
                const vs f = wc * GS(px + c, j8);
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
        for (int l = 0; l < cnt; ++l) {
            for (int c = 0; c < 3; ++c)
                num[3 * (p + l) + c] = s_num[c][l], den[3 * (p + l) + c] = s_den[c][l];
            if (mom)
                for (int c = 0; c < 9; ++c) mom[9 * (p + l) + c] = s_mom[c][l];
        }
    }
}

/* DiskSSS._gather_hdrp (hdrp_pixels, disk_body.h) for the centre pixels [p0, p1), VW at a
 * time (a last vector shorter than VW repeats its last pixel in the spare lanes: computed, not
 * written). Every sample lands on the scalar loop's pixel: its offsets ppm r sin(psi) and
 * ppm r cos(psi), psi = theta0 + turn, are rounded half to even to whole pixels, and the sin
 * and cos enter nothing else. They come from the addition theorem (cos / sin of the pattern's
 * angles once per call, of each pixel's turn once per pixel: libm), within
 * 8.8e-16 + 1.2e-16 |psi| of libm's of the rounded sum (libm within 1 ulp, the sum's rounding,
 * three products and a sum); where an offset lies within a tolerance of that times ppm r (x4),
 * plus 1e-15 of the offsets, of a half-integer, or is NaN, the lane takes libm's sin and cos of
 * psi, the scalar loop's values (tests/ops/test_disk_native.py: offsets where the two round to
 * different pixels). The fetches (prefetched a chunk of DISK_CHUNK samples ahead, then
 * gathered), the 3D distance and the profile follow the scalar loop's operations and order;
 * the one difference is the exp, wexp_'s (vexpf_ for a float32 image, vexp_ for a float64
 * one) instead of libm's: DISK_NATIVE_AGREEMENT's bound (_disk_native.py). Issue 30,
 * measured 2026-12-06 (512² close-up, skin_deon6, 32 samples, 2 threads, 7 interleaved
 * rounds): 0.245x the time of the scalar loop (0.49x with libm's sin and cos in every lane,
 * half of it then in libm's sincos), 0.87x the "sssbench" estimator's vectorised loop. */
__attribute__((target(ISA_TARGET))) static void DV(hdrp_vec_)(const disk_args *a, int64_t p0,
                                                               int64_t p1) {
    typedef DV(vd_) vd;
    typedef DV(vl_) vl;
    typedef DV(vs_) vs;
    const SCALAR *px = (const SCALAR *)a->packed;
    SCALAR *num = (SCALAR *)a->num, *den = (SCALAR *)a->den;
    const int64_t w = a->w;
    const double hmax = (double)(a->h - 1), wmax = (double)(a->w - 1);
    const vd zero = {0};
    const vs szero = {0};
    /* cos / sin of the pattern's angles, once (without the memory: libm in every lane) */
    double *cs0 = malloc(sizeof(double) * (size_t)(2 * (a->n > 0 ? a->n : 1)));
    double *sn0 = cs0 ? cs0 + a->n : NULL;
    for (int64_t k = 0; cs0 && k < a->n; ++k)
        cs0[k] = cos(a->theta0[k]), sn0[k] = sin(a->theta0[k]);
    for (int64_t p = p0; p < p1; p += VW) {
        const int64_t cnt = p1 - p < VW ? p1 - p : VW;
        vd row, col, ppm, turn, ct = zero, st = zero;
        vl base;
        vs z_cs;
        for (int l = 0; l < VW; ++l) { /* per pixel (hdrp_pixels) */
            const int64_t q = p + (l < cnt ? l : cnt - 1), pix = a->pix[q];
            const int64_t rem = pix % a->hw;
            base[l] = pix - rem;
            row[l] = (double)(rem / w), col[l] = (double)(rem % w);
            z_cs[l] = px[8 * pix + 3];
            ppm[l] = a->step[q], turn[l] = a->turn[q];
            if (cs0) ct[l] = cos(turn[l]), st[l] = sin(turn[l]);
        }
        vs s_num[3] = {szero, szero, szero}, s_den[3] = {szero, szero, szero};
        vl c_j8[DISK_CHUNK];
        vs c_inside[DISK_CHUNK];
        for (int64_t i0 = 0; i0 < a->n; i0 += DISK_CHUNK) {
            const int64_t chunk = a->n - i0 < DISK_CHUNK ? a->n - i0 : DISK_CHUNK;
            for (int64_t t = 0; t < chunk; ++t) { /* the samples' pixels, prefetched */
                const int64_t k = i0 + t;
                const double rk = a->u0[k];
                const vd psi = a->theta0[k] + turn;
                const vd prk = ppm * rk;
                vd xs, xc; /* ppm rk sin psi, ppm rk cos psi */
                vl redo = zero == zero; /* the lanes that take libm's sin and cos */
                if (cs0) {
                    /* by the addition theorem, then libm where its rounding could differ
                     * (header): ds, dc the offsets' distances to a half-integer */
                    const vd sn = sn0[k] * ct + cs0[k] * st, cs = cs0[k] * ct - sn0[k] * st;
                    xs = prk * sn, xc = prk * cs;
                    const vd ax = DSEL(psi < zero, -psi, psi);
                    const vd tol = prk * (4e-15 + 4e-16 * ax) +
                                   (DSEL(xs < zero, -xs, xs) + DSEL(xc < zero, -xc, xc)) * 1e-15;
                    vd ds = xs - VFLOOR(xs) - 0.5, dc = xc - VFLOOR(xc) - 0.5;
                    ds = DSEL(ds < zero, -ds, ds), dc = DSEL(dc < zero, -dc, dc);
                    redo = ~((ds > tol) & (dc > tol)); /* also NaN */
                }
                if (VANY(redo))
                    for (int l = 0; l < VW; ++l)
                        if (redo[l]) xs[l] = prk[l] * sin(psi[l]), xc[l] = prk[l] * cos(psi[l]);
                /* row + nearbyint(ppm rk sin psi): integers, exact in double */
                vd ri = row + VRINT(xs), ci = col + VRINT(xc);
                const vl inside = (ri >= zero) & (ri <= hmax) & (ci >= zero) & (ci <= wmax);
                ri = DSEL(ri > zero, ri, zero), ci = DSEL(ci > zero, ci, zero); /* NaN: 0 */
                ri = DSEL(ri < hmax, ri, zero + hmax), ci = DSEL(ci < wmax, ci, zero + wmax);
                const vl j = base + __builtin_convertvector(ri, vl) * w +
                             __builtin_convertvector(ci, vl);
                c_j8[t] = j << 3;
                c_inside[t] = __builtin_convertvector(DSEL(inside, zero + 1.0, zero), vs);
                for (int l = 0; l < VW; ++l) __builtin_prefetch(px + c_j8[t][l]);
            }
            for (int64_t t = 0; t < chunk; ++t) {
                const int64_t k = i0 + t;
                const double rk = a->u0[k];
                const vl j8 = c_j8[t];
                const vd dz = __builtin_convertvector(GS(px + 3, j8) - z_cs, vd);
                const vd r3 = VSQRT(rk * rk + dz * dz);
                vd pol[3];
                if (a->profile_kind == 1) { /* _Kernel.polar: HDRP's EvalBurley, S/(8 pi) (...) */
                    for (int c = 0; c < 3; ++c) {
                        const double dc = a->prof_a[c];
                        pol[c] = (DV(wexp_)(-r3 / (3.0 * dc)) + DV(wexp_)(-r3 / dc)) /
                                 (EIGHT_PI * dc);
                    }
                } else { /* r R_c(r) / total_c (profile_eval; no exp where every lane's
                            argument is below EXP_ZERO: there exp is +0) */
                    vd prof[3] = {zero, zero, zero};
                    const vd d2 = -(r3 * r3);
                    for (int64_t g = 0; g < a->n_gauss; ++g) {
                        const double v = a->prof_a[g];
                        const vd x = d2 / (2.0 * v);
                        if (!VANY(~(x < zero + EXP_ZERO))) continue; /* (NaN: computed) */
                        const vd e = DV(wexp_)(x) / (TWO_PI * v);
                        for (int c = 0; c < 3; ++c) prof[c] += e * a->prof_b[3 * g + c];
                    }
                    for (int c = 0; c < 3; ++c) pol[c] = r3 * prof[c] / a->total[c];
                }
                const vs gate = c_inside[t] * GS(px + 4, j8);
                for (int c = 0; c < 3; ++c) {
                    const vs wc = __builtin_convertvector(pol[c] * a->rcp[k], vs) * gate;
                    s_num[c] += wc * GS(px + c, j8);
                    s_den[c] += wc;
                }
            }
        }
        for (int l = 0; l < cnt; ++l)
            for (int c = 0; c < 3; ++c)
                num[3 * (p + l) + c] = s_num[c][l], den[3 * (p + l) + c] = s_den[c][l];
    }
    free(cs0);
}

#undef DSEL
#undef GF64
#undef GI64
#undef GS
#undef DV_FN
#undef DV
/* the instantiating level's macros (disk_body.h defines them before each include) */
#undef ISA
#undef ISA_TARGET
#undef VW
#undef VGATHER_F64
#undef VGATHER_I64
#undef VGATHER_S
#undef VFLOOR
#undef VTRUNC
#undef VRINT
#undef VSQRT
#undef VANY
#undef VEXP2_32
#undef VEXP2_8F

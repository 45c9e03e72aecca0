/* The vectorised tap loop for one scalar type and one instruction set (included by
 * gather_body.h once per set: ISA names it, ISA_TARGET is its target attribute, VW the pixels
 * per vector, GATHER_RAW(base, int32 index vector) its gather of VW SCALARs, SHUFFLE2(lo, hi,
 * LANE index vector) the lanes of two vectors' concatenation and IANY(int32 mask) whether any
 * lane is set).
 *
 * The scalar loop (taps_ in gather_body.h) computes one pixel at a time, its (r, g, b, depth)
 * in one 4-lane vector; here one vector holds VW pixels that lie next to each other on one
 * row: along the row for an x pass, and for a y pass VW columns of the same row, so that the
 * pixels a vector holds are contiguous in memory in both passes (the y pass walks its strip of
 * columns row block by row block, as the spans list it). The line's window is kept as four
 * planes (r, g, b, depth; line_window_ with PLANAR = 1: packed into the thread's buffer, or an
 * x pass's row read in place when the pass writes elsewhere: ln->pl), the centre pixels of a
 * whole vector are loaded, each tap's two samples are fetched per plane by loads and permutes
 * or selects (or a gather), and every pixel goes through the same float operations in the same
 * order as in the scalar loop (lane-wise IEEE arithmetic, no FMA: the library is built with
 * -ffp-contract=off; min / max / clamp as the same selects, or as one min instruction where
 * that is the same select, VMINV / VIMIN, and the lerp factor's max left out where it cannot
 * change a bit; the weights broadcast as they are): the results are bitwise those of
 * the scalar loop, so of the torch loop, but for the gaussian follow-surface's factor: its
 * exponent formed as |dz|^2 k (segment_) and its exp computed by a vectorised table and
 * polynomial (expz_ below, the only code with fused multiply-adds) instead of the C library's
 * expf / exp of -0.5 d d. Built without -march: the functions carry target attributes and
 * sss_gather_ calls them only when the CPU has the set (sss_set_simd in gather.c). */

#define SIMDN(name) CAT(CAT(name, SUFFIX), CAT(_, ISA))
#define SIMD_FN static inline __attribute__((always_inline, target(ISA_TARGET)))

typedef SCALAR SIMDN(vs_) __attribute__((vector_size(VW * sizeof(SCALAR))));
typedef LANE SIMDN(vm_) __attribute__((vector_size(VW * sizeof(SCALAR))));
typedef int32_t SIMDN(vi_) __attribute__((vector_size(VW * 4)));
typedef uint32_t SIMDN(vu_) __attribute__((vector_size(VW * 4)));

/* whether any int32 lane of a exceeds b's, unsigned (ANY_GTU), or a differs from b or c
 * from d (ANY_NE2): on AVX-512 for float straight into a mask register (KANY_*: gather.c),
 * else by the vector extensions' compares and IANY */
#ifdef KANY_GTU
#define ANY_GTU(a, b) KANY_GTU(a, b)
#define ANY_NE2(a, b, c, d) KANY_NE2(a, b, c, d)
#else
#define ANY_GTU(a, b) IANY((SIMDN(vu_))(a) > (SIMDN(vu_))(b))
#define ANY_NE2(a, b, c, d) IANY(((a) != (b)) | ((c) != (d)))
#endif

/* The gaussian follow-surface factor of 000 eq. 7, exp(-d^2 / 2), d = |dz| / surface_scale,
 * as exp(-z ln 2 / 8) with z = d^2 (4 / ln 2) >= 0, the exponent in units of ln 2 / 8 (formed
 * in segment_ as |dz|^2 k per channel: one product), all lanes at once (expz_ below). Not the
 * C library's exp of the torch loop's argument: the measured bound is BACKEND_AGREEMENT's,
 * sssbench/ops/gather.py. */
#if EXP_TABLE
/* float, since issue 30's last round (one table lookup, no select, no product by 2^n, no
 * reduction constant): z is clamped to 1008 (one min; also +inf, NaN -> 1008), where
 * exp(-1008 ln 2 / 8) = 2^-126 = FLT_MIN; n8 = round(-z) by subtracting z from 1.5 2^23 (tm,
 * whose ulp is 1: one rounding, to nearest even, and tm's low mantissa bits hold n8, no
 * conversions); t = z + n8 in [-1/2, 1/2] exactly; exp(-z L) = 2^n 2^(j/8) e^(-t L) with
 * n8 = 8 n + j, L = ln 2 / 8 (|t L| <= ln 2 / 16); 2^(j/8) from a table of 8 floats (one
 * permute of one vector: the low 3 bits of tm index it; AVX-512's 16 lanes hold it twice),
 * each within 0.34 ulp of 2^(j/8); e^(-t L) - 1 by a degree-3 polynomial in t (minimax
 * coefficients with the linear one -L: 2.6e-8 relative, 0.43 ulp at most); assembled as
 * 2^(j/8) + 2^(j/8) (e^(-t L) - 1) in one fused multiply-add, and 2^n added to its exponent
 * field as an integer (n >= -126 and the product >= 1 when n = -126: always normal). 13
 * vector operations (before: 27 on AVX2, with a 16-entry table and a second, low-order one,
 * a two-float reduction constant and a select of 0 where 2^n is subnormal). Within 1 ulp of
 * the correctly rounded exp(-z L) at every float z in [0, 1008] (checked exhaustively on
 * AVX2 and on AVX-512, every float z in [0, 1200]: tests/ops/exp_exhaustive.c; and through
 * a pass by tests/ops/test_gather_backends.py); where the exact result is subnormal
 * (z > 1008) it returns FLT_MIN (1.2e-38 or less from it; a weight times it underflows to 0
 * under the pass's flush-to-zero). The fused multiply-adds here are the only ones of the loop
 * (the bitwise-specified tap arithmetic stays unfused).
 * Since 2026-12-06 (issue 30) expz_ takes y = z / 8 (EXPZ_SCALE; segment_ folds it into k:
 * the factor is 2^-y), clamped to 126, tm from 1.5 2^20 (ulp 1/8), t and the polynomial's
 * coefficients 1/8, 1/8^2, 1/8^3 of the above: every quantity is the one above times a power
 * of 2 (exact; tm's mantissa bits, the table's index and n are the same), so the same bits.
 * On AVX-512, 2^n is then applied as vscalefps(p, r) = p 2^floor(r), r = tm - 1.5 2^20 =
 * n8 / 8 (already formed for t; floor(r) = n): one instruction instead of the exponent
 * field's shift, mask and add, 10 vector operations instead of 12 (checked bit for bit
 * against the z form at every float z in [0, 1200]: docs/numerics.md). */
static const float SIMDN(exp_tab_)[16] __attribute__((aligned(64))) = {
    1.0f, 1.0905077457427979f, 1.1892070770263672f, 1.2968395948410034f,
    1.4142135381698608f, 1.5422108173370361f, 1.6817928552627563f, 1.8340080976486206f,
    1.0f, 1.0905077457427979f, 1.1892070770263672f, 1.2968395948410034f,
    1.4142135381698608f, 1.5422108173370361f, 1.6817928552627563f, 1.8340080976486206f};

/* e^(-t L) - 1 for t in [-1/2, 1/2], L = ln 2 / 8: -L t + c2 L^2 t^2 + c3 L^3 t^3, c2 and c3
 * minimax (expz_ and expz_near_); here of t / 8 in [-1/16, 1/16] (expz_'s y units), its
 * coefficients those of t times 8^3, 8^2 and 8 (exact: -0.00010840770846698433,
 * 0.0037540236953645945 and -0.08664339780807495 in t) */
SIMD_FN SIMDN(vs_) SIMDN(expm1t_)(SIMDN(vs_) t) {
    const SIMDN(vs_) zero = {0};
    SIMDN(vs_) q = VFMA(t, zero + (SCALAR)-0.05550474673509598,
                        zero + (SCALAR)0.24025751650333405);
    q = VFMA(q, t, zero + (SCALAR)-0.6931471824645996);
    return q * t;
}

SIMD_FN SIMDN(vs_) SIMDN(expz_)(SIMDN(vs_) y) { /* y = z / 8 (EXPZ_SCALE) */
    typedef SIMDN(vs_) vec;
    typedef SIMDN(vm_) mask;
    typedef SIMDN(vu_) uivec;
    const vec zero = {0};
    y = VMINPS(y, zero + (SCALAR)126); /* min(y, 126): also +inf, NaN -> 126 */
    /* tm = 1.5 2^20 + n8 / 8, n8 = round(-z) in [-1008, 0] (one rounding: tm's ulp is 1/8) */
    const vec magic = zero + (SCALAR)1572864.0;
    const vec tm = magic - y;
    const vec r = tm - magic;        /* n8 / 8, exact */
    const vec t = y + r;             /* (z - round(z)) / 8 in [-1/16, 1/16], exact */
    const vec q = SIMDN(expm1t_)(t); /* e^(-8 t ln 2 / 8) - 1 */
    vec tab;
    __builtin_memcpy(&tab, SIMDN(exp_tab_), sizeof tab);
    const vec hi = (vec)VPERMUTE(tab, (mask)tm); /* 2^(j/8): the low bits of tm */
    const vec p = VFMA(hi, q, hi);               /* in [0.97, 1.92] */
#ifdef VSCALEF
    return (vec)VSCALEF(p, r); /* p 2^floor(n8 / 8) = p 2^n */
#else
    /* n << 23 = (n8 << 20) with the low 23 bits cleared (tm's high bits shift out) */
    const uivec e = ((uivec)tm << 20) & 0xFF800000u;
    return (vec)((uivec)p + e);
#endif
}

/* expz_ where every lane's z lies in [0, 1/2), y = z / 8 in [0, 1/16) (expz_lanes_ checks,
 * expz_near_below_): there round(z) = 0 (1/2 itself would round to the even 0 too; the check
 * keeps below it), so expz_'s min leaves y, t = y + 0 = y, the table's entry is 2^0 = 1, 2^n
 * is 1, and fma(1, q, 1) = 1 + q (the product exact, one rounding either way): expz_'s bits,
 * bit for bit, in 4 vector operations instead of 12 (10 on AVX-512 since 2026-12-06). Issue 30: the artist pass's factors of its
 * near taps and of its broad channels (exp(-z ln 2 / 8) > 0.958): in the perf close-up 72 %,
 * 44 % and 36 % of its vectors' red, green and blue exps. Measured (2026-12-06, 1080p
 * close-up, experiments/ab_native, 6 processes): the artist pass 0.960 ± 0.006 the time of
 * the loop without it, paired per process with the unchanged pre-integrated pass (0.94-0.99
 * in each). A second tier, every lane below VW - 1/2 (a table of 2^(n8 / 8), no exponent
 * add: 8 operations), measured no faster: its check costs about what it saves. Checked for
 * every float z below 1/2 against expz_ by tests/ops/exp_exhaustive.c, and through passes
 * by tests/ops/test_gather_backends.py. */
SIMD_FN SIMDN(vs_) SIMDN(expz_near_)(SIMDN(vs_) y) {
    const SIMDN(vs_) zero = {0};
    return SIMDN(expm1t_)(y) + (zero + 1);
}

/* whether every lane of y = z / 8 lies in [0, 1/16): as unsigned int32 the bits of a float in
 * [+0, 1/16) are below those of 1/16 (0x3D800000), and those of -0, every negative float,
 * every NaN (either sign) and infinity are not */
SIMD_FN int SIMDN(expz_near_below_)(SIMDN(vs_) y) {
    const SIMDN(vi_) izero = {0};
    return !ANY_GTU(y, izero + 0x3D7FFFFF);
}

/* expz_ of every lane: expz_near_ where all lanes allow it, else expz_ (the same bits) */
SIMD_FN SIMDN(vs_) SIMDN(expz_lanes_)(SIMDN(vs_) y) {
    return SIMDN(expz_near_below_)(y) ? SIMDN(expz_near_)(y) : SIMDN(expz_)(y);
}
#else
/* exp(x) for x <= 0 (also -inf), double: Cody-Waite reduction x = n ln 2 + r, |r| <= ln 2 / 2,
 * then the Taylor polynomial of degree 13 (the float branch, Cephes' degree-7 polynomial, is
 * unused since issue 30), scaled by 2^n built in the exponent bits; 0 where 2^n would be
 * subnormal (an absolute error below 2.3e-308). */
SIMD_FN SIMDN(vs_) SIMDN(exp_)(SIMDN(vs_) x) {
    typedef SIMDN(vs_) vec;
    typedef SIMDN(vm_) mask;
    typedef SIMDN(vi_) ivec;
    const int F32 = sizeof(SCALAR) == 4;
    const vec zero = {0};
    const vec lowest = zero + (SCALAR)(F32 ? -104.0 : -746.0);
    x = VSELECT(x > lowest, x, lowest); /* also -inf; n stays within int32 */
    const vec t = x * (SCALAR)1.44269504088896340736 - (SCALAR)0.5; /* x log2(e) - 1/2 <= 0 */
    const ivec n = __builtin_convertvector(t, ivec);                 /* round(x log2(e)) */
    const vec nf = __builtin_convertvector(n, vec);
    vec r;
    if (F32)
        r = (x - nf * (SCALAR)0.693359375) - nf * (SCALAR)-2.12194440e-4;
    else
        r = (x - nf * (SCALAR)6.93145751953125E-1) - nf * (SCALAR)1.42860682030941723212E-6;
    vec p;
    if (F32) {
        p = zero + (SCALAR)1.9875691500E-4;
        p = p * r + (SCALAR)1.3981999507E-3;
        p = p * r + (SCALAR)8.3334519073E-3;
        p = p * r + (SCALAR)4.1665795894E-2;
        p = p * r + (SCALAR)1.6666665459E-1;
        p = p * r + (SCALAR)5.0000001201E-1;
        p = p * (r * r) + r + (SCALAR)1;
    } else {
        static const double inv_fact[14] = {
            1.0, 1.0, 1.0 / 2, 1.0 / 6, 1.0 / 24, 1.0 / 120, 1.0 / 720, 1.0 / 5040,
            1.0 / 40320, 1.0 / 362880, 1.0 / 3628800, 1.0 / 39916800, 1.0 / 479001600,
            1.0 / 6227020800.0};
        p = zero + (SCALAR)inv_fact[13];
        for (int i = 12; i >= 0; --i) p = p * r + (SCALAR)inv_fact[i];
    }
    const int bias = F32 ? 127 : 1023, shift = F32 ? 23 : 52;
    const ivec biased = n + bias; /* > 0: 2^n is normal */
    const mask e = __builtin_convertvector(biased, mask) << shift;
    const vec scale = VSELECT(__builtin_convertvector(biased > 0, mask), (vec)e, zero);
    return p * scale;
}

/* exp(-z ln 2 / 8) for z >= 0 (double, EXPZ_SCALE 1: z itself): the polynomial above */
SIMD_FN SIMDN(vs_) SIMDN(expz_)(SIMDN(vs_) z) {
    return SIMDN(exp_)(z * (SCALAR)-0.08664339756999316);
}

/* double: no near range (expz_ of every lane) */
SIMD_FN SIMDN(vs_) SIMDN(expz_lanes_)(SIMDN(vs_) z) {
    return SIMDN(expz_)(z);
}
#endif

/* The taps of the active pixels [a, b) of row `row` (within the line's strip), VW at a time;
 * `scale` holds their scales. The last vector of a run shorter than VW repeats its last pixel
 * in the spare lanes (computed, not written). */
SIMD_FN void SIMDN(segment_)(const CAT(job_, SUFFIX) *j, const CAT(line_, SUFFIX) *ln,
                             int64_t row, int64_t a, int64_t b, const SCALAR *scale,
                             int64_t n_axis, const int AXIS_Y, const int FOLLOW,
                             const int MULTI) {
    typedef SIMDN(vs_) vec;
    typedef SIMDN(vm_) mask;
    typedef SIMDN(vi_) ivec;
    typedef SIMDN(vu_) uivec;
    const int64_t w = j->w, hw = j->h * w;
    const SCALAR *p0 = ln->pl[0], *p1 = ln->pl[1], *p2 = ln->pl[2], *p3 = ln->pl[3];
    const vec zero = {0}, one = zero + 1, last = zero + (SCALAR)(n_axis - 1);
    const mask sign = (mask)(-zero); /* the sign bits (-0.0) */
    const ivec izero = {0}, ilast = izero + (int32_t)(n_axis - 1);
    const ivec win0 = izero + (int32_t)ln->lo, pitch = izero + (int32_t)ln->pitch;
    const vec inv0 = zero + j->inv_scale[0], inv1 = zero + j->inv_scale[1],
              inv2 = zero + j->inv_scale[2];
    /* the follow-surface lerp's factor clamp(|dz| inv, 0, 1) as the scalar loop's min then max
     * (VMIN / VMAX), the min in one instruction (VMINV: the same select). Its max can change
     * a bit only where |dz| inv is negative or -0: never when no inv has its sign bit set
     * (taps_in_ makes a NaN inv the largest SCALAR; |dz| has its sign bit clear; a product
     * that is NaN the min makes 1): then it is left out (issue 30: 6 of the x pass's about
     * 80 instructions per tap on AVX-512, and the y pass's alike) */
    const int neg_inv = signbit(j->inv_scale[0]) || signbit(j->inv_scale[1]) ||
                        signbit(j->inv_scale[2]);
    /* the gaussian's exponent in units of ln 2 / 8 (expz_): z = d^2 / 2 / (ln 2 / 8) =
     * (|dz| m)^2 = |dz|^2 k per channel, m = (1 / surface_scale) sqrt(4 / ln 2) (clamped to
     * the largest finite SCALAR, as 1 / surface_scale is: 0 m = 0), k = m^2, each rounded once
     * from double; |dz|^2 k when every k lies in [1e-35, 1e30] (then |dz|^2 or the product
     * under- or overflows only where the exact factor rounds to 1, or is below FLT_MIN,
     * anyway), else (|dz| m)^2; either times EXPZ_SCALE (float: y = z / 8) */
    double kd[3], md[3];
    int zk = 1;
    for (int ch = 0; ch < 3; ++ch) {
        const double inv = (double)j->inv_scale[ch];
        kd[ch] = inv * inv * 5.7707801635558535;                 /* 4 / ln 2 */
        md[ch] = fmin(inv * 2.4022448175728996, (double)SCALAR_MAX); /* sqrt(4 / ln 2) */
        zk = zk && kd[ch] >= 1e-35 && kd[ch] <= 1e30;
        kd[ch] *= EXPZ_SCALE; /* expz_'s units (exact: a power of 2, k / 8 >= 1.25e-36) */
    }
    const vec m0 = zero + (SCALAR)md[0], m1 = zero + (SCALAR)md[1], m2 = zero + (SCALAR)md[2];
    const vec k0 = zero + (SCALAR)kd[0], k1 = zero + (SCALAR)kd[1], k2 = zero + (SCALAR)kd[2];
    /* MULTI: a sweep of j->nsets weight sets (see taps_ in gather_body.h). Set 0 runs in the
     * tap loop below as the single pass does; for the others the loop keeps, per tap of a
     * chunk of TAP_CHUNK, what the sets share (fan-out: the samples after the follow-surface
     * lerp; fan-in: where the samples are, their fraction and the lerp factors; the
     * gaussian's factors), and after each chunk every further set runs over it with its
     * sums in registers (the same operations per set in the same order as a pass of its
     * own: bitwise its result). A fan-in's set s reads input s (planes ln->plx[s]): two rows
     * of it where the tap's samples share one row pair (the common case), else a gather. */
    const int64_t ns = MULTI ? j->nsets : 1;
    const int fan_in = MULTI && j->fan_in;
    enum { TAP_CHUNK = 16 };
    ivec iota;
    for (int l = 0; l < VW; ++l) iota[l] = l;
    for (int64_t c = a; c < b; c += VW) {
        const int64_t n = b - c < VW ? b - c : VW;
        vec sc;
        ivec lane = iota; /* the pixel of each lane: c + lane */
        if (n == VW) {
            __builtin_memcpy(&sc, scale + (c - a), sizeof sc);
        } else {
            for (int l = 0; l < VW; ++l) {
                const int m = l < n ? l : (int)n - 1;
                lane[l] = m;
                sc[l] = scale[c - a + m];
            }
        }
        const ivec posi = AXIS_Y ? izero + (int32_t)row : lane + (int32_t)c;
        const ivec col = AXIS_Y ? lane + (int32_t)(c - ln->s0) : izero;
        const vec pos = __builtin_convertvector(posi, vec);
        const ivec centre = (posi - win0) * pitch + col;
        /* the pixels themselves: contiguous in a whole vector, else gathered */
#define CENTRE(P, out)                                                            \
    do {                                                                          \
        if (n == VW)                                                              \
            __builtin_memcpy(&(out), (P) + centre[0], sizeof(out));               \
        else                                                                      \
            (out) = (vec)GATHER_RAW((P), centre);                                 \
    } while (0)
/* a tap's two samples of plane P from two whole-vector loads at o1 and o2 (consecutive
 * positions of an x pass's row, a row pair of a y pass's strip), lerped by fr */
#define LOADED_PAIR(P, o1, o2, fr, out)                                           \
    do {                                                                          \
        vec a_, b_;                                                               \
        __builtin_memcpy(&a_, (P) + (o1), sizeof a_);                             \
        __builtin_memcpy(&b_, (P) + (o2), sizeof b_);                             \
        (out) = a_ + (fr) * (b_ - a_);                                            \
    } while (0)
        vec c0, c1, c2, cz;
        CENTRE(p0, c0);
        CENTRE(p1, c1);
        CENTRE(p2, c2);
        CENTRE(p3, cz);
        vec accx[MAX_SETS][3];  /* sets 1..: their sums between chunks */
        vec tv[TAP_CHUNK][3];    /* fan-out: the samples; fan-in: the lerp factors */
        vec te[TAP_CHUNK][3];    /* the gaussian's factors (tsc: applied) */
        vec tf[TAP_CHUNK];       /* fan-in: the fraction */
        ivec tia[TAP_CHUNK], tib[TAP_CHUNK];
        int64_t tat[TAP_CHUNK]; /* fan-in: the row pair's offset, or -1: gather */
        /* fan-in, a tap whose lanes' rows lie within four (the selects of set 0, tat -1):
         * the four rows' offsets and each lane's row of the pair, for the other sets' same
         * selects (a gather per set and channel instead costs about as much as all the
         * rest of a close-up's y sweep: measured, issue 30) */
        int64_t tsel[TAP_CHUNK][4];
        ivec tra[TAP_CHUNK], trb[TAP_CHUNK];
        int tsok[TAP_CHUNK];
        int tsc[TAP_CHUNK];
        for (int64_t s = 1; s < ns; ++s) accx[s][0] = accx[s][1] = accx[s][2] = zero;
        vec acc0 = zero, acc1 = zero, acc2 = zero;
        for (int64_t t = 0; t < j->k; ++t) {
            const int64_t tt = t % TAP_CHUNK;
            if (fan_in) tat[tt] = -1, tsok[tt] = 0;
            vec p = pos + j->offsets[t] * sc;
            /* border; NaN -> 0. VMINV(last, p) = last < p ? last : p is the scalar loop's
             * p <= last ? p : last wherever p is not NaN (at p = last the same value, -0 kept
             * at last = 0), and a NaN p takes the outer select's 0 either way */
            p = VSELECT(p >= zero, VMINV(last, p), zero);
            const ivec i0 = __builtin_convertvector(p, ivec); /* = floor(p) since p >= 0 */
            const vec f = p - __builtin_convertvector(i0, vec);
            const ivec i1 = VIMIN(i0 + 1, ilast); /* i0 + 1 <= ilast ? i0 + 1 : ilast */
            const ivec ia = (i0 - win0) * pitch + col, ib = (i1 - win0) * pitch + col;
            vec v0, v1, v2, v3;
            if (!AXIS_Y) {
                /* the lanes' first samples at consecutive positions (the scale varies little
                 * over VW pixels, as a rule) and none clamped at the line's end (then
                 * i1 = i0 + 1 in every lane): each plane's samples are two unaligned loads,
                 * the very values the permutes below would select (issue 30: on AVX2 a
                 * two-vector permute is two vpermps and a blend, per sample and plane) */
                if ((int64_t)i0[0] + VW < n_axis &&
                    !ANY_NE2(i0 - iota, izero + i0[0], izero, izero)) {
                    const int32_t at = ia[0];
                    LOADED_PAIR(p0, at, at + 1, f, v0);
                    LOADED_PAIR(p1, at, at + 1, f, v1);
                    LOADED_PAIR(p2, at, at + 1, f, v2);
                    LOADED_PAIR(p3, at, at + 1, f, v3);
                    goto fetched;
                }
                /* the lanes' samples lie within 2 VW positions of the first's, as a rule:
                 * two loads and a two-vector permute per plane instead of a gather */
                const int32_t base = ia[0] > 2 ? ia[0] - 2 : 0;
                const ivec ra = ia - base, rb = ib - base;
                if (!ANY_GTU(ra | rb, izero + (2 * VW - 1))) {
                    const mask sa = __builtin_convertvector(ra, mask);
                    const mask sb = __builtin_convertvector(rb, mask);
#define PERMUTED(P, out)                                                          \
    do {                                                                          \
        vec lo_, hi_;                                                             \
        __builtin_memcpy(&lo_, (P) + base, sizeof lo_);                           \
        __builtin_memcpy(&hi_, (P) + base + VW, sizeof hi_);                      \
        const vec a_ = (vec)SHUFFLE2(lo_, hi_, sa);                               \
        const vec b_ = (vec)SHUFFLE2(lo_, hi_, sb);                               \
        out = a_ + f * (b_ - a_);                                                 \
    } while (0)
                    PERMUTED(p0, v0);
                    PERMUTED(p1, v1);
                    PERMUTED(p2, v2);
                    PERMUTED(p3, v3);
#undef PERMUTED
                    goto fetched;
                }
            } else {
                /* the lanes' rows lie within one of the first lane's, as a rule: four
                 * contiguous rows of VW columns and selects per plane instead of a gather */
                const int32_t r0 = i0[0] - 1;
                const ivec ra = i0 - r0, rb = i1 - r0;
                if (!ANY_NE2(ra, izero + 1, rb, izero + 2)) { /* one row pair: no selects */
                    const int64_t at1 = (i0[0] - ln->lo) * ln->pitch + (c - ln->s0);
                    const int64_t at2 = at1 + ln->pitch;
                    LOADED_PAIR(p0, at1, at2, f, v0);
                    LOADED_PAIR(p1, at1, at2, f, v1);
                    LOADED_PAIR(p2, at1, at2, f, v2);
                    LOADED_PAIR(p3, at1, at2, f, v3);
                    if (fan_in) tat[tt] = at1;
                    goto fetched;
                }
                if (!ANY_GTU(ra | rb, izero + 3)) {
                    int64_t at[4];
                    for (int k = 0; k < 4; ++k) {
                        int64_t r = r0 + k;
                        r = r < ln->lo ? ln->lo : (r > ln->hi ? ln->hi : r);
                        at[k] = (r - ln->lo) * ln->pitch + (c - ln->s0);
                    }
                    const mask a1 = __builtin_convertvector(ra == 1, mask),
                               a2 = __builtin_convertvector(ra == 2, mask),
                               a3 = __builtin_convertvector(ra == 3, mask),
                               b1 = __builtin_convertvector(rb == 1, mask),
                               b2 = __builtin_convertvector(rb == 2, mask),
                               b3 = __builtin_convertvector(rb == 3, mask);
#define SELECTED(P, out)                                                          \
    do {                                                                          \
        vec q0_, q1_, q2_, q3_;                                                   \
        __builtin_memcpy(&q0_, (P) + at[0], sizeof q0_);                          \
        __builtin_memcpy(&q1_, (P) + at[1], sizeof q1_);                          \
        __builtin_memcpy(&q2_, (P) + at[2], sizeof q2_);                          \
        __builtin_memcpy(&q3_, (P) + at[3], sizeof q3_);                          \
        const vec a_ = VSELECT(a1, q1_, VSELECT(a2, q2_, VSELECT(a3, q3_, q0_))); \
        const vec b_ = VSELECT(b1, q1_, VSELECT(b2, q2_, VSELECT(b3, q3_, q0_))); \
        out = a_ + f * (b_ - a_);                                                 \
    } while (0)
                    SELECTED(p0, v0);
                    SELECTED(p1, v1);
                    SELECTED(p2, v2);
                    SELECTED(p3, v3);
                    if (fan_in) {
                        tsok[tt] = 1;
                        for (int k = 0; k < 4; ++k) tsel[tt][k] = at[k];
                        tra[tt] = ra;
                        trb[tt] = rb;
                    }
                    goto fetched;
                }
            }
            {
                vec va, vb;
                va = (vec)GATHER_RAW(p0, ia);
                vb = (vec)GATHER_RAW(p0, ib);
                v0 = va + f * (vb - va);
                va = (vec)GATHER_RAW(p1, ia);
                vb = (vec)GATHER_RAW(p1, ib);
                v1 = va + f * (vb - va);
                va = (vec)GATHER_RAW(p2, ia);
                vb = (vec)GATHER_RAW(p2, ib);
                v2 = va + f * (vb - va);
                va = (vec)GATHER_RAW(p3, ia);
                vb = (vec)GATHER_RAW(p3, ib);
                v3 = va + f * (vb - va);
            }
        fetched:;
            const SCALAR *wt = j->weights4 + 4 * t;
            /* the weights as they are (the scalar loop's), not 0 + w: the same sums, since
             * w = -0 and w = +0 give products of 0 that leave acc, which starts at +0 and is
             * never -0, unchanged */
            vec w0 = (vec)VSET1(wt[0]), w1 = (vec)VSET1(wt[1]), w2 = (vec)VSET1(wt[2]);
            vec e0 = one, e1 = one, e2 = one;
            int scaled = 0;
            if (FOLLOW) {
                const vec dz = (vec)((mask)(v3 - cz) & ~sign); /* |dz| */
                if (FOLLOW == 1) { /* min then max as VMIN / VMAX: a < b ? a : b */
                    const vec d0 = dz * inv0, d1 = dz * inv1, d2 = dz * inv2;
                    vec t0 = VMINV(d0, one), t1 = VMINV(d1, one), t2 = VMINV(d2, one);
                    if (neg_inv) { /* else t > 0 or t = +0 already: the max changes no bit */
                        t0 = VSELECT(t0 > zero, t0, zero);
                        t1 = VSELECT(t1 > zero, t1, zero);
                        t2 = VSELECT(t2 > zero, t2, zero);
                    }
                    v0 = v0 + t0 * (c0 - v0);
                    v1 = v1 + t1 * (c1 - v1);
                    v2 = v2 + t2 * (c2 - v2);
                    if (fan_in) {
                        tv[tt][0] = t0;
                        tv[tt][1] = t1;
                        tv[tt][2] = t2;
                    }
                } else if (j->offsets[t] != 0) {
                    /* 000 eq. 7, exp(-(|dz| / surface_scale)^2 / 2) = exp(-z ln 2 / 8)
                     * with z = |dz|^2 k: one product per channel (the torch loop's -0.5 d d,
                     * d = |dz| / surface_scale, three; z within 1.5 ulp of the exact, the
                     * torch loop's argument within 1.5 ulp too); a centre tap (offset 0)
                     * fetches its own pixel, dz = 0 and exp(-0) = 1 exactly (here, in
                     * expf / exp and in torch): not computed */
                    vec z0, z1, z2;
                    if (zk) { /* |dz|^2 k, k = m^2: one product per channel */
                        const vec dz2 = dz * dz;
                        z0 = dz2 * k0, z1 = dz2 * k1, z2 = dz2 * k2;
                    } else { /* (|dz| m)^2: no under- or overflow the torch loop has not */
                        const vec d0 = dz * m0, d1 = dz * m1, d2 = dz * m2;
                        z0 = d0 * d0, z1 = d1 * d1, z2 = d2 * d2;
                        if (EXPZ_SCALE != 1) /* exact, or below FLT_MIN where the factor is 1 */
                            z0 *= (SCALAR)EXPZ_SCALE, z1 *= (SCALAR)EXPZ_SCALE,
                                z2 *= (SCALAR)EXPZ_SCALE;
                    }
                    /* per channel, expz_'s bits; for the float loops by expz_near_ where
                     * every lane allows it (the artist's broad red channel mostly does) */
                    e0 = SIMDN(expz_lanes_)(z0);
                    e1 = SIMDN(expz_lanes_)(z1);
                    e2 = SIMDN(expz_lanes_)(z2);
                    scaled = 1;
                    w0 = w0 * e0;
                    w1 = w1 * e1;
                    w2 = w2 * e2;
                }
            }
            acc0 = acc0 + w0 * v0;
            acc1 = acc1 + w1 * v1;
            acc2 = acc2 + w2 * v2;
            if (ns > 1) { /* what the other sets share of this tap */
                tsc[tt] = scaled;
                te[tt][0] = e0;
                te[tt][1] = e1;
                te[tt][2] = e2;
                if (fan_in) {
                    tf[tt] = f;
                    tia[tt] = ia;
                    tib[tt] = ib;
                } else {
                    tv[tt][0] = v0;
                    tv[tt][1] = v1;
                    tv[tt][2] = v2;
                }
            }
            if (ns == 1 || (tt != TAP_CHUNK - 1 && t != j->k - 1)) continue;
            const int64_t t0_ = t - tt; /* the chunk's first tap */
            for (int64_t s = 1; s < ns; ++s) { /* the other sets over the chunk */
                vec a0 = accx[s][0], a1 = accx[s][1], a2 = accx[s][2];
                const SCALAR *q0 = fan_in ? ln->plx[s][0] : NULL, *q1 = fan_in ? ln->plx[s][1] : NULL,
                             *q2 = fan_in ? ln->plx[s][2] : NULL;
                vec m0 = zero, m1 = zero, m2 = zero; /* fan-in: input s's centre pixels */
                if (fan_in && FOLLOW == 1) {
                    CENTRE(q0, m0);
                    CENTRE(q1, m1);
                    CENTRE(q2, m2);
                }
                for (int64_t u = 0; u <= tt; ++u) {
                    vec x0, x1, x2;
                    if (fan_in) {
                        const vec fr = tf[u];
                        if (tat[u] >= 0) {
                            const int64_t o1 = tat[u], o2 = o1 + ln->pitch;
                            LOADED_PAIR(q0, o1, o2, fr, x0);
                            LOADED_PAIR(q1, o1, o2, fr, x1);
                            LOADED_PAIR(q2, o1, o2, fr, x2);
                        } else if (tsok[u]) { /* set 0's four rows and selects */
                            const int64_t *at = tsel[u];
                            const mask a1 = __builtin_convertvector(tra[u] == 1, mask),
                                       a2 = __builtin_convertvector(tra[u] == 2, mask),
                                       a3 = __builtin_convertvector(tra[u] == 3, mask),
                                       b1 = __builtin_convertvector(trb[u] == 1, mask),
                                       b2 = __builtin_convertvector(trb[u] == 2, mask),
                                       b3 = __builtin_convertvector(trb[u] == 3, mask);
                            const vec f = fr;
                            SELECTED(q0, x0);
                            SELECTED(q1, x1);
                            SELECTED(q2, x2);
                        } else {
                            vec a_, b_;
#define GATHERED(Q, out)                                                          \
    do {                                                                          \
        a_ = (vec)GATHER_RAW(Q, tia[u]);                                          \
        b_ = (vec)GATHER_RAW(Q, tib[u]);                                          \
        out = a_ + fr * (b_ - a_);                                                \
    } while (0)
                            GATHERED(q0, x0);
                            GATHERED(q1, x1);
                            GATHERED(q2, x2);
#undef GATHERED
#undef SELECTED
                        }
                        if (FOLLOW == 1) {
                            x0 = x0 + tv[u][0] * (m0 - x0);
                            x1 = x1 + tv[u][1] * (m1 - x1);
                            x2 = x2 + tv[u][2] * (m2 - x2);
                        }
                    } else {
                        x0 = tv[u][0];
                        x1 = tv[u][1];
                        x2 = tv[u][2];
                    }
                    const SCALAR *ws = j->weights4 + 4 * (s * j->k + t0_ + u);
                    vec u0 = (vec)VSET1(ws[0]), u1 = (vec)VSET1(ws[1]), u2 = (vec)VSET1(ws[2]);
                    if (tsc[u]) {
                        u0 = u0 * te[u][0];
                        u1 = u1 * te[u][1];
                        u2 = u2 * te[u][2];
                    }
                    a0 = a0 + u0 * x0;
                    a1 = a1 + u1 * x1;
                    a2 = a2 + u2 * x2;
                }
                accx[s][0] = a0;
                accx[s][1] = a1;
                accx[s][2] = a2;
            }
        }
        if (fan_in) { /* 0 + c_0 r_0 + c_1 r_1 + ...: the sets' blend */
            const SCALAR *cs = j->coef4;
            vec s0 = zero + cs[0] * acc0, s1 = zero + cs[1] * acc1, s2 = zero + cs[2] * acc2;
            for (int64_t s = 1; s < ns; ++s) {
                cs = j->coef4 + 4 * s;
                s0 = s0 + cs[0] * accx[s][0];
                s1 = s1 + cs[1] * accx[s][1];
                s2 = s2 + cs[2] * accx[s][2];
            }
            acc0 = s0;
            acc1 = s1;
            acc2 = s2;
        } else if (MULTI) /* a fan-out: set s's result into output s */
            for (int64_t s = 1; s < ns; ++s) {
                SCALAR *o = j->dst + s * j->set_stride + row * w + c;
                if (n == VW) {
                    __builtin_memcpy(o, &accx[s][0], sizeof acc0);
                    __builtin_memcpy(o + hw, &accx[s][1], sizeof acc0);
                    __builtin_memcpy(o + 2 * hw, &accx[s][2], sizeof acc0);
                } else {
                    for (int64_t l = 0; l < n; ++l) {
                        o[l] = accx[s][0][l];
                        o[hw + l] = accx[s][1][l];
                        o[2 * hw + l] = accx[s][2][l];
                    }
                }
            }
        SCALAR *o = j->dst + row * w + c;
        if (n == VW) {
            __builtin_memcpy(o, &acc0, sizeof acc0);
            __builtin_memcpy(o + hw, &acc1, sizeof acc1);
            __builtin_memcpy(o + 2 * hw, &acc2, sizeof acc2);
        } else {
            for (int64_t l = 0; l < n; ++l) {
                o[l] = acc0[l];
                o[hw + l] = acc1[l];
                o[2 * hw + l] = acc2[l];
            }
        }
        if (j->blend_out) { /* lerp(blend_out, result, blend_w): BLEND_LERP, lane-wise */
            SCALAR *bo = j->blend_out + row * w + c;
            const vec accs[3] = {acc0, acc1, acc2};
            for (int ch = 0; ch < 3; ++ch) {
                const SCALAR wt = j->blend_w[ch];
                const int small = FABSF(wt) < (SCALAR)0.5;
                vec ov;
                if (n == VW) {
                    __builtin_memcpy(&ov, bo + ch * hw, sizeof ov);
                } else {
                    ov = zero;
                    for (int64_t l = 0; l < n; ++l) ov[l] = bo[ch * hw + l];
                }
                const vec e = accs[ch];
                const vec r = small ? ov + wt * (e - ov) : e - (e - ov) * ((SCALAR)1 - wt);
                if (n == VW) {
                    __builtin_memcpy(bo + ch * hw, &r, sizeof r);
                } else {
                    for (int64_t l = 0; l < n; ++l) bo[ch * hw + l] = r[l];
                }
            }
        }
    }
}

/* line_scales_ in gather_body.h, a vector of pixels at a time in double (the same operations
 * per pixel: bitwise the same scales; the largest |scale| is a maximum, whatever the order) */
SIMD_FN SCALAR SIMDN(scales_)(const CAT(job_, SUFFIX) *j, const CAT(line_, SUFFIX) *ln) {
    enum { DW = VW * sizeof(SCALAR) / 8 }; /* doubles per vector */
    typedef double vd __attribute__((vector_size(VW * sizeof(SCALAR))));
    typedef SCALAR vsd __attribute__((vector_size(DW * sizeof(SCALAR))));
    typedef LANE vsdm __attribute__((vector_size(DW * sizeof(SCALAR))));
    const vd dzero = {0}, fpx = dzero + j->focal_px, corr = dzero + j->correction,
             maxdd = dzero + j->maxdd, ws = dzero + j->width_scalar,
             big = dzero + (double)SCALAR_MAX;
    const vsd zero = {0};
    const vsdm sign = (vsdm)(-zero);
    vsd vmax = zero;
    SCALAR max_abs = 0;
    int64_t idx = 0;
    for (int64_t e = 0; e < ln->count; ++e) {
        const int64_t *sp = j->spans + 3 * ln->ids[e];
        const int64_t c0 = sp[1] > ln->s0 ? sp[1] : ln->s0, c1 = sp[2] < ln->s1 ? sp[2] : ln->s1;
        CAT(prefetch_scales_, SUFFIX)(j, ln, e);
        const int64_t base = sp[0] * j->w;
        int64_t c = c0;
        for (; c + DW <= c1; c += DW) {
            vsd t;
            __builtin_memcpy(&t, j->depth + base + c, sizeof t);
            vd denom = __builtin_convertvector(t, vd);
            if (j->ddepth) {
                __builtin_memcpy(&t, j->ddepth + base + c, sizeof t);
                const vd dd = __builtin_convertvector(t, vd);
                denom = denom + corr * VSELECT(dd < maxdd, dd, maxdd);
            }
            vd sc = fpx / denom;
            if (j->width) {
                __builtin_memcpy(&t, j->width + base + c, sizeof t);
                sc = sc * __builtin_convertvector(t, vd);
            } else {
                sc = sc * ws;
            }
            if (j->mask) {
                __builtin_memcpy(&t, j->mask + base + c, sizeof t);
                sc = sc * __builtin_convertvector(t, vd);
            }
            sc = VSELECT(sc <= big, sc, big); /* also NaN -> big */
            const vsd out = __builtin_convertvector(sc, vsd);
            __builtin_memcpy(j->scale + idx, &out, sizeof out);
            idx += DW;
            const vsd a = (vsd)((vsdm)out & ~sign);
            vmax = VSELECT(a > vmax, a, vmax);
        }
        for (; c < c1; ++c) {
            const SCALAR sc = CAT(scale_at_, SUFFIX)(j, base + c);
            const SCALAR a = FABSF(sc);
            if (!(a <= max_abs)) max_abs = a == a ? a : (SCALAR)INFINITY;
            j->scale[idx++] = sc;
        }
    }
    for (int l = 0; l < DW; ++l)
        if (!(vmax[l] <= max_abs)) max_abs = vmax[l];
    return max_abs;
}

/* This thread's lines, as lines_ in gather_body.h, the taps VW pixels at a time. */
SIMD_FN void SIMDN(lines_)(const CAT(job_, SUFFIX) *j, const int AXIS_Y, const int FOLLOW,
                           const int MULTI) {
    const int64_t n_axis = AXIS_Y ? j->h : j->w;
    for (int64_t q = j->first; q < j->last; ++q) {
        CAT(line_, SUFFIX) ln;
        if (!CAT(line_begin_, SUFFIX)(j, q, AXIS_Y, &ln)) continue;
        CAT(line_window_, SUFFIX)(j, q, AXIS_Y, 1, SIMDN(scales_)(j, &ln), &ln);
        int64_t idx = 0;
        for (int64_t e = 0; e < ln.count; ++e) {
            const int64_t *sp = j->spans + 3 * ln.ids[e];
            const int64_t a = sp[1] > ln.s0 ? sp[1] : ln.s0, b = sp[2] < ln.s1 ? sp[2] : ln.s1;
            if (AXIS_Y) CAT(line_pack_, SUFFIX)(j, &ln, sp[0] + ln.margin + 2);
            SIMDN(segment_)(j, &ln, sp[0], a, b, j->scale + idx, n_axis, AXIS_Y, FOLLOW, MULTI);
            idx += b - a;
        }
    }
}

/* One thread's lines at this level: run_f32_avx2 and the like */
LINES_ALL(SIMDN(lines_), SIMDN(run_), __attribute__((target(ISA_TARGET))))

#undef CENTRE
#undef LOADED_PAIR
#undef SIMDN
#undef SIMD_FN
#undef ANY_GTU
#undef ANY_NE2

/* The tap loop of sssbench.ops.gather for one scalar type (included twice by gather.c).
 *
 * Mirrors sssbench.ops.gather._accumulate operation by operation (same order of float
 * operations, so results agree with the torch loop to rounding); see that function and
 * separable_pass for the formulas and their citations. Expects SCALAR, SUFFIX, EXPF, FABSF and
 * ISCALAR (the signed integer of SCALAR's size).
 */

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)

typedef struct {
    const SCALAR *src;      /* (3, H*W) image planes of one image */
    const SCALAR *depth;    /* (H*W,) linear depth, mm */
    const int64_t *lin;     /* (n,) active flat pixel indices, NULL: every pixel */
    const SCALAR *mask;     /* (H*W,) strength (003 s' = s * alpha), NULL: none */
    const SCALAR *width;    /* (H*W,) per-pixel width multiplier, NULL: width_scalar */
    const SCALAR *ddepth;   /* (H*W,) |d depth / d axis| for the JG10 stretch, NULL: none */
    const SCALAR *offsets;  /* (k,) tap offsets, mm per width unit */
    const SCALAR *weights;  /* (k, 3) tap weights */
    const SCALAR *inv_scale;/* (3,) 1 / surface_scale per channel */
    SCALAR *dst;            /* (3, H*W) output planes written at the active pixels, or (3, n)
                               compact rows when compact != 0 */
    SCALAR *packed;         /* (H*W, 4) r, g, b, depth interleaved, NULL: use the planes */
    const SCALAR *weights4; /* (k, 4) weights with a zero fourth lane */
    SCALAR focal_px, width_scalar, correction, maxdd;
    int64_t n, k, h, w, begin, end;
    int axis_y, follow, compact;
} CAT(job_, SUFFIX);

typedef SCALAR CAT(vec_, SUFFIX) __attribute__((vector_size(4 * sizeof(SCALAR))));

/* (r, g, b, depth) of flat pixel l: one 4-lane load from the interleaved copy when PACKED,
 * else four loads from the planes. */
static inline __attribute__((always_inline)) CAT(vec_, SUFFIX)
    CAT(fetch_, SUFFIX)(const CAT(job_, SUFFIX) *j, int64_t l, int64_t hw, const int PACKED) {
    CAT(vec_, SUFFIX) v;
    if (PACKED) {
        __builtin_memcpy(&v, j->packed + 4 * l, sizeof v);
    } else {
        v[0] = j->src[l];
        v[1] = j->src[hw + l];
        v[2] = j->src[2 * hw + l];
        v[3] = j->depth[l];
    }
    return v;
}

/* The tap loop over pixels [begin, end) of the job, 4-lane: lanes r, g, b carry the colour,
 * lane 3 carries depth through the lerp (its weight is 0); lane by lane these are the float
 * operations of the torch loop, in its order. */
static inline __attribute__((always_inline)) void CAT(taps_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, const int PACKED, const int FOLLOW) {
    typedef CAT(vec_, SUFFIX) vec;
    const int64_t w = j->w, hw = j->h * j->w, k = j->k;
    const int64_t n_axis = j->axis_y ? j->h : j->w;
    const int64_t stride = j->axis_y ? j->w : 1;
    const SCALAR last = (SCALAR)(n_axis - 1);
    const vec inv = {j->inv_scale[0], j->inv_scale[1], j->inv_scale[2], 0};
    const vec one = {1, 1, 1, 1}, zero = {0, 0, 0, 0};
    const int64_t plane = j->compact ? j->n : hw;
    for (int64_t i = j->begin; i < j->end; ++i) {
        const int64_t l = j->lin ? j->lin[i] : i;
        const int64_t row = l / w, col = l - row * w;
        const vec c = CAT(fetch_, SUFFIX)(j, l, hw, PACKED);
        const SCALAR cz = c[3];
        /* pixels per kernel-offset unit: DESIGN §2 pinhole, 003 §7.3.1 stretch and s' = s a */
        SCALAR denom = cz;
        if (j->ddepth) {
            SCALAR dd = j->ddepth[l];
            denom = cz + j->correction * (dd < j->maxdd ? dd : j->maxdd);
        }
        SCALAR scale = j->focal_px / denom;
        scale = scale * (j->width ? j->width[l] : j->width_scalar);
        if (j->mask) scale = scale * j->mask[l];
        const SCALAR pos = (SCALAR)(j->axis_y ? row : col);
        const int64_t fixed = j->axis_y ? col : row * w;
        vec acc = zero;
        for (int64_t t = 0; t < k; ++t) {
            SCALAR p = pos + j->offsets[t] * scale;
            p = p >= 0 ? (p <= last ? p : last) : 0; /* border clamp; NaN -> 0, never OOB */
            const int64_t i0 = (int64_t)p;           /* = floor(p) since p >= 0 */
            const SCALAR f = p - (SCALAR)i0;
            const int64_t a = fixed + i0 * stride;
            const int64_t bb = fixed + (i0 + 1 < n_axis ? i0 + 1 : n_axis - 1) * stride;
            const vec va = CAT(fetch_, SUFFIX)(j, a, hw, PACKED);
            const vec vb = CAT(fetch_, SUFFIX)(j, bb, hw, PACKED);
            vec v = va + f * (vb - va), wt;
            __builtin_memcpy(&wt, j->weights4 + 4 * t, sizeof wt);
            if (FOLLOW) {
                const vec d = FABSF(v[3] - cz) * inv; /* |dz| / surface_scale per channel */
                if (FOLLOW == 1) { /* 002 appendix shader: lerp back by clamp(d, 0, 1) */
                    const vec s = VMAX(VMIN(d, one), zero);
                    v = v + s * (c - v);
                } else { /* 000 eq. 7 */
                    const vec e = {EXPF((SCALAR)-0.5 * d[0] * d[0]),
                                   EXPF((SCALAR)-0.5 * d[1] * d[1]),
                                   EXPF((SCALAR)-0.5 * d[2] * d[2]), 0};
                    wt = wt * e;
                }
            }
            acc = acc + wt * v;
        }
        const int64_t o = j->compact ? i : l;
        j->dst[o] = acc[0];
        j->dst[plane + o] = acc[1];
        j->dst[2 * plane + o] = acc[2];
    }
}

/* The tap loop, specialised per layout and follow-surface mode (both constants there). */
static void *CAT(run_taps_, SUFFIX)(void *arg) {
    const CAT(job_, SUFFIX) *j = (const CAT(job_, SUFFIX) *)arg;
    const int packed = j->packed != NULL, follow = j->follow;
    if (packed && follow == 0) CAT(taps_, SUFFIX)(j, 1, 0);
    else if (packed && follow == 1) CAT(taps_, SUFFIX)(j, 1, 1);
    else if (packed) CAT(taps_, SUFFIX)(j, 1, 2);
    else if (follow == 0) CAT(taps_, SUFFIX)(j, 0, 0);
    else if (follow == 1) CAT(taps_, SUFFIX)(j, 0, 1);
    else CAT(taps_, SUFFIX)(j, 0, 2);
    return NULL;
}

/* Interleave pixels [begin, end) of the planes and depth into job->packed. */
static void *CAT(run_pack_, SUFFIX)(void *arg) {
    const CAT(job_, SUFFIX) *j = (const CAT(job_, SUFFIX) *)arg;
    const int64_t hw = j->h * j->w;
    SCALAR *restrict out = j->packed;
    for (int64_t l = j->begin; l < j->end; ++l) {
        out[4 * l] = j->src[l];
        out[4 * l + 1] = j->src[hw + l];
        out[4 * l + 2] = j->src[2 * hw + l];
        out[4 * l + 3] = j->depth[l];
    }
    return NULL;
}

/* Run jobs[0..threads) on threads (jobs[0] on the caller's); a thread that cannot be started
 * has its share run by the caller. */
static void CAT(parallel_, SUFFIX)(void *(*run)(void *), CAT(job_, SUFFIX) * jobs, int threads) {
    pthread_t ids[64];
    int started = 1;
    for (int t = 1; t < threads; ++t, ++started)
        if (pthread_create(&ids[t], NULL, run, &jobs[t]) != 0) break;
    for (int t = started; t < threads; ++t) run(&jobs[t]);
    run(&jobs[0]);
    for (int t = 1; t < started; ++t) pthread_join(ids[t], NULL);
}

int CAT(sss_gather_, SUFFIX)(const SCALAR *src, const SCALAR *depth, const int64_t *lin,
                             const SCALAR *mask, const SCALAR *width, const SCALAR *ddepth,
                             const SCALAR *offsets, const SCALAR *weights,
                             const SCALAR *inv_scale, SCALAR *dst, SCALAR *packed,
                             double focal_px,
                             double width_scalar, double correction, double maxdd, int64_t n,
                             int64_t k, int64_t h, int64_t w, int axis_y, int follow,
                             int compact, int threads) {
    enum { MAX_THREADS = 64 };
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (n < 16384 * threads) threads = 1; /* start-up and a still-spinning OpenMP pool cost more */
    const int64_t hw = h * w;
    SCALAR *weights4 = (SCALAR *)malloc(sizeof(SCALAR) * 4 * (size_t)k);
    if (!weights4) return 1;
    for (int64_t t = 0; t < k; ++t) {
        for (int ch = 0; ch < 3; ++ch) weights4[4 * t + ch] = weights[3 * t + ch];
        weights4[4 * t + 3] = 0;
    }
    /* packed, an (H*W, 4) buffer, given: interleave the image into it once, then one 4-lane
     * load per fetch (the caller gives it when most of the image is covered); NULL: fetch
     * from the planes (time follows covered pixels, no full-image pass) */
    CAT(job_, SUFFIX) jobs[MAX_THREADS];
    for (int t = 0; t < threads; ++t) {
        CAT(job_, SUFFIX) jb = {src, depth, lin, mask, width, ddepth, offsets, weights,
                                inv_scale, dst, packed, weights4, (SCALAR)focal_px,
                                (SCALAR)width_scalar, (SCALAR)correction, (SCALAR)maxdd, n, k, h,
                                w, hw * t / threads, hw * (t + 1) / threads, axis_y, follow,
                                compact};
        jobs[t] = jb;
    }
    if (packed) CAT(parallel_, SUFFIX)(CAT(run_pack_, SUFFIX), jobs, threads);
    for (int t = 0; t < threads; ++t) { /* the taps: split the active pixels */
        jobs[t].begin = n * t / threads;
        jobs[t].end = n * (t + 1) / threads;
    }
    CAT(parallel_, SUFFIX)(CAT(run_taps_, SUFFIX), jobs, threads);
    free(weights4);
    return 0;
}

#undef CAT
#undef CAT_

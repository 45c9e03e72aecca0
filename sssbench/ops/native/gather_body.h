/* The tap loop of sssbench.ops.gather for one scalar type (included twice by gather.c).
 *
 * Mirrors sssbench.ops.gather._accumulate operation by operation (same order of float
 * operations, so results agree with the torch loop to rounding); see that function and
 * separable_pass for the formulas and their citations. Expects SCALAR, SUFFIX, EXPF.
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
    SCALAR focal_px, width_scalar, correction, maxdd;
    int64_t n, k, h, w, begin, end;
    int axis_y, follow, compact;
} CAT(job_, SUFFIX);

static void *CAT(run_, SUFFIX)(void *arg) {
    const CAT(job_, SUFFIX) *j = (const CAT(job_, SUFFIX) *)arg;
    /* locals, so that the compiler need not reload them after each store to dst */
    const int64_t w = j->w, hw = j->h * j->w, k = j->k;
    const int64_t n_axis = j->axis_y ? j->h : j->w;
    const int64_t stride = j->axis_y ? j->w : 1;
    const SCALAR last = (SCALAR)(n_axis - 1);
    const SCALAR *restrict r = j->src, *restrict g = j->src + hw, *restrict b = j->src + 2 * hw;
    const SCALAR *restrict depth = j->depth, *restrict offsets = j->offsets;
    const SCALAR *restrict weights = j->weights;
    const SCALAR inv[3] = {j->inv_scale[0], j->inv_scale[1], j->inv_scale[2]};
    const int follow = j->follow, axis_y = j->axis_y;
    const int64_t plane = j->compact ? j->n : hw;
    SCALAR *restrict dst = j->dst;
    for (int64_t i = j->begin; i < j->end; ++i) {
        const int64_t l = j->lin ? j->lin[i] : i;
        const int64_t row = l / w, col = l - row * w;
        const SCALAR cz = depth[l];
        /* pixels per kernel-offset unit: DESIGN §2 pinhole, 003 §7.3.1 stretch and s' = s a */
        SCALAR denom = cz;
        if (j->ddepth) {
            SCALAR dd = j->ddepth[l];
            denom = cz + j->correction * (dd < j->maxdd ? dd : j->maxdd);
        }
        SCALAR scale = j->focal_px / denom;
        scale = scale * (j->width ? j->width[l] : j->width_scalar);
        if (j->mask) scale = scale * j->mask[l];
        const SCALAR pos = (SCALAR)(axis_y ? row : col);
        const int64_t fixed = axis_y ? col : row * w;
        const SCALAR c[3] = {r[l], g[l], b[l]};
        SCALAR acc[3] = {0, 0, 0};
        for (int64_t t = 0; t < k; ++t) {
            SCALAR p = pos + offsets[t] * scale;
            p = p >= 0 ? (p <= last ? p : last) : 0; /* border clamp; NaN -> 0, never OOB */
            const int64_t i0 = (int64_t)p;           /* = floor(p) since p >= 0 */
            const SCALAR f = p - (SCALAR)i0;
            const int64_t a = fixed + i0 * stride;
            const int64_t bb = fixed + (i0 + 1 < n_axis ? i0 + 1 : n_axis - 1) * stride;
            SCALAR v[3] = {r[a] + f * (r[bb] - r[a]), g[a] + f * (g[bb] - g[a]),
                           b[a] + f * (b[bb] - b[a])};
            const SCALAR zs = depth[a] + f * (depth[bb] - depth[a]);
            const SCALAR adz = zs - cz < 0 ? cz - zs : zs - cz;
            for (int ch = 0; ch < 3; ++ch) {
                SCALAR wt = weights[t * 3 + ch];
                if (follow) {
                    const SCALAR dz = adz * inv[ch];
                    if (follow == 1) { /* 002 appendix shader: lerp back to the centre */
                        const SCALAR s = dz < 0 ? 0 : (dz > 1 ? 1 : dz);
                        v[ch] = v[ch] + s * (c[ch] - v[ch]);
                    } else { /* 000 eq. 7 */
                        wt = wt * EXPF((SCALAR)-0.5 * dz * dz);
                    }
                }
                acc[ch] = acc[ch] + wt * v[ch];
            }
        }
        const int64_t o = j->compact ? i : l;
        dst[o] = acc[0];
        dst[plane + o] = acc[1];
        dst[2 * plane + o] = acc[2];
    }
    return NULL;
}

int CAT(sss_gather_, SUFFIX)(const SCALAR *src, const SCALAR *depth, const int64_t *lin,
                             const SCALAR *mask, const SCALAR *width, const SCALAR *ddepth,
                             const SCALAR *offsets, const SCALAR *weights,
                             const SCALAR *inv_scale, SCALAR *dst, double focal_px,
                             double width_scalar, double correction, double maxdd, int64_t n,
                             int64_t k, int64_t h, int64_t w, int axis_y, int follow,
                             int compact, int threads) {
    enum { MAX_THREADS = 64 };
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (n < 4096 * threads) threads = 1; /* thread start-up costs more than a few pixels */
    CAT(job_, SUFFIX) jobs[MAX_THREADS];
    pthread_t ids[MAX_THREADS];
    for (int t = 0; t < threads; ++t) {
        CAT(job_, SUFFIX) jb = {src, depth, lin, mask, width, ddepth, offsets, weights,
                                inv_scale, dst, (SCALAR)focal_px, (SCALAR)width_scalar,
                                (SCALAR)correction, (SCALAR)maxdd, n, k, h, w,
                                n * t / threads, n * (t + 1) / threads, axis_y, follow,
                                compact};
        jobs[t] = jb;
    }
    int started = 1;
    for (int t = 1; t < threads; ++t, ++started)
        if (pthread_create(&ids[t], NULL, CAT(run_, SUFFIX), &jobs[t]) != 0) break;
    /* threads that could not be started: their share runs here */
    for (int t = started; t < threads; ++t) CAT(run_, SUFFIX)(&jobs[t]);
    CAT(run_, SUFFIX)(&jobs[0]);
    for (int t = 1; t < started; ++t) pthread_join(ids[t], NULL);
    return 0;
}

#undef CAT
#undef CAT_

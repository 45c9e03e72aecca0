/* The tap loop of sssbench.ops.gather for one scalar type (included twice by gather.c).
 *
 * Mirrors sssbench.ops._gather_torch (pixel_scales, _accumulate) operation by operation
 * (same float operations in the same order: bitwise equal results but for exp, see
 * BACKEND_AGREEMENT in sssbench/ops/gather.py); see those functions for the formulas and
 * their citations. Expects SCALAR, LANE (the signed integer of its size), SCALAR_MAX, SUFFIX,
 * EXPF, FABSF, VMIN and VMAX.
 *
 * Work is done per line: a row of the image for an x pass, a strip of columns for a y pass (a
 * y tap stays in its column). For each line the active pixels' scales are computed
 * first; their largest step bounds how far any tap can reach, and only that window of the line
 * is interleaved as (r, g, b, depth) into a small per-thread buffer, still in cache when the
 * taps read it (one 4-lane load per fetch). So a pass reads the image once around the active
 * pixels, never writes a full-image copy, and reads every sample before it writes the line's
 * results: the output may be the input (an in-place pass), since lines never share pixels.
 */

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)

typedef struct {
    const SCALAR *src;       /* (3, H*W) image planes of one image */
    const SCALAR *depth;     /* (H*W,) linear depth, mm */
    const int64_t *spans;    /* (n_spans, 3) runs of active pixels: row, first col, end col;
                                sorted by row, then column */
    const SCALAR *mask;      /* (H*W,) strength (003 s' = s * alpha), NULL: none */
    const SCALAR *width;     /* (H*W,) per-pixel width multiplier, NULL: width_scalar */
    const SCALAR *ddepth;    /* (H*W,) |d depth / d axis| for the JG10 stretch, NULL: none */
    const SCALAR *offsets;   /* (k,) tap offsets, mm per width unit */
    const SCALAR *weights4;  /* (k, 4) tap weights with a zero fourth lane */
    const SCALAR *inv_scale; /* (3,) 1 / surface_scale per channel */
    SCALAR *dst;             /* (3, H*W) output planes, written at the active pixels */
    const int64_t *lines;    /* per line: (first entry in ids, span count, active pixels) */
    const int64_t *ids;      /* the spans crossing each line, line after line, in order */
    double focal_px, width_scalar, correction, maxdd; /* the scale is computed in double */
    SCALAR max_offset;
    int64_t k, h, w, first, last, strip; /* this thread's lines [first, last); strip width */
    int axis_y, follow, copy; /* copy: dst starts as a copy of src, line by line */
    int direct; /* dst shares no memory with src: an x pass of the vectorised loops may
                   read its window in place instead of packing it (line_window_) */
    SCALAR *buf;   /* per thread: the line's interleaved (r, g, b, depth) window */
    SCALAR *scale; /* per thread: the scales of one line's active pixels */
    SCALAR *blend_out;      /* (3, H*W) NULL, or lerped toward each result as it is written */
    const SCALAR *blend_w;  /* (3,) per-channel blend weights of blend_out */
    /* the sweep of weight sets over the same taps (sss_gather_'s nsets > 1, or fan_in): set s's
     * weights at weights4 + 4 k s; fan_in = 0: one src, set s's result at dst + s set_stride;
     * fan_in = 1: set s reads src + s set_stride and dst gets sum_s coef4[4 s + ch] times
     * set s's result (0 + c_0 r_0 + c_1 r_1 + ..., in that order) */
    int64_t nsets, set_stride;
    int fan_in;
    const SCALAR *coef4; /* (nsets, 4) per-set per-channel coefficients (fan_in) */
    /* (3, H*W) NULL, or (fan_in) every input's value at the inactive pixels, in place of
     * what the inputs hold there (line_run_: the windows are packed from it there) */
    const SCALAR *inactive;
    /* (3, H*W) NULL, or (not a fan-in) src's inactive pixels copied here line by line, its
     * active pixels left as they are (a fresh result's inactive pixels: the fused sum of
     * Gaussians' x sweep fills its y sweep's output there) */
    SCALAR *inactive_to;
    /* several threads: the lines are handed out in chunks (chunk c: lines chunks[c] ..
     * chunks[c + 1] - 1), each thread taking the next unclaimed one (*claim) until none is
     * left; first / last are then the chunk's. NULL: this job's lines are [first, last) */
    int64_t *claim;
    const int64_t *chunks;
    int64_t n_chunks;
} CAT(job_, SUFFIX);

/* most weight sets of one sweep (the stack arrays of the loops below) */
#define MAX_SETS 16

/* o <- lerp(o, e, wt): the sum-of-Gaussians blend (003 §7.3.3), torch.lerp's formula with a
 * separate multiply and add, the branch on |wt| < 0.5 as in run_blend_ below (bitwise its
 * result: the blend fused into a pass writes what a separate blend of the pass's result would) */
#define BLEND_LERP(o, e, wt, small) \
    ((small) ? (o) + (wt) * ((e) - (o)) : (e) - ((e) - (o)) * (1 - (wt)))

typedef SCALAR CAT(vec_, SUFFIX) __attribute__((vector_size(4 * sizeof(SCALAR))));
/* 16 bytes (one SSE register) of SCALARs and the lane masks of comparing two: the stencil scan */
typedef SCALAR CAT(vec16_, SUFFIX) __attribute__((vector_size(16)));
typedef LANE CAT(lanes16_, SUFFIX) __attribute__((vector_size(16)));

/* y-pass strip widths (columns): one cache line of each plane row when few pixels are active
 * (a narrow strip packs no column it does not need), 256 bytes of each when many are or the
 * whole image is copied. Wide strips were 512 bytes (fewer strips cross each page of the
 * planes: fewer TLB misses) but for a fan-in sweep, whose packed rows hold 3 S + 1 planes
 * (the 6-set fused sum of Gaussians, 1080p close-up, 7 taps, avx512, alternated in one
 * process, 41 rounds: 0.93x the CPU time, 0.92x the wall time of 512 bytes; 128 bytes: 1.05x).
 * Once a y strip's scales asked for their rows ahead (prefetch_scales_), 256 bytes won for
 * the single-input passes too: a packed window row of 1 KB, so twice the rows of a wide
 * kernel's window stay in L1 (issue 30, level avx512, alternated rounds in one process, wall
 * time against 512 bytes: 1080p close-up at 2 threads, 7-tap pre-integrated 0.93x, 0.98x and
 * 0.96x ± 0.02 in three runs, the artist pass 0.93x, 0.98x and 0.95x ± 0.01; at 1 thread
 * 0.97x and 0.95x; 512² close-up at 1 thread 0.95x and 0.94x; 128 bytes 0.96-0.98x and
 * 0.94-0.96x; 1024 bytes 1.09x and 1.12x) */
#define NARROW_STRIP ((int64_t)(64 / sizeof(SCALAR)))
#define WIDE_STRIP ((int64_t)(256 / sizeof(SCALAR)))

/* pixels per kernel-offset unit at flat pixel l: DESIGN §2 pinhole, 003 §7.3.1 stretch and
 * s' = s * alpha; the torch loop's operations in its order (pixel_scales in
 * sssbench/ops/_gather_torch.py): in double, clamped to the largest finite SCALAR before the
 * cast (also NaN, which validated inputs never give), so that offset * s is never NaN */
static inline SCALAR CAT(scale_at_, SUFFIX)(const CAT(job_, SUFFIX) *j, int64_t l) {
    double denom = (double)j->depth[l];
    if (j->ddepth) {
        const double dd = (double)j->ddepth[l];
        denom = denom + j->correction * (dd < j->maxdd ? dd : j->maxdd);
    }
    double s = j->focal_px / denom;
    s = s * (j->width ? (double)j->width[l] : j->width_scalar);
    if (j->mask) s = s * (double)j->mask[l];
    if (!(s <= (double)SCALAR_MAX)) s = (double)SCALAR_MAX;
    return (SCALAR)s;
}

/* The taps of one pixel at position pos along the axis. The window buffer holds positions
 * [win0, ...] of the line; position q is at vector (q - win0) * pitch + lane. Lanes r, g, b
 * carry the colour, lane 3 depth through the lerp (its weight is 0). Returns set 0's sum;
 * with MULTI (a sweep of j->nsets weight sets) sets 1.. go to more[s - 1], and with
 * j->fan_in set s reads input s, whose window is the same layout `stride` SCALARs further
 * (each tap's position, depth sample and follow-surface factor computed once for all). */
static inline __attribute__((always_inline)) CAT(vec_, SUFFIX) CAT(taps_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, const SCALAR *buf, int64_t pitch, int64_t lane, int64_t win0,
    SCALAR pos, SCALAR scale, int64_t n_axis, const int FOLLOW, const int MULTI,
    int64_t stride, CAT(vec_, SUFFIX) *more) {
    typedef CAT(vec_, SUFFIX) vec;
    const SCALAR last = (SCALAR)(n_axis - 1);
    const vec inv = {j->inv_scale[0], j->inv_scale[1], j->inv_scale[2], 0};
    const vec one = {1, 1, 1, 1}, zero = {0, 0, 0, 0};
    const int64_t ns = MULTI ? j->nsets : 1, nin = MULTI && j->fan_in ? ns : 1;
    vec c, cx[MAX_SETS], vx[MAX_SETS]; /* input 0's centre; inputs 1.. (fan_in) */
    __builtin_memcpy(&c, buf + 4 * (((int64_t)pos - win0) * pitch + lane), sizeof c);
    for (int64_t i = 1; i < nin; ++i)
        __builtin_memcpy(&cx[i], buf + i * stride + 4 * (((int64_t)pos - win0) * pitch + lane),
                         sizeof c);
    const SCALAR cz = c[3];
    vec acc = zero;
    for (int64_t s = 1; s < ns; ++s) more[s - 1] = zero;
    for (int64_t t = 0; t < j->k; ++t) {
        SCALAR p = pos + j->offsets[t] * scale;
        p = p >= 0 ? (p <= last ? p : last) : 0; /* border clamp; NaN -> 0 */
        const int64_t i0 = (int64_t)p;           /* = floor(p) since p >= 0 */
        const SCALAR f = p - (SCALAR)i0;
        const int64_t i1 = i0 + 1 < n_axis ? i0 + 1 : n_axis - 1;
        vec va, vb, wt;
        __builtin_memcpy(&va, buf + 4 * ((i0 - win0) * pitch + lane), sizeof va);
        __builtin_memcpy(&vb, buf + 4 * ((i1 - win0) * pitch + lane), sizeof vb);
        vec v = va + f * (vb - va);
        for (int64_t i = 1; i < nin; ++i) {
            __builtin_memcpy(&va, buf + i * stride + 4 * ((i0 - win0) * pitch + lane), sizeof va);
            __builtin_memcpy(&vb, buf + i * stride + 4 * ((i1 - win0) * pitch + lane), sizeof vb);
            vx[i] = va + f * (vb - va);
        }
        __builtin_memcpy(&wt, j->weights4 + 4 * t, sizeof wt);
        vec e = one;
        int scaled = 0;
        if (FOLLOW) {
            const vec d = FABSF(v[3] - cz) * inv; /* |dz| / surface_scale per channel */
            if (FOLLOW == 1) { /* 002 appendix shader: lerp back by clamp(d, 0, 1) */
                const vec s = VMAX(VMIN(d, one), zero);
                v = v + s * (c - v);
                for (int64_t i = 1; i < nin; ++i) vx[i] = vx[i] + s * (cx[i] - vx[i]);
            } else if (j->offsets[t] != 0) { /* 000 eq. 7 (the centre tap: exp(-0) = 1) */
                const vec e_ = {EXPF((SCALAR)-0.5 * d[0] * d[0]),
                                EXPF((SCALAR)-0.5 * d[1] * d[1]),
                                EXPF((SCALAR)-0.5 * d[2] * d[2]), 0};
                e = e_;
                scaled = 1;
                wt = wt * e;
            }
        }
        acc = acc + wt * v;
        for (int64_t s = 1; s < ns; ++s) { /* the other sets: the same sample(s), own weights */
            vec ws;
            __builtin_memcpy(&ws, j->weights4 + 4 * (s * j->k + t), sizeof ws);
            if (scaled) ws = ws * e;
            more[s - 1] = more[s - 1] + ws * (nin > 1 ? vx[s] : v);
        }
    }
    return acc;
}

/* The window [lo, hi] of positions along the axis that the taps of pixels at positions
 * [pmin, pmax] with scales up to max_abs can read: every step is |offset * scale| <=
 * max_offset * max_abs (float rounding is monotone), plus a pixel for the lerp's second
 * sample and one of margin; a NaN or huge step clamps anywhere, so the whole line. */
static inline int64_t CAT(window_, SUFFIX)(const CAT(job_, SUFFIX) *j, SCALAR max_abs,
                                           int64_t pmin, int64_t pmax, int64_t n_axis,
                                           int64_t *lo, int64_t *hi) {
    const SCALAR reach = j->max_offset * max_abs;
    if (!(reach < (SCALAR)n_axis)) { /* also NaN */
        *lo = 0;
        *hi = n_axis - 1;
        return n_axis;
    }
    const int64_t r = (int64_t)reach + 2;
    *lo = pmin - r > 0 ? pmin - r : 0;
    *hi = pmax + r < n_axis - 1 ? pmax + r : n_axis - 1;
    return r; /* a pixel at p reads positions p - r .. p + r at most */
}

/* Ask for the cache lines a pass will read on row `row` between columns c0 and c1 (its
 * active pixels, a few pixels of the window around them): the planes, depth and the per-pixel
 * inputs (first = 0), or depth and the per-pixel inputs only (first = 3: what the scales read,
 * prefetch_scales_). For a y strip: PACK_AHEAD rows before they are packed (line_pack_). For
 * an x pass: called one active row ahead for rows of at most SHORT_ROW pixels, so that a far-away
 * object's short rows, which the hardware prefetcher does not see as streams, are fetched while
 * the row before is computed (measured on a 1 %-of-1080p object: 5 % less CPU time in its x
 * pass; a close-up's long rows are streams the hardware already fetches: not asked). */
#define SHORT_ROW ((int64_t)256)
/* every cache line holding one of the columns [c0, c1) (c0 < c1) of the row at `row` */
static inline void CAT(prefetch_cols_, SUFFIX)(const SCALAR *row, int64_t c0, int64_t c1) {
    const int64_t step = 64 / (int64_t)sizeof(SCALAR);
    for (int64_t c = c0; c < c1 + step; c += step) __builtin_prefetch(row + (c < c1 ? c : c1 - 1));
}
static inline void CAT(prefetch_row_, SUFFIX)(const CAT(job_, SUFFIX) *j, int64_t row,
                                              int64_t c0, int64_t c1, int first) {
    const int64_t w = j->w, hw = j->h * w;
    c0 = c0 > 8 ? c0 - 8 : 0;
    c1 = c1 + 8 < w ? c1 + 8 : w;
    const SCALAR *rows[7] = {j->src + row * w, j->src + hw + row * w, j->src + 2 * hw + row * w,
                             j->depth + row * w, j->mask ? j->mask + row * w : NULL,
                             j->width ? j->width + row * w : NULL,
                             j->ddepth ? j->ddepth + row * w : NULL};
    for (int a = first; a < 7; ++a)
        if (rows[a]) CAT(prefetch_cols_, SUFFIX)(rows[a], c0, c1);
}

/* src's inactive pixels of line q into `to` ((3, H*W) planes: copy mode's outputs, or
 * j->inactive_to): the columns [s0, s1) of every row the line holds (one for an x pass, all h
 * for a y strip) but those of the line's spans, ids[0 .. count - 1] (row order, then column
 * order; a y strip's clipped to it) */
static inline void CAT(inactive_to_, SUFFIX)(const CAT(job_, SUFFIX) *j, const int64_t *ids,
                                             int64_t count, int64_t q, int64_t s0, int64_t s1,
                                             const int AXIS_Y, SCALAR *to) {
    const int64_t w = j->w, hw = j->h * w;
    int64_t e = 0;
    for (int64_t r = AXIS_Y ? 0 : q; r < (AXIS_Y ? j->h : q + 1); ++r) {
        int64_t c = s0;
        for (; e < count && j->spans[3 * ids[e]] == r; ++e) {
            const int64_t *sp = j->spans + 3 * ids[e];
            const int64_t a = sp[1] > s0 ? sp[1] : s0, b = sp[2] < s1 ? sp[2] : s1;
            if (a > c)
                for (int ch = 0; ch < 3; ++ch)
                    memcpy(to + ch * hw + r * w + c, j->src + ch * hw + r * w + c,
                           sizeof(SCALAR) * (size_t)(a - c));
            if (b > c) c = b;
        }
        if (s1 > c)
            for (int ch = 0; ch < 3; ++ch)
                memcpy(to + ch * hw + r * w + c, j->src + ch * hw + r * w + c,
                       sizeof(SCALAR) * (size_t)(s1 - c));
    }
}

/* One line's preparation, shared by the scalar loop and the vectorised ones (gather_simd.h),
 * in three steps (line_begin_, line_scales_ or its vectorised twin, line_window_):
 * the copy of the line's pixels (copy mode; or its inactive ones into inactive_to), the
 * prefetch of the next short row (x pass), the scales of its active pixels into j->scale, the
 * window [lo, hi] along the axis and the window's samples in j->buf. PLANAR = 0: interleaved (r, g, b, depth) vectors, position p,
 * column c at vector (p - lo) * pitch + (c - s0); PLANAR = 1: four planes (r, g, b, depth) of
 * plane SCALARs each, the same index within a plane. line_begin_ returns 0 when the line has
 * no active pixel. */
typedef struct {
    const int64_t *ids; /* the spans crossing the line */
    int64_t count, s0, s1, lo, hi, pitch, plane;
    const SCALAR *pl[4]; /* PLANAR: the (r, g, b, depth) planes, window index 0 at pl[i][0] */
    const SCALAR *plx[MAX_SETS][3]; /* PLANAR, fan_in: inputs 1..'s (r, g, b) planes */
    int64_t stride; /* interleaved, fan_in: from input i's window to input i + 1's */
    /* PLANAR y strip, packed as its rows are reached (line_pack_): the next row to pack, the
     * margin r of window_ (a pixel on row p reads rows p - r .. p + r at most) */
    int64_t packed, margin;
    int64_t run; /* j->inactive: the first of ids not before the row being packed (line_run_) */
} CAT(line_, SUFFIX);

static inline __attribute__((always_inline)) int CAT(line_begin_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, int64_t q, const int AXIS_Y, CAT(line_, SUFFIX) *ln) {
    const int64_t w = j->w, h = j->h, hw = h * w;
    const int64_t *ids = j->ids + j->lines[3 * q], count = j->lines[3 * q + 1];
    const int64_t s0 = AXIS_Y ? q * j->strip : 0;
    const int64_t s1 = AXIS_Y && s0 + j->strip < w ? s0 + j->strip : w;
    /* copy mode with several sets (a fan-out sweep, never a fan-in): into every output */
    const int64_t n_out = j->fan_in ? 1 : j->nsets;
    if (j->copy && !AXIS_Y) /* the row's inactive pixels: its results write the others */
        for (int64_t o = 0; o < n_out; ++o)
            CAT(inactive_to_, SUFFIX)(j, ids, count, q, 0, w, 0, j->dst + o * j->set_stride);
    else if (j->copy) /* the line's pixels, before its results overwrite the active ones */
        for (int64_t o = 0; o < n_out; ++o)
            for (int ch = 0; ch < 3; ++ch)
                for (int64_t r = AXIS_Y ? 0 : q; r < (AXIS_Y ? h : q + 1); ++r)
                    memcpy(j->dst + o * j->set_stride + ch * hw + r * w + s0,
                           j->src + ch * hw + r * w + s0, sizeof(SCALAR) * (size_t)(s1 - s0));
    if (j->inactive_to) CAT(inactive_to_, SUFFIX)(j, ids, count, q, s0, s1, AXIS_Y, j->inactive_to);
    if (count == 0) return 0;
    if (!AXIS_Y && !j->copy) { /* the next active row of this thread, prefetched */
        int64_t nq = q + 1;
        while (nq < j->last && j->lines[3 * nq + 1] == 0) ++nq;
        if (nq < j->last) {
            const int64_t *nids = j->ids + j->lines[3 * nq];
            const int64_t nc = j->lines[3 * nq + 1];
            const int64_t a = j->spans[3 * nids[0] + 1], b = j->spans[3 * nids[nc - 1] + 2];
            if (b - a <= SHORT_ROW) CAT(prefetch_row_, SUFFIX)(j, nq, a, b, 0);
        }
    }
    ln->ids = ids;
    ln->count = count;
    ln->s0 = s0;
    ln->s1 = s1;
    return 1;
}

/* A y strip's scales (line_scales_, scales_, before its window is packed) read the per-pixel
 * inputs of its rows w SCALARs apart: a page per row and input, which the hardware
 * prefetcher does not follow (perf, issue 30, 1080p close-up, 7-tap two-pass, level avx512,
 * 2 threads: 14 % of the y pass's samples on the loads of depth and mask there). The inputs of
 * the span SCALE_AHEAD spans on are asked for while this one is computed: the two-pass took
 * 0.96x ± 0.01, 0.98x ± 0.01 and 0.98x ± 0.015 of the wall time in three runs of 25
 * alternated rounds in one process (bitwise the same output; the artist pass 1.00x ± 0.02;
 * 4 spans ahead 0.98x ± 0.02, 16 spans 1.04x ± 0.02). An x row (the whole width) reads its
 * inputs as streams: not asked. */
#define SCALE_AHEAD ((int64_t)8)
static inline __attribute__((always_inline)) void CAT(prefetch_scales_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, const CAT(line_, SUFFIX) *ln, int64_t e) {
    if (ln->s1 - ln->s0 == j->w) return; /* an x row (or a strip as wide as the image) */
    if (e + SCALE_AHEAD >= ln->count) return;
    const int64_t *sp = j->spans + 3 * ln->ids[e + SCALE_AHEAD];
    const int64_t c0 = sp[1] > ln->s0 ? sp[1] : ln->s0, c1 = sp[2] < ln->s1 ? sp[2] : ln->s1;
    CAT(prefetch_row_, SUFFIX)(j, sp[0], c0, c1, 3);
}

/* the scales of the line's active pixels into j->scale; returns the largest |scale| */
static inline __attribute__((always_inline)) SCALAR CAT(line_scales_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, const CAT(line_, SUFFIX) *ln) {
    SCALAR max_abs = 0;
    int64_t idx = 0;
    for (int64_t e = 0; e < ln->count; ++e) {
        const int64_t *sp = j->spans + 3 * ln->ids[e];
        CAT(prefetch_scales_, SUFFIX)(j, ln, e);
        const int64_t c0 = sp[1] > ln->s0 ? sp[1] : ln->s0, c1 = sp[2] < ln->s1 ? sp[2] : ln->s1;
        for (int64_t c = c0; c < c1; ++c) {
            const SCALAR sc = CAT(scale_at_, SUFFIX)(j, sp[0] * j->w + c);
            const SCALAR a = FABSF(sc);
            if (!(a <= max_abs)) max_abs = a == a ? a : (SCALAR)INFINITY;
            j->scale[idx++] = sc;
        }
    }
    return max_abs;
}

/* j->inactive: where the run of columns that starts at column c of row r ends (at most at
 * end), and whether its pixels are active (*active). ln->ids lists the line's spans in row
 * order, then column order; ln->run, the first of them not on a row before r, only moves on
 * (a line's rows are packed in increasing order; line_window_ starts it at 0), and the call
 * moves it past the spans of row r that end at or before c. */
static inline int64_t CAT(line_run_, SUFFIX)(const CAT(job_, SUFFIX) *j,
                                             CAT(line_, SUFFIX) *ln, int64_t r, int64_t c,
                                             int64_t end, int *active) {
    const int64_t *sp = NULL;
    for (; ln->run < ln->count; ++ln->run) {
        sp = j->spans + 3 * ln->ids[ln->run];
        if (sp[0] > r || (sp[0] == r && sp[2] > c)) break;
        sp = NULL;
    }
    if (sp == NULL || sp[0] != r) { /* no active pixel left on this row */
        *active = 0;
        return end;
    }
    *active = sp[1] <= c;
    const int64_t stop = *active ? sp[2] : sp[1];
    return stop < end ? stop : end;
}

/* PLANAR packing of one row: columns c0 .. c0 + cw - 1 of image row r, plane p (r, g, b,
 * depth, then a fan-in's further inputs' r, g, b) at o + p * gap; with j->inactive, every
 * input's inactive pixels from it (line_run_) */
static inline __attribute__((always_inline)) void CAT(pack_row_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, CAT(line_, SUFFIX) *ln, SCALAR *o, int64_t r, int64_t c0,
    int64_t cw, int64_t gap) {
    const int64_t w = j->w, hw = j->h * w;
    const int64_t nin = j->fan_in ? j->nsets : 1;
    memcpy(o + 3 * gap, j->depth + r * w + c0, sizeof(SCALAR) * (size_t)cw);
    for (int64_t c = c0, next; c < c0 + cw; c = next) {
        int active = 1;
        next = j->inactive ? CAT(line_run_, SUFFIX)(j, ln, r, c, c0 + cw, &active) : c0 + cw;
        const size_t bytes = sizeof(SCALAR) * (size_t)(next - c);
        const SCALAR *rgb = (active ? j->src : j->inactive) + r * w + c;
        SCALAR *at = o + (c - c0);
        for (int ch = 0; ch < 3; ++ch) memcpy(at + ch * gap, rgb + ch * hw, bytes);
        for (int64_t i = 1; i < nin; ++i) /* a fan-in's further inputs, after depth */
            for (int ch = 0; ch < 3; ++ch)
                memcpy(at + (4 + 3 * (i - 1) + ch) * gap,
                       rgb + (active ? i * j->set_stride : 0) + ch * hw, bytes);
    }
}

/* the window and its samples in j->buf (see above), given the largest |scale|; or, for an
 * x pass of the vectorised loops that writes elsewhere (j->direct), the row's planes where
 * they are (ln->pl; measured on the 1080p close-up, issue 30: 7.5 % less CPU time for the
 * 7-tap two-pass with the copy of the inactive pixels only and the centre loads) */
static inline __attribute__((always_inline)) void CAT(line_window_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, int64_t q, const int AXIS_Y, const int PLANAR, SCALAR max_abs,
    CAT(line_, SUFFIX) *ln) {
    const int64_t w = j->w, h = j->h, hw = h * w, n_axis = AXIS_Y ? h : w;
    const int64_t s0 = ln->s0, s1 = ln->s1;
    const int64_t *head = j->spans + 3 * ln->ids[0], *tail = j->spans + 3 * ln->ids[ln->count - 1];
    int64_t lo, hi; /* the window along the axis */
    ln->margin = CAT(window_, SUFFIX)(j, max_abs, AXIS_Y ? head[0] : head[1],
                         AXIS_Y ? tail[0] : tail[2] - 1, n_axis, &lo, &hi);
    /* rows r0..r1 x columns c0..c1 (a y strip; an x row's window) */
    const int64_t r0 = AXIS_Y ? lo : q, r1 = AXIS_Y ? hi : q;
    const int64_t c0 = AXIS_Y ? s0 : lo, c1 = AXIS_Y ? s1 - 1 : hi;
    const int64_t pitch = AXIS_Y ? s1 - s0 : 1; /* from one position to the next */
    const int64_t plane = (r1 - r0 + 1) * (c1 - c0 + 1);
    ln->lo = lo;
    ln->hi = hi;
    ln->pitch = pitch;
    ln->plane = plane;
    /* an x pass that writes elsewhere reads its row's window where it is (the vectorised
     * loops' loads may read up to 2 * VW_MAX SCALARs past the window: not past the image's
     * last plane). A y pass packs its strip, a fan-in sweep's 3 S + 1 planes too: read in
     * place, its strip's rows are w SCALARs apart, a page per row and plane, and the
     * 1080p close-up's 6-set y sweep took 1.3x the CPU time it took packed plane by plane
     * (measured, issue 30; each further set cost more than a whole single-set y pass); packed
     * row by row as the loop reaches them, its planes side by side (below), the whole fused
     * sweep takes 0.8x that (102 -> 81 ms CPU, measured) */
    const int64_t nin = j->fan_in ? j->nsets : 1;
    ln->stride = 4 * plane;
    const int in_place = !AXIS_Y && q * w + hi + 64 < hw && !j->inactive;
    if (PLANAR && j->direct && in_place) { /* each input's planes too */
        const int64_t at = q * w + lo;
        ln->pl[0] = j->src + at;
        ln->pl[1] = ln->pl[0] + hw;
        ln->pl[2] = ln->pl[0] + 2 * hw;
        ln->pl[3] = j->depth + at;
        for (int64_t i = 1; i < nin; ++i)
            for (int ch = 0; ch < 3; ++ch) ln->plx[i][ch] = ln->pl[ch] + i * j->set_stride;
        return;
    }
    /* PLANAR: plane p's sample at window index x lies at pl[p][x]. A y strip's planes are
     * interleaved row by row (row r of every plane side by side, pitch = planes x strip
     * width: the rows a tap reads of all 3 S + 1 planes are one stretch of memory, not
     * 3 S + 1 streams 'plane' SCALARs apart) and packed as the loop reaches them
     * (line_pack_: a packed row is read while it is still in cache); an x row's planes
     * lie one after the other (pitch 1), packed here. */
    const int64_t n_planes = 4 + 3 * (nin - 1), cw = c1 - c0 + 1;
    const int64_t gap = PLANAR && AXIS_Y ? cw : plane; /* from plane p to plane p + 1 */
    if (PLANAR && AXIS_Y) ln->pitch = n_planes * cw;
    for (int i = 0; i < 4; ++i) ln->pl[i] = j->buf + i * gap;
    for (int64_t i = 1; i < nin; ++i)
        for (int ch = 0; ch < 3; ++ch) ln->plx[i][ch] = j->buf + (4 + 3 * (i - 1) + ch) * gap;
    ln->packed = lo;
    ln->run = 0;
    if (PLANAR && AXIS_Y) return; /* line_pack_ */
    for (int64_t r = r0; r <= r1; ++r) {
        const SCALAR *rgb = j->src + r * w, *z = j->depth + r * w;
        if (PLANAR) { /* an x row (a y strip: line_pack_) */
            CAT(pack_row_, SUFFIX)(j, ln, j->buf, r, c0, cw, gap);
            continue;
        }
        for (int64_t c0r = c0, next; c0r <= c1; c0r = next) { /* runs (j->inactive) */
            int active = 1;
            next = j->inactive ? CAT(line_run_, SUFFIX)(j, ln, r, c0r, c1 + 1, &active) : c1 + 1;
            for (int64_t i = 0; i < nin; ++i) { /* input i's window 4 plane SCALARs further */
                SCALAR *o = j->buf + i * 4 * plane + 4 * (r - r0) * (c1 - c0 + 1) - 4 * c0;
                const SCALAR *in = active ? rgb + i * j->set_stride : j->inactive + r * w;
                for (int64_t c = c0r; c < next; ++c) {
                    o[4 * c] = in[c];
                    o[4 * c + 1] = in[hw + c];
                    o[4 * c + 2] = in[2 * hw + c];
                    o[4 * c + 3] = z[c];
                }
            }
        }
    }
}

/* A single-input y strip's rows are asked for (prefetch_row_: the planes, depth and the
 * per-pixel inputs its scales read) PACK_AHEAD rows before line_pack_ copies them: a strip row
 * was 512 bytes of each plane then (256 since: WIDE_STRIP), a whole image row from the next,
 * and its copy waited for memory
 * (perf: memmove 18 % of the CPU time of the two-pass; issue 30, 1080p close-up, 7-tap
 * two-pass, level avx512, 25 interleaved rounds in one process: 0.91x the wall time, 0.92x
 * the CPU time with the four planes asked for; distance 4 the same within noise; with
 * prefetch_row_'s inputs too, the same within 1 %, 2 x 21 rounds). Not for a fan-in
 * sweep's 3 S + 1 planes: their rows ahead made the fused sweep 1-6 % slower, and at distances
 * 1, 2 and 4 gained nothing (same rounds). */
#define PACK_AHEAD ((int64_t)8)
/* A fan-in's strip rows are asked for FANIN_AHEAD rows ahead (prefetch_inputs_: every input's
 * r, g, b and the depth) since its inputs lie in 2 MB pages (the fused sum of Gaussians'
 * workspace, sssbench/ops/_pages.py): the 1-6 % loss above was with 4 KB pages, a page per row
 * and plane. Measured (2026-12-06, 1080p close-up, 6-set fused sweep, 2 threads, level avx512;
 * the distance a run-time variable of one build, alternated in one process, 21 rounds):
 * distance 4 0.972, 0.980, 0.970, 0.973 and 0.961 the wall time of none in five processes,
 * distance 2 0.966-0.989 in seven, 8 0.98-0.99 and 16 0.98-1.01 in three. The same bits (a
 * prefetch reads nothing into the loop). */
#define FANIN_AHEAD ((int64_t)4)
static inline void CAT(prefetch_inputs_, SUFFIX)(const CAT(job_, SUFFIX) *j, int64_t row,
                                                 int64_t c0, int64_t c1) {
    const int64_t w = j->w, hw = j->h * w;
    for (int64_t i = 0; i < j->nsets; ++i)
        for (int ch = 0; ch < 3; ++ch)
            CAT(prefetch_cols_, SUFFIX)(j->src + i * j->set_stride + ch * hw + row * w, c0, c1);
    CAT(prefetch_cols_, SUFFIX)(j->depth + row * w, c0, c1);
}
/* A PLANAR y strip's window (line_window_), packed up to row 'upto' (clamped to the window):
 * the rows from ln->packed on, each row's planes side by side. The loop asks for the rows a
 * pixel on row p may read before it computes row p (p + margin + 2: window_'s margin plus
 * two rows for a sample position rounded up past it), and its rows come in increasing order
 * (the spans are listed in row order), so every row it reads is packed, and packed before
 * any result of a row at or after it is written: an in-place pass packs the values as they
 * were, as when the whole window was packed at once. */
static inline __attribute__((always_inline)) void CAT(line_pack_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, CAT(line_, SUFFIX) *ln, int64_t upto) {
    const int64_t cw = ln->s1 - ln->s0;
    const int64_t end = upto < ln->hi ? upto : ln->hi;
    for (int64_t r = ln->packed; r <= end; ++r) { /* each row's planes side by side */
        CAT(pack_row_, SUFFIX)(j, ln, j->buf + (r - ln->lo) * ln->pitch, r, ln->s0, cw, cw);
        const int64_t ahead = r + PACK_AHEAD;
        if (ahead <= ln->hi && !j->fan_in)
            CAT(prefetch_row_, SUFFIX)(j, ahead, ln->s0, ln->s1, 0);
        if (j->fan_in && r + FANIN_AHEAD <= ln->hi)
            CAT(prefetch_inputs_, SUFFIX)(j, r + FANIN_AHEAD, ln->s0, ln->s1);
    }
    if (end >= ln->packed) ln->packed = end + 1;
}

/* This thread's lines: rows (x pass) or strips of j->strip columns (y pass). The spans
 * crossing a line are listed in j->ids in row order; a y pass clips them to its strip. The
 * scalar loop: one pixel at a time, its (r, g, b, depth) as one 4-lane vector. */
static inline __attribute__((always_inline)) void CAT(lines_, SUFFIX)(
    const CAT(job_, SUFFIX) *j, const int AXIS_Y, const int FOLLOW, const int MULTI) {
    const int64_t w = j->w, h = j->h, hw = h * w, n_axis = AXIS_Y ? h : w;
    for (int64_t q = j->first; q < j->last; ++q) {
        CAT(line_, SUFFIX) ln;
        if (!CAT(line_begin_, SUFFIX)(j, q, AXIS_Y, &ln)) continue;
        CAT(line_window_, SUFFIX)(j, q, AXIS_Y, 0, CAT(line_scales_, SUFFIX)(j, &ln), &ln);
        int64_t idx = 0;
        for (int64_t e = 0; e < ln.count; ++e) { /* the taps */
            const int64_t *sp = j->spans + 3 * ln.ids[e];
            const int64_t row = sp[0];
            const int64_t a = sp[1] > ln.s0 ? sp[1] : ln.s0, b = sp[2] < ln.s1 ? sp[2] : ln.s1;
            for (int64_t c = a; c < b; ++c) {
                CAT(vec_, SUFFIX) more[MAX_SETS];
                CAT(vec_, SUFFIX) acc = CAT(taps_, SUFFIX)(
                    j, j->buf, ln.pitch, AXIS_Y ? c - ln.s0 : 0, ln.lo,
                    (SCALAR)(AXIS_Y ? row : c), j->scale[idx++], n_axis, FOLLOW, MULTI,
                    ln.stride, more);
                const int64_t l = row * w + c;
                if (MULTI && j->fan_in) { /* 0 + c_0 r_0 + c_1 r_1 + ...: the sets' blend */
                    CAT(vec_, SUFFIX) cs, sum = {0, 0, 0, 0};
                    __builtin_memcpy(&cs, j->coef4, sizeof cs);
                    sum = sum + cs * acc;
                    for (int64_t s = 1; s < j->nsets; ++s) {
                        __builtin_memcpy(&cs, j->coef4 + 4 * s, sizeof cs);
                        sum = sum + cs * more[s - 1];
                    }
                    acc = sum;
                } else if (MULTI) /* a fan-out: set s's result into output s */
                    for (int64_t s = 1; s < j->nsets; ++s)
                        for (int ch = 0; ch < 3; ++ch)
                            j->dst[s * j->set_stride + ch * hw + l] = more[s - 1][ch];
                j->dst[l] = acc[0];
                j->dst[hw + l] = acc[1];
                j->dst[2 * hw + l] = acc[2];
                if (j->blend_out)
                    for (int ch = 0; ch < 3; ++ch) {
                        const SCALAR wt = j->blend_w[ch], e = acc[ch];
                        SCALAR *o = j->blend_out + ch * hw + l;
                        *o = BLEND_LERP(*o, e, wt, FABSF(wt) < (SCALAR)0.5);
                    }
            }
        }
    }
}

#ifndef LINES_ALL
/* One thread's lines, specialised per axis, follow-surface mode and single / several weight
 * sets (constants there), each specialisation its own out-of-line function: one function
 * holding all twelve inlined made the compiler's register passes superlinear (issue 30's
 * multi-set sweep took the library's build from 18 s to 132 s of CPU on one machine, 83 s on
 * another; out of line, 33 s on the second). The code of each loop is the same, and so are
 * its results (tests/ops/test_gather_backends.py, bitwise at every level). */
#define LINES_DISPATCH(LINES, RUN, ATTR)                                        \
    ATTR RUN_LINKAGE void *RUN(void *arg) {                                     \
        static void (*const table[2][3][2])(const CAT(job_, SUFFIX) *) = {        \
            {{CAT(LINES, _x0s), CAT(LINES, _x0m)}, {CAT(LINES, _x1s), CAT(LINES, _x1m)},  \
             {CAT(LINES, _x2s), CAT(LINES, _x2m)}},                                 \
            {{CAT(LINES, _y0s), CAT(LINES, _y0m)}, {CAT(LINES, _y1s), CAT(LINES, _y1m)},  \
             {CAT(LINES, _y2s), CAT(LINES, _y2m)}}};                                \
        const CAT(job_, SUFFIX) *j = (const CAT(job_, SUFFIX) *)arg;             \
        void (*const lines)(const CAT(job_, SUFFIX) *) =                        \
            table[j->axis_y != 0][j->follow][j->nsets > 1 || j->fan_in];         \
        FTZ_BEGIN(j->follow == 2); /* the gaussian's underflow: FTZ_BEGIN in gather.c */ \
        if (!j->claim) {                                                        \
            lines(j);                                                           \
        } else {                                                                \
            CAT(job_, SUFFIX) part = *j;                                        \
            for (;;) { /* the next unclaimed chunk of lines */                  \
                const int64_t c = __atomic_fetch_add(j->claim, 1, __ATOMIC_RELAXED); \
                if (c >= j->n_chunks) break;                                    \
                part.first = j->chunks[c];                                      \
                part.last = j->chunks[c + 1];                                   \
                lines(&part);                                                   \
            }                                                                   \
        }                                                                       \
        FTZ_END();                                                              \
        return NULL;                                                            \
    }
/* the twelve specialisations of LINES (a function-like name) with attributes ATTR, then
 * RUN, one thread's work (pool_run's signature), which runs the one a job asks for */
#define LINES_ALL(LINES, RUN, ATTR)                                               \
    LINES_ONE(LINES, ATTR, x0s, 0, 0, 0) LINES_ONE(LINES, ATTR, x0m, 0, 0, 1)     \
    LINES_ONE(LINES, ATTR, x1s, 0, 1, 0) LINES_ONE(LINES, ATTR, x1m, 0, 1, 1)     \
    LINES_ONE(LINES, ATTR, x2s, 0, 2, 0) LINES_ONE(LINES, ATTR, x2m, 0, 2, 1)     \
    LINES_ONE(LINES, ATTR, y0s, 1, 0, 0) LINES_ONE(LINES, ATTR, y0m, 1, 0, 1)     \
    LINES_ONE(LINES, ATTR, y1s, 1, 1, 0) LINES_ONE(LINES, ATTR, y1m, 1, 1, 1)     \
    LINES_ONE(LINES, ATTR, y2s, 1, 2, 0) LINES_ONE(LINES, ATTR, y2m, 1, 2, 1)     \
    LINES_DISPATCH(LINES, RUN, ATTR)
#define LINES_ONE(LINES, ATTR, TAG, AX, FO, MU)                                 \
    ATTR __attribute__((noinline)) static void CAT(LINES, _##TAG)(const CAT(job_, SUFFIX) * j) { \
        LINES(j, AX, FO, MU);                                                   \
    }
#endif

/* a set's run_ (LINES_DISPATCH): static, but for the AVX-512 loops of a unit of their own
 * (SSS_AVX512_UNIT, gather.c), where it is the library's hidden symbol the other unit calls */
#define RUN_LINKAGE static
#if SSS_SIMD /* the vectorised loops (gather_simd.h), one per instruction set */
#if !SSS_LOOPS512_ONLY
#define ISA avx2
#define ISA_TARGET "avx2,fma"
#define VW VW_AVX2
#define GATHER_RAW GATHER_AVX2
#define IANY IANY_AVX2
#define SHUFFLE2 SHUFFLE2_AVX2
#define VFMA FMA_AVX2
#define VMINV VMINV_AVX2
#define VSET1 VSET1_AVX2
#define VIMIN VIMIN_AVX2
#ifdef MINPS_AVX2
#define VMINPS MINPS_AVX2
#define VPERMUTE PERMUTE_AVX2
#endif
#include "gather_simd.h"
#undef VMINPS
#undef VPERMUTE
#undef VMINV
#undef VSET1
#undef VIMIN
#undef ISA
#undef ISA_TARGET
#undef VW
#undef GATHER_RAW
#undef IANY
#undef SHUFFLE2
#undef VFMA
#endif
#if !SSS_LOOPS512_APART || SSS_LOOPS512_ONLY
#if SSS_LOOPS512_ONLY
#undef RUN_LINKAGE
#define RUN_LINKAGE __attribute__((visibility("hidden")))
#endif
#define ISA avx512
#define ISA_TARGET "avx512f"
#define VW VW_AVX512
#define GATHER_RAW GATHER_AVX512
#define IANY IANY_AVX512
#define SHUFFLE2 SHUFFLE2_AVX512
#define VFMA FMA_AVX512
#define VMINV VMINV_AVX512
#define VSET1 VSET1_AVX512
#define VIMIN VIMIN_AVX512
#ifdef MINPS_AVX512
#define VMINPS MINPS_AVX512
#define VPERMUTE PERMUTE_AVX512
#define VSCALEF SCALEF_AVX512
#endif
#ifdef KANY_GTU_AVX512
#define KANY_GTU KANY_GTU_AVX512
#define KANY_NE2 KANY_NE2_AVX512
#endif
#include "gather_simd.h"
#undef VMINPS
#undef VPERMUTE
#undef VSCALEF
#undef VMINV
#undef VSET1
#undef VIMIN
#undef KANY_GTU
#undef KANY_NE2
#undef ISA
#undef ISA_TARGET
#undef VW
#undef GATHER_RAW
#undef IANY
#undef SHUFFLE2
#undef VFMA
#undef RUN_LINKAGE
#define RUN_LINKAGE static
#else /* the AVX-512 loops are another unit's: run_f32_avx512 / run_f64_avx512 */
__attribute__((visibility("hidden"))) void *CAT(CAT(run_, SUFFIX), _avx512)(void *arg);
#endif
#endif

#if !SSS_LOOPS512_ONLY /* the rest: the scalar loop, the pass's entry, the blend, the spans */
/* One thread's lines: run_f32 / run_f64 */
LINES_ALL(CAT(lines_, SUFFIX), CAT(run_, SUFFIX), )

/* The kernel's float64 taps and 1 / surface_scale in SCALAR, as sssbench.ops.gather._taps and
 * _inverse_scale convert them (the same operations, bitwise): offsets and inverse scales
 * clamped to the largest finite SCALAR before the cast (an infinite offset would give inf * 0 =
 * NaN at a pixel of zero width), weights cast as they are (checked finite by the caller).
 * out: the (k, 4) weights with a zero fourth lane (k = taps times weight sets: set after
 * set), then 4 inverse scales (the fourth lane 0), then the taps' offsets. */
static void CAT(taps_in_, SUFFIX)(const double *offsets, const double *weights,
                                 const double *inv_scale, int64_t k, int64_t n_offsets,
                                 SCALAR *out) {
    const double big = (double)SCALAR_MAX;
    SCALAR *weights4 = out, *inv = out + 4 * k, *offsets_s = out + 4 * k + 4;
    for (int64_t t = 0; t < k; ++t) {
        for (int ch = 0; ch < 3; ++ch) weights4[4 * t + ch] = (SCALAR)weights[3 * t + ch];
        weights4[4 * t + 3] = 0;
    }
    for (int ch = 0; ch < 3; ++ch) {
        const double v = inv_scale[ch];
        inv[ch] = (SCALAR)(v <= big ? v : big); /* also NaN -> big, as torch.where */
    }
    inv[3] = 0;
    for (int64_t t = 0; t < n_offsets; ++t) {
        const double o = offsets[t];
        offsets_s[t] = (SCALAR)(o < -big ? -big : (o > big ? big : o)); /* NaN stays NaN */
    }
}

/* One pass over the active pixels of one image (see the job fields); returns their number,
 * -1 when memory for the per-thread buffers cannot be had, or -2 when a kernel weight is not
 * finite in SCALAR (nothing is written then). The kernel comes in float64 (offsets (k,),
 * weights (k, 3), 1 / surface_scale (3,): see taps_in_). blend_out (3, H*W) or NULL: each
 * result written to dst is also blended into it, blend_out <- lerp(blend_out, result, blend_w)
 * per channel at the same pixel (the sum of Gaussians' blend fused into its step's last pass:
 * bitwise sss_blend_ of the pass's output, without reading that output back).
 * nsets > 1 (at most MAX_SETS): a sweep of nsets weight sets over the same offsets, weights
 * (nsets, k, 3) float64, sharing each tap's position, fetch and follow-surface factor; fan_in
 * 0: dst + s set_stride gets set s's pass of src (copy: src everywhere else, in each);
 * fan_in 1 (copy 0, any nsets): set s reads src + s set_stride, and dst's active pixels get
 * sum_s coef[s] times set s's result (coef (nsets, 3) float64, cast to SCALAR); inactive
 * (3, H*W) or NULL: with fan_in, every set's input at the inactive pixels (the windows' samples
 * there), whatever src holds there (it may be dst: a fan-in writes only active pixels). The
 * blend is for a single pass only (nsets = 1, fan_in 0). inactive_to (3, H*W) or NULL: not
 * with fan_in; src's inactive pixels copied into it, its active ones not written (it shares no
 * memory with the pass's other arrays). */
int64_t CAT(sss_gather_, SUFFIX)(const SCALAR *src, const SCALAR *depth, const int64_t *spans,
                             const SCALAR *mask, const SCALAR *width, const SCALAR *ddepth,
                             const double *offsets, const double *weights,
                             const double *inv_scale, SCALAR *dst, double focal_px,
                             double width_scalar, double correction, double maxdd,
                             int64_t n_spans, int64_t k, int64_t h, int64_t w, int axis_y,
                             int follow, int copy, int threads, SCALAR *blend_out,
                             const SCALAR *blend_w, int64_t nsets, int64_t set_stride,
                             int fan_in, const double *coef, const SCALAR *inactive,
                             SCALAR *inactive_to) {
    enum { MAX_THREADS = 64 };
    if (nsets < 1 || nsets > MAX_SETS || ((nsets > 1 || fan_in) && blend_out) ||
        (fan_in && (copy || inactive_to)))
        return -3;
    /* a fan-in of one set is a fan-in too: dst gets 0 + c_0 r_0 (the loops' MULTI path; it was
     * run as a plain pass until 2026-12-06, its coefficients left out) */
    for (int64_t i = 0; i < 3 * k * nsets; ++i) /* every weight finite in SCALAR, first */
        if (!(FABSF((SCALAR)weights[i]) <= SCALAR_MAX)) return -2;
    if (fan_in)
        for (int64_t i = 0; i < 3 * nsets; ++i)
            if (!(FABSF((SCALAR)coef[i]) <= SCALAR_MAX)) return -2;
    const int64_t nin = fan_in ? nsets : 1;
    int64_t n = 0; /* active pixels */
    for (int64_t s = 0; s < n_spans; ++s) n += spans[3 * s + 2] - spans[3 * s + 1];
    const int copies = copy || inactive_to != NULL; /* a copy of every inactive pixel */
    if (n == 0 && !copies) return 0; /* nothing to compute or copy */
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    const int64_t work = n + (copies ? h * w / 16 : 0); /* a copied pixel is cheap, not free */
    /* at least MIN_THREAD_WORK pixels per thread: splitting a pass costs CPU time that does
     * not scale with its pixels (waking a worker on a core whose caches hold other work, and
     * moving the lines the other thread wrote in the previous pass across cores), measured
     * 0.1-0.3 ms per two-pass call at 20k-160k pixels (1080p, 7 taps, this 2-core machine):
     * 13 % of the work at 20k pixels, 2 % at 80k; with 16384 pixels per thread it stays
     * below ~10 % */
    enum { MIN_THREAD_WORK = 16384 };
    if (work < MIN_THREAD_WORK * (int64_t)threads)
        threads = work < 2 * MIN_THREAD_WORK ? 1 : (int)(work / MIN_THREAD_WORK);
    const int64_t strip = 4 * n < h * w && !copy ? NARROW_STRIP : WIDE_STRIP;
    const int64_t n_lines = axis_y ? (w + strip - 1) / strip : h;
    const int64_t line_len = axis_y ? h * strip : w; /* pixels of one line at most */
    /* per line: (first entry, span count, work), then the entries: span indices,
     * line after line in span order (a row is one line: its spans are already consecutive) */
    int64_t entries = n_spans;
    if (axis_y)
        for (int64_t s = 0; s < n_spans; ++s)
            entries += (spans[3 * s + 2] - 1) / strip - spans[3 * s + 1] / strip;
    /* window (4 lanes) + scales, and a margin the vectorised loops' loads may read past the
     * window (into values they never select) */
    const size_t per_thread = (size_t)line_len * (4 * nin + 1) + 64;
    const size_t list_bytes = ((size_t)(3 * n_lines + entries) * sizeof(int64_t) + 63) / 64 * 64;
    int owned;
    /* taps_in_'s SCALARs and the coefficients, 4-aligned */
    const size_t taps = ((size_t)k * (4 * nsets + 1) + 4 + 4 * nsets + 3) / 4 * 4;
    char *block = (char *)workspace_acquire(
        list_bytes + sizeof(SCALAR) * (taps + per_thread * (size_t)threads), &owned);
    if (!block) return -1;
    SCALAR *memory = (SCALAR *)(block + list_bytes);
    CAT(taps_in_, SUFFIX)(offsets, weights, inv_scale, k * nsets, k, memory);
    SCALAR *coef4 = memory + 4 * k * nsets + 4 + k;
    for (int64_t s = 0; s < nsets; ++s)
        for (int ch = 0; ch < 4; ++ch)
            coef4[4 * s + ch] = fan_in && ch < 3 ? (SCALAR)coef[3 * s + ch] : 0;
    int64_t *lists = (int64_t *)block;
    memset(lists, 0, list_bytes);
    int64_t *lines = lists, *ids = lists + 3 * n_lines;
    for (int pass = 0; pass < 2; ++pass) { /* count, then fill */
        for (int64_t s = 0; s < n_spans; ++s) {
            const int64_t c0 = spans[3 * s + 1], c1 = spans[3 * s + 2];
            const int64_t q0 = axis_y ? c0 / strip : spans[3 * s];
            const int64_t q1 = axis_y ? (c1 - 1) / strip : q0;
            for (int64_t q = q0; q <= q1; ++q) {
                if (pass) {
                    ids[lines[3 * q] + lines[3 * q + 1]++] = s;
                    continue;
                }
                const int64_t a = axis_y && c0 < q * strip ? q * strip : c0;
                const int64_t b = axis_y && c1 > (q + 1) * strip ? (q + 1) * strip : c1;
                ++lines[3 * q + 1];
                lines[3 * q + 2] += b - a; /* the line's active pixels, */
            }
        }
        if (!pass) {
            if (copies) /* and its share of the copy */
                for (int64_t q = 0; q < n_lines; ++q) lines[3 * q + 2] += (work - n) / n_lines;
            for (int64_t q = 1; q < n_lines; ++q) lines[3 * q] = lines[3 * q - 3] + lines[3 * q - 2];
            for (int64_t q = 0; q < n_lines; ++q) lines[3 * q + 1] = 0;
        }
    }
    const SCALAR *weights4 = memory, *inv_s = memory + 4 * k * nsets,
                 *offsets_s = memory + 4 * k * nsets + 4;
    SCALAR max_offset = 0;
    for (int64_t t = 0; t < k; ++t) {
        const SCALAR a = FABSF(offsets_s[t]);
        if (!(a <= max_offset)) max_offset = a == a ? a : (SCALAR)INFINITY;
    }
    /* src and dst disjoint (a new output, as a rule): no pass writes what it reads */
    const int64_t span_in = (nin - 1) * set_stride + 3 * h * w;
    const int64_t span_out = (fan_in ? 0 : (nsets - 1) * set_stride) + 3 * h * w;
    const int direct = dst + span_out <= src || src + span_in <= dst;
    CAT(job_, SUFFIX) jobs[MAX_THREADS];
    int64_t total = 0;
    for (int64_t l = 0; l < n_lines; ++l) total += lines[3 * l + 2];
    /* several threads take whole lines in chunks of about 1 / (CHUNKS_PER_THREAD T) of the
     * work, each the next unclaimed chunk (job.claim): a thread that gets less of its core
     * (another process, or torch's OpenMP workers still spinning after an operation: 7-8 ms
     * more per 1080p two-pass call right after kornia's blur with a fixed share per thread,
     * 4 ms with chunks, measured, issue 30) computes fewer lines instead of the pass waiting
     * for its fixed share. Which thread computes a line changes no result: every line is
     * computed alone (tests/ops/test_gather_backends.py, 1, 2 and 4 threads bitwise). */
    enum { CHUNKS_PER_THREAD = 16 };
    int64_t chunks[MAX_THREADS * CHUNKS_PER_THREAD + 1], n_chunks = 0, claim = 0;
    {
        const int64_t parts = (int64_t)threads * CHUNKS_PER_THREAD;
        int64_t q = 0, done = 0;
        chunks[0] = 0;
        for (int64_t c = 0; c < parts && q < n_lines; ++c) { /* split where the work passes c/P */
            while (q < n_lines && (c == parts - 1 || done < total * (c + 1) / parts))
                done += lines[3 * q++ + 2];
            if (q > chunks[n_chunks]) chunks[++n_chunks] = q;
        }
        if (chunks[n_chunks] < n_lines) chunks[++n_chunks] = n_lines;
    }
    for (int t = 0; t < threads; ++t) {
        const int64_t first = 0, last = n_lines; /* one thread: every line */
        SCALAR *mine = memory + taps + per_thread * (size_t)t;
        CAT(job_, SUFFIX) jb = {src, depth, spans, mask, width, ddepth, offsets_s, weights4,
                                inv_s, dst, lines, ids, focal_px, width_scalar,
                                correction, maxdd, max_offset, k, h, w, first, last, strip, axis_y, follow, copy,
                                direct,
                                mine, mine + 4 * (size_t)nin * (size_t)line_len, blend_out, blend_w,
                                nsets, set_stride, fan_in, coef4, fan_in ? inactive : NULL,
                                inactive_to,
                                threads > 1 ? &claim : NULL, chunks, n_chunks};
        jobs[t] = jb;
    }
    void *(*run)(void *) = CAT(run_, SUFFIX); /* the widest loop the CPU allows (sss_set_simd) */
#if SSS_SIMD
    /* its gathers index the line's window with int32 */
    const int level = sss_get_simd();
    if (line_len < INT32_MAX && (axis_y ? h : w) < INT32_MAX)
        run = level >= 2 ? CAT(CAT(run_, SUFFIX), _avx512)
              : level == 1 ? CAT(CAT(run_, SUFFIX), _avx2) : run;
#endif
    pool_run(run, (char *)jobs, sizeof jobs[0], threads);
    workspace_release(block, owned);
    return n;
}

/* out <- lerp(out, end, weight) per channel at the active pixels of spans [first, last): the
 * sum-of-Gaussians blend (003 §7.3.3), torch.lerp's formula with a separate multiply and add
 * (torch fuses them: the results agree to a rounding) */
typedef struct {
    SCALAR *out;
    const SCALAR *end, *weight;
    const int64_t *spans;
    int64_t first, last, hw, w;
} CAT(blend_job_, SUFFIX);

static void *CAT(run_blend_, SUFFIX)(void *arg) {
    const CAT(blend_job_, SUFFIX) *j = (const CAT(blend_job_, SUFFIX) *)arg;
    for (int ch = 0; ch < 3; ++ch) {
        const SCALAR wt = j->weight[ch], small = FABSF(wt) < (SCALAR)0.5;
        SCALAR *o = j->out + ch * j->hw;
        const SCALAR *e = j->end + ch * j->hw;
        for (int64_t s = j->first; s < j->last; ++s) {
            const int64_t base = j->spans[3 * s] * j->w;
            for (int64_t l = base + j->spans[3 * s + 1]; l < base + j->spans[3 * s + 2]; ++l)
                o[l] = BLEND_LERP(o[l], e[l], wt, small);
        }
    }
    return NULL;
}

int64_t CAT(sss_blend_, SUFFIX)(SCALAR *out, const SCALAR *end, const int64_t *spans,
                               const SCALAR *weight, int64_t n_spans, int64_t h, int64_t w,
                               int threads) {
    enum { MAX_THREADS = 64 };
    int64_t n = 0;
    for (int64_t s = 0; s < n_spans; ++s) n += spans[3 * s + 2] - spans[3 * s + 1];
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (n < 65536 * (int64_t)threads) threads = n < 131072 ? 1 : (int)(n / 65536);
    CAT(blend_job_, SUFFIX) jobs[MAX_THREADS];
    int64_t s = 0, done = 0;
    for (int t = 0; t < threads; ++t) { /* whole spans, split where the count passes 1/T */
        const int64_t first = s;
        while (s < n_spans && (t == threads - 1 || done < n * (t + 1) / threads)) {
            done += spans[3 * s + 2] - spans[3 * s + 1];
            ++s;
        }
        CAT(blend_job_, SUFFIX) jb = {out, end, weight, spans, first, s, h * w, w};
        jobs[t] = jb;
    }
    pool_run(CAT(run_blend_, SUFFIX), (char *)jobs, sizeof jobs[0], threads);
    return n;
}

/* The stencil as runs: (row, first column, end column) of every run of pixels with
 * mask > 0 (NaN is not > 0, as in torch), row after row, written to out (3 int64 per run)
 * while fewer than cap; returns the number of runs (the caller calls again with a larger out
 * when it exceeds cap). One read of the (h, w) mask, a block of 16 pixels at a time where a
 * block is all off or all on: the stencil of a call is rebuilt from the mask's contents on
 * every call (sssbench.ops._stencil.image_spans), so it can never be stale. */
int64_t CAT(sss_spans_, SUFFIX)(const SCALAR *mask, int64_t h, int64_t w, int64_t *out,
                                int64_t cap) {
    typedef CAT(vec16_, SUFFIX) vec;
    typedef CAT(lanes16_, SUFFIX) lanes;
    enum { BLOCK = 4 * 16 / sizeof(SCALAR) }; /* pixels: four vectors */
    const vec zero = {0};
    int64_t n = 0;
    for (int64_t r = 0; r < h; ++r) {
        const SCALAR *m = mask + r * w;
        int64_t c = 0;
        while (c < w) {
            for (; c + BLOCK <= w; c += BLOCK) { /* skip blocks with no active pixel */
                vec v0, v1, v2, v3; /* four loads into registers (an array went via the stack) */
                __builtin_memcpy(&v0, m + c, sizeof v0);
                __builtin_memcpy(&v1, m + c + BLOCK / 4, sizeof v1);
                __builtin_memcpy(&v2, m + c + BLOCK / 2, sizeof v2);
                __builtin_memcpy(&v3, m + c + 3 * BLOCK / 4, sizeof v3);
                const lanes on = (v0 > zero) | (v1 > zero) | (v2 > zero) | (v3 > zero);
                uint64_t bits[2]; /* the lane masks as words: no lane extracts */
                __builtin_memcpy(bits, &on, sizeof on);
                if (bits[0] | bits[1]) break;
            }
            while (c < w && !(m[c] > 0)) ++c;
            if (c >= w) break;
            const int64_t c0 = c;
            for (; c + BLOCK <= w; c += BLOCK) { /* skip blocks of active pixels only */
                vec v0, v1, v2, v3;
                __builtin_memcpy(&v0, m + c, sizeof v0);
                __builtin_memcpy(&v1, m + c + BLOCK / 4, sizeof v1);
                __builtin_memcpy(&v2, m + c + BLOCK / 2, sizeof v2);
                __builtin_memcpy(&v3, m + c + 3 * BLOCK / 4, sizeof v3);
                const lanes on = (v0 > zero) & (v1 > zero) & (v2 > zero) & (v3 > zero);
                uint64_t bits[2];
                __builtin_memcpy(bits, &on, sizeof on);
                if ((bits[0] & bits[1]) != ~(uint64_t)0) break;
            }
            while (c < w && m[c] > 0) ++c;
            if (n < cap) {
                out[3 * n] = r;
                out[3 * n + 1] = c0;
                out[3 * n + 2] = c;
            }
            ++n;
        }
    }
    return n;
}
#endif /* !SSS_LOOPS512_ONLY */

#undef RUN_LINKAGE
#undef NARROW_STRIP
#undef PACK_AHEAD
#undef WIDE_STRIP
#undef SHORT_ROW
#undef BLEND_LERP
#undef CAT
#undef CAT_

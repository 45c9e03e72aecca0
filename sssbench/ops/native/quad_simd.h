/* The reference's Gauss–Legendre cell sums (quad.c) for one instruction set: included by
 * quad.c once per set with QISA naming it, QISA_TARGET its target attribute and QVW the cells
 * per vector (double lanes). Undefines the three at its end. */

#define QV(name) QCAT(name, QISA)
#define QFN static inline __attribute__((always_inline, target(QISA_TARGET)))

typedef double QV(qd) __attribute__((vector_size(QVW * 8)));
typedef int64_t QV(ql) __attribute__((vector_size(QVW * 8)));

/* lane-wise m ? a : b (m: all-ones / all-zeros 64-bit lanes) */
QFN QV(qd) QV(qsel)(QV(ql) m, QV(qd) a, QV(qd) b) {
    return (QV(qd))((((QV(ql))a) & m) | (((QV(ql))b) & ~m));
}

/* 2^(j/32) lane-wise from the table sss_exp2_32 (exp2_32.h), j in [0, 31]: on AVX-512 (8
 * lanes) the table in four vectors, two two-source shuffles (vpermt2pd) of bits 0-3 and a
 * select on bit 4; with 2 or 4 lanes one load per lane. The same entries at every level. */
QFN QV(qd) QV(qexp2_32)(QV(ql) j) {
    QV(qd) tab;
#if QVW == 8
    QV(qd) t0, t1, t2, t3;
    __builtin_memcpy(&t0, sss_exp2_32, sizeof t0);
    __builtin_memcpy(&t1, sss_exp2_32 + 8, sizeof t1);
    __builtin_memcpy(&t2, sss_exp2_32 + 16, sizeof t2);
    __builtin_memcpy(&t3, sss_exp2_32 + 24, sizeof t3);
    const QV(qd) lo = __builtin_shuffle(t0, t1, j & 15);
    const QV(qd) hi = __builtin_shuffle(t2, t3, j & 15);
    tab = QV(qsel)((j & 16) != 0, hi, lo);
#else
    for (int l = 0; l < QVW; ++l) tab[l] = sss_exp2_32[j[l]];
#endif
    return tab;
}

/* exp(x) lane-wise, the scheme of exp2_32.h: 32 n + j = round(32 x / ln 2) by the 1.5 2^52
 * shift (round to nearest), s = 2^(j/32) 2^n (qexp2_32 times 2^n built in the exponent bits:
 * exact) and exp(x) = s + s q; +0 below x = -708.4 (where 2^n would be subnormal: an absolute
 * error below 2.3e-308), x clamped to [-746, 709] (the reference never gets above 0 but by
 * rounding: its exponents are -|distance|^2 / 2v), NaN kept. Since 2026-12-03 (before: no
 * table, a degree-13 polynomial on |r| <= ln 2 / 2): 8 fewer products and sums per exp; the
 * whole bilinear reference of a 256² face at 0.1 mm/px took 18 % less CPU (one thread, both
 * builds alternated in one process), and moved by 4.3e-16 of its largest value. Within
 * QUAD_EXP_ULP of libm (tests/ops/test_reference_quad.py). */
QFN QV(qd) QV(qexp)(QV(qd) x) {
    typedef QV(qd) vd;
    typedef QV(ql) vl;
    const vd zero = {0};
    const vd x0 = x;
    x = QV(qsel)(x > zero - 746.0, x, zero - 746.0);
    x = QV(qsel)(x < zero + 709.0, x, zero + 709.0);
    const double shifter = 6755399441055744.0; /* 1.5 2^52 */
    const vd t = x * SSS_32_OVER_LN2 + shifter; /* 32 x / ln 2, rounded by the shift */
    const vd nf = t - shifter;
    const vd r = (x - nf * SSS_LN2_32_HI) - nf * SSS_LN2_32_LO;
    const vd q = SSS_EXPM1_DEG6(r);
    const vl n32 = (vl)t - (vl)(zero + shifter);
    const vl biased = (n32 >> 5) + 1023; /* n = floor((32 n + j) / 32) */
    const vl normal = biased > 0;
    const vd s = QV(qexp2_32)(n32 & 31) * QV(qsel)(normal, (vd)(biased << 52), zero);
    const vd y = s + s * q;
    return QV(qsel)(x0 != x0, x0, y);
}

/* qexp(x) where every lane has |x| <= QEXP_SMALL: there 32 x / ln 2 rounds to 0 (|32 x /
 * ln 2| <= 0.4986), so qexp's reduction leaves r = x and its scale s = 1 exactly, and
 * qexp(x) = 1 + 1 q = 1 + q: the same bits from the polynomial alone (tested against
 * quad_exp_array by quad_exp_small_array, tests/ops/test_reference_quad.py) */
QFN QV(qd) QV(qexp_small)(QV(qd) x) { return SSS_EXPM1_DEG6(x) + 1.0; }

/* qexp (small: qexp_small) of n doubles, a tail padded with 0 (quad.c quad_exps) */
__attribute__((target(QISA_TARGET), unused)) static void QV(quad_exp_array)(const double *x,
                                                                        double *y, int64_t n,
                                                                        int small) {
    typedef QV(qd) vd;
    for (int64_t i = 0; i < n; i += QVW) {
        vd v = {0};
        const int64_t k = n - i < QVW ? n - i : QVW;
        for (int64_t l = 0; l < k; ++l) v[l] = x[i + l];
        v = small ? QV(qexp_small)(v) : QV(qexp)(v);
        for (int64_t l = 0; l < k; ++l) y[i + l] = v[l];
    }
}

/* The two parts of a node's exponent from the six features f (quad.c): the row node's
 * (xi_s, as_s = |Delta + h xi_s t_x|^2) and the column node's (xi_t, bt_t = |Delta + h xi_t
 * t_y|^2 - |Delta|^2); the cross term is xi_s xi_t f5 */
QFN QV(qd) QV(quad_row)(const QV(qd) f[6], double xs) {
    return (f[0] + xs * f[1]) + (xs * xs) * f[3];
}
QFN QV(qd) QV(quad_col)(const QV(qd) f[6], double xt) { return xt * f[2] + (xt * xt) * f[4]; }

/* One Gaussian's node sums, added to o (R^2 vectors, o[b R + c]): sum_s rs[c][s] sum_t
 * rt[b][t] e_st with e_st = exp(c_g Q_st) and Q_st = |Delta + h xi_s t_x + h xi_t t_y|^2 from
 * the six features f (quad.c), one exp per node. */
QFN void QV(quad_direct)(const QV(qd) f[6], int64_t n, double cg, const double *xi,
                         const double *rt, const double *rs, int64_t rows, QV(qd) *o) {
    typedef QV(qd) vd;
    const vd zero = {0};
    vd bt[QUAD_MAX_NODES];
    for (int64_t t = 0; t < n; ++t) bt[t] = QV(quad_col)(f, xi[t]);
    for (int64_t s = 0; s < n; ++s) {
        const double xs = xi[s];
        const vd as = QV(quad_row)(f, xs), ps = xs * f[5];
        vd acc[QUAD_MAX_ROWS] = {zero, zero, zero};
        for (int64_t t = 0; t < n; ++t) {
            const vd e = QV(qexp)(((as + bt[t]) + xi[t] * ps) * cg);
            for (int64_t b = 0; b < rows; ++b) acc[b] += rt[b * n + t] * e;
        }
        for (int64_t b = 0; b < rows; ++b)
            for (int64_t c = 0; c < rows; ++c) o[b * rows + c] += rs[c * n + s] * acc[b];
    }
}

/* quad_direct's sums for symmetric nodes (quad_symmetric) with e_st = V_s U_t W_st split
 * along the exponent's three parts, Q_st = as_s + bt_t + xi_s xi_t f5 (quad.c's features):
 * V_s = exp(c_g as_s), U_t = exp(c_g bt_t) and W_st = exp(kappa xi_s xi_t), kappa = c_g f5.
 * With the nodes +-a_i, W takes n^2/4 values exp(kappa a_i a_j) and their reciprocals (the
 * opposite signs), so n^2/4 + 2n exps and n^2/4 divisions instead of n^2 exps (the same
 * product in real arithmetic; in floating point within a few ulp times the factors'
 * exponents, at most 2 QUAD_SPLIT_MAX + |c_g as_s|: the guard below). Terms summed over t in
 * the same order as quad_direct; every lane the same IEEE operations. Returns whether it
 * took the Gaussian. */
QFN int QV(quad_split)(const QV(qd) f[6], int64_t n, double cg, const double *xi,
                       const double *rt, const double *rs, int64_t rows, QV(qd) *o) {
    typedef QV(qd) vd;
    const vd zero = {0}, one = zero + 1.0, kap = f[5] * cg;
    const int64_t h = n / 2; /* pairs; an odd n has the node 0 at index h */
    /* taken only where the factors' exponents c_g bt_t (t's own part) and kappa (the cross
     * part's, |xi_s xi_t| <= 1) are at most QUAD_SPLIT_MAX in every lane (NaN: not taken), so
     * that no factor overflows or cancels more than e^(2 QUAD_SPLIT_MAX) of the node's value
     * (s's own part, c_g as_s, is <= 0): else 0, o untouched, and quad_direct's sums */
    vd ue[QUAD_MAX_NODES];
    int ok = 1;
    for (int l = 0; l < QVW; ++l) ok &= kap[l] <= QUAD_SPLIT_MAX && -kap[l] <= QUAD_SPLIT_MAX;
    for (int64_t t = 0; t < n && ok; ++t) {
        ue[t] = QV(quad_col)(f, xi[t]) * cg;
        for (int l = 0; l < QVW; ++l) ok &= ue[t][l] <= QUAD_SPLIT_MAX;
    }
    if (!ok) return 0;
    vd ru[QUAD_MAX_ROWS][QUAD_MAX_NODES];
    for (int64_t t = 0; t < n; ++t) {
        const vd u = QV(qexp)(ue[t]);
        for (int64_t b = 0; b < rows; ++b) ru[b][t] = rt[b * n + t] * u;
    }
    /* kappa = 0 in every lane (a surface sloped along one axis or none): W = 1, so the sums
     * over t do not depend on s; summed once, the same additions as below with w = 1 */
    int plain = 1;
    for (int l = 0; l < QVW; ++l) plain &= kap[l] == 0.0;
    vd plain_acc[QUAD_MAX_ROWS] = {zero, zero, zero};
    if (plain)
        for (int64_t t = 0; t < n; ++t)
            for (int64_t b = 0; b < rows; ++b) plain_acc[b] += ru[b][t];
    /* the largest |kappa| of the lanes: a cross factor whose exponent is at most QEXP_SMALL
     * in every lane (|kappa a_i a_j| <= kmax a_i a_j, rounded monotonically) by qexp_small */
    double kmax = 0.0;
    for (int l = 0; l < QVW; ++l) kmax = fmax(kmax, fabs(kap[l]));
    vd pw[QUAD_MAX_NODES / 2], qw[QUAD_MAX_NODES / 2];
    for (int64_t i = 0; i <= h; ++i) {
        const int centre = i == h;
        if (centre && !(n & 1)) break;
        if (!centre && !plain)
            for (int64_t j = 0; j < h; ++j) { /* t = j has xi = -a_j, t = n - 1 - j has +a_j */
                const double aij = xi[n - 1 - i] * xi[n - 1 - j];
                pw[j] = kmax * aij <= QEXP_SMALL ? QV(qexp_small)(kap * aij) : QV(qexp)(kap * aij);
                qw[j] = one / pw[j];
            }
        for (int side = 0; side < (centre ? 1 : 2); ++side) {
            /* side 0: s = n - 1 - i (+a_i), 1: s = i (-a_i); the centre: s = h, W = 1 */
            const int64_t s = centre ? h : side ? i : n - 1 - i;
            const double xs = xi[s];
            vd acc[QUAD_MAX_ROWS] = {plain_acc[0], plain_acc[1], plain_acc[2]};
            if (!plain)
                for (int64_t t = 0; t < n; ++t) {
                    vd w = one;
                    if (!centre && t < h) w = side ? pw[t] : qw[t];
                    else if (!centre && t >= n - h) w = side ? qw[n - 1 - t] : pw[n - 1 - t];
                    for (int64_t b = 0; b < rows; ++b) acc[b] += ru[b][t] * w;
                }
            const vd v = QV(qexp)(QV(quad_row)(f, xs) * cg);
            for (int64_t b = 0; b < rows; ++b)
                for (int64_t c = 0; c < rows; ++c) o[b * rows + c] += rs[c * n + s] * (acc[b] * v);
        }
    }
    return 1;
}

/* quad_cell_sums for cells [i0, i0 + k), k <= QVW, one cell per lane, with rows (1 or 3) a
 * constant of each call site (quad_block below) */
QFN void QV(quad_block_rows)(const quad_args *a, int64_t i0, int64_t k, const int64_t rows) {
    typedef QV(qd) vd;
    const int64_t m = a->m, nb = rows * rows;
    const vd zero = {0};
    vd g6[6];
    for (int f = 0; f < 6; ++f) {
        g6[f] = zero;
        for (int64_t l = 0; l < k; ++l) g6[f][l] = a->geom[f * m + i0 + l];
    }
    const vd dx = g6[0], dy = g6[1], dz = g6[2], hh = g6[3], sx = g6[4], sy = g6[5];
    /* the six features of _reference_near._cell_features and the area element */
    const vd two_h = hh * 2.0, h2 = hh * hh, sx2 = sx * sx, sy2 = sy * sy;
    const vd f0 = (dx * dx + dy * dy) + dz * dz;   /* |Delta|^2 */
    const vd f1 = two_h * (dx + sx * dz);          /* 2h Delta.t_x */
    const vd f2 = two_h * (dy + sy * dz);          /* 2h Delta.t_y */
    const vd f3 = h2 + h2 * sx2;                   /* h^2 |t_x|^2 */
    const vd f4 = h2 + h2 * sy2;                   /* h^2 |t_y|^2 */
    const vd f5 = ((two_h * hh) * sx) * sy;        /* 2h^2 t_x.t_y */
    const vd ael = (sx2 + 1.0) + sy2;
    vd area = zero;
    for (int l = 0; l < QVW; ++l) area[l] = sqrt(ael[l]) * h2[l]; /* dA = sqrt(1 + |grad z|^2) */
    vd wsum[3][QUAD_MAX_NB];
    for (int c = 0; c < 3; ++c)
        for (int64_t j = 0; j < nb; ++j) wsum[c][j] = zero;
    const double *xi = a->xi, *rt = a->red_t, *rs = a->red_s;
    const vd feat[6] = {f0, f1, f2, f3, f4, f5};
    for (int64_t g = 0; g < a->n_gauss; ++g) {
        const int64_t n = a->order[g];
        const double cg = a->coef[g];
        vd o[QUAD_MAX_NB];
        for (int64_t j = 0; j < nb; ++j) o[j] = zero;
        if (!(quad_split_on && quad_symmetric(xi, n) &&
              QV(quad_split)(feat, n, cg, xi, rt, rs, rows, o)))
            QV(quad_direct)(feat, n, cg, xi, rt, rs, rows, o);
        for (int c = 0; c < 3; ++c) {
            const double wc = a->w[g * 3 + c];
            for (int64_t j = 0; j < nb; ++j) wsum[c][j] += wc * o[j];
        }
        xi += n, rt += rows * n, rs += rows * n;
    }
    for (int c = 0; c < 3; ++c)
        for (int64_t j = 0; j < nb; ++j) {
            wsum[c][j] *= area;
            if (a->extra)
                for (int64_t l = 0; l < k; ++l)
                    wsum[c][j][l] += a->extra[(c * nb + j) * m + i0 + l];
        }
    /* the contraction with the neighbours' rows, in the torch code's order of neighbours */
    for (int64_t l = 0; l < k; ++l) {
        const int64_t cell = a->cells[i0 + l];
        double num[3] = {0, 0, 0}, den[3] = {0, 0, 0};
        for (int64_t j = 0; j < nb; ++j) {
            const double *row = a->values + 4 * (cell + a->hat[j]);
            for (int c = 0; c < 3; ++c) {
                num[c] += wsum[c][j][l] * row[1 + c];
                den[c] += wsum[c][j][l] * row[0];
            }
        }
        for (int c = 0; c < 3; ++c) {
            a->out[c * m + i0 + l] = num[c];
            a->out[(3 + c) * m + i0 + l] = den[c];
        }
    }
}

/* quad_block_rows compiled once per reconstruction (since 2026-12-05, issue 30): with rows a
 * constant the loops over the rows and the R^2 neighbours are unrolled, with constant bounds
 * and indices, where a run-time rows left them loops with run-time bounds and indices (the
 * R^2 sums of quad_split are still updated in memory at every row node: perf annotate). The
 * same operations in the same order: bitwise the same sums. Measured on native_cell_sums
 * calls captured from references (one thread, 25 rounds, the builds in random order each
 * round, one process): 0.85x the CPU time on the box reference of the 256² face at
 * 0.3 mm/px, 0.91x on the bilinear one of pores at 1 mm/px (docs/numerics.md). */
__attribute__((target(QISA_TARGET))) static void QV(quad_block)(const quad_args *a, int64_t i0,
                                                               int64_t k) {
    if (a->rows == QUAD_MAX_ROWS)
        QV(quad_block_rows)(a, i0, k, QUAD_MAX_ROWS);
    else
        QV(quad_block_rows)(a, i0, k, 1);
}

__attribute__((target(QISA_TARGET))) static void QV(quad_run)(const quad_args *a) {
    for (int64_t i0 = 0; i0 < a->m; i0 += QVW)
        QV(quad_block)(a, i0, a->m - i0 < QVW ? a->m - i0 : QVW);
}

#undef QV
#undef QFN
#undef QISA
#undef QISA_TARGET
#undef QVW

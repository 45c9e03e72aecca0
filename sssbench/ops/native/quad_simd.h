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

/* exp(x) lane-wise, without a table: x = n ln 2 + r, n = round(x / ln 2) (the 1.5 2^52 shift:
 * round to nearest), |r| <= ln 2 / 2 + ulp by the two-part ln 2 of fdlibm (its high part has
 * 21 trailing zero bits: n ln2_hi is exact for |n| < 2^21), e^r - 1 = q by its Taylor
 * polynomial of degree 13 (truncation below 5e-18 relative at |r| = 0.347), and
 * exp(x) = 2^n + 2^n q with 2^n built in the exponent bits; +0 below x = -708.39 (where 2^n
 * would be subnormal: an absolute error below 2.3e-308), x clamped to 709 above (the reference
 * never gets there: its exponents are -|distance|^2 / 2v <= 0 up to rounding), NaN kept. */
QFN QV(qd) QV(qexp)(QV(qd) x) {
    typedef QV(qd) vd;
    typedef QV(ql) vl;
    const vd zero = {0};
    const vd x0 = x;
    x = QV(qsel)(x > zero - 746.0, x, zero - 746.0);
    x = QV(qsel)(x < zero + 709.0, x, zero + 709.0);
    const double shifter = 6755399441055744.0; /* 1.5 2^52 */
    const vd t = x * 1.4426950408889634 + shifter;
    const vd nf = t - shifter;
    const vd r = (x - nf * 6.93147180369123816490e-01) - nf * 1.90821492927058770002e-10;
    vd q = r * (1.0 / 6227020800.0) + 1.0 / 479001600.0; /* 1/13!, 1/12! */
    q = q * r + 1.0 / 39916800.0;
    q = q * r + 1.0 / 3628800.0;
    q = q * r + 1.0 / 362880.0;
    q = q * r + 1.0 / 40320.0;
    q = q * r + 1.0 / 5040.0;
    q = q * r + 1.0 / 720.0;
    q = q * r + 1.0 / 120.0;
    q = q * r + 1.0 / 24.0;
    q = q * r + 1.0 / 6.0;
    q = q * r + 0.5;
    q = q * r + 1.0;
    q = q * r;
    const vl n = (vl)t - (vl)(zero + shifter);
    const vl biased = n + 1023;
    const vl normal = biased > 0;
    const vd scale = QV(qsel)(normal, (vd)(biased << 52), zero);
    const vd y = scale + scale * q;
    return QV(qsel)(x0 != x0, x0, y);
}

__attribute__((target(QISA_TARGET), unused)) static void QV(quad_exp_array)(const double *x,
                                                                        double *y, int64_t n) {
    typedef QV(qd) vd;
    for (int64_t i = 0; i < n; i += QVW) {
        vd v = {0};
        const int64_t k = n - i < QVW ? n - i : QVW;
        for (int64_t l = 0; l < k; ++l) v[l] = x[i + l];
        v = QV(qexp)(v);
        for (int64_t l = 0; l < k; ++l) y[i + l] = v[l];
    }
}

/* quad_cell_sums for cells [i0, i0 + k), k <= QVW, one cell per lane */
__attribute__((target(QISA_TARGET))) static void QV(quad_block)(const quad_args *a, int64_t i0,
                                                               int64_t k) {
    typedef QV(qd) vd;
    const int64_t m = a->m, rows = a->rows, nb = rows * rows;
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
    for (int64_t g = 0; g < a->n_gauss; ++g) {
        const int64_t n = a->order[g];
        const double cg = a->coef[g];
        vd o[QUAD_MAX_NB], bt[QUAD_MAX_NODES];
        for (int64_t j = 0; j < nb; ++j) o[j] = zero;
        for (int64_t t = 0; t < n; ++t) bt[t] = xi[t] * f2 + (xi[t] * xi[t]) * f4;
        for (int64_t s = 0; s < n; ++s) {
            const double xs = xi[s];
            const vd as = (f0 + xs * f1) + (xs * xs) * f3, ps = xs * f5;
            vd acc[QUAD_MAX_ROWS] = {zero, zero, zero};
            for (int64_t t = 0; t < n; ++t) {
                const vd e = QV(qexp)(((as + bt[t]) + xi[t] * ps) * cg);
                for (int64_t b = 0; b < rows; ++b) acc[b] += rt[b * n + t] * e;
            }
            for (int64_t b = 0; b < rows; ++b)
                for (int64_t c = 0; c < rows; ++c) o[b * rows + c] += rs[c * n + s] * acc[b];
        }
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

__attribute__((target(QISA_TARGET))) static void QV(quad_run)(const quad_args *a) {
    for (int64_t i0 = 0; i0 < a->m; i0 += QVW)
        QV(quad_block)(a, i0, a->m - i0 < QVW ? a->m - i0 : QVW);
}

#undef QV
#undef QFN
#undef QISA
#undef QISA_TARGET
#undef QVW

/* Gauss–Legendre cell sums of the exact reference's near field (sssbench.ops._reference_near,
 * hat_cell_sums), fused with the contraction against the neighbours' values. Its own small
 * library (sssbench/ops/native/__init__.py quad_library: a second build of a few seconds, so
 * the first references never wait for the tap loop's long build); called through ctypes.
 *
 * The torch code it replaces is the specification and stays the fallback:
 * _reference_near._quadrant_sums (the exponents as a (nodes, 6) x (6, M) product, one exp,
 * the t and s reductions as products) and the nine fused multiply-adds of hat_cell_sums. Per
 * cell (offset Delta = (dx, dy, dz) from the target, half-size h, slopes sx, sy, all mm) and
 * Gauss–Legendre Gaussian g with the nodes xi_s, xi_t of its rule (n per axis):
 *
 *   e_ts = exp(c_g (|Delta|^2 + xi_s 2h Delta.t_x + xi_t 2h Delta.t_y + xi_s^2 h^2 |t_x|^2
 *                   + xi_t^2 h^2 |t_y|^2 + xi_s xi_t 2h^2 t_x.t_y)),  c_g = -1 / (2 v_g)
 *   W_c,ba += w_gc A sum_s red_s[a][s] sum_t red_t[b][t] e_ts            (000 eq. 7: 001 eq. 7)
 *
 * with A = sqrt(1 + sx^2 + sy^2) h^2 the area element, red_t / red_s the quadrature (and hat)
 * weights of the rows b and columns a (R of each: 3 for the bilinear reconstruction's hats,
 * 1 for the box's whole cell), then W += extra (the closed-form rules, computed by the torch
 * code) and out[c] = sum_j W_c,j values[cell + hat_j][1 + c], out[3 + c] = sum_j W_c,j
 * values[cell + hat_j][0] over the R^2 neighbours j = b R + a.
 *
 * The same terms as the torch code summed in another order (and exp below, within a few ulp
 * of libm's): equal to rounding, tested against the direct contraction of hat_cell_weights
 * (tests/ops/test_reference_quad.py).
 *
 * Split exponent (quad_split in quad_simd.h, since 2026-12-05): the exponent is the sum of a
 * part of s, a part of t and the cross term xi_s xi_t 2h^2 t_x.t_y, so e_ts is the product of
 * three exps; with the rules' nodes symmetric about 0 the cross factor takes n^2/4 values and
 * their reciprocals, so a Gaussian costs n^2/4 + 2n exps and n^2/4 divisions instead of n^2
 * exps (where every factor's exponent is at most QUAD_SPLIT_MAX; else one exp per node as
 * before). Equal to the one-exp form to rounding (tests/ops/test_reference_quad.py, with
 * quad_set_split(0) as the oracle); measured on the cell sums of a 512² paper-benchmark
 * scene (one thread, both builds alternated in one process): pores at 0.3 mm/px, bilinear,
 * 0.76x the CPU time; the face at 0.1 mm/px, box, 0.83x.
 *
 * Vectorised across cells with GCC's vector extensions, compiled three times through target
 * attributes (SSE2 baseline, AVX2, AVX-512F; no -march) and selected at run time by the CPU
 * (__builtin_cpu_supports) or quad_set_level; every lane performs the same IEEE operations
 * (no FMA: -ffp-contract=off), so the levels agree bitwise.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

typedef struct {
    const double *geom;    /* (6, m): dx, dy, dz, hh, sx, sy */
    const double *extra;   /* (3, R^2, m) added before the contraction, or NULL */
    const double *values;  /* (N, 4): stencil, then the three channels times the stencil */
    const int64_t *cells;  /* (m,) each cell's row in values */
    const int64_t *hat;    /* (R^2,) the neighbours' row shifts, j = b R + a */
    const int64_t *order;  /* (G,) nodes per axis of each Gaussian's rule */
    const double *xi;      /* (sum order,) the nodes in [-1, 1], Gaussian after Gaussian */
    const double *red_t;   /* per Gaussian (R, order) weights of the rows b, concatenated */
    const double *red_s;   /* per Gaussian (R, order) weights of the columns a, concatenated */
    const double *coef;    /* (G,) -1 / (2 v_g) */
    const double *w;       /* (G, 3) channel weights */
    double *out;           /* (6, m) */
    int64_t m, n_gauss, rows;
} quad_args;

#define QUAD_MAX_ROWS 3
#define QUAD_MAX_NB (QUAD_MAX_ROWS * QUAD_MAX_ROWS)
#define QUAD_MAX_NODES 64 /* nodes per axis of a rule (the largest in use: 12) */

#include "exp2_32.h" /* sss_exp2_32: the table of qexp (quad_simd.h) */

/* |x| up to which qexp's reduction is x itself and its scale 1 (ln 2 / 64 = 0.010830...,
 * with a margin for the rounding of 32 x / ln 2): qexp_small (quad_simd.h) */
#define QEXP_SMALL 0.0108
/* the largest exponent of a factor of quad_split (quad_simd.h) */
#define QUAD_SPLIT_MAX 30.0
/* 0: every Gaussian by quad_direct (for tests: the split form's oracle); 1 (the default):
 * quad_split where it applies (quad_set_split) */
static int quad_split_on = 1;

/* whether the n nodes are symmetric about 0 (xi[n - 1 - k] == -xi[k] for every k: the
 * reference's Gauss-Legendre rules are), the condition of quad_split */
static int quad_symmetric(const double *xi, int64_t n) {
    for (int64_t k = 0; k < n; ++k)
        if (xi[n - 1 - k] != -xi[k]) return 0;
    return 1;
}

#define QCAT_(a, b) a##_##b
#define QCAT(a, b) QCAT_(a, b)

/* the level's loop: quad_simd.h included once per instruction set */
#define QISA sse2
#define QISA_TARGET "sse2"
#define QVW 2
#include "quad_simd.h"
#define QISA avx2
#define QISA_TARGET "avx2"
#define QVW 4
#include "quad_simd.h"
#define QISA avx512
#define QISA_TARGET "avx512f"
#define QVW 8
#include "quad_simd.h"

/* -1: the widest the CPU supports; else 0 sse2, 1 avx2, 2 avx512 (capped at the CPU's) */
static int quad_level = -1;

/* set whether quad_split may be used; returns the previous setting */
int quad_set_split(int on) {
    const int previous = quad_split_on;
    quad_split_on = on != 0;
    return previous;
}

int quad_best_level(void) {
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f")) return 2;
    if (__builtin_cpu_supports("avx2")) return 1;
    return 0;
}

int quad_set_level(int level) {
    const int best = quad_best_level();
    quad_level = level < 0 || level > best ? -1 : level;
    return quad_level < 0 ? best : quad_level;
}

int quad_get_level(void) { return quad_level < 0 ? quad_best_level() : quad_level; }

/* 0: done; -1: bad arguments (rows not 1 or 3, m or n_gauss negative, a rule's nodes per
 * axis outside 1..QUAD_MAX_NODES) */
int quad_cell_sums(const quad_args *a) {
    if (a->rows != 1 && a->rows != QUAD_MAX_ROWS) return -1;
    if (a->m < 0 || a->n_gauss < 0) return -1;
    for (int64_t g = 0; g < a->n_gauss; ++g)
        if (a->order[g] < 1 || a->order[g] > QUAD_MAX_NODES) return -1;
    switch (quad_get_level()) {
        case 2: quad_run_avx512(a); break;
        case 1: quad_run_avx2(a); break;
        default: quad_run_sse2(a); break;
    }
    return 0;
}

/* exp of n doubles at the current level (a tail padded with 0): qexp, or qexp_small where
 * small (every |x| <= QEXP_SMALL); their error against libm, and their agreement, are tested
 * (tests/ops/test_reference_quad.py) */
static void quad_exps(const double *x, double *y, int64_t n, int small) {
    switch (quad_get_level()) {
        case 2: quad_exp_array_avx512(x, y, n, small); break;
        case 1: quad_exp_array_avx2(x, y, n, small); break;
        default: quad_exp_array_sse2(x, y, n, small); break;
    }
}

void quad_exp_array(const double *x, double *y, int64_t n) { quad_exps(x, y, n, 0); }

void quad_exp_small_array(const double *x, double *y, int64_t n) { quad_exps(x, y, n, 1); }

/* QEXP_SMALL, the bound of quad_exp_small_array (for its test) */
double quad_exp_small_bound(void) { return QEXP_SMALL; }

/* The reference's per-offset neighbour fields (reference._sog_chunk): for the offsets
 * shift[j] (flat, in the padded surface) of the centres centre[i], out[f][j][i] =
 * fields[f][centre[i] + shift[j]], minus fields[f][centre[i]] for the first three fields (the
 * offset dx, dy, dz from the centre): torch.gather and one subtraction, the same values. The
 * caller checks the indices. fields (nf, n) field-major; out (nf, c, e). */
void quad_offset_fields(const double *fields, int64_t nf, int64_t n, const int64_t *centre,
                        int64_t e, const int64_t *shift, int64_t c, double *out) {
    for (int64_t f = 0; f < nf; ++f) {
        const double *src = fields + f * n;
        for (int64_t j = 0; j < c; ++j) {
            double *dst = out + (f * c + j) * e;
            const double *at = src + shift[j];
            if (f < 3)
                for (int64_t i = 0; i < e; ++i) dst[i] = at[centre[i]] - src[centre[i]];
            else
                for (int64_t i = 0; i < e; ++i) dst[i] = at[centre[i]];
        }
    }
}

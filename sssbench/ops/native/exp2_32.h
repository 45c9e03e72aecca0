/* What the vectorised double exps of the disk's loop (disk_simd.h vexp_) and of the reference's
 * quadrature (quad_simd.h qexp) share: exp(x) = 2^n 2^(j/32) (1 + q) with 32 n + j =
 * round(32 x / ln 2), r = x - (32 n + j) ln 2 / 32 by the two-part ln 2 / 32 below (the high
 * part has 17 trailing zero bits: its product by 32 n + j, |32 n + j| < 2^16, is exact),
 * |r| <= ln 2 / 64, q = e^r - 1 by its Taylor polynomial of degree 6 (truncation below 4e-18
 * relative; Estrin's scheme), and 2^(j/32) from the table. Each loop keeps its own rounding of
 * 32 x / ln 2 and its own lane types. Included by disk.c and quad.c; part of both libraries'
 * sources (sssbench/ops/native/__init__.py) and of the reference's code digest. */
#ifndef SSS_EXP2_32_H
#define SSS_EXP2_32_H
#define SSS_32_OVER_LN2 46.16624130844683
#define SSS_LN2_32_HI 0.021660849392446835
#define SSS_LN2_32_LO 5.145609244655338e-14
/* 8 / ln 2 and ln 2 / 8 (the disk's float32-precision exp, disk_simd.h vexpf_) */
#define SSS_8_OVER_LN2 11.541560327111707
#define SSS_LN2_8 0.08664339756999316
/* e^r - 1 by Estrin's scheme: r ((1 + r/2) + r^2 (1/6 + r/24) + r^4 (1/120 + r/720)), the
 * three pairs and r^2, r^4 independent of each other, so the chain of dependent operations is
 * 7 long instead of Horner's 12 (no FMA: the libraries build with -ffp-contract=off). Since
 * 2026-12-05 (before: Horner's scheme from 1/6!): the reference's cell sums took 0.95-0.96x
 * the CPU time (5 alternated rounds, pores at 0.3 mm/px and the face at 0.1 mm/px, 512²),
 * the exps being latency-bound there; the same error bound (tests against libm). */
#define SSS_EXPM1_DEG6(r)                                                                   \
    ((r) * ((((r) * 0.5 + 1.0) + ((r) * (r)) * ((r) * (1.0 / 24) + 1.0 / 6)) +                \
            (((r) * (r)) * ((r) * (r))) * ((r) * (1.0 / 720) + 1.0 / 120)))
/* 2^(j/32), j = 0..31, correctly rounded (computed in 60-digit decimal arithmetic) */
static const double sss_exp2_32[32] __attribute__((aligned(64))) = {
    1.0, 1.0218971486541166, 1.0442737824274138, 1.0671404006768237,
    1.0905077326652577, 1.1143867425958924, 1.1387886347566916, 1.1637248587775775,
    1.189207115002721, 1.215247359980469, 1.241857812073484, 1.2690509571917332,
    1.2968395546510096, 1.3252366431597413, 1.3542555469368927, 1.383909881963832,
    1.4142135623730951, 1.4451808069770467, 1.4768261459394993, 1.5091644275934228,
    1.5422108254079407, 1.5759808451078865, 1.6104903319492543, 1.645755478153965,
    1.681792830507429, 1.718619298122478, 1.7562521603732995, 1.7947090750031072,
    1.8340080864093424, 1.8741676341103, 1.9152065613971474, 1.9571441241754002};
#endif

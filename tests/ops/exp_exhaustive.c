/* The exhaustive check behind docs/numerics.md's bound on the vectorised loops' float32 exp
 * (expz_ in sssbench/ops/native/gather_simd.h: exp(-z ln 2 / 8) for z >= 0, given y = z / 8
 * since 2026-12-06): every float z in [0, 1200] (1.15e9 of them, or every STRIDE-th: argv[2];
 * the result is subnormal beyond z = 1008) through expz_f32_avx512 (argv[1] = "512") or
 * expz_f32_avx2 ("2") of z / 8 (exact under flush-to-zero, or 0 where exp rounds to 1), with
 * flush-to-zero as in a gaussian pass, against the correctly rounded exp (libm's double exp
 * of -z times ln 2 / 8 in double, rounded to float). Prints the largest ulp distance where
 * the exact result is normal and the count of lanes over 1 ulp, or, where it is subnormal,
 * not 0 or normal or 1.2e-38 or more from it. Not run by the test suite (8 s of CPU per level,
 * and gather.c takes ~35 s to compile):
 *
 *   gcc -O2 -ffp-contract=off -fno-math-errno -Wno-psabi -Isssbench/ops/native \
 *       -o /tmp/exp_exhaustive tests/ops/exp_exhaustive.c -lm -lpthread
 *   /tmp/exp_exhaustive 512 && /tmp/exp_exhaustive 2
 *
 * Measured (the 8-entry table and z in units of ln 2 / 8): worst 1 ulp, 0 over, at both
 * levels ("2" on an AVX2-only AMD EPYC; "512" and "2" on an AVX-512 AMD EPYC, 7 s each).
 * Then expz_near_ (the loop's path where every lane's z is below 1/2, y below 1/16) against
 * expz_ for every float y in [0, 1/16): bit for bit at both levels (AVX-512 AMD EPYC,
 * 2026-12-06). */
#include "gather.c"
#include <stdio.h>

typedef float v16 __attribute__((vector_size(64)));
typedef float v8 __attribute__((vector_size(32)));
static long long worst, over;

static void check(const float *y, const float *got, int n) {
    for (int i = 0; i < n; ++i) {
        const float exact = (float)exp(-(double)y[i] * 0.08664339756999316); /* ln 2 / 8 */
        if (!(exact >= FLT_MIN)) { /* normal or 0, and within 1.2e-38 */
            if ((got[i] != 0 && !(got[i] >= FLT_MIN)) || !(fabsf(got[i] - exact) < 1.2e-38f))
                ++over;
            continue;
        }
        int32_t a, b;
        memcpy(&a, &got[i], 4);
        memcpy(&b, &exact, 4);
        const long long d = llabs((long long)a - b);
        if (d > worst) worst = d;
        if (d > 1) ++over;
    }
}

#define SWEEP(W, VEC, FN)                                                              \
    do {                                                                               \
        const unsigned int csr = _mm_getcsr();                                         \
        _mm_setcsr(csr | 0x8000u);                                                     \
        const float highest = 1200.0f;                                                 \
        uint32_t last;                                                                 \
        memcpy(&last, &highest, 4);                                                    \
        float xs[W], out[W];                                                           \
        for (uint64_t u = 0; u <= last; u += (uint64_t)W * stride) {                   \
            for (int l = 0; l < W; ++l) {                                              \
                const uint64_t v = u + (uint64_t)l * stride;                           \
                const uint32_t bits = (uint32_t)(v > last ? last : v);                 \
                memcpy(&xs[l], &bits, 4);                                              \
            }                                                                          \
            VEC x;                                                                     \
            memcpy(&x, xs, sizeof x);                                                  \
            const VEC e = FN(x * 0.125f);                                              \
            memcpy(out, &e, sizeof e);                                                 \
            check(xs, out, W);                                                         \
        }                                                                              \
        _mm_setcsr(csr);                                                               \
    } while (0)

__attribute__((target("avx512f"))) static void sweep512(uint64_t stride) {
    SWEEP(16, v16, expz_f32_avx512);
}

__attribute__((target("avx2,fma"))) static void sweep256(uint64_t stride) {
    SWEEP(8, v8, expz_f32_avx2);
}

/* expz_near_ (every lane's y below 1/16, where the loop's expz_lanes_ takes it) against
 * expz_: every float y in [0, 1/16), bit for bit; and expz_near_below_ accepts every vector
 * of them and refuses the one that holds 1/16 itself */
static long long near_differ, near_checked, near_refused;
#define NEAR_SWEEP(W, VEC, NEAR, FULL, OK)                                             \
    do {                                                                               \
        const unsigned int csr = _mm_getcsr();                                         \
        _mm_setcsr(csr | 0x8000u);                                                     \
        const uint32_t last = 0x3D800000u; /* 1/16 */                                  \
        for (uint64_t u = 0; u <= last; u += W) {                                      \
            uint32_t bits[W];                                                          \
            for (int l = 0; l < W; ++l)                                                \
                bits[l] = (uint32_t)(u + l > last ? last : u + l);                     \
            VEC x;                                                                     \
            memcpy(&x, bits, sizeof x);                                                \
            const int holds_last = u + W - 1 >= last;                                  \
            if (!OK(x)) {                                                              \
                ++near_refused;                                                        \
                if (!holds_last) ++near_differ; /* refused below 1/2 */                \
                continue;                                                              \
            }                                                                          \
            if (holds_last) ++near_differ; /* 1/2 accepted */                          \
            const VEC a = NEAR(x), b = FULL(x);                                        \
            near_checked += W;                                                         \
            if (memcmp(&a, &b, sizeof a)) ++near_differ;                               \
        }                                                                              \
        _mm_setcsr(csr);                                                               \
    } while (0)

__attribute__((target("avx512f"))) static void near512(void) {
    NEAR_SWEEP(16, v16, expz_near_f32_avx512, expz_f32_avx512, expz_near_below_f32_avx512);
}

__attribute__((target("avx2,fma"))) static void near256(void) {
    NEAR_SWEEP(8, v8, expz_near_f32_avx2, expz_f32_avx2, expz_near_below_f32_avx2);
}

int main(int argc, char **argv) {
    const int avx2 = argc > 1 && argv[1][0] == '2';
    const uint64_t stride = argc > 2 ? strtoull(argv[2], NULL, 10) : 1;
    if (avx2 ? !__builtin_cpu_supports("avx2") : !__builtin_cpu_supports("avx512f")) {
        printf("the CPU lacks the level\n");
        return 2;
    }
    if (avx2) sweep256(stride ? stride : 1);
    else sweep512(stride ? stride : 1);
    printf("%s: worst %lld ulp, %lld over\n", avx2 ? "avx2" : "avx512", worst, over);
    if (avx2) near256();
    else near512();
    printf("%s y below 1/16: %lld floats checked, %lld vectors refused (1 expected: the "
           "last, holding 1/16), %lld wrong\n",
           avx2 ? "avx2" : "avx512", near_checked, near_refused, near_differ);
    return over != 0 || near_differ != 0 || near_refused != 1;
}

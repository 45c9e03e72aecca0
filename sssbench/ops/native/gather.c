/* Native tap loop of the one gather primitive (sssbench.ops.gather), float32 and float64.
 * Built on first use by sssbench/ops/native/__init__.py with the system C compiler and
 * called through ctypes; the torch loop is the specification and the fallback.
 *
 * The build compiles this file twice, side by side (two compilers on two cores: half the wall
 * time of one unit, whose float32 and float64 halves take about the same time), and links the
 * objects with disk.c's: SSS_PART=1 gives the shared state (the OpenMP hand-over, the SIMD
 * level) and the float32 loops, SSS_PART=2 the float64 loops; without SSS_PART, one unit holds
 * all of it. The two halves share no static function; pool.h's pool and workspace are static,
 * so each half has its own (as disk.c has), each used by its own passes one at a time.
 *
 * SSS_AVX512_UNIT splits a part once more, along its loops (since 2026-12-06: gcc 12 takes
 * about 5 s of a part's 12 s on its AVX-512 loops, 5 s on its AVX2 ones, 3 s on the rest):
 * 0, this unit holds the part but its AVX-512 loops, which it calls as run_f32_avx512 /
 * run_f64_avx512, hidden symbols of the library; 1, this unit holds those loops only (their
 * run_ and what they inline: the same source, so the same instructions). Undefined: the
 * part's loops all here. */
#ifndef SSS_PART
#define SSS_PART 0
#endif
#ifdef SSS_AVX512_UNIT
#define SSS_LOOPS512_APART 1
#define SSS_LOOPS512_ONLY (SSS_AVX512_UNIT == 1)
#else
#define SSS_LOOPS512_APART 0
#define SSS_LOOPS512_ONLY 0
#endif
/* the OpenMP hand-over, the SIMD level */
#define SSS_PART_SHARED (SSS_PART != 2 && !SSS_LOOPS512_ONLY)
#define SSS_PART_F32 (SSS_PART != 2)
#define SSS_PART_F64 (SSS_PART != 1)
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

/* lane-wise a < b ? a : b and a > b ? a : b (the second operand where either is NaN): the
 * SSE min / max instructions for float, lane masks otherwise */
#define VSELECT(cond, a, b) \
    ((__typeof__(a))(((__typeof__(cond))(a) & (cond)) | ((__typeof__(cond))(b) & ~(cond))))
#if defined(__SSE__)
#include <xmmintrin.h>
#define VMIN_F32(a, b) ((__typeof__(a))_mm_min_ps((__m128)(a), (__m128)(b)))
#define VMAX_F32(a, b) ((__typeof__(a))_mm_max_ps((__m128)(a), (__m128)(b)))
#else
#define VMIN_F32(a, b) VSELECT((a) < (b), a, b)
#define VMAX_F32(a, b) VSELECT((a) > (b), a, b)
#endif
#define VMIN_F64(a, b) VSELECT((a) < (b), a, b)
#define VMAX_F64(a, b) VSELECT((a) > (b), a, b)

/* Flush-to-zero for the gaussian follow-surface passes only (000 eq. 7's exp(-d^2 / 2) of a
 * sample far across a depth step underflows; a subnormal factor, or a weight times it, costs a
 * microcode assist of ~100 cycles per lane on x86 and made the artist pass 1.3x slower, issue
 * 30): the pass's threads set the x86 MXCSR FTZ bit for the pass and restore it after, so every
 * result that would be subnormal is 0 instead (an absolute error below the smallest normal
 * number, 1.2e-38 / 2.2e-308, inside BACKEND_AGREEMENT's tolerance). Inputs are not flushed
 * (no DAZ); the lerp and plain passes never run with it (their bitwise claim). */
#if defined(__SSE__)
#define FTZ_BEGIN(on)                         \
    const unsigned int csr_ = _mm_getcsr();   \
    if (on) _mm_setcsr(csr_ | 0x8000u)
#define FTZ_END() _mm_setcsr(csr_)
#else
#define FTZ_BEGIN(on) (void)(on)
#define FTZ_END() ((void)0)
#endif

#include "pool.h"

int sss_get_simd(void); /* the SIMD level a pass uses (below: SSS_PART_SHARED) */

#if SSS_PART_SHARED
sss_omp_parallel_fn sss_omp_parallel = NULL;
int (*sss_omp_thread_num)(void) = NULL;
int (*sss_omp_num_threads)(void) = NULL;
int (*sss_omp_in_parallel)(void) = NULL;
pid_t sss_omp_pid = 0;

/* Run the passes on the OpenMP team of the runtime whose GOMP_parallel, omp_get_thread_num,
 * omp_get_num_threads and omp_in_parallel these are (torch's: pool.h); any NULL: the own pool.
 * Only in this process (a forked child uses the own pool). Returns whether it is used. */
int sss_set_omp(void *parallel, void *thread_num, void *num_threads, void *in_parallel) {
    const int on = parallel && thread_num && num_threads && in_parallel;
    sss_omp_parallel = NULL; /* never half set: the pointers first, the switch last */
    sss_omp_thread_num = on ? (int (*)(void))thread_num : NULL;
    sss_omp_num_threads = on ? (int (*)(void))num_threads : NULL;
    sss_omp_in_parallel = on ? (int (*)(void))in_parallel : NULL;
    sss_omp_pid = getpid();
    sss_omp_parallel = on ? (sss_omp_parallel_fn)parallel : NULL;
    return on;
}
#endif

/* The vectorised tap loop (gather_simd.h): x86-64 with GCC or clang builds it for AVX2 and
 * AVX-512F through target attributes (no -march: the library runs on any x86-64) and a pass
 * uses the widest set the CPU and OS support, or the level sss_set_simd asked for. */
#if (defined(__x86_64__) || defined(_M_X64)) && defined(__GNUC__)
#define SSS_SIMD 1
#include <immintrin.h>
#else
#define SSS_SIMD 0
#endif

/* lanes idx (0..15) of the 16 floats of lo and hi (AVX2): vpermps of each, the second's
 * lanes where bit 3 of the index is set (two-vector permutes through intrinsics: GCC 12 makes
 * of __builtin_shuffle with a variable index element-by-element code for AVX2, and clang has
 * no __builtin_shuffle) */
#define SHUFFLE2_PS(lo, hi, idx)                                                        \
    _mm256_blendv_ps(_mm256_permutevar8x32_ps((lo), (idx)),                            \
                     _mm256_permutevar8x32_ps((hi), (idx)),                            \
                     _mm256_castsi256_ps(_mm256_slli_epi32((idx), 28)))

#if SSS_PART_SHARED
static int simd_level = -1; /* 0: the scalar loop, 1: AVX2, 2: AVX-512F; -1: not chosen yet */

/* the widest level this CPU (and the OS, which must save its registers) supports */
int sss_simd_best(void) {
#if SSS_SIMD
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f")) return 2;
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return 1;
#endif
    return 0;
}

/* use `level` (capped at the best the CPU supports; < 0: the best); returns the level set */
int sss_set_simd(int level) {
    const int best = sss_simd_best();
    const int chosen = level < 0 || level > best ? best : level;
    __atomic_store_n(&simd_level, chosen, __ATOMIC_RELAXED);
    return chosen;
}

int sss_get_simd(void) {
    const int level = __atomic_load_n(&simd_level, __ATOMIC_RELAXED);
    return level >= 0 ? level : sss_set_simd(-1);
}
#endif

#if SSS_PART_F32
#define SCALAR float
#define LANE int32_t
#define SUFFIX f32
#define SCALAR_MAX FLT_MAX
#define EXPF expf
#define FABSF fabsf
#define VMIN VMIN_F32
#define VMAX VMAX_F32
#define VW_AVX2 8
#define GATHER_AVX2(base, idx) _mm256_i32gather_ps((base), (__m256i)(idx), 4)
#define VW_AVX512 16
#define GATHER_AVX512(base, idx) _mm512_i32gather_ps((__m512i)(idx), (base), 4)
#define IANY_AVX2(m) _mm256_movemask_ps((__m256)(m))
#define SHUFFLE2_AVX2(lo, hi, idx) SHUFFLE2_PS((__m256)(lo), (__m256)(hi), (__m256i)(idx))
#define SHUFFLE2_AVX512(lo, hi, idx) \
    _mm512_permutex2var_ps((__m512)(lo), (__m512i)(idx), (__m512)(hi))
#define IANY_AVX512(m) _mm512_test_epi32_mask((__m512i)(m), (__m512i)(m))
/* a * b + c rounded once (the table exp only: every other operation stays unfused) */
#define FMA_AVX2(a, b, c) \
    ((__typeof__(a))_mm256_fmadd_ps((__m256)(a), (__m256)(b), (__m256)(c)))
#define FMA_AVX512(a, b, c) \
    ((__typeof__(a))_mm512_fmadd_ps((__m512)(a), (__m512)(b), (__m512)(c)))
/* lane-wise min(a, b), b where either is NaN (the table exp's clamp: one instruction) */
#define MINPS_AVX2(a, b) ((__typeof__(a))_mm256_min_ps((__m256)(a), (__m256)(b)))
#define MINPS_AVX512(a, b) ((__typeof__(a))_mm512_min_ps((__m512)(a), (__m512)(b)))
/* lanes idx (low 3 / 4 bits) of one vector (the table exp's lookup) */
#define PERMUTE_AVX2(v, idx) _mm256_permutevar8x32_ps((__m256)(v), (__m256i)(idx))
#define PERMUTE_AVX512(v, idx) _mm512_permutexvar_ps((__m512i)(idx), (__m512)(v))
#define EXP_TABLE 1 /* the vectorised exp by a table of 2^(j/8) (gather_simd.h) */
#define EXPZ_SCALE 0.125 /* its argument: z / 8, in units of ln 2 (gather_simd.h) */
/* a 2^floor(b) (the table exp's 2^n on AVX-512: one instruction) */
#define SCALEF_AVX512(a, b) ((__typeof__(a))_mm512_scalef_ps((__m512)(a), (__m512)(b)))
/* lane-wise a < b ? a : b in one instruction (min returns its second operand where either is
 * NaN or both are zeros: exactly the select), for the follow-surface lerp's clamp */
#define VMINV_AVX2(a, b) ((__typeof__(a))_mm256_min_ps((__m256)(a), (__m256)(b)))
#define VMINV_AVX512(a, b) ((__typeof__(a))_mm512_min_ps((__m512)(a), (__m512)(b)))
/* x in every lane, as it is (a tap's weight: not 0 + x, one scalar addition fewer) */
#define VSET1_AVX2(x) _mm256_set1_ps(x)
#define VSET1_AVX512(x) _mm512_set1_ps(x)
/* lane-wise min of int32 vectors (the tap's second sample row / column: i0 + 1 capped) */
#define VIMIN_AVX2(a, b) ((__typeof__(a))_mm256_min_epi32((__m256i)(a), (__m256i)(b)))
#define VIMIN_AVX512(a, b) ((__typeof__(a))_mm512_min_epi32((__m512i)(a), (__m512i)(b)))
/* whether any int32 lane of a exceeds b's (unsigned) / differs from b's, straight into a
 * mask register (the vector extensions' compare makes a vector of lanes first, then tests
 * it: two instructions more per tap) */
#define KANY_GTU_AVX512(a, b) (_mm512_cmpgt_epu32_mask((__m512i)(a), (__m512i)(b)) != 0)
#define KANY_NE2_AVX512(a, b, c, d)                                   \
    ((_mm512_cmpneq_epi32_mask((__m512i)(a), (__m512i)(b)) |          \
      _mm512_cmpneq_epi32_mask((__m512i)(c), (__m512i)(d))) != 0)
#include "gather_body.h"
#undef SCALAR
#undef LANE
#undef SUFFIX
#undef SCALAR_MAX
#undef EXPF
#undef FABSF
#undef VMIN
#undef VMAX
#undef VW_AVX2
#undef GATHER_AVX2
#undef VW_AVX512
#undef GATHER_AVX512
#undef IANY_AVX2
#undef IANY_AVX512
#undef SHUFFLE2_AVX2
#undef SHUFFLE2_AVX512
#undef FMA_AVX2
#undef FMA_AVX512
#undef MINPS_AVX2
#undef MINPS_AVX512
#undef PERMUTE_AVX2
#undef PERMUTE_AVX512
#undef SCALEF_AVX512
#undef EXP_TABLE
#undef EXPZ_SCALE
#undef VMINV_AVX2
#undef VMINV_AVX512
#undef VSET1_AVX2
#undef VSET1_AVX512
#undef VIMIN_AVX2
#undef VIMIN_AVX512
#undef KANY_GTU_AVX512
#undef KANY_NE2_AVX512
#endif

#if SSS_PART_F64
#define SCALAR double
#define LANE int64_t
#define SUFFIX f64
#define SCALAR_MAX DBL_MAX
#define EXPF exp
#define FABSF fabs
#define VMIN VMIN_F64
#define VMAX VMAX_F64
#define VW_AVX2 4
#define GATHER_AVX2(base, idx) _mm256_i32gather_pd((base), (__m128i)(idx), 8)
#define VW_AVX512 8
#define GATHER_AVX512(base, idx) _mm512_i32gather_pd((__m256i)(idx), (base), 8)
#define IANY_AVX2(m) _mm_movemask_ps((__m128)(m))
#define IANY_AVX512(m) _mm256_movemask_ps((__m256)(m))
/* the float permute on each double's two halves: indices 2i, 2i + 1 per 64-bit lane */
#define SHUFFLE2_AVX2(lo, hi, idx)                                                  \
    _mm256_castps_pd(SHUFFLE2_PS((__m256)(lo), (__m256)(hi),                        \
                                 (__m256i)(((idx) << 1) | ((((idx) << 1) + 1) << 32))))
#define SHUFFLE2_AVX512(lo, hi, idx) \
    _mm512_permutex2var_pd((__m512d)(lo), (__m512i)(idx), (__m512d)(hi))
#define EXP_TABLE 0 /* double: the degree-13 polynomial */
#define EXPZ_SCALE 1.0 /* its argument: z, in units of ln 2 / 8 */
#define VMINV_AVX2(a, b) ((__typeof__(a))_mm256_min_pd((__m256d)(a), (__m256d)(b)))
#define VMINV_AVX512(a, b) ((__typeof__(a))_mm512_min_pd((__m512d)(a), (__m512d)(b)))
#define VSET1_AVX2(x) _mm256_set1_pd(x)
#define VSET1_AVX512(x) _mm512_set1_pd(x)
#define VIMIN_AVX2(a, b) ((__typeof__(a))_mm_min_epi32((__m128i)(a), (__m128i)(b)))
#define VIMIN_AVX512(a, b) ((__typeof__(a))_mm256_min_epi32((__m256i)(a), (__m256i)(b)))
#include "gather_body.h"
#endif

/* Native tap loop of the one gather primitive (sssbench.ops.gather), float32 and float64.
 * Built on first use by sssbench/ops/native/__init__.py with the system C compiler and
 * called through ctypes; the torch loop is the specification and the fallback. */
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

#include "pool.h"

#define SCALAR float
#define LANE int32_t
#define SUFFIX f32
#define SCALAR_MAX FLT_MAX
#define EXPF expf
#define FABSF fabsf
#define VMIN VMIN_F32
#define VMAX VMAX_F32
#include "gather_body.h"
#undef SCALAR
#undef LANE
#undef SUFFIX
#undef SCALAR_MAX
#undef EXPF
#undef FABSF
#undef VMIN
#undef VMAX

#define SCALAR double
#define LANE int64_t
#define SUFFIX f64
#define SCALAR_MAX DBL_MAX
#define EXPF exp
#define FABSF fabs
#define VMIN VMIN_F64
#define VMAX VMAX_F64
#include "gather_body.h"

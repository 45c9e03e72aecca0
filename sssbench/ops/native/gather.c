/* Native tap loop of the one gather primitive (sssbench.ops.gather), float32 and float64.
 * Built on first use by sssbench/ops/native/__init__.py with the system C compiler and
 * called through ctypes; the torch loop is the specification and the fallback. */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>

#define SCALAR float
#define SUFFIX f32
#define EXPF expf
#define FABSF fabsf
#define ISCALAR int32_t
#include "gather_body.h"
#undef SCALAR
#undef SUFFIX
#undef EXPF
#undef FABSF
#undef ISCALAR

#define SCALAR double
#define SUFFIX f64
#define EXPF exp
#define FABSF fabs
#define ISCALAR int64_t
#include "gather_body.h"

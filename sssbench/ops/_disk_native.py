"""The disk's sample loop in C (``native/disk.c``, ``native/disk_body.h``), called by
:class:`~sssbench.ops.DiskSSS` in place of its torch loops.

:meth:`DiskSSS._gather <sssbench.ops.disk.DiskSSS._gather>` and ``_gather_hdrp`` are the
specification: the C loop runs, per centre pixel, the same samples in the same order with the
same float operations — the sample's geometry in float64 whatever the image's dtype (the
kilometre-depth guarantee of ``docs/reliability.md``), colours and sums in the image's dtype —
and takes the per-pixel noise (rotation, radial shift) from the torch code, so the random
rotation is identical by construction (the hash rotation and radial shift are hashed in C from
``disk.hash_key``'s keys: the same integers). What differs is libm's elementary functions against
torch's (each within 1 ulp) and, for a sum of Gaussians, the order of the sum over the
Gaussians (torch: a BLAS product); at the AVX2 / AVX-512 levels the default point fetch runs a
loop vectorised across pixels (``native/disk_simd.h``) whose exp is within
:data:`DISK_EXP_ULP` of libm's for a float64 image and within :data:`DISK_EXPF_REL` (float32
precision: the weights are rounded to float32 there) for a float32 one, whose angles come from
the addition theorem and whose few divisions are products by reciprocals:
:data:`DISK_NATIVE_AGREEMENT`, measured by ``tests/ops/test_disk_native.py`` at every level.

When the C loop runs (:func:`usable`), else the torch loop, never a different answer:

- the gather backend is ``"native"`` (the default; ``with sssbench.ops.gather.backend("torch")``
  runs the torch loop) and the C library is available (built with the separable passes';
  without a compiler: the torch loop, after the library's one warning);
- the image is float32 or float64;
- the profile is :class:`~sssbench.profiles.BurleyNormalized` or
  :class:`~sssbench.profiles.SumOfGaussians` (their closed forms are written in C; any other
  profile class, or a subclass, runs the torch loop: its ``evaluate`` is Python);
- autograd does not record the call (grad mode on and the diffuse, depth or a profile tensor
  requiring a gradient: the torch loop, which is differentiable; the C loop has no backward).

Every option of :class:`~sssbench.ops.DiskSSS` is covered (both estimators, patterns,
rotations, frames, normalise, jitter, point and bilinear fetch, adaptive counts, surface
area, per-pixel profiles and ``cross_profile``): those are applied around the gather call.
Threads: ``torch.get_num_threads()``, at least 65536 pixel-samples each, on the native pool
(``native/pool.h``); the SIMD level of the separable passes (:func:`~sssbench.ops.native.simd`).
"""

from __future__ import annotations

import ctypes
import math

import torch

from sssbench.ops import native
from sssbench.ops._disk_radial import BurleyRadial, TabulatedRadial
from sssbench.ops.gather import get_backend
from sssbench.profiles import burley as _burley
from sssbench.profiles.burley import BurleyNormalized
from sssbench.profiles.sum_of_gaussians import SumOfGaussians

__all__ = [
    "DISK_NATIVE_AGREEMENT",
    "DISK_EXP_ULP",
    "DISK_EXPF_REL",
    "DISK_BURLEY_R_ABS",
    "DISK_BURLEY_INV_REL",
    "usable",
    "usable_profile",
    "gather",
    "gather_hdrp",
    "vexp",
    "burley_radial",
]

#: how the C loop's results relate to the torch loop's, as a bound on the largest difference
#: over the output's largest value (tests/ops/test_disk_native.py, every option combination of
#: the disk tests, every SIMD level of an AVX-512 machine): measured float64 at most 5e-14 (the
#: vectorised loop's few-ulp weights included); float32 bitwise equal in every combination at
#: the scalar level, and at the vector levels, whose exp has float32 precision since issue 30
#: (:data:`DISK_EXPF_REL`), within 1.8e-7 (measured on an AVX2-only machine, 2026-12-04, and
#: again on an AVX-512 one on 2026-12-06 with HDRP's estimator vectorised too: 1.8e-7 for
#: "sssbench", 1.2e-7 for HDRP's, 3.3e-16 in float64; 9 of 35 combinations still bitwise,
#: the 7 of the bilinear fetch, which runs the scalar loop); the float32 bound allows a
#: weight rounded to the other float32 neighbour after a few-ulp difference of a float64
#: weight. AVX2 and AVX-512 bitwise the same
DISK_NATIVE_AGREEMENT = {torch.float64: 1e-11, torch.float32: 2e-6}

#: buckets of the tabulated sampler's guide table (a power of two: ``u · G`` is exact). 16384
#: since 2026-12-06 (issue 30; 4096 before): with the 4097 nodes of a profile's table the
#: vectorised loop's binary search ran 1.46 steps a sample, 0.29 with 65536 buckets; the
#: default disk (skin_deon6, 32 samples, close-up, 2 threads, 21 interleaved rounds) took 0.964
#: ± 0.006 the time at 512² and 0.963 ± 0.004 at 256² (8192: 0.970, 32768: 0.951-0.957; the
#: table, 128 KB, is built every call and counted). The same node found, so the same bits.
_GUIDE = 16384

_P = ctypes.c_void_p


class DiskArgs(ctypes.Structure):
    """``disk_args`` of ``native/disk.c`` (same fields, same order)."""

    _fields_ = [
        (name, _P)
        for name in (
            "area", "packed", "pix", "turn", "shift", "step", "u0",
            "theta0", "rcp", "num", "den", "mom", "tab_r", "tab_cdf", "guide", "prof_a",
            "prof_b", "total",
        )  # fmt: skip
    ] + [
        ("sampler_d", ctypes.c_double),
        ("per_mm", ctypes.c_double),
        ("eps", ctypes.c_double),
    ] + [
        (name, ctypes.c_int64)
        for name in ("m", "n", "h", "w", "hw", "nodes", "guide_n", "n_gauss")
    ] + [
        (name, ctypes.c_int32)
        for name in ("sampler_kind", "profile_kind", "bilinear", "threads")
    ] + [
        (name, ctypes.c_int64) for name in ("turn_key", "shift_key")
    ]  # fmt: skip


def _profile_tensors(profile) -> tuple[torch.Tensor, ...]:
    if type(profile) is BurleyNormalized:
        return profile.d, profile.albedo
    return profile.variances, profile.weights


def usable_profile(kernel) -> bool:
    """Whether the C loop has the closed forms of ``kernel``'s profile and sampler (module
    doc): :class:`~sssbench.profiles.BurleyNormalized` or
    :class:`~sssbench.profiles.SumOfGaussians` exactly, not a subclass."""
    return type(kernel.profile) in (BurleyNormalized, SumOfGaussians) and isinstance(
        kernel.sampler, (BurleyRadial, TabulatedRadial)
    )


def usable(ctx, kernel) -> bool:
    """Whether the C loop runs this gather (module doc): ``ctx`` the disk's ``_Pixels``,
    ``kernel`` its ``_Kernel``."""
    if ctx.dtype not in (torch.float32, torch.float64) or get_backend() != "native":
        return False
    if not usable_profile(kernel):
        return False
    if torch.is_grad_enabled():
        tensors = (ctx.rgb, ctx.pos, ctx.area, kernel.total, *_profile_tensors(kernel.profile))
        if any(t is not None and t.requires_grad for t in tensors):
            return False
    return native.library() is not None


def _packed(ctx, accept: torch.Tensor) -> torch.Tensor:
    """``(N, 8)`` per pixel ``(r, g, b, z, accept, area, x, y)`` in the image dtype (copies,
    no arithmetic; area 0 without ``surface_area``): a fetched pixel is one cache line (the
    loop's random reads dominated its time), and a centre's position is read from the same
    lines (no channels-last copy of the positions); built once per forward and acceptance
    (kept on ``ctx``)."""
    cache = ctx.__dict__.setdefault("_disk_native_packed", {})
    key = id(accept)
    if key not in cache:
        n = ctx.rgb.shape[0]
        area = ctx.area if ctx.area is not None else torch.zeros(n, dtype=ctx.dtype)
        cols = [ctx.rgb.detach(), ctx.depth.detach()[:, None], accept.detach()[:, None]]
        cols += [area.detach()[:, None], ctx.pos.detach()[:, :2]]
        cache[key] = (accept, torch.cat(cols, 1))
    return cache[key][1]


class _Call:
    """One call's arguments, keeping every tensor they point into alive."""

    def __init__(self, ctx, kernel, accept: torch.Tensor, pix: torch.Tensor) -> None:
        self.keep: list[torch.Tensor] = []
        a = self.args = DiskArgs()
        dt = ctx.dtype
        a.packed = self.ptr(_packed(ctx, accept), dt)
        a.pix = self.ptr(pix, torch.int64)
        m = pix.numel()
        a.m, a.h, a.w, a.hw = m, ctx.h, ctx.w, ctx.hw
        a.per_mm = 2.0 * math.tan(ctx.fov_y / 2.0) / ctx.h  # gbuffer.pixel_size_mm
        a.threads = torch.get_num_threads()
        profile = kernel.profile
        if type(profile) is BurleyNormalized:
            a.profile_kind = 1
            a.prof_a = self.ptr(profile.d)
            a.prof_b = self.ptr(profile.albedo)
            a.eps = _burley._EPS
        else:
            a.profile_kind = 0
            a.prof_a = self.ptr(profile.variances)
            a.prof_b = self.ptr(profile.weights)
            a.n_gauss = profile.variances.numel()
        a.total = self.ptr(kernel.total)
        sampler = kernel.sampler
        if isinstance(sampler, BurleyRadial):
            a.sampler_kind, a.sampler_d = 1, sampler.d
        else:
            edges = torch.arange(_GUIDE + 1, dtype=torch.float64) / _GUIDE
            guide = torch.searchsorted(sampler.cdf, edges, right=True) - 1
            a.tab_r, a.tab_cdf = self.ptr(sampler.r), self.ptr(sampler.cdf)
            a.guide, a.guide_n, a.nodes = self.ptr(guide, torch.int64), _GUIDE, sampler.r.numel()
        self.num = torch.empty(m, 3, dtype=dt)
        self.den = torch.empty(m, 3, dtype=dt)
        a.num, a.den = self.num.data_ptr(), self.den.data_ptr()

    def ptr(self, t: torch.Tensor, dtype: torch.dtype = torch.float64) -> int:
        """The address of ``t`` as a contiguous ``dtype`` tensor (kept alive)."""
        t = t.detach().to(dtype).contiguous()
        self.keep.append(t)
        return t.data_ptr()


def gather(
    ctx,
    kernel,
    accept: torch.Tensor,
    pix: torch.Tensor,
    turn: torch.Tensor,
    shift: torch.Tensor | None,
    step: torch.Tensor,
    u0: torch.Tensor,
    theta0: torch.Tensor,
    bilinear: bool,
    *,
    turn_key: int | None = None,
    shift_key: int | None = None,
    moments: bool = True,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """:meth:`DiskSSS._gather <sssbench.ops.disk.DiskSSS._gather>` in C: ``Σ w E``, ``Σ w``
    ``(M, 3)`` and the moments ``(M, 3, 3)`` in the image dtype (``moments=False``: ``None``,
    and the loop does not form them: the same sums, bit for bit, with nine fewer per sample).
    ``pix`` ``(M,)`` the centre pixels (flat), ``turn`` ``(M,)`` 2π × their rotation (radians),
    ``shift`` ``(M,)`` their radial shift or ``None`` (no jitter), ``step`` ``(M,)`` pixels per
    mm at the centre, ``u0``/``theta0`` ``(n,)`` the pattern (float64). ``turn_key`` (with
    ``turn=None``) and ``shift_key`` (with ``shift=None``): the C loop draws the rotation (``2π
    ×``) and the radial shift of pixel ``p`` as ``disk.hash_uniform`` does, ``lowbias32((p mod
    H·W) ^ key) / 2³²`` (``disk.hash_key``): the same integers, so the same float64 values."""
    if (turn is None) == (turn_key is None):
        raise ValueError("gather needs exactly one of turn and turn_key")
    if shift is not None and shift_key is not None:
        raise ValueError("gather takes at most one of shift and shift_key")
    call = _Call(ctx, kernel, accept, pix)
    a = call.args
    a.turn = None if turn is None else call.ptr(turn)
    a.step = call.ptr(step)
    a.shift = None if shift is None else call.ptr(shift)
    a.turn_key = -1 if turn_key is None else turn_key
    a.shift_key = -1 if shift_key is None else shift_key
    a.u0, a.theta0, a.n = call.ptr(u0), call.ptr(theta0), u0.numel()
    a.area = None if ctx.area is None else call.ptr(ctx.area, ctx.dtype)
    a.bilinear = int(bilinear)
    mom = torch.empty(pix.numel(), 3, 3, dtype=ctx.dtype) if moments else None
    a.mom = None if mom is None else mom.data_ptr()
    lib = native.library()
    (lib.sss_disk_f32 if ctx.dtype == torch.float32 else lib.sss_disk_f64)(ctypes.byref(a))
    return call.num, call.den, mom


def gather_hdrp(
    ctx,
    kernel,
    accept: torch.Tensor,
    pix: torch.Tensor,
    turn: torch.Tensor,
    ppm: torch.Tensor,
    r: torch.Tensor,
    rcp_pdf: torch.Tensor,
    phi: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`DiskSSS._gather_hdrp <sssbench.ops.disk.DiskSSS._gather_hdrp>` in C: ``Σ w E``
    and ``Σ w`` ``(M, 3)``. ``ppm`` ``(M,)`` HDRP's pixels per mm, ``r``, ``rcp_pdf``, ``phi``
    ``(n,)`` the samples' radii (mm), inverse polar densities and angles (radians)."""
    call = _Call(ctx, kernel, accept, pix)
    a = call.args
    a.turn, a.step = call.ptr(turn), call.ptr(ppm)
    a.turn_key = a.shift_key = -1
    a.u0, a.rcp, a.theta0, a.n = call.ptr(r), call.ptr(rcp_pdf), call.ptr(phi), r.numel()
    lib = native.library()
    (lib.sss_disk_hdrp_f32 if ctx.dtype == torch.float32 else lib.sss_disk_hdrp_f64)(
        ctypes.byref(a)
    )
    return call.num, call.den


#: Burley's radial sampler vectorised (``native/disk_simd.h`` ``burley_radial_``: ``vlog_``,
#: ``vlog1p_``, a sinh series and ``wexp_`` for libm's ``asinh``, ``sinh``, ``log`` and
#: ``exp``) against the scalar loop's, by :func:`burley_radial` (tests/ops/test_disk_native.py):
#: the radius within ``DISK_BURLEY_R_ABS · d`` everywhere (measured 2.0e-14 · d at 10^6
#: quantiles and both ends, d = 0.05, 0.7 and 12 mm: the formula is ill-conditioned as u → 0,
#: where r → 0 and both are some 30 ulp from the exact radius, checked at 3000 quantiles in
#: 40-digit arithmetic, the vectorised one no further), and the inverse density, where
#: r >= d / 10, within ``DISK_BURLEY_INV_REL`` relative for a float64 image (measured 1.4e-14)
#: and that plus :data:`DISK_EXPF_REL` for a float32 one (its exp of float32 precision)
DISK_BURLEY_R_ABS = 1e-13
DISK_BURLEY_INV_REL = 1e-13

#: the vectorised loop's exp (``native/disk_simd.h`` ``vexp_``) against the C library's, in
#: units in the last place where the result is normal (below ``exp(-708.4)``, subnormal, it
#: gives +0): the bound ``tests/ops/test_disk_native.py`` checks at every vector level
DISK_EXP_ULP = 1

#: the vectorised loop's exp for float32 images (``native/disk_simd.h`` ``vexpf_``: the
#: reduction in float64, the polynomial and the table in float32) against the C library's, as
#: a bound on the relative error where the result is normal (+0 below ``exp(-708.4)``): 2^-23,
#: one float32 ulp at the bottom of a binade; measured 8.9e-8 (1.5 × 2^-24) at 2.1·10⁶
#: arguments in [-745, 0] (tests/ops/test_disk_native.py)
DISK_EXPF_REL = 2.0**-23


def _test_entry(caller: str, symbol: str, level: str, image_dtype: torch.dtype):
    """The C library's test entry ``symbol`` for :func:`burley_radial` and :func:`vexp`
    (``caller``), after checking ``level`` and ``image_dtype``: ``RuntimeError`` without the
    C library, ``ValueError`` for an unknown level or dtype."""
    lib = native.library()
    if lib is None:
        raise RuntimeError(f"{caller} needs the native library (no C compiler?)")
    if level not in native.SIMD_LEVELS:
        raise ValueError(f"level must be one of {native.SIMD_LEVELS}, got {level!r}")
    if image_dtype not in (torch.float32, torch.float64):
        raise ValueError(f"image_dtype must be torch.float32 or torch.float64, got {image_dtype}")
    return getattr(lib, symbol)


def burley_radial(
    u: torch.Tensor, d: float, level: str, image_dtype: torch.dtype = torch.float64
) -> tuple[torch.Tensor, torch.Tensor, str]:
    """Burley's radial sampler (``BurleyRadial.sample`` in C, shape ``d`` mm) at the float64
    quantiles ``u``: ``(r, 1 / pdf_area, level used)`` by the disk's vectorised sampler at
    ``level`` (``"avx2"`` or ``"avx512"``, capped at the CPU's; ``"scalar"``: the scalar
    loop's, libm's ``asinh``, ``sinh``, ``log`` and ``exp``) for images of ``image_dtype``
    (the density's exp: ``vexp_`` for float64, ``vexpf_`` for float32): for its test against
    the scalar loop. Raises ``RuntimeError`` without the C library and ``ValueError`` for an
    unknown level or dtype."""
    fn = _test_entry("burley_radial", "sss_disk_burley_radial", level, image_dtype)
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.c_double, _P, _P, _P, ctypes.c_int64, ctypes.c_int, ctypes.c_int]
    src = u.detach().to(torch.float64).contiguous()
    r, inv = torch.empty_like(src), torch.empty_like(src)
    f32 = int(image_dtype == torch.float32)
    used = fn(float(d), src.data_ptr(), r.data_ptr(), inv.data_ptr(), src.numel(),
              native.SIMD_LEVELS.index(level), f32)  # fmt: skip
    return r, inv, native.SIMD_LEVELS[used]


def vexp(
    x: torch.Tensor, level: str, image_dtype: torch.dtype = torch.float64
) -> tuple[torch.Tensor, str]:
    """``exp`` of float64 ``x`` (any shape) by the disk's vectorised exp at ``level``
    (``"avx2"`` or ``"avx512"``, capped at the CPU's; ``"scalar"``: the C library's ``exp``)
    for images of ``image_dtype`` (float64: ``vexp_``, :data:`DISK_EXP_ULP`; float32:
    ``vexpf_``, :data:`DISK_EXPF_REL`) and the level used: for its test against the C library.
    Raises ``RuntimeError`` without the C library and ``ValueError`` for an unknown level or
    dtype."""
    fn = _test_entry("vexp", "sss_disk_vexp", level, image_dtype)
    fn.restype = ctypes.c_int
    fn.argtypes = [_P, _P, ctypes.c_int64, ctypes.c_int, ctypes.c_int]
    src = x.detach().to(torch.float64).contiguous()
    out = torch.empty_like(src)
    f32 = int(image_dtype == torch.float32)
    used = fn(src.data_ptr(), out.data_ptr(), src.numel(), native.SIMD_LEVELS.index(level), f32)
    return out, native.SIMD_LEVELS[used]

"""The one gather primitive: a depth-aware separable blur pass (DESIGN §4).

Every separable method of the papers (pre-integrated, artist, 2012, SVD rank-N, sum of
Gaussians) is a kernel builder plus a schedule of calls to :func:`separable_pass`; the papers'
variants are options of this function, not copies of its loop. One module because the pass's
validation, backend choice and dispatch (the fused blend's too) are one public entry whose
options every method shares; the loops themselves are in ``_gather_torch`` / ``_gather_native``.

The loop is the CPU counterpart of the papers' blur shader (002 appendix, 003 Listing 7.1):
for each active pixel, step along the pass axis by ``offset × width × (pixels per mm at this
pixel's depth)``, fetch the neighbour with linear interpolation along the axis (bilinear when
stochastic rotation turns the axis), clamp at the image border, and accumulate
``weight × sample``.

This module is the public entry: validation, the choice of backend and the dispatch. The loop
itself has one specification, the differentiable torch loop
(:mod:`sssbench.ops._gather_torch`), and a fast C counterpart registered as the torch
operators ``torch.ops.sssbench.gather`` / ``gather_`` (:mod:`sssbench.ops._gather_native`,
sources in ``native/``). Pixels with ``mask > 0`` are compacted into one list per image
(stencil: masked-out pixels are never computed, 002 §4 / 003 §7.3.1), so time follows covered
pixels: the native loop's runs are rebuilt from the mask once per call (one read of it,
:func:`~sssbench.ops._stencil.image_spans`), the torch loop's index lists memoised per mask
contents (:func:`~sssbench._memo.memoised`). Without autograd the native pass is called
directly rather than through the dispatcher (whose argument binding cost more per pass than
a small object's work), with the kernel's taps as they are (the C loop converts them to the
pass's dtype itself, bitwise as :func:`_taps` does) and its tensors by address: such a pass
makes no torch call but the stencil's output buffer, each of which cost ~25 µs of CPU on a
call whose caches the previous frame's work had evicted (1080p, this machine), more than a
far-away object's pass spends on some of its rows; the operators are used when autograd
records the pass or a graph is compiled.

Backends (:data:`BACKENDS`, chosen per block with :func:`backend`, default ``"native"``):

- ``"native"``: the C loop, differentiable (its backward recomputes the torch loop), used
  unless the pass has rotated taps or a ``sample_weight`` (torch loop then) or the library
  cannot be built (one warning, torch loop). :data:`BACKEND_AGREEMENT` says how its results
  relate to the torch loop's.
- ``"torch"``: the eager torch loop.
- ``"compile"``: the torch loop through ``torch.compile`` (inductor; the first call per dtype,
  direction and follow-surface mode compiles for tens of seconds).
- ``"gl"``: the pass as a GLSL fragment shader with ``SeparableSSS.h`` semantics on a headless
  OpenGL context (:mod:`sssbench.gl`, the ``gl`` extra; float32 textures, upload and read-back
  per pass; rotation included; no gradients, no ``sample_weight``: both refused with a
  ``ValueError``). Entering the block without a GL context raises
  :class:`sssbench.gl.GLUnavailable` naming what to install: never a silent fall-back.

Threads: the C loop splits its lines over ``torch.get_num_threads()`` threads, so
``torch.set_num_threads`` governs both, but gives each thread at least 16384 pixels of work
(``MIN_THREAD_WORK`` in ``native/gather_body.h``): a split costs CPU time that does not scale
with the pixels (a worker woken on a core whose caches hold other work, lines the other thread
wrote moved across cores), measured 0.1–0.3 ms per two-pass call, 13 % of a 20k-pixel call's
work; a smaller object is computed on the calling thread (its wall time is then up to twice
what two idle cores would give). A ctypes library cannot use torch's OpenMP pool, so
its workers are kept in a small pool of their own (``native/pool.h``) that sleep on a condition
variable between passes and never spin: they take no core from torch's threads, and a pass is
synchronous, so the two pools never compute at once. Measured reason to keep the pool rather
than start threads per pass (2 threads, this 2-core machine shared with other jobs, 2000 runs):
handing a pass to a sleeping worker costs 10 µs (min; mean 35 µs), starting and joining a fresh
thread 21 µs (mean 80 µs), against 30–100 µs for a whole pass over a small object.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import torch

from sssbench._checks import check_choice, check_scalar, check_tensor
from sssbench._memo import call_scoped, memo_scope
from sssbench.gbuffer import GBuffer
from sssbench.kernels.kernel1d import Kernel1D
from sssbench.ops import native
from sssbench.ops._gather_native import (  # registers torch.ops.sssbench.*
    MAX_SETS,
    native_pass,
    run_pass,
    weights_overflow,
)
from sssbench.ops._gather_torch import SampleWeight, compiled_accumulate, gather_torch, sweep_torch
from sssbench.ops._overlap import has_internal_overlap, shares_memory
from sssbench.ops._stencil import image_spans, image_stencils
from sssbench.ops.pass_backends import PASS_BACKENDS_ABOVE, _pass_backend
from sssbench.ops.timing import PassRecord, add_record

__all__ = [
    "separable_pass",
    "separable_sweep",
    "MAX_SETS",
    "blend_on_stencil",
    "backend",
    "get_backend",
    "check_writable",
    "BACKENDS",
    "BACKEND_AGREEMENT",
    "Stretch",
    "Rotation",
    "FOLLOW_SURFACE",
    "SampleWeight",
]

FOLLOW_SURFACE = (None, "lerp", "gaussian")
BACKENDS = ("native", "torch", "compile", "gl")

#: How the native loop's results relate to the torch loop's (tested in
#: ``tests/reliability/test_gather_safety.py``; the fallback warning says it).
BACKEND_AGREEMENT = (
    "bitwise equal in float32 and float64 with follow_surface None or 'lerp', at every "
    "instruction-set level of the native loop (scalar, AVX2, AVX-512: the same IEEE operations "
    "in the same order per pixel, the per-pixel scale in float64 in all); with 'gaussian' the "
    "depth factor differs by a few ulp (torch's vectorised exp of (-0.5 d) d; the C library's "
    "exp of the same argument in the scalar native loop; in the vectorised ones the argument "
    "formed as |dz|^2 k, within 1.5 ulp of exact as torch's is, and a table and polynomial exp "
    "within 1 ulp of the correctly rounded one), and the native loop flushes results that "
    "would be subnormal to 0 (x86 flush-to-zero during a gaussian pass: an absolute error "
    "below 1.2e-38 / 2.2e-308), so results agree to within 1e-6 (float32) / 1e-14 (float64) "
    "relative to the image's range"
)

_BACKEND: ContextVar[str] = ContextVar("sssbench_gather_backend", default="native")


@contextmanager
def backend(name: str) -> Iterator[None]:
    """Run the gather passes of this block on backend ``name`` (one of :data:`BACKENDS`).

    A context variable, not a process-wide switch: it applies to the current thread / task and
    is restored on exit, also when the block raises; new threads start with the default,
    ``"native"``.

    Example:
        >>> with backend("torch"):
        ...     get_backend()
        'torch'
    """
    token = _BACKEND.set(check_choice("backend", name, BACKENDS))
    if name in PASS_BACKENDS_ABOVE:
        try:
            # e.g. the GL context: GLUnavailable (one line: what to install) before any pass
            _pass_backend(name)[0]()
        except BaseException:
            _BACKEND.reset(token)
            raise
    try:
        yield
    finally:
        _BACKEND.reset(token)


def get_backend() -> str:
    """The backend chosen by the innermost :func:`backend` block (default ``"native"``)."""
    return _BACKEND.get()


@dataclass(frozen=True)
class Stretch:
    """JG10 stretch factors (003 §7.3.1) in millimetre units.

    003 computes ``s_x = ssslevel / (d + correction · min(|ddx d|, maxdd))`` with depth in
    "units" of a head one unit tall, 20° fov and 720 px. Here the pinhole mapping already turns
    mm into pixels, so ``ssslevel`` is a dimensionless multiplier of the physical scale (1.0 =
    physically sized kernel); ``correction`` keeps its unit, pixels (003: 800), and ``maxdd`` is
    in mm of depth per pixel: 003's 0.001 head units per pixel × a 230 mm head = 0.23 mm/px.
    The resulting factor multiplies the pinhole pixels-per-mm:
    ``ssslevel · d / (d + correction · min(|∂d/∂axis|, maxdd))``. Checked on construction
    (a method whose passes are all culled by LOD still refuses a bad stretch) and again by
    :func:`separable_pass`: all finite, ``ssslevel > 0``, ``correction >= 0``, ``maxdd >= 0``.
    """

    ssslevel: float = 1.0
    correction: float = 800.0
    maxdd: float = 0.23

    def __post_init__(self) -> None:
        check_scalar("ssslevel", self.ssslevel, 0.0, low_inclusive=False)
        check_scalar("correction", self.correction, 0.0)
        check_scalar("maxdd", self.maxdd, 0.0)


@dataclass(frozen=True)
class Rotation:
    """Stochastic kernel rotation (000 §6).

    Attributes:
        angles: per-pixel rotation of the sampling axis in radians, ``(B, 1, H, W)``, finite.
        radius: fraction of the kernel extent within which taps are rotated (000 §6: 0.1;
            0.3 for extreme close-ups), in [0, 1]. Taps farther out stay on the axis (cache
            friendly in the paper; here it keeps their 1D interpolation).
    """

    angles: torch.Tensor
    radius: float = 0.1

    def __post_init__(self) -> None:
        # checked on construction, not only by a pass that LOD may skip
        check_tensor("angles", self.angles, ndim=4, channels=1)
        check_scalar("radius", self.radius, 0.0, 1.0)


def _axis_derivative(depth: torch.Tensor, axis: int) -> torch.Tensor:
    """|∂depth/∂axis| in mm per pixel by central differences (one-sided at the border).

    003 uses the shader's ``ddx``, a forward difference within a 2×2 quad; a central
    difference is its symmetric counterpart and does not shift silhouettes by half a pixel.
    """
    d = torch.gradient(depth, dim=axis)[0]
    return d.abs()


def check_writable(name: str, target: torch.Tensor, others: dict[str, torch.Tensor | None]) -> None:
    """Raise ``ValueError`` unless ``target`` can be overwritten in place while ``others`` are
    read: it must be writable here (not an inference tensor outside ``torch.inference_mode``,
    which torch refuses to write), have no two elements at one address (an ``expand``ed,
    stride-0 view), and share no byte with any of ``others`` (a field that is a view of it, or
    of the memory under it, would change during the pass: a silent wrong answer). Both are
    decided exactly from sizes and strides (:func:`has_internal_overlap`,
    :func:`shares_memory`): a window view writes in place, and interleaved but disjoint views
    do not count as overlapping.

    Args:
        name: how the caller calls ``target`` (``"image"``, ``"gbuffer.diffuse"``).
        target: the tensor to be written.
        others: name -> tensor read during the write (``None`` entries are skipped).
    """
    if target.is_inference() and not torch.is_inference_mode_enabled():
        raise ValueError(
            f"{name} is an inference tensor (made under torch.inference_mode) and cannot be "
            "written in place outside inference mode: call inside torch.inference_mode(), or "
            "with inplace=False"
        )
    # a contiguous tensor has none: not asked, a call less
    if not target.is_contiguous() and has_internal_overlap(target):
        raise ValueError(
            f"{name} has elements sharing memory (an expanded or stride-0 view, strides "
            f"{target.stride()}) and cannot be written in place: pass a tensor that owns its "
            "memory (e.g. .contiguous()), or inplace=False"
        )
    for other_name, other in others.items():
        if other is not None and shares_memory(target, other):
            raise ValueError(
                f"{name} shares memory with {other_name}: writing {name} in place would change "
                f"{other_name} while the pass reads it; give them separate memory (e.g. "
                f"{other_name}.clone()), or use inplace=False"
            )


def _check_pass_inputs(
    image: torch.Tensor,
    kernel: Kernel1D,
    direction: str,
    gbuffer: GBuffer,
    width: float | torch.Tensor,
    follow_surface: str | None,
    surface_scale: float | torch.Tensor | None,
    stretch: Stretch | None,
    rotation: Rotation | None,
    guide: torch.Tensor | None,
    sample_weight: SampleWeight | None,
    check_finite: bool,
) -> None:
    """Every argument of :func:`separable_pass`, each error naming what it checks."""
    check_tensor("image", image, ndim=4, channels=3, finite=check_finite)
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if not isinstance(kernel, Kernel1D):
        raise TypeError(f"kernel must be a Kernel1D, got {type(kernel).__name__}")
    if image.shape != gbuffer.diffuse.shape:
        raise ValueError(
            f"image must have the G-buffer's shape {tuple(gbuffer.diffuse.shape)}, "
            f"got {tuple(image.shape)}"
        )
    if image.dtype != gbuffer.dtype:
        raise TypeError(f"image dtype {image.dtype} must match the G-buffer's {gbuffer.dtype}")
    check_choice("direction", direction, ("x", "y"))
    check_choice("follow_surface", follow_surface, FOLLOW_SURFACE)
    if isinstance(width, torch.Tensor):
        check_tensor("width", width, ndim=4, channels=1)
        if width.shape != gbuffer.depth.shape:
            raise ValueError(
                f"width must be a scalar or have shape {tuple(gbuffer.depth.shape)}, "
                f"got {tuple(width.shape)}"
            )
        if bool((width < 0).any()):
            raise ValueError(f"width must be >= 0 mm, got min {float(width.min()):g}")
    else:
        check_scalar("width", width, 0.0, low_inclusive=False)
    if follow_surface is not None and surface_scale is None:
        raise ValueError(
            f"surface_scale (mm, > 0) must be given with follow_surface={follow_surface!r}"
        )
    if isinstance(surface_scale, torch.Tensor):
        check_tensor("surface_scale", surface_scale, ndim=1)
        if surface_scale.shape != (3,) or not bool((surface_scale > 0).all()):
            raise ValueError(
                "surface_scale must be a scalar > 0 or a (3,) tensor of per-channel mm > 0, "
                f"got {surface_scale.tolist()}"
            )
    elif surface_scale is not None:
        check_scalar("surface_scale", surface_scale, 0.0, low_inclusive=False)
    if stretch is not None:
        if not isinstance(stretch, Stretch):
            raise TypeError(f"stretch must be a Stretch, got {type(stretch).__name__}")
        check_scalar("stretch.ssslevel", stretch.ssslevel, 0.0, low_inclusive=False)
        check_scalar("stretch.correction", stretch.correction, 0.0)
        check_scalar("stretch.maxdd", stretch.maxdd, 0.0)
    if rotation is not None:
        if not isinstance(rotation, Rotation):
            raise TypeError(f"rotation must be a Rotation, got {type(rotation).__name__}")
        check_tensor("rotation.angles", rotation.angles, ndim=4, channels=1)
        if rotation.angles.shape != gbuffer.depth.shape:
            raise ValueError(
                f"rotation.angles must have shape {tuple(gbuffer.depth.shape)}, "
                f"got {tuple(rotation.angles.shape)}"
            )
        check_scalar("rotation.radius", rotation.radius, 0.0, 1.0)
    if (guide is None) != (sample_weight is None):
        raise ValueError("guide and sample_weight must be given together")
    if guide is not None:
        check_tensor("guide", guide, ndim=4)
        if guide.shape[0] != image.shape[0] or guide.shape[2:] != image.shape[2:]:
            raise ValueError(
                f"guide must have shape (B, G, H, W) = ({image.shape[0]}, G, "
                f"{image.shape[2]}, {image.shape[3]}), got {tuple(guide.shape)}"
            )


def _taps(kernel: Kernel1D, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """The kernel's offsets ``(K,)`` (mm per width unit) and weights ``(K, 3)`` in ``dtype``.

    Offsets beyond the dtype's range (a float64 kernel of variance 1e600 mm² in a float32
    pass) are clamped to its largest finite value: such a tap lands beyond the border either
    way, and an infinite offset would give ``inf · 0`` = NaN at a pixel of zero width. Weights
    must be finite in ``dtype`` (``ValueError`` naming ``kernel.weights``)."""
    big = torch.finfo(dtype).max
    offsets = kernel.offsets.to(torch.float64).clamp(-big, big).to(dtype)
    weights = kernel.weights.to(dtype)
    if not bool(torch.isfinite(weights).all()):
        raise weights_overflow(kernel.weights, dtype)
    return offsets, weights


def _reciprocal(surface_scale: float | torch.Tensor | None) -> torch.Tensor | tuple[float, ...]:
    """1 / surface_scale per channel in float64 (1/mm; 0: unused): three floats for a scalar
    (no torch call), a ``(3,)`` tensor (differentiable) for per-channel scales."""
    if surface_scale is None:
        return (0.0, 0.0, 0.0)
    if isinstance(surface_scale, torch.Tensor):  # per channel (differentiable)
        return surface_scale.to(torch.float64).reciprocal()
    return (1.0 / float(surface_scale),) * 3


def _inverse_scale(surface_scale: float | torch.Tensor | None, dtype: torch.dtype) -> torch.Tensor:
    """``(3,)`` 1 / surface_scale in 1/mm (0: unused), computed in float64
    (:func:`_reciprocal`) and clamped to the dtype's largest finite value (a surface_scale of
    1e-40 mm must not give ``0 · inf``)."""
    inv = _reciprocal(surface_scale)
    if not isinstance(inv, torch.Tensor):
        inv = torch.tensor(inv, dtype=torch.float64)
    big = torch.finfo(dtype).max
    return torch.where(inv <= big, inv, big).to(dtype)


def _pass_constants(
    kernel: Kernel1D, surface_scale: float | torch.Tensor | None, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_taps` and :func:`_inverse_scale`, shared by the passes of one operator call
    (:func:`~sssbench._memo.call_scoped` on the kernel's tensors: built anew in every call)."""
    scale_t = surface_scale if isinstance(surface_scale, torch.Tensor) else None
    tag = ("pass-constants", dtype, None if scale_t is not None else surface_scale)
    return call_scoped(
        (kernel.offsets, kernel.weights, scale_t),
        tag,
        lambda: (*_taps(kernel, dtype), _inverse_scale(surface_scale, dtype)),
    )


def separable_pass(
    image: torch.Tensor,
    kernel: Kernel1D,
    direction: str,
    gbuffer: GBuffer,
    *,
    width: float | torch.Tensor = 1.0,
    follow_surface: str | None = None,
    surface_scale: float | torch.Tensor | None = None,
    stretch: Stretch | None = None,
    use_mask: bool = True,
    rotation: Rotation | None = None,
    guide: torch.Tensor | None = None,
    sample_weight: SampleWeight | None = None,
    name: str | None = None,
    check_finite: bool = True,
    inplace: bool = False,
    blend_into: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """One depth-aware 1D gather pass over the active pixels (DESIGN §4).

    Args:
        image: the image to blur, ``(B, 3, H, W)``, the G-buffer's dtype.
        kernel: taps; ``offsets`` in mm (times ``width``), ``weights (K, 3)``.
        direction: ``"x"`` (along rows) or ``"y"`` (along columns).
        gbuffer: supplies ``depth`` (mm), ``fov_y`` and ``mask``.
        width: multiplier of the kernel offsets (mm per offset unit): a scalar > 0 or a
            per-pixel ``(B, 1, H, W)`` tensor >= 0 (curvature modulation). Kernels built in mm
            use 1.0; the 2012 kernel is built in units of its ``width``.
        follow_surface: ``None``; ``"lerp"``: lerp each sample back to the centre colour by
            ``clamp(|Δz| / surface_scale, 0, 1)`` (002 appendix shader); ``"gaussian"``:
            multiply the tap weight by ``exp(-Δz² / 2 surface_scale²)`` with ``surface_scale =
            σ_max`` (000 eq. 7).
        surface_scale: mm, required with ``follow_surface``: the depth step at which a
            sample is fully replaced (lerp) or the σ_max of eq. 7 (gaussian); a scalar or a
            ``(3,)`` tensor of per-channel values (the artist model's σ_f). The methods
            pass their profile's widest length scale (the 2012 shader's constant
            ``300 · distToProjWindow · sssWidth`` likewise replaces a sample fully at a depth
            step of about the kernel's width).
        stretch: JG10 stretch factors (003 §7.3.1), see :class:`Stretch`; every field must be
            finite (``ssslevel > 0``, ``correction, maxdd >= 0``).
        use_mask: use ``gbuffer.mask`` as stencil and strength: pixels with mask 0 are not
            computed (copied through), others have their step scaled by the mask (003 §7.3.1
            ``s' = s · alpha``; the 2012 shader's ``finalStep *= SSSS_STRENGTH_SOURCE``).
        rotation: stochastic rotation of the inner taps (000 §6), see :class:`Rotation`.
        guide: ``(B, G, H, W)`` auxiliary image fetched with the samples for ``sample_weight``.
        sample_weight: bilateral weight ``f(centre_guide (N, G), sample_guide (N, G))`` ->
            ``(N, 1)`` or ``(N, 3)`` (004 §3.3); the result is renormalised by the summed weights.
        name: name of the :class:`~sssbench.ops.timing.PassRecord` (default ``"pass.<dir>"``).
        check_finite: scan ``image`` for NaN / Inf (a full read of the image). The methods
            pass ``False``: their first image is ``gbuffer.diffuse``, validated when the
            G-buffer was built, and each later one is a pass output of finite inputs; on a
            far-away object the scan would otherwise cost more than the pass (measured).
        inplace: write the result into ``image`` and return it instead of a new tensor, for
            a caller that owns ``image`` (an intermediate of its own schedule): the pass then
            costs no full-image copy, only work on the active pixels, and bumps ``image``'s
            version counter like any torch in-place op. Honoured when no gradient is needed
            and ``image`` is contiguous; otherwise a new tensor is returned. Refused
            (``ValueError``, :func:`check_writable`) when ``image`` shares memory with a
            G-buffer field or another input, has elements sharing memory (an expanded view),
            or is an inference tensor outside ``torch.inference_mode``.
        blend_into: ``(target, weight)`` or ``None``: after the pass,
            ``blend_on_stencil(target, result, weight, mask)`` (:func:`blend_on_stencil`, the
            sum of Gaussians' blend of a step into its result, 003 §7.3.3) with this pass's
            stencil (``gbuffer.mask`` with ``use_mask``, else every pixel); ``target``
            ``(B, 3, H, W)`` of the image's dtype is overwritten there. On the native backend
            without autograd and a contiguous ``target`` the blend is done by the pass itself
            as it writes each result (bitwise the separate native blend, one read of the
            result less); otherwise by :func:`blend_on_stencil` after it. ``target`` must not
            share memory with the pass's inputs or its result (``ValueError``,
            :func:`check_writable`).

    Returns:
        ``(B, 3, H, W)``: blurred where active, ``image`` elsewhere. Differentiable with
        respect to ``image``, ``gbuffer.depth``, ``gbuffer.mask``, a per-pixel ``width``, the
        kernel's tensors and a per-channel ``surface_scale`` on every backend (the native
        one's backward is the torch loop's, see :mod:`sssbench.ops._gather_native`).

    Raises:
        ValueError / TypeError: a bad argument, named (every scalar, tensor and
            :class:`Stretch` / :class:`Rotation` field is checked on entry).

    Shape:
        - image: ``(B, 3, H, W)``
        - output: ``(B, 3, H, W)``

    Example:
        >>> g = GBuffer(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 100.0), 0.5)
        >>> k = Kernel1D(torch.tensor([-1.0, 0.0, 1.0]), torch.full((3, 3), 1 / 3))
        >>> separable_pass(g.diffuse, k, "x", g).shape
        torch.Size([1, 3, 8, 8])
    """
    _check_pass_inputs(
        image, kernel, direction, gbuffer, width, follow_surface, surface_scale, stretch,
        rotation, guide, sample_weight, check_finite,
    )  # fmt: skip
    b_, _, h_, w_ = image.shape
    dtype = image.dtype
    axis = 3 if direction == "x" else 2
    strength = gbuffer.mask if (use_mask and gbuffer.mask is not None) else None
    f_px = h_ / (2.0 * math.tan(gbuffer.fov_y / 2.0))  # pixels per mm at 1 mm depth
    ddepth = None  # |∂depth/∂axis| (mm / px), 003 §7.3.1
    correction = maxdd = 0.0
    if stretch is not None:
        f_px *= stretch.ssslevel
        if not math.isfinite(f_px):
            raise ValueError(
                f"stretch.ssslevel={stretch.ssslevel:g} times the focal length "
                f"{f_px / stretch.ssslevel:g} px overflows float64"
            )
        ddepth = _axis_derivative(gbuffer.depth, axis)
        correction, maxdd = float(stretch.correction), float(stretch.maxdd)
    per_pixel = width if isinstance(width, torch.Tensor) else None
    width_scalar = 0.0 if per_pixel is not None else float(width)
    follow = FOLLOW_SURFACE.index(follow_surface)
    if inplace:
        check_writable("image", image, {
            "gbuffer.depth": gbuffer.depth, "gbuffer.mask": strength, "width": per_pixel,
            "guide": guide, "rotation.angles": None if rotation is None else rotation.angles,
        })  # fmt: skip
    if blend_into is not None:
        target, blend_w = _check_blend_into(blend_into, image, {
            "image": image, "gbuffer.depth": gbuffer.depth, "gbuffer.mask": strength,
            "width": per_pixel, "guide": guide,
        })  # fmt: skip
    scale_t = surface_scale if isinstance(surface_scale, torch.Tensor) else None
    grads = torch.is_grad_enabled() and any(
        t is not None and t.requires_grad
        for t in (image, gbuffer.depth, strength, per_pixel, kernel.offsets, kernel.weights,
                  scale_t, guide)
    )  # fmt: skip
    inplace = inplace and not grads and image.is_contiguous()
    name_ = _backend_for(image, rotation, sample_weight)
    if name_ == "gl" and grads:
        raise ValueError(
            "the gl backend computes no gradients: run passes that autograd records (fits, "
            "sampling='optimised' fitting) on backend 'native' or 'torch'"
        )
    direct = name_ == "native" and not (grads or torch.compiler.is_compiling())
    fused = None  # the blend done by the C loop as it writes each result
    if blend_into is not None and direct and target.is_contiguous():
        if not (torch.is_grad_enabled() and (target.requires_grad or blend_w.requires_grad)):
            fused = (target, blend_w.detach().to(dtype))
    if direct:  # the C loop converts the kernel's taps itself, as _pass_constants does
        taps = (kernel.offsets, kernel.weights, _reciprocal(surface_scale))
    else:
        taps = _pass_constants(kernel, surface_scale, dtype)
    args = (gbuffer.depth, strength, per_pixel, ddepth, *taps, f_px, width_scalar, correction,
            maxdd, axis == 2, follow)  # fmt: skip

    start = time.perf_counter()
    with memo_scope():  # the stencil is built once per call (see sssbench._memo)
        if name_ in PASS_BACKENDS_ABOVE:
            out, n_total = _pass_backend(name_)[1](
                image, kernel, direction, gbuffer, strength=strength,
                width=per_pixel if per_pixel is not None else width_scalar,
                follow_surface=follow_surface, surface_scale=surface_scale, stretch=stretch,
                rotation=rotation, out=image if inplace else None,
            )  # fmt: skip
        elif name_ == "native" and not direct:
            # through the dispatcher: autograd records the operator (its backward is the
            # torch loop's), a compiled graph traces it
            if inplace:
                torch.ops.sssbench.gather_(image, *args)
                out = image
            else:
                out = torch.ops.sssbench.gather(image, *args)
            spans = image_spans(strength, (b_, h_, w_))
            n_total = int(sum(int((s[:, 2] - s[:, 1]).sum()) for s in spans))
        elif name_ == "native":
            # no autograd: the operator's implementation called directly (the dispatcher and
            # its argument binding cost ~65 us per pass, more than a small object's work),
            # bumping the version counter of an in-place target as the operator would
            out, n_total = run_pass(image, args, inplace, blend=fused)
            if inplace and not image.is_inference():
                torch.autograd.graph.increment_version(image)
            if fused is not None and not target.is_inference():
                torch.autograd.graph.increment_version(target)
        else:
            rot = None
            if rotation is not None:
                rot = (rotation.angles, rotation.radius * kernel.extent)
            out, n_total = gather_torch(
                image, *args, rotation=rot, guide=guide, sample_weight=sample_weight,
                out=image if inplace else None,
                accumulate=compiled_accumulate() if name_ == "compile" else None,
            )  # fmt: skip
        if blend_into is not None and fused is None:
            blend_on_stencil(target, out, blend_w, strength)
    ms = (time.perf_counter() - start) * 1e3
    add_record(PassRecord(name or f"pass.{direction}", len(kernel), n_total, ms))
    return out


def separable_sweep(
    images: torch.Tensor,
    kernels: Sequence[Kernel1D],
    direction: str,
    gbuffer: GBuffer,
    *,
    coefficients: torch.Tensor | None = None,
    out: torch.Tensor | None = None,
    width: float | torch.Tensor = 1.0,
    follow_surface: str | None = None,
    surface_scale: float | torch.Tensor | None = None,
    use_mask: bool = True,
    name: str | None = None,
    check_finite: bool = True,
    keep_inactive: bool = True,
    inactive_from: torch.Tensor | None = None,
    inactive_into: torch.Tensor | None = None,
) -> torch.Tensor:
    """:func:`separable_pass` with ``S`` weight sets over the same tap offsets in one sweep
    (000 §3 eq. 2's rank-S sum of separable kernels, 003 §7.3's Gaussians applied directly):
    each tap's position, fetch and follow-surface factor are computed once per pixel for all
    sets (the native loop; the torch loop runs ``S`` passes, :func:`~sssbench.ops._gather_torch.
    sweep_torch`, its specification). Results equal ``S`` separate :func:`separable_pass` calls
    (summed with ``coefficients``, in set order from 0) as :data:`BACKEND_AGREEMENT` states:
    bitwise with follow_surface ``None`` / ``"lerp"`` on every backend and level.

    Args:
        images: fan-out (``coefficients`` ``None``): one image ``(B, 3, H, W)``, the
            G-buffer's dtype; fan-in: ``(S, B, 3, H, W)``, set ``s`` blurs ``images[s]``.
        kernels: ``S`` :class:`Kernel1D` (1 <= S <= :data:`MAX_SETS`) with equal ``offsets``.
        direction, gbuffer, width, follow_surface, surface_scale, use_mask, name,
            check_finite: as :func:`separable_pass` (no rotation, no ``sample_weight``).
        coefficients: ``(S, 3)`` finite per-set per-channel factors: the fan-in, whose result
            is ``Σ_s coefficients[s] · pass_s(images[s])`` at the active pixels.
        out: fan-in: ``(B, 3, H, W)`` target written at the active pixels and nowhere
            else (must share no memory with the inputs); ``None``: a new tensor holding
            ``Σ_s coefficients[s] · images[s]`` at the inactive pixels (what the separate
            passes summed give there). Fan-out: ``None`` or a contiguous ``(S, B, 3, H, W)``
            workspace of the image's dtype that the native loop overwrites entirely (every
            pixel of every set) and returns, when no gradient is needed (otherwise a new
            tensor is returned): a caller that sweeps frame after frame saves allocating
            and faulting in ``S`` images per call.
        keep_inactive: fan-out: ``True`` (default) writes ``images`` into every set's
            inactive pixels (what separate passes give there); ``False`` (with ``out``)
            leaves them as ``out`` holds them on the native loop (no copy: 0.94x the time
            of the 1080p close-up's fused sum of Gaussians, issue 30), for a caller whose
            fan-in reads them from ``inactive_from``; the torch loop writes them anyway.
        inactive_from: fan-in (with ``out``): ``None``, or a ``(B, 3, H, W)`` image of the
            images' dtype taken as every set's image at the inactive pixels, whatever
            ``images`` holds there (``torch.where(active, images[s], inactive_from)``):
            the taps' samples there read it. May be ``out`` (a fan-in writes only the
            active pixels).
        inactive_into: fan-out: ``None``, or a ``(B, 3, H, W)`` tensor of the image's dtype
            (sharing no memory with the inputs or ``out``) that gets ``images`` at the
            inactive pixels, its active pixels left as they are: a fresh target for a fan-in
            with ``inactive_from=images`` that writes the active ones (the native loop's
            threads copy each line as they reach it; for the fused sum of Gaussians' new
            image, in place of a copy of the whole image before the sweeps, issue 30).

    Returns:
        fan-out: ``(S, B, 3, H, W)``, ``[s]`` set ``s``'s pass (``images`` at inactive pixels);
        fan-in: ``(B, 3, H, W)`` (``out`` when given). Differentiable on the torch loop
        (used whenever autograd records an input); the ``gl`` backend has no shader for it
        (``ValueError``).
    """
    if not isinstance(kernels, Sequence) or not kernels:
        raise TypeError("kernels must be a non-empty sequence of Kernel1D")
    if len(kernels) > MAX_SETS:
        raise ValueError(f"kernels must hold at most {MAX_SETS} weight sets, got {len(kernels)}")
    for i, k in enumerate(kernels):
        if not isinstance(k, Kernel1D):
            raise TypeError(f"kernels[{i}] must be a Kernel1D, got {type(k).__name__}")
        if not torch.equal(k.offsets, kernels[0].offsets):
            raise ValueError(f"kernels[{i}].offsets must equal kernels[0].offsets (shared taps)")
    n_sets = len(kernels)
    fan_in = coefficients is not None
    if fan_in:  # with inactive_from only the active pixels are read (checked below)
        check_tensor("images", images, ndim=5, finite=check_finite and inactive_from is None)
        if images.shape[0] != n_sets:
            raise ValueError(
                f"images must have shape (S, B, 3, H, W) with S = {n_sets} (one per kernel) "
                f"for a fan-in, got {tuple(images.shape)}"
            )
        check_tensor("coefficients", coefficients, ndim=2, finite=True)
        if coefficients.shape != (n_sets, 3):
            raise ValueError(
                f"coefficients must have shape ({n_sets}, 3), got {tuple(coefficients.shape)}"
            )
        first = images[0]
        if inactive_from is not None:
            check_tensor("inactive_from", inactive_from, ndim=4, finite=check_finite)
            if inactive_from.shape != first.shape or inactive_from.dtype != first.dtype:
                raise ValueError(
                    f"inactive_from must have the images' shape {tuple(first.shape)} and dtype "
                    f"{first.dtype}, got {tuple(inactive_from.shape)} {inactive_from.dtype}"
                )
            if out is None:
                raise ValueError("inactive_from needs out (the fan-in's target)")
    else:
        first = images
        if inactive_from is not None:
            raise ValueError("inactive_from is for a fan-in (coefficients given)")
    if inactive_into is not None:
        if fan_in:
            raise ValueError("inactive_into is for a fan-out (no coefficients)")
        if (
            not isinstance(inactive_into, torch.Tensor) or inactive_into.shape != first.shape
            or inactive_into.dtype != first.dtype
        ):  # fmt: skip
            raise ValueError(
                f"inactive_into must be a tensor of the image's shape {tuple(first.shape)} "
                f"and dtype {first.dtype}"
            )
    if not keep_inactive and (fan_in or out is None):
        raise ValueError("keep_inactive=False is for a fan-out into a given out")
    _check_pass_inputs(
        first, kernels[0], direction, gbuffer, width, follow_surface, surface_scale, None,
        None, None, None, check_finite and inactive_from is None,
    )  # fmt: skip
    strength = gbuffer.mask if (use_mask and gbuffer.mask is not None) else None
    per_pixel = width if isinstance(width, torch.Tensor) else None
    if inactive_from is not None and check_finite:
        read = images if strength is None else torch.where(strength > 0, images, 0)
        check_tensor("images (at the active pixels)", read, ndim=5, finite=True)
    if out is not None:
        want = first.shape if fan_in else (n_sets, *first.shape)
        if not isinstance(out, torch.Tensor) or out.shape != want or out.dtype != first.dtype:
            raise ValueError(
                f"out must be a tensor of shape {tuple(want)} and dtype {first.dtype}, got "
                f"{tuple(out.shape) if isinstance(out, torch.Tensor) else type(out).__name__}"
                f"{' ' + str(out.dtype) if isinstance(out, torch.Tensor) else ''}"
            )
        check_writable("out", out, {
            "images": images, "gbuffer.depth": gbuffer.depth, "gbuffer.mask": strength,
            "width": per_pixel,
        })  # fmt: skip
    if inactive_into is not None:
        check_writable("inactive_into", inactive_into, {
            "images": images, "gbuffer.depth": gbuffer.depth, "gbuffer.mask": strength,
            "width": per_pixel, "out": out,
        })  # fmt: skip
    name_ = get_backend()
    if name_ == "gl":
        raise ValueError(
            "the gl backend has no shader for separable_sweep (several weight sets in one "
            "sweep): run it on backend 'native', 'torch' or 'compile'"
        )
    dtype = first.dtype
    axis = 3 if direction == "x" else 2
    _, _, h_, _ = first.shape
    f_px = h_ / (2.0 * math.tan(gbuffer.fov_y / 2.0))  # pixels per mm at 1 mm depth
    follow = FOLLOW_SURFACE.index(follow_surface)
    weights = torch.stack([k.weights for k in kernels])  # (S, K, 3)
    scale_t = surface_scale if isinstance(surface_scale, torch.Tensor) else None
    grads = torch.is_grad_enabled() and any(
        t is not None and t.requires_grad
        for t in (images, gbuffer.depth, strength, per_pixel, weights, kernels[0].offsets,
                  scale_t, coefficients, out)
    )  # fmt: skip
    lib = native.library_for(dtype) if name_ == "native" and first.device.type == "cpu" else None
    native_ok = lib is not None
    start = time.perf_counter()
    with memo_scope():
        if native_ok and not (grads or torch.compiler.is_compiling()):
            taps = (kernels[0].offsets, weights, _reciprocal(surface_scale))
            args = (gbuffer.depth, strength, per_pixel, None, *taps, f_px,
                    0.0 if per_pixel is not None else float(width), 0.0, 0.0, axis == 2,
                    follow)  # fmt: skip
            images_c = images.contiguous()
            if fan_in:
                c = coefficients.detach().to(torch.float64).contiguous()
                if out is None:  # Σ_s c_s · images[s] at the inactive pixels, in set order
                    out = torch.zeros_like(first, memory_format=torch.contiguous_format)
                    for img, cs in zip(images_c, c.to(dtype), strict=True):
                        out = out + cs.view(1, 3, 1, 1) * img
                target = out if out.is_contiguous() else out.contiguous()
                rest = None if inactive_from is None else inactive_from.contiguous()
                n_total = native_pass(lib, images_c, target, args, False,
                                      sets=(True, c), inactive=rest)  # fmt: skip
                if target is not out:
                    out.copy_(target)
                elif not out.is_inference():
                    torch.autograd.graph.increment_version(out)
                result = out
            else:
                result = out
                if result is None or not result.is_contiguous():
                    result = torch.empty((n_sets, *first.shape), dtype=dtype, device=first.device)
                elif not result.is_inference():
                    torch.autograd.graph.increment_version(result)
                into = inactive_into
                if into is not None and not into.is_contiguous():
                    into = into.contiguous()
                n_total = native_pass(lib, images_c, result, args,
                                      keep_inactive or result is not out,
                                      sets=(False, None), inactive_to=into)  # fmt: skip
                if into is not inactive_into:
                    inactive_into.copy_(into)
                elif into is not None and not into.is_inference():
                    torch.autograd.graph.increment_version(into)
        else:
            offsets, w_t = _taps(kernels[0], dtype)[0], weights.to(dtype)
            if not bool(torch.isfinite(w_t).all()):
                raise weights_overflow(weights, dtype)
            args = (gbuffer.depth, strength, per_pixel, None, offsets, w_t,
                    _inverse_scale(surface_scale, dtype), f_px,
                    0.0 if per_pixel is not None else float(width), 0.0, 0.0, axis == 2,
                    follow)  # fmt: skip
            if inactive_from is not None and strength is not None:
                images = torch.where(strength > 0, images, inactive_from)
            result, n_total = sweep_torch(
                images, *args, coefficients=None if not fan_in else coefficients.to(dtype),
                out=out if fan_in else None,
                accumulate=compiled_accumulate() if name_ == "compile" else None,
            )  # fmt: skip
            if inactive_into is not None and strength is not None:
                inactive_into.copy_(torch.where(strength > 0, inactive_into, images))
    ms = (time.perf_counter() - start) * 1e3
    fetched = len(kernels[0]) * (n_sets if fan_in else 1)  # samples per pixel
    add_record(PassRecord(name or f"sweep.{direction}", fetched, n_total, ms))
    return result


def _check_blend_into(
    blend_into: object, image: torch.Tensor, others: dict[str, torch.Tensor | None]
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(target, weight)`` of :func:`separable_pass`'s ``blend_into``, checked: a pair of
    tensors, ``target`` of the image's shape and dtype and writable beside ``others``
    (:func:`check_writable`), ``weight`` ``(3,)`` finite."""
    if not (isinstance(blend_into, tuple) and len(blend_into) == 2):
        raise TypeError("blend_into must be a (target, weight) pair of tensors or None")
    target, weight = blend_into
    if not isinstance(target, torch.Tensor) or not isinstance(weight, torch.Tensor):
        raise TypeError("blend_into must be a (target, weight) pair of tensors or None")
    if target.shape != image.shape or target.dtype != image.dtype:
        raise ValueError(
            f"blend_into target must have the image's shape {tuple(image.shape)} and dtype "
            f"{image.dtype}, got {tuple(target.shape)} {target.dtype}"
        )
    check_tensor("blend_into weight", weight, ndim=1)
    if weight.shape != (3,):
        raise ValueError(f"blend_into weight must have shape (3,), got {tuple(weight.shape)}")
    check_writable("blend_into target", target, others)
    return target, weight


def _backend_for(
    image: torch.Tensor, rotation: Rotation | None, sample_weight: SampleWeight | None
) -> str:
    """The backend this pass runs on (see :func:`backend`)."""
    name = get_backend()
    if name == "gl":
        if sample_weight is not None:
            raise ValueError(
                "the gl backend has no shader for sample_weight (halo reduction's bilateral "
                "weight is a Python function): run it on backend 'native' or 'torch'"
            )
        return "gl"
    if rotation is not None or sample_weight is not None:
        return "torch"  # rotated taps and bilateral weights: torch loop only
    if name != "native":
        return name
    if image.device.type != "cpu" or native.library_for(image.dtype) is None:
        return "torch"
    return "native"


def blend_on_stencil(
    out: torch.Tensor, end: torch.Tensor, weight: torch.Tensor, mask: torch.Tensor | None
) -> torch.Tensor:
    """``out ← lerp(out, end, weight)`` on the pixels with ``mask > 0`` (every pixel without a
    mask), in place: the sum-of-Gaussians blend of a blurred step into the result (003
    §7.3.3, Listing 7.2), on the stencil's pixels only.

    Args:
        out: ``(B, 3, H, W)`` contiguous, overwritten at the active pixels (its version counter
            is bumped on every backend).
        end: ``(B, 3, H, W)`` the blurred step.
        weight: ``(3,)`` per-channel blend weight.
        mask: ``(B, 1, H, W)`` stencil or ``None``.

    Returns:
        ``out``. With the native backend (no gradient needed) a C loop over the stencil's
        runs (``torch.ops.sssbench.blend_``); otherwise ``torch.lerp`` at the stencil's indices
        (the two agree to a rounding: torch fuses the multiply-add).
    """
    b_, c_, h_, w_ = out.shape
    weight = weight.to(dtype=out.dtype, device=out.device)
    grads = torch.is_grad_enabled() and any(t.requires_grad for t in (out, end, weight))
    if not grads and out.is_contiguous() and _backend_for(out, None, None) == "native":
        with memo_scope():
            torch.ops.sssbench.blend_(out, end, weight, mask)
        return out
    stencils = [None] * b_ if mask is None else image_stencils(mask)
    for bi, lin in enumerate(stencils):
        flat, blurred = out[bi].view(c_, -1), end[bi].reshape(c_, -1)
        if lin is None:
            flat.copy_(torch.lerp(flat, blurred, weight.view(c_, 1)))
        else:
            flat[:, lin] = torch.lerp(flat[:, lin], blurred[:, lin], weight.view(c_, 1))
    return out

"""The native tap loop as torch operators: ``torch.ops.sssbench.gather`` (a new tensor) and
``torch.ops.sssbench.gather_`` (in place), plus ``torch.ops.sssbench.blend_`` (the
sum-of-Gaussians blend on the stencil, in place).

Registered with :func:`torch.library.custom_op`, so that the dispatcher treats the C loop like
any torch kernel:

- the in-place forms declare ``mutates_args``: every write bumps the tensor's version counter
  as a torch in-place op does, so autograd raises on a saved tensor the pass overwrote instead
  of computing a wrong gradient;
- ``register_fake`` gives the output's shape, so ``torch.compile(fullgraph=True)`` traces a
  module that calls the op without a graph break (``separable_pass`` itself validates its
  inputs with data-dependent checks, e.g. ``width >= 0``, which break a graph: a compiled
  module calls the operator with validated inputs);
- ``register_autograd`` gives ``gather`` a backward: the vector-Jacobian product of the torch
  loop (:func:`~sssbench.ops._gather_torch.gather_torch`), recomputed inside backward from the
  saved inputs and differentiated by autograd (the loop is a gather, its adjoint a scatter-add
  of the same taps; recomputing costs one torch-loop forward per backward and keeps one
  specification instead of a second hand-written adjoint). First-order only: the backward
  itself is not differentiable (no double backward).

Without the C library (no compiler, failed load) the operators run the torch loop, so they work
everywhere; :mod:`sssbench.ops.gather` decides which backend a pass uses.
"""

from __future__ import annotations

import ctypes

import numpy as np
import torch

from sssbench.ops import native
from sssbench.ops._gather_torch import gather_torch
from sssbench.ops._stencil import image_spans

__all__ = [
    "gather", "gather_", "blend_", "native_pass", "run_pass", "weights_overflow", "MAX_SETS",
]  # fmt: skip

#: most weight sets of one sweep (``MAX_SETS`` in ``native/gather_body.h``)
MAX_SETS = 16

Tensor = torch.Tensor


#: the schema's arguments after ``image``, in :func:`~sssbench.ops._gather_torch.gather_torch`'s
#: order (see there for shapes and units)
_PASS_ARGS = (
    "Tensor depth, Tensor? strength, Tensor? width, Tensor? ddepth, Tensor offsets, "
    "Tensor weights, Tensor inv_scale, float f_px, float width_scalar, float correction, "
    "float maxdd, bool axis_y, int follow"
)
_N_TENSORS = 8  # image and the seven tensors above: what the backward differentiates


def weights_overflow(weights: Tensor, dtype: torch.dtype) -> ValueError:
    """The error for kernel ``weights`` that are not finite in the pass's ``dtype``."""
    return ValueError(
        f"kernel.weights overflow {dtype} (largest |weight| "
        f"{float(weights.detach().abs().max()):g}): use float64 or normalise the kernel"
    )


def native_pass(
    lib: object,
    image: Tensor,
    out: Tensor,
    args: tuple,
    copy: bool,
    blend: tuple[Tensor, Tensor] | None = None,
    sets: tuple[bool, Tensor | None] | None = None,
    inactive: Tensor | None = None,
    inactive_to: Tensor | None = None,
) -> int:
    """One pass over a batch through the C loop (``native/gather_body.h``); the active pixel
    count. ``args``: the arguments after ``image`` of
    :func:`~sssbench.ops._gather_torch.gather_torch`, but for the taps: ``offsets``,
    ``weights`` and ``inv_scale`` may be of any float dtype (the kernel's own, float64 as a
    rule; ``inv_scale`` also a sequence of 3 floats, 1 / surface_scale), and the C loop
    converts them to ``image``'s dtype as :func:`~sssbench.ops.gather.separable_pass` does for
    the torch loop (bitwise the same values; ``ValueError`` when a weight overflows it).
    ``out`` ``(B, 3, H, W)`` contiguous may be ``image`` (the loop reads every sample of a row
    (x) or column strip (y) into its own buffer before it writes any result there); ``copy``:
    ``out`` is uninitialised and gets ``image``'s pixels everywhere else (copied line by line
    as the loop goes, no separate full-image pass). Threads: ``torch.get_num_threads()``, at
    most one per 16384 pixels of work (see :mod:`sssbench.ops.gather`).

    ``blend``: ``(target, weight)`` or ``None``: ``target`` ``(B, 3, H, W)`` contiguous in
    ``image``'s dtype, sharing no memory with the pass's tensors, and ``weight`` ``(3,)``;
    every result the pass writes is also blended into ``target`` at the same pixel,
    ``target ← lerp(target, result, weight)`` (the sum of Gaussians' blend, 003 §7.3.3, fused
    into its step's last pass: bitwise ``torch.ops.sssbench.blend_(target, out, weight,
    mask)`` after the pass, without reading ``out`` back).

    ``sets``: ``None`` (one pass, ``weights (K, 3)``) or ``(fan_in, coefficients)``, the
    sweep of ``S`` weight sets over the same offsets (``weights (S, K, 3)``, at most
    :data:`MAX_SETS`; see :func:`sweep_torch`, its specification): ``fan_in=False``:
    ``image (B, 3, H, W)`` and ``out (S, B, 3, H, W)``, set ``s``'s pass into ``out[s]``;
    ``fan_in=True`` (``copy`` False): ``image (S, B, 3, H, W)``, ``out (B, 3, H, W)`` gets
    ``Σ_s coefficients[s] · pass_s(image[s])`` at the active pixels (``coefficients (S, 3)``).
    Stacked tensors must be contiguous. ``inactive``: ``None`` or, for a fan-in, a
    ``(B, 3, H, W)`` image taken as every set's input at the inactive pixels (the taps' samples
    there), whatever ``image`` holds there; it may be ``out`` (a fan-in writes only active
    pixels). ``inactive_to``: ``None`` or, not for a fan-in, a contiguous ``(B, 3, H, W)``
    tensor of ``image``'s dtype sharing no memory with the pass's tensors, which gets
    ``image``'s inactive pixels (copied line by line by the pass's threads as their lines
    come); its active pixels are not written.

    Tensors already contiguous in the right dtype (the rule) are passed by address, image by
    image, without a torch call: on a far-away object the fixed cost of a pass is what its
    time is made of."""
    depth, strength, width, ddepth, offsets, weights, inv_scale, *scalars = args
    f_px, width_scalar, correction, maxdd, axis_y, follow = scalars
    nsets, set_stride, fan_in, coef = 1, 0, 0, None
    if sets is not None:
        nsets, fan_in = weights.shape[0], int(sets[0])
        stacked = image if fan_in else out
        if not stacked.is_contiguous():
            raise ValueError("the stacked images of a sweep must be contiguous")
        set_stride = stacked.stride(0)
        image, out = (image[0], out) if fan_in else (image, out[0])
    b, _, h, w = image.shape
    dtype = image.dtype
    keep = []  # converted copies and ctypes arrays must outlive the call

    def planes(t: Tensor | None, want: torch.dtype = dtype) -> tuple[int | None, int]:
        """(address of image 0, bytes from one image to the next) of ``t`` in ``want``."""
        if t is None:
            return None, 0
        if t.dtype != want or not t.is_contiguous():
            t = t.detach().to(want).contiguous()
            keep.append(t)
        return t.data_ptr(), t.stride(0) * t.element_size()

    def f64(t: Tensor | tuple[float, ...]) -> int:
        if isinstance(t, Tensor):
            return planes(t, torch.float64)[0]
        keep.append(arr := (ctypes.c_double * len(t))(*t))
        return ctypes.addressof(arr)

    fn = lib.sss_gather_f32 if dtype == torch.float32 else lib.sss_gather_f64
    if out.dtype != dtype or not out.is_contiguous():
        raise ValueError(f"out must be contiguous {dtype}, got {out.dtype} strides {out.stride()}")
    if inactive is not None and (not fan_in or inactive.shape != out.shape):
        raise ValueError("inactive is for a fan-in sweep, of the result's shape")
    if inactive_to is not None and (
        fan_in or inactive_to.shape != image.shape or inactive_to.dtype != dtype
        or not inactive_to.is_contiguous()
    ):  # fmt: skip
        raise ValueError("inactive_to is for a pass or fan-out, contiguous of the image's shape")
    fields = [planes(t) for t in (image, depth, strength, width, ddepth, out, inactive,
                                  inactive_to)]  # fmt: skip
    taps = (f64(offsets), f64(weights), f64(inv_scale))
    if fan_in:
        coef = f64(sets[1])
    target, blend_w = (None, 0), None
    if blend is not None:
        if blend[0].dtype != dtype or not blend[0].is_contiguous():
            raise ValueError("the blend target must be contiguous in the image's dtype")
        target = planes(blend[0])
        blend_w = planes(blend[1].reshape(3))[0]
    n_total = 0
    threads = torch.get_num_threads()
    for bi, spans in enumerate(image_spans(strength, (b, h, w))):
        src, z, mask, wid, dd, dst, rest, rest_to = (
            None if p is None else p + bi * step for p, step in fields
        )
        status = fn(
            src, z, spans.data_ptr(), mask, wid, dd, *taps, dst, f_px, width_scalar, correction,
            maxdd, spans.shape[0], offsets.numel(), h, w, int(axis_y), follow, int(copy), threads,
            None if target[0] is None else target[0] + bi * target[1], blend_w,
            nsets, set_stride, fan_in, coef, rest, rest_to,
        )  # fmt: skip
        if status == -3:
            raise ValueError(f"native gather: {nsets} weight sets (at most {MAX_SETS}, no blend)")
        if status == -2:
            raise weights_overflow(weights, dtype)
        if status < 0:
            raise MemoryError(f"native gather: no memory for the line buffers of a {h}x{w} image")
        n_total += status
    return n_total


def serial_copy(image: Tensor) -> Tensor:
    """A contiguous copy of ``image`` made on the calling thread alone, for a tensor a native
    pass writes next (the 12-pass sum of Gaussians' blend target, whose inactive pixels are
    the image's; the fused sweep's new result was one until its x sweep filled that result's
    inactive pixels itself, ``separable_sweep(..., inactive_into=)``). torch's ``clone`` of a large
    tensor runs on its OpenMP threads, which then spin for milliseconds waiting for more work,
    on the core the native pass's second thread needs: measured 0.91x the wall time of the
    1080p ``sum_of_gaussians_fused`` call with this copy instead (21 interleaved rounds,
    issue 30; the 12-pass schedule's call 0.96-1.03x in three runs of 21 rounds: not
    resolved, its one copy is amortised over 12 passes). ``clone`` where autograd must see
    the copy (``image`` requires a gradient)."""
    if image.requires_grad or image.device.type != "cpu":
        return image.clone(memory_format=torch.contiguous_format)
    return torch.from_numpy(np.array(image.numpy(), order="C", copy=True))


def run_pass(
    image: Tensor, args: tuple, inplace: bool, blend: tuple[Tensor, Tensor] | None = None
) -> tuple[Tensor, int]:
    """One gather pass over a batch without autograd: ``(result, active pixel count)``.

    ``inplace``: the result is written into ``image`` (contiguous, overlapping no other
    argument: :func:`~sssbench.ops.gather.check_writable`), only the active pixels touched;
    otherwise a new ``(B, 3, H, W)`` contiguous tensor, the active pixels blurred and the
    others ``image``'s. ``args`` as :func:`~sssbench.ops._gather_torch.gather_torch`'s after
    ``image`` (validated by :func:`~sssbench.ops.gather.separable_pass`, the public entry;
    with the C library the taps may also come as :func:`native_pass` takes them). The torch
    loop without the C library. Bumps no version counter: the operators below
    (and :func:`~sssbench.ops.gather.separable_pass` when it calls this directly) do.
    ``blend``: see :func:`native_pass` (the C library is required for it)."""
    lib = native.library_for(image.dtype)
    if lib is None:
        with torch.no_grad():
            return gather_torch(image, *args, out=image if inplace else None)
    out = image if inplace else torch.empty(image.shape, dtype=image.dtype, device=image.device)
    return out, native_pass(lib, image, out, args, copy=not inplace, blend=blend)


def _gather(image: Tensor, *args) -> Tensor:
    """``torch.ops.sssbench.gather``: :func:`run_pass`, a new tensor."""
    return run_pass(image, args, inplace=False)[0]


def _gather_inplace(image: Tensor, *args) -> None:
    """``torch.ops.sssbench.gather_``: :func:`run_pass` in place. Bumps ``image``'s version
    counter (``mutates_args``). No autograd: not for a tensor autograd records."""
    run_pass(image, args, inplace=True)


gather = torch.library.custom_op(
    "sssbench::gather", _gather, mutates_args=(), device_types="cpu",
    schema=f"(Tensor image, {_PASS_ARGS}) -> Tensor",
)  # fmt: skip
gather_ = torch.library.custom_op(
    "sssbench::gather_", _gather_inplace, mutates_args=("image",), device_types="cpu",
    schema=f"(Tensor(a!) image, {_PASS_ARGS}) -> ()",
)  # fmt: skip


@gather.register_fake
def _(image, *args):
    return torch.empty(image.shape, dtype=image.dtype, device=image.device)


@gather_.register_fake
def _(image, *args) -> None:
    return None


def _setup_context(ctx, inputs, output) -> None:
    ctx.save_for_backward(*inputs[:_N_TENSORS])
    ctx.scalars = inputs[_N_TENSORS:]


def _backward(ctx, grad_out: Tensor):
    """The vector-Jacobian product of the torch loop at the saved inputs (see the module
    docstring): gradients for the eight tensor inputs, ``None`` for the scalars."""
    saved = ctx.saved_tensors
    needs = ctx.needs_input_grad[:_N_TENSORS]
    with torch.enable_grad():
        leaves = [
            None if t is None else t.detach().requires_grad_(bool(n) and t.is_floating_point())
            for t, n in zip(saved, needs, strict=True)
        ]
        out, _ = gather_torch(*leaves, *ctx.scalars)
        wrt = [t for t in leaves if t is not None and t.requires_grad]
        grads = iter(torch.autograd.grad(out, wrt, grad_out, allow_unused=True) if wrt else ())
    result = [next(grads) if t is not None and t.requires_grad else None for t in leaves]
    return (*result, *([None] * len(ctx.scalars)))


gather.register_autograd(_backward, setup_context=_setup_context)


def _blend(out: Tensor, end: Tensor, weight: Tensor, mask: Tensor | None) -> None:
    """``torch.ops.sssbench.blend_``: ``out ← lerp(out, end, weight)`` at the pixels with
    ``mask > 0`` (all without a mask), in place (bumps ``out``'s version): the
    sum-of-Gaussians blend (003 §7.3.3, Listing 7.2) in C, torch.lerp's formula with a
    separate multiply and add (torch fuses them: the two agree to a rounding).

    ``out``, ``end``: ``(B, 3, H, W)`` (``out`` contiguous); ``weight``: ``(3,)`` of their
    dtype; ``mask``: ``(B, 1, H, W)`` or ``None``. Needs the C library of their dtype
    (:func:`~sssbench.ops.native.library_for`)."""
    lib = native.library_for(out.dtype)
    b, _, h, w = out.shape
    fn = lib.sss_blend_f32 if out.dtype == torch.float32 else lib.sss_blend_f64
    end = end.contiguous()
    weight = weight.to(out.dtype).contiguous()
    for bi, spans in enumerate(image_spans(mask, (b, h, w))):
        if spans.shape[0]:
            fn(out[bi].data_ptr(), end[bi].data_ptr(), spans.data_ptr(), weight.data_ptr(),
               spans.shape[0], h, w, torch.get_num_threads())  # fmt: skip


blend_ = torch.library.custom_op(
    "sssbench::blend_", _blend, mutates_args=("out",), device_types="cpu",
    schema="(Tensor(a!) out, Tensor end, Tensor weight, Tensor? mask) -> ()",
)  # fmt: skip


@blend_.register_fake
def _(out, end, weight, mask) -> None:
    return None

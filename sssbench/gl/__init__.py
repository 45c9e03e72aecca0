"""``sssbench.gl``: the separable methods and the disk as GLSL fragment shaders on a headless
OpenGL context.

The passes are GLSL 330 fragment shaders with ``SeparableSSS.h`` semantics
(:mod:`sssbench.gl.shaders`, 002 appendix ``SSSSBlurPS``), and the disk
(:class:`~sssbench.ops.DiskSSS`, both estimators; HDRP's ``SubsurfaceScattering.compute``) is
one fragment shader (:mod:`sssbench.gl.disk_shader`), run by moderngl on an EGL context:
Mesa's llvmpipe on a machine without a GPU, the GPU's own driver where there is one. Float32
textures throughout (RGBA32F colour, R32F depth / mask / width, RG32F rotation).

Two ways in:

- :func:`run_method` runs a built method's whole pass schedule on the device (textures stay
  there between passes) and returns the image, per-pass ``GL_TIME_ELAPSED`` times (median of
  repeats after warm-up) and the renderer — what a renderer pays for the passes;
- ``with sssbench.backend("gl"):`` makes every :func:`~sssbench.ops.separable_pass` run its
  pass as the GL shader (upload, draw, read back), so any method or pipeline built on the
  gather primitive computes its blur passes on GL, and every :class:`~sssbench.ops.DiskSSS`
  its disk (the two are registered with :mod:`sssbench.ops.pass_backends`).

No context (no moderngl, no EGL): :class:`GLUnavailable`, one line naming what to install;
never a silent fall-back to torch. :func:`available` asks without raising.
"""

from __future__ import annotations

import statistics
from typing import NamedTuple

import torch

from sssbench.gbuffer import GBuffer
from sssbench.gl._context import (
    INSTALL_HINT,
    LLVMPIPE_NOTE,
    GLContext,
    GLUnavailable,
    available,
    get_context,
)
from sssbench.gl._disk import (
    DISK_GEOMETRIES,
    disk_geometry,
    disk_pass,
    disk_schedule,
    disk_specs,
    set_disk_geometry,
)
from sssbench.gl._run import Frame, GLMethodError, make_frame, pass_spec, schedule
from sssbench.gl.shaders import PassShader, pass_source
from sssbench.ops.pass_backends import register_pass_backend
from sssbench.ops.timing import PassRecord

__all__ = [
    "available",
    "get_context",
    "context",
    "GLContext",
    "GLUnavailable",
    "GLMethodError",
    "GLRun",
    "run_method",
    "gather_pass",
    "run_pass_sources",
    "renderer_info",
    "DISK_GEOMETRIES",
    "disk_geometry",
    "set_disk_geometry",
    "pass_source",
    "PassShader",
    "INSTALL_HINT",
    "LLVMPIPE_NOTE",
    "TIMING_SEMANTICS",
]

#: what a GL pass time is (docs/gl.md)
TIMING_SEMANTICS = (
    "GPU time of each draw from a GL_TIME_ELAPSED query (glBeginQuery / glEndQuery around the "
    "full-screen triangle of the pass), textures resident on the device, after warm-up draws; "
    "median over repeats. Uploads and read-back are not included."
)


def context() -> GLContext:
    """The process's GL context (:class:`GLUnavailable` when there is none)."""
    return get_context()


def renderer_info() -> dict[str, object]:
    """``{"renderer": GL_RENDERER, "version": GL_VERSION, "vendor", "software": bool, "note"}``;
    ``note`` says when the times are a software rasteriser's (llvmpipe)."""
    return get_context().info


class GLRun(NamedTuple):
    """The result of :func:`run_method`.

    Attributes:
        image: ``(B, 3, H, W)`` in the G-buffer's dtype (computed in float32).
        pass_times_ms: pass name -> median GL time (ms) over the repeats, in pass order
            (summed over the batch's images); empty with ``repeats=0``.
        renderer: :func:`renderer_info`.
        passes: one :class:`~sssbench.ops.timing.PassRecord` per pass (name, taps, pixels the
            pass computed, the median GL ms), as the CPU runs record them.
        repeats: per timed repeat, its :class:`~sssbench.ops.timing.PassRecord` list (GL ms of
            that repeat): what ``sssbench.run.runner.pass_stats`` takes for median / min / max.
    """

    image: torch.Tensor
    pass_times_ms: dict[str, float]
    renderer: dict[str, object]
    passes: list[PassRecord]
    repeats: list[list[PassRecord]]


def _pixels(method, gbuffer: GBuffer, name: str) -> int:
    """Pixels a pass computes: the stencil's, under the sum of Gaussians' LOD for its passes."""
    import math

    from sssbench.ops import SumOfGaussiansSSS

    mask = gbuffer.mask_or_ones()
    if isinstance(method, SumOfGaussiansSSS) and name.startswith("sog") and method.lod:
        i = int(name[3:].split(".")[0])
        step = method.steps[i]
        if name.endswith(".x") or name.endswith(".y") or name.endswith(".blend"):
            mask = method._lod_mask(gbuffer, math.sqrt(step.increment))
    if name.endswith(".sum"):
        return int(mask.numel())
    return int((mask > 0).sum())


def run_method(
    method: torch.nn.Module,
    gbuffer: GBuffer,
    *,
    width: torch.Tensor | None = None,
    repeats: int = 5,
    warmup: int = 2,
    hardware_filter: bool = False,
) -> GLRun:
    """Run ``method``'s pass schedule on the GL device; image, per-pass GL times, renderer.

    Covered: :class:`~sssbench.ops.PreintegratedSSS`, :class:`~sssbench.ops.Jimenez2012SSS`,
    :class:`~sssbench.ops.ArtistSSS`, :class:`~sssbench.ops.LowRankSSS` (rank-N passes, summed
    by additive blending) and :class:`~sssbench.ops.SumOfGaussiansSSS` (blur passes, 003
    Listing 7.2's blend state, LOD, JG10 stretch), each with its follow-surface mode,
    stochastic rotation, and the mask as stencil and strength; :class:`~sssbench.ops.DiskSSS`
    (one ``disk`` draw per frame and profile, :mod:`sssbench.gl.disk_shader`). Halo
    reduction and the disk's ``adaptive`` are refused (:class:`GLMethodError`).

    Args:
        method: a built method (e.g. :func:`sssbench.run.registry.build_method`).
        gbuffer: the G-buffer (float32 or float64; the passes compute in float32).
        width: per-pixel width multiplier ``(B, 1, H, W)`` (curvature modulation), or ``None``.
        repeats: timed runs of the whole schedule (0: one untimed run).
        warmup: untimed runs before them (program compilation, driver caches).
        hardware_filter: fetch the taps with ``texture()`` and the texture unit's
            ``GL_LINEAR`` filter, as ``SSSSBlurPS`` does, instead of the float32 lerp of two
            texels (a GPU's 8-bit sub-texel weights then differ from torch by ~1e-3; llvmpipe
            filters float textures in float).

    Returns:
        :class:`GLRun`. How a run records it: ``passes`` in place of the CPU pass records,
        ``renderer["renderer"]`` / ``["version"]`` beside the times, ``renderer["note"]``
        (the llvmpipe caveat) in the report; for the disk ``renderer["disk_geometry"]``,
        the precision its shader formed the sample geometry in (:func:`disk_geometry`).

    Raises:
        GLUnavailable: no GL context (one line naming what to install).
        GLMethodError: a method or option without a GL schedule.
    """
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    glc = get_context()
    fn = _schedule(method)
    info = glc.info
    if fn is disk_schedule:
        info = {**info, "disk_geometry": disk_geometry()}
    b = gbuffer.diffuse.shape[0]
    images = []
    per_pass: dict[str, list[float]] = {}
    samples: dict[str, int] = {}
    with torch.no_grad():
        for bi in range(b):
            frame = make_frame(glc, gbuffer, bi, method, width, None)
            frame.hardware_filter = hardware_filter
            try:
                out = fn(frame, method, gbuffer, width is not None)
                images.append(glc.read(out))
                for _ in range(warmup):
                    fn(frame, method, gbuffer, width is not None)
                for r in range(repeats):
                    frame.timings = []
                    fn(frame, method, gbuffer, width is not None)
                    for name, k, ns in frame.timings:
                        lst = per_pass.setdefault(name, [0.0] * repeats)
                        lst[r] += ns / 1e6
                        samples[name] = k
            finally:
                _release(frame)
    image = torch.stack(images).to(dtype=gbuffer.dtype, device=gbuffer.device)
    times = {name: statistics.median(v) for name, v in per_pass.items()}
    pixels = {name: _pixels(method, gbuffer, name) for name in times}
    records = [PassRecord(name, samples[name], pixels[name], ms) for name, ms in times.items()]
    per_repeat = [
        [PassRecord(name, samples[name], pixels[name], v[r]) for name, v in per_pass.items()]
        for r in range(repeats)
    ]
    return GLRun(image, times, info, records, per_repeat)


def _schedule(method):
    """The GL schedule of ``method``: the disk's (:mod:`sssbench.gl._disk`, refusing an option
    without a shader by name) or a separable method's (:func:`sssbench.gl._run.schedule`)."""
    from sssbench.ops import DiskSSS

    if isinstance(method, DiskSSS):
        disk_specs(method)  # every profile's shader exists (and the geometry is available)
        return disk_schedule
    return schedule(method)


def _release(frame: Frame) -> None:
    for fb in frame._fbos.values():
        fb.release()
    for tex in frame.textures.values():
        tex.release()


def gather_pass(
    image: torch.Tensor,
    kernel,
    direction: str,
    gbuffer: GBuffer,
    *,
    strength: torch.Tensor | None,
    width: torch.Tensor | float,
    follow_surface: str | None,
    surface_scale,
    stretch,
    rotation,
    out: torch.Tensor | None = None,
) -> tuple[torch.Tensor, int]:
    """One :func:`~sssbench.ops.separable_pass` on GL (the ``"gl"`` backend's dispatch):
    upload, one draw of the pass shader per image, read back. ``(out, active pixels)``."""
    glc = get_context()
    b, _, h, w = image.shape
    per_pixel = isinstance(width, torch.Tensor)
    radius = None if rotation is None else rotation.radius * kernel.extent
    spec = pass_spec(
        kernel, direction, width=1.0 if per_pixel else float(width),
        width_texture=per_pixel, follow_surface=follow_surface, surface_scale=surface_scale,
        stretch=stretch, rotation_radius=radius,
    )  # fmt: skip
    ones = None
    results = []
    for bi in range(b):
        if strength is None:
            ones = ones if ones is not None else torch.ones(1, h, w)
        frame = Frame(
            glc,
            image[bi].detach(),
            gbuffer.depth[bi],
            ones if strength is None else strength[bi],
            gbuffer.fov_y,
            width[bi] if per_pixel else None,
            None if rotation is None else rotation.angles[bi],
        )
        try:
            dst = frame.target("out")
            frame.blur(spec, frame.textures["color"], dst)
            results.append(glc.read(dst))
        finally:
            _release(frame)
    res = torch.stack(results).to(dtype=image.dtype, device=image.device)
    n_total = b * h * w if strength is None else int((strength > 0).sum())
    if out is None:
        return res, n_total
    out.copy_(res)
    return out, n_total


def run_pass_sources(
    passes: list[tuple[str, str]],
    gbuffer: GBuffer,
    *,
    width: torch.Tensor | None = None,
    rotation: torch.Tensor | None = None,
) -> torch.Tensor:
    """Run pass shaders given as source text one after the other on ``gbuffer.diffuse``: each
    ``(source, axis)`` with ``axis`` ``"x"`` or ``"y"`` reads the previous pass's output — e.g.
    the file ``sssbench-export-kernel --format glsl-pass`` wrote
    (:func:`sssbench.export.split_passes`) for a two-pass method: ``[(src, "x"), (src, "y")]``.

    Args:
        passes: ``(source, axis)`` pairs (:func:`~sssbench.gl.shaders.pass_source` sources).
        gbuffer: the G-buffer (depth, mask, fov).
        width: per-pixel width ``(B, 1, H, W)`` for ``SSSS_WIDTH_TEXTURE`` passes.
        rotation: per-pixel angles ``(B, 1, H, W)`` for ``SSSS_ROTATION`` passes.

    Returns:
        ``(B, 3, H, W)`` in the G-buffer's dtype.
    """
    glc = get_context()
    out = []
    for bi in range(gbuffer.diffuse.shape[0]):
        frame = Frame(
            glc, gbuffer.diffuse[bi], gbuffer.depth[bi], gbuffer.mask_or_ones()[bi],
            gbuffer.fov_y, None if width is None else width[bi],
            None if rotation is None else rotation[bi],
        )  # fmt: skip
        try:
            src, names = frame.textures["color"], ("a", "b")
            for i, (source, axis) in enumerate(passes):
                dst = frame.target(names[i % 2])
                frame.blur_source(source, 0 if axis == "x" else 1, src, dst)
                src = dst
            out.append(glc.read(src))
        finally:
            _release(frame)
    return torch.stack(out).to(dtype=gbuffer.dtype, device=gbuffer.device)


# the gather dispatches `backend("gl")` passes here without importing this package (it sits
# above the operators: docs/architecture.md)
register_pass_backend("gl", get_context, gather_pass, disk_pass=disk_pass)

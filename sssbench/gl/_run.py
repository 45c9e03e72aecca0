"""Methods' pass schedules on the GL device: textures stay on the device from the first pass to
the last, each draw optionally timed with a ``GL_TIME_ELAPSED`` query."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from sssbench.gbuffer import GBuffer
from sssbench.gl._context import GLContext, get_context
from sssbench.gl.shaders import BLEND_SOURCE, COMPOSITE_SOURCE, FOLLOW_MODES, PassShader
from sssbench.gl.shaders import pass_source as _pass_source
from sssbench.kernels.kernel1d import Kernel1D

__all__ = ["PassSpec", "pass_spec", "Frame", "schedule", "GLMethodError"]


#: blend factors moderngl has no name for (GL 1.4 core, glext.h)
GL_CONSTANT_COLOR = 0x8001
GL_ONE_MINUS_CONSTANT_COLOR = 0x8002


class GLMethodError(ValueError):
    """A method or option the GL backend does not run (named in the message)."""


@dataclass(frozen=True)
class PassSpec:
    """A blur pass: its baked shader (:class:`~sssbench.gl.shaders.PassShader`) and axis."""

    shader: PassShader
    axis: int
    name: str = "pass"
    samples: int = 0

    def source(self, header: tuple[str, ...] = ()) -> str:
        return _pass_source(self.shader, header)


def _follow_factor(surface_scale: float | torch.Tensor | None) -> tuple[float, float, float]:
    """``(3,)`` 1 / surface_scale as the pass computes it in float32 (0: unused)."""
    from sssbench.ops.gather import _inverse_scale

    return tuple(float(v) for v in _inverse_scale(surface_scale, torch.float32).tolist())


def kernel_taps(kernel: Kernel1D) -> tuple[list[tuple[float, float, float, float]], bool, list]:
    """The kernel's taps ``(r, g, b, offset)`` as float32 values in the shader's order (centre
    first, :func:`sssbench.export.shader_order`), whether the first is the centre, and the
    float32 offsets in that order."""
    from sssbench.gl.shaders import shader_order
    from sssbench.ops.gather import _taps

    offsets, weights = _taps(kernel, torch.float32)
    order, centred = shader_order(kernel)
    off = offsets.tolist()
    wts = weights.tolist()
    taps = [(*wts[j], off[j]) for j in order]
    return taps, centred, [off[j] for j in order]


def pass_spec(
    kernel: Kernel1D,
    axis: str,
    *,
    width: float = 1.0,
    width_texture: bool = False,
    follow_surface: str | None = None,
    surface_scale: float | torch.Tensor | None = None,
    stretch=None,
    rotation_radius: float | None = None,
    lod: tuple[float, float] | None = None,
    inactive_scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
    hardware_filter: bool = False,
    name: str = "pass",
) -> PassSpec:
    """The :class:`PassSpec` of one ``separable_pass``-equivalent blur.

    Args:
        kernel: taps (offsets in mm per ``width``).
        axis: ``"x"`` or ``"y"``.
        width: mm per offset unit (the 2012 kernel's ``width``; 1 otherwise).
        width_texture: ``width`` is multiplied by a per-pixel texture (curvature).
        follow_surface, surface_scale: as ``separable_pass``.
        stretch: a :class:`~sssbench.ops.Stretch` or ``None``.
        rotation_radius: the rotated taps' radius in offset units (``radius · extent``), or
            ``None`` for no rotation.
        lod: ``(σ · ssslevel mm, threshold px)`` of the sum of Gaussians' LOD, or ``None``.
        inactive_scale: colour factor at pixels not computed.
        hardware_filter: fetch with ``texture()`` (see :mod:`sssbench.gl.shaders`).
    """
    taps, centred, offsets = kernel_taps(kernel)
    rotated: tuple[bool, ...] = ()
    if rotation_radius is not None:
        rotated = tuple(abs(o) <= rotation_radius for o in offsets)
    shader = PassShader(
        taps=tuple(tuple(t) for t in taps),
        centre_first=centred,
        rotated=rotated if any(rotated) else (),
        follow=FOLLOW_MODES[follow_surface],
        follow_factor=_follow_factor(surface_scale if follow_surface else None),
        width=float(width),
        stretch=None if stretch is None else (float(stretch.ssslevel),
                                              float(stretch.correction), float(stretch.maxdd)),
        width_texture=width_texture,
        lod=lod,
        inactive_scale=tuple(float(v) for v in inactive_scale),
        hardware_filter=hardware_filter,
    )  # fmt: skip
    return PassSpec(shader, 0 if axis == "x" else 1, name, len(kernel))


@dataclass
class Frame:
    """One G-buffer image's textures on the device and the draws of a schedule.

    ``timings``: when set to a list, each draw appends ``(name, samples, ns)`` from a
    ``GL_TIME_ELAPSED`` query around it.
    """

    glc: GLContext
    diffuse: torch.Tensor  # (3, H, W)
    depth: torch.Tensor  # (1, H, W)
    strength: torch.Tensor  # (1, H, W)
    fov_y: float = 0.5
    width_map: torch.Tensor | None = None  # (1, H, W)
    rotation: torch.Tensor | None = None  # (1, H, W) angles
    timings: list | None = None
    #: fetch taps with texture() / GL_LINEAR in every blur pass (see sssbench.gl.shaders)
    hardware_filter: bool = False
    textures: dict[str, object] = field(default_factory=dict)
    _fbos: dict[int, object] = field(default_factory=dict)
    #: (1, H, W) int per-pixel profile index (the disk with a list of profiles), or None
    profile_id: torch.Tensor | None = None

    def __post_init__(self) -> None:
        g = self.glc
        _, self.h, self.w = self.diffuse.shape
        t = self.textures
        t["color"] = g.texture(self.diffuse)
        t["depth"] = g.texture(self.depth)
        t["strength"] = g.texture(self.strength)
        if self.width_map is not None:
            t["width"] = g.texture(self.width_map)
        if self.rotation is not None:
            a = self.rotation.to(torch.float32)
            t["rotation"] = g.texture(torch.cat([torch.cos(a), torch.sin(a)], 0))
        if self.profile_id is not None:  # small integers: exact in R32F
            t["profile_id"] = g.texture(self.profile_id.to(torch.float32))

    def target(self, name: str) -> object:
        """A named RGBA32F render target of the frame's size (made once)."""
        tex = self.textures.get(name)
        if tex is None:
            tex = self.textures[name] = self.glc.target(self.w, self.h)
        return tex

    def fbo(self, tex) -> object:
        fb = self._fbos.get(id(tex))
        if fb is None:
            fb = self._fbos[id(tex)] = self.glc.ctx.framebuffer(color_attachments=[tex])
        return fb

    def _bind(self, prog, units: dict[str, object]) -> None:
        for unit, (uniform, tex) in enumerate(units.items()):
            u = prog.get(uniform, None)
            if u is not None:
                tex.use(location=unit)
                u.value = unit

    def _run(self, prog, dst, name: str, samples: int) -> None:
        fb = self.fbo(dst)
        fb.use()
        if self.timings is None:
            self.glc.draw(prog)
            return
        q = self.glc.ctx.query(time=True)
        with q:
            self.glc.draw(prog)
        self.timings.append((name, samples, q.elapsed))

    def blur(self, spec: PassSpec, src, dst, *, additive: bool = False) -> None:
        """One blur pass ``src`` -> ``dst`` (``additive``: summed into ``dst`` by blending)."""
        if self.hardware_filter and not spec.shader.hardware_filter:
            spec = dataclasses.replace(
                spec, shader=dataclasses.replace(spec.shader, hardware_filter=True)
            )
        self.blur_source(
            spec.source(),
            spec.axis,
            src,
            dst,
            additive=additive,
            name=spec.name,
            samples=spec.samples,
        )

    def blur_source(
        self,
        source: str,
        axis: int,
        src,
        dst,
        *,
        additive: bool = False,
        name: str = "pass",
        samples: int = 0,
    ) -> None:
        """One draw of the pass shader ``source`` (:func:`~sssbench.gl.shaders.pass_source`,
        or the file ``sssbench-export-kernel --format glsl-pass`` wrote) ``src`` -> ``dst``."""
        prog = self.glc.program(source)
        t = self.textures
        units = {"colorTex": src, "depthTex": t["depth"], "strengthTex": t["strength"]}
        if "width" in t:
            units["widthTex"] = t["width"]
        if "rotation" in t:
            units["rotationTex"] = t["rotation"]
        self._bind(prog, units)
        focal = self.h / (2.0 * math.tan(self.fov_y / 2.0))
        for k, v in {"axis": int(axis), "focalPx": focal}.items():
            u = prog.get(k, None)
            if u is not None:
                u.value = v
        ctx = self.glc.ctx
        if additive:  # 000 eq. 2: the terms are summed (ROP blending ONE, ONE)
            ctx.enable(self.glc.moderngl.BLEND)
            ctx.blend_func = (self.glc.moderngl.ONE, self.glc.moderngl.ONE)
        try:
            self._run(prog, dst, name, samples)
        finally:
            if additive:
                ctx.disable(self.glc.moderngl.BLEND)

    def blend(
        self,
        src,
        dst,
        weight: tuple[float, float, float],
        lod: tuple[float, float] | None,
        name: str,
    ) -> None:
        """003 Listing 7.2: ``dst ← src · w' + dst · (1 − w')`` at the computed pixels."""
        mgl = self.glc.moderngl
        prog = self.glc.program(BLEND_SOURCE)
        t = self.textures
        self._bind(prog, {"colorTex": src, "depthTex": t["depth"], "strengthTex": t["strength"]})
        prog["useLod"].value = 0 if lod is None else 1
        if lod is not None:
            prog["lodWidth"].value, prog["lodThreshold"].value = lod
        ctx = self.glc.ctx
        ctx.enable(mgl.BLEND)
        ctx.blend_func = (GL_CONSTANT_COLOR, GL_ONE_MINUS_CONSTANT_COLOR)
        _blend_color(ctx, weight)
        try:
            self._run(prog, dst, name, 0)
        finally:
            ctx.disable(mgl.BLEND)

    def composite(self, sum_tex, dst, name: str) -> None:
        """Rank-N result: ``sum_tex`` where the stencil is set, the input elsewhere."""
        prog = self.glc.program(COMPOSITE_SOURCE)
        t = self.textures
        self._bind(prog, {"colorTex": t["color"], "sumTex": sum_tex, "strengthTex": t["strength"]})
        self._run(prog, dst, name, 0)

    def clear(self, tex) -> None:
        fb = self.fbo(tex)
        fb.use()
        fb.clear(0.0, 0.0, 0.0, 0.0)


def _blend_color(ctx, rgb: tuple[float, float, float]) -> None:
    """``glBlendColor`` (moderngl has no wrapper): through the context's GL function."""
    import ctypes

    fn = _gl_function("glBlendColor", ctypes.CFUNCTYPE(None, *(ctypes.c_float,) * 4))
    fn(*(float(v) for v in rgb), 1.0)


_GL_FUNCS: dict[str, object] = {}


def _gl_function(name: str, proto):
    fn = _GL_FUNCS.get(name)
    if fn is None:
        import ctypes
        import ctypes.util

        egl = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        addr = egl.eglGetProcAddress(name.encode())
        if not addr:
            raise RuntimeError(f"{name} not found through eglGetProcAddress")
        fn = _GL_FUNCS[name] = proto(addr)
    return fn


# ----------------------------------------------------------------------------- schedules
#: ``schedule(frame, method, gbuffer) -> result texture``
Schedule = Callable[[Frame, object, GBuffer], object]


def _rotation_radius(method, kernel: Kernel1D) -> float | None:
    return None if method.rotation is None else float(method.rotation) * kernel.extent


def _two_pass(
    frame: Frame, method, gbuffer: GBuffer, kernel: Kernel1D, name: str, width: float, wt: bool
) -> object:
    """000 eq. 2 with N = 1 (:func:`sssbench.ops.two_pass`): x then y."""
    opts = dict(
        follow_surface=method.follow_surface,
        surface_scale=method.surface_scale,
        width=width,
        width_texture=wt,
        rotation_radius=_rotation_radius(method, kernel),
    )
    sx = pass_spec(kernel, "x", name=f"{name}.x", **opts)
    sy = pass_spec(kernel, "y", name=f"{name}.y", **opts)
    a, b = frame.target("a"), frame.target("b")
    frame.blur(sx, frame.textures["color"], a)
    frame.blur(sy, a, b)
    return b


def _preintegrated(frame, method, gbuffer, wt):
    from sssbench.kernels.sampling import OPTIMISED
    from sssbench.kernels.sources import use_optimised

    if getattr(method, "sampling", None) == OPTIMISED and method.pixel_mm is None:
        use_optimised(method, gbuffer)
    return _two_pass(frame, method, gbuffer, method.kernel, "preintegrated", 1.0, wt)


def _artist(frame, method, gbuffer, wt):
    return _two_pass(frame, method, gbuffer, method.kernel, "artist", 1.0, wt)


def _jimenez2012(frame, method, gbuffer, wt):
    from sssbench.kernels.sampling import OPTIMISED
    from sssbench.kernels.sources import use_optimised

    if method.sampling == OPTIMISED and method.pixel_mm is None:
        use_optimised(method, gbuffer)
    return _two_pass(frame, method, gbuffer, method.kernel, "jimenez2012", float(method.width), wt)


def _low_rank(frame, method, gbuffer, wt):
    """000 eq. 2: Σ_i (E * a_i) * a'_i; inactive pixels carry ``E · Σ a_i`` between a term's
    passes (:class:`~sssbench.ops.LowRankSSS`)."""
    a, acc, out = frame.target("a"), frame.target("sum"), frame.target("b")
    frame.clear(acc)
    for i, (hk, vk) in enumerate(method.kernel.terms):
        h_sum = tuple(float(v) for v in hk.sum().to(torch.float32).tolist())
        opts = dict(
            follow_surface=method.follow_surface,
            surface_scale=method.surface_scale,
            width_texture=wt,
        )
        sx = pass_spec(
            hk,
            "x",
            name=f"low_rank{i}.x",
            inactive_scale=h_sum,
            rotation_radius=_rotation_radius(method, hk),
            **opts,
        )
        sy = pass_spec(
            vk,
            "y",
            name=f"low_rank{i}.y",
            rotation_radius=_rotation_radius(method, vk),
            **opts,
        )
        frame.blur(sx, frame.textures["color"], a)
        frame.blur(sy, a, acc, additive=True)
    frame.composite(acc, out, "low_rank.sum")
    return out


def _sum_of_gaussians(frame, method, gbuffer, wt):
    """003 §7.3: per Gaussian an x and a y pass on top of the previous one (RT1), blended into
    the result (RTF) with ``w'`` (Listing 7.2), each pass skipping pixels under the LOD width
    (§7.3.2), with the JG10 stretch (§7.3.1)."""
    from sssbench.kernels.sampling import OPTIMISED
    from sssbench.kernels.sources import use_optimised

    if method.sampling == OPTIMISED and method.pixel_mm is None:
        use_optimised(method, gbuffer)
    h, w, fov = frame.h, frame.w, gbuffer.fov_y
    color = frame.textures["color"]
    rtf = frame.target("rtf")
    # RTF starts as the input (the unblurred first Gaussian, w'_1 = 1)
    frame.glc.ctx.copy_framebuffer(frame.fbo(rtf), frame.fbo(color))
    rt1, pong = color, ("a", "b")
    k = 0
    for i, step in enumerate(method.steps):
        if step.kernel is None:
            continue
        sigma = math.sqrt(step.increment)
        level = 1.0 if method.stretch is None else float(method.stretch.ssslevel)
        lod = (sigma * level, method.lod_threshold) if method.lod else None
        opts = dict(
            follow_surface=method.follow_surface,
            surface_scale=method.surface_scale,
            width_texture=wt,
            lod=lod,
            rotation_radius=_rotation_radius(method, step.kernel),
        )
        # a pass along an axis of length 1 runs without the stretch (SumOfGaussiansSSS)
        sx = pass_spec(
            step.kernel,
            "x",
            name=f"sog{i}.x",
            stretch=method.stretch if w > 1 else None,
            **opts,
        )
        sy = pass_spec(
            step.kernel,
            "y",
            name=f"sog{i}.y",
            stretch=method.stretch if h > 1 else None,
            **opts,
        )
        tmp = frame.target("tmp")
        nxt = frame.target(pong[k % 2])
        frame.blur(sx, rt1, tmp)
        frame.blur(sy, tmp, nxt)
        lod_u = (
            None
            if lod is None
            else (sigma * level * h / (2.0 * math.tan(fov / 2.0)), method.lod_threshold)
        )
        frame.blend(nxt, rtf, tuple(float(v) for v in step.blend.tolist()), lod_u, f"sog{i}.blend")
        rt1 = nxt
        k += 1
    return rtf


def schedule(method) -> Schedule:
    """The GL schedule of ``method`` (:class:`GLMethodError` naming why when there is none)."""
    from sssbench.ops import (
        ArtistSSS,
        Jimenez2012SSS,
        LowRankSSS,
        PreintegratedSSS,
        SumOfGaussiansSSS,
    )

    table = [
        (PreintegratedSSS, _preintegrated),
        (Jimenez2012SSS, _jimenez2012),
        (ArtistSSS, _artist),
        (LowRankSSS, _low_rank),
        (SumOfGaussiansSSS, _sum_of_gaussians),
    ]
    for cls, fn in table:
        if isinstance(method, cls):
            if getattr(method, "halo", None) is not None:
                raise GLMethodError(
                    f"{cls.__name__}(halo={method.halo!r}): halo reduction's bilateral weight is "
                    "a Python function of the guide; the GL backend has no shader for it"
                )
            return fn
    raise GLMethodError(
        f"the GL backend has no schedule for {type(method).__name__}: it runs preintegrated, "
        "jimenez2012, artist, low_rank, sum_of_gaussians and disk"
    )


def make_frame(
    glc: GLContext | None, gbuffer: GBuffer, bi: int, method, width_map, timings
) -> Frame:
    """The textures of image ``bi`` of ``gbuffer`` for ``method``."""
    from sssbench.ops.disk import DISK_ROTATIONS
    from sssbench.ops.rotation import random_rotation

    glc = glc or get_context()
    rot = None
    if getattr(method, "rotation", None) not in (None, *DISK_ROTATIONS):  # (the disk: its own)
        rot = random_rotation(gbuffer, method.rotation, method.seed).angles[bi]
    per_pixel = getattr(method, "per_pixel", False) and gbuffer.profile_id is not None
    return Frame(
        glc,
        gbuffer.diffuse[bi],
        gbuffer.depth[bi],
        gbuffer.mask_or_ones()[bi],
        gbuffer.fov_y,
        None if width_map is None else width_map[bi],
        rot,
        timings,
        profile_id=gbuffer.profile_id[bi] if per_pixel else None,
    )

"""The headless OpenGL context (moderngl on EGL), its programs and float32 textures."""

from __future__ import annotations

import threading

import numpy as np
import torch

from sssbench.gl.shaders import VERTEX

__all__ = [
    "GLContext",
    "GLUnavailable",
    "available",
    "get_context",
    "INSTALL_HINT",
    "LLVMPIPE_NOTE",
]

#: what to install when there is no EGL (the one line of :class:`GLUnavailable`)
INSTALL_HINT = (
    "pip install 'sssbench[gl]' (moderngl) and Mesa's EGL with llvmpipe, e.g. "
    "apt-get install libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri"
)
#: said beside GL times measured on Mesa's software rasteriser
LLVMPIPE_NOTE = (
    "renderer is llvmpipe (Mesa's software rasteriser on the CPU): these GL times are a "
    "software rasteriser's, not a GPU's"
)


class GLUnavailable(RuntimeError):
    """No OpenGL 3.3 context could be made (no moderngl, no EGL, no driver); the message is one
    line naming what to install."""


_LOCK = threading.Lock()
_CONTEXT: GLContext | None = None
_FAILURE: str | None = None


class GLContext:
    """A standalone (headless) moderngl context on EGL with a cache of compiled programs.

    Attributes:
        ctx: the ``moderngl.Context``.
        renderer: ``GL_RENDERER``; version: ``GL_VERSION``; vendor: ``GL_VENDOR``.
    """

    def __init__(self) -> None:
        import moderngl

        self.moderngl = moderngl
        self.ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
        info = self.ctx.info
        self.renderer = str(info.get("GL_RENDERER", "?"))
        self.version = str(info.get("GL_VERSION", "?"))
        self.vendor = str(info.get("GL_VENDOR", "?"))
        #: the thread the context is current on (EGL: one thread at a time)
        self.thread = threading.get_ident()
        self._programs: dict[tuple[str, str], object] = {}
        self._vaos: dict[int, object] = {}

    @property
    def info(self) -> dict[str, str]:
        """``{"renderer", "version", "vendor", "software", "note"}`` of this context."""
        software = "llvmpipe" in self.renderer.lower() or "softpipe" in self.renderer.lower()
        return {
            "renderer": self.renderer,
            "version": self.version,
            "vendor": self.vendor,
            "software": software,
            "note": LLVMPIPE_NOTE if software else "",
        }

    def program(self, fragment: str):
        """The compiled program of ``fragment`` (cached by source text)."""
        key = (VERTEX, fragment)
        prog = self._programs.get(key)
        if prog is None:
            prog = self.ctx.program(vertex_shader=VERTEX, fragment_shader=fragment)
            self._programs[key] = prog
        return prog

    def draw(self, program) -> None:
        """One full-screen triangle with ``program`` into the bound framebuffer."""
        vao = self._vaos.get(id(program))
        if vao is None:
            vao = self.ctx.vertex_array(program, [])
            self._vaos[id(program)] = vao
        vao.render(self.moderngl.TRIANGLES, vertices=3)

    def texture(self, plane: torch.Tensor) -> object:
        """A float32 texture of a ``(C, H, W)`` plane set: ``C = 1`` R32F, 2 RG32F, 3 or 4
        RGBA32F (a 3-channel image gets alpha 1). Linear filtering (``GL_LINEAR``, what
        ``SSSSBlurPS``'s ``texture()`` taps and the backend's ``hardware_filter`` read; the
        backend's own taps are filtered in the shader from ``texelFetch``, see
        :mod:`sssbench.gl.shaders`), clamp to edge."""
        c, h, w = plane.shape
        data = plane.detach().to(device="cpu", dtype=torch.float32)
        comps = 4 if c == 3 else c
        if c == 3:
            data = torch.cat([data, torch.ones(1, h, w)], 0)
        arr = np.ascontiguousarray(data.permute(1, 2, 0).numpy())
        tex = self.ctx.texture((w, h), comps, arr.tobytes(), dtype="f4")
        self._sampling(tex)
        return tex

    @property
    def fp64(self) -> bool:
        """Whether the driver runs double-precision shader arithmetic (GL 4.0 core, GLSL 400:
        ``double``, ``packDouble2x32``, ``frexp`` / ``ldexp`` on doubles, ``precise``)."""
        return self.ctx.version_code >= 400

    def texture_f64(self, plane: torch.Tensor) -> object:
        """An exact float64 texture of a ``(C, H, W)`` plane set, ``C`` 1 or 2: each double
        as its two 32-bit halves (low word first) in an RG32UI / RGBA32UI texel, read in the
        shader with ``packDouble2x32(texelFetch(...).xy)`` (GL has no double texture
        format). Nearest filtering (an integer texture is not filterable)."""
        c, h, w = plane.shape
        if c not in (1, 2):
            raise ValueError(f"plane must have 1 or 2 channels, got {c}")
        data = plane.detach().to(device="cpu", dtype=torch.float64)
        arr = np.ascontiguousarray(data.permute(1, 2, 0).numpy()).view(np.uint32)
        tex = self.ctx.texture((w, h), 2 * c, arr.tobytes(), dtype="u4")
        tex.filter = (self.moderngl.NEAREST, self.moderngl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def target(self, w: int, h: int) -> object:
        """An empty RGBA32F texture of ``w × h``."""
        tex = self.ctx.texture((w, h), 4, dtype="f4")
        self._sampling(tex)
        return tex

    def _sampling(self, tex) -> None:
        tex.filter = (self.moderngl.LINEAR, self.moderngl.LINEAR)  # SSSSSample: linear
        tex.repeat_x = tex.repeat_y = False  # clamp to edge

    def read(self, tex) -> torch.Tensor:
        """``(3, H, W)`` float32 of an RGBA32F texture."""
        w, h = tex.size
        arr = np.frombuffer(tex.read(), dtype=np.float32).reshape(h, w, 4)
        return torch.from_numpy(arr[..., :3].copy()).permute(2, 0, 1).contiguous()


def _create() -> GLContext:
    global _CONTEXT, _FAILURE
    with _LOCK:
        if _CONTEXT is not None:
            return _CONTEXT
        if _FAILURE is not None:
            raise GLUnavailable(_FAILURE)
        try:
            import moderngl  # noqa: F401
        except ImportError:
            _FAILURE = f"the GL backend needs moderngl, which is not installed: {INSTALL_HINT}"
            raise GLUnavailable(_FAILURE) from None
        try:
            _CONTEXT = GLContext()
        except Exception as exc:  # noqa: BLE001 - any driver / loader error means no context
            why = " ".join(str(exc).split()) or type(exc).__name__
            _FAILURE = f"no headless OpenGL 3.3 context on EGL ({why}): install {INSTALL_HINT}"
            raise GLUnavailable(_FAILURE) from None
        return _CONTEXT


def get_context() -> GLContext:
    """The process's GL context, made on first use; :class:`GLUnavailable` (one line naming what
    to install) when there is none. The context is current on the thread that made it: a call
    from another thread raises ``RuntimeError`` (run GL work on one thread)."""
    ctx = _CONTEXT if _CONTEXT is not None else _create()
    if ctx.thread != threading.get_ident():
        raise RuntimeError(
            "the GL context is current on the thread that created it; run sssbench.gl work "
            "(and backend('gl') blocks) on that thread"
        )
    return ctx


def available() -> tuple[bool, str]:
    """``(True, "<renderer> / <version>")`` when a GL 3.3 context can be made, else
    ``(False, reason)`` with the reason naming what to install."""
    try:
        c = get_context()
    except (GLUnavailable, RuntimeError) as exc:
        return False, str(exc)
    return True, f"{c.renderer} / {c.version}"

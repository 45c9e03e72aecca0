"""The disk (:class:`~sssbench.ops.DiskSSS`) on the GL device: its shader constants, its
textures (pattern, radial table, per-pixel noise, surface areas) and one draw per frame.

Both ways in use it: :func:`disk_schedule` is the disk's schedule for
:func:`sssbench.gl.run_method` (timed draws, textures resident), :func:`disk_pass` the
``backend("gl")`` dispatch of :meth:`DiskSSS.forward` (registered with
:func:`sssbench.ops.pass_backends.register_pass_backend`).
"""

from __future__ import annotations

import math

import torch

from sssbench.gbuffer import GBuffer
from sssbench.gl._context import get_context
from sssbench.gl._run import Frame, GLMethodError
from sssbench.gl.disk_shader import PATTERN_ROW, SOG_MAX, DiskShader, disk_source
from sssbench.ops.timing import timed_pass

__all__ = [
    "disk_spec",
    "disk_specs",
    "check_profile_id",
    "disk_schedule",
    "disk_pass",
    "DISK_PASS",
    "DISK_GEOMETRIES",
    "disk_geometry",
    "set_disk_geometry",
]

#: the name of the disk's draw (one per frame), as the torch disk records it
DISK_PASS = "disk"
#: the precisions of a disk sample's geometry in the shader: ``"float64"`` (default; GLSL 400,
#: the torch disk's own, whole images equal to ≤ 1e-5 relative RMS) and ``"float32"`` (the
#: GLSL 330 fallback for a driver without doubles, chosen explicitly: docs/gl.md states its
#: tolerance)
DISK_GEOMETRIES = ("float64", "float32")
_GEOMETRY = {"requested": "float64"}


def set_disk_geometry(precision: str) -> str:
    """Choose the precision the disk shader forms each sample's geometry in (``"float64"``,
    the default, or ``"float32"``, the fallback for a driver without doubles); returns the
    previous choice. Nothing ever falls back by itself: with ``"float64"`` on a driver
    without GLSL 400 the disk raises :class:`GLMethodError` naming this function."""
    if precision not in DISK_GEOMETRIES:
        raise ValueError(f"precision must be one of {DISK_GEOMETRIES}, got {precision!r}")
    old = _GEOMETRY["requested"]
    _GEOMETRY["requested"] = precision
    return old


def disk_geometry() -> str:
    """The precision the disk shader forms its sample geometry in on this context
    (:func:`set_disk_geometry`; recorded by runs as ``gl_disk_geometry``).
    :class:`GLMethodError` when ``"float64"`` is asked of a driver without doubles."""
    want = _GEOMETRY["requested"]
    if want == "float64":
        glc = get_context()
        if not glc.fp64:
            raise GLMethodError(
                f"DiskSSS on GL forms each sample's geometry in float64 as the torch disk does, "
                f"which needs GLSL 400 (double); this driver is {glc.renderer} / {glc.version}. "
                "Call sssbench.gl.set_disk_geometry('float32') to run the float32-geometry "
                "shader (its tolerance: docs/gl.md)"
            )
    return want


def _profile_constants(profile, name: str) -> dict:
    """Burley ``d`` or sum-of-Gaussians constants of ``profile`` (GLMethodError otherwise)."""
    from sssbench.profiles.burley import BurleyNormalized
    from sssbench.profiles.sum_of_gaussians import SumOfGaussians

    if type(profile) is BurleyNormalized:
        return {"burley_d": tuple(float(v) for v in profile.d.double().tolist())}
    if type(profile) is SumOfGaussians:
        v = profile.variances.double()
        w = profile.weights.double() / profile.total().double()
        if v.numel() > SOG_MAX:
            raise GLMethodError(
                f"DiskSSS {name}: the GL disk takes at most {SOG_MAX} Gaussians, got {v.numel()}"
            )
        a = w / (2 * math.pi * v[:, None])
        return {
            "sog": tuple(
                (float(1.0 / (2.0 * v[k])), tuple(float(x) for x in a[k].tolist()))
                for k in range(v.numel())
            )
        }
    raise GLMethodError(
        f"DiskSSS {name}={type(profile).__name__}: the GL disk evaluates BurleyNormalized and "
        "SumOfGaussians profiles in the shader; run other profiles on backend 'native' or "
        "'torch'"
    )


def disk_spec(method, geometry: str | None = None, kernel: int = 0) -> DiskShader:
    """The :class:`DiskShader` of profile ``kernel`` of a built :class:`~sssbench.ops.DiskSSS`
    (one draw per profile of a list) with its sample geometry in ``geometry`` (default
    :func:`disk_geometry`); GLMethodError naming an option the shader does not run
    (``adaptive``, an unsupported profile class)."""
    from sssbench.ops._disk_radial import BurleyRadial
    from sssbench.ops.disk import HDRP_MIN_PIXEL_MM, HDRP_PIXELS_PER_SAMPLE

    if method.adaptive is not None:
        raise GLMethodError(
            f"DiskSSS(adaptive={method.adaptive!r}): the adaptive pilot and refinement passes "
            "have no GL shader (docs/gl.md says why); run it on backend 'native' or 'torch'"
        )
    k = method.kernels[kernel]
    consts = _profile_constants(k.profile, f"profile[{kernel}]" if method.per_pixel else "profile")
    sampler = k.sampler
    table = None if isinstance(sampler, BurleyRadial) else int(sampler.r.numel() - 1)
    hdrp = method.estimator == "hdrp"
    return DiskShader(
        hdrp=hdrp,
        samples=method.samples,
        normalise=method.normalise,
        jitter=method.jitter_radius,
        bilinear=method.fetch == "bilinear",
        surface_area=method.surface_area,
        radial_table=table,
        sampled_d=sampler.d if table is None else 1.0,
        filter_radius=k.filter_radius if hdrp else 0.0,
        min_pixel_mm=HDRP_MIN_PIXEL_MM,
        pixels_per_sample=HDRP_PIXELS_PER_SAMPLE,
        fp64=(geometry or disk_geometry()) == "float64",
        per_pixel=method.per_pixel,
        profile_index=kernel,
        cross_accept=method.cross_profile == "accept",
        **consts,
    )


def disk_specs(method, geometry: str | None = None) -> list[DiskShader]:
    """One :class:`DiskShader` per profile of ``method`` (one for a single profile)."""
    geometry = geometry or disk_geometry()
    return [disk_spec(method, geometry, k) for k in range(len(method.kernels))]


def check_profile_id(method, gbuffer: GBuffer) -> None:
    """The torch disk's checks of ``gbuffer.profile_id`` for a list of profiles
    (``DiskSSS._groups``), before anything is uploaded."""
    if not method.per_pixel:
        return
    if gbuffer.profile_id is None:
        raise ValueError("DiskSSS with a list of profiles needs gbuffer.profile_id")
    top = int(gbuffer.profile_id.max())
    if top >= len(method.kernels):
        raise ValueError(f"profile_id must index the {len(method.kernels)} profiles, got max {top}")


def _radial_plane(sampler) -> torch.Tensor:
    """``(4, 1, K + 1)`` per tabulated node ``(c_k, 1 − c_k, r_k, dr/dc)`` (``dr/dc`` of the
    interval ``[k, k + 1]``), formed in float64: the shader needs no difference of two float32
    CDF values, and ``1 − c_k`` keeps its digits in the tail where ``c_k`` rounds to 1."""
    tiny = torch.finfo(torch.float64).tiny
    c, r = sampler.cdf, sampler.r
    slope = ((c[1:] - c[:-1]) / (r[1:] - r[:-1])).clamp_min(tiny)
    drdc = torch.cat([(1.0 / slope).clamp_max(torch.finfo(torch.float32).max), slope[-1:] * 0])
    return torch.stack([c, 1.0 - c, r, drdc])[:, None, :]


def _split(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``x`` (float64) as a float32 pair ``hi + lo`` (float-float)."""
    hi = x.float().double()
    return hi, x - hi


def _pattern_plane(pattern: str, n: int) -> torch.Tensor:
    """``(4, rows, PATTERN_ROW)`` of the pattern's ``(u_i, θ_i / 2π mod 1, 1 − u_i)``, the
    last as a float32 pair (float64 first)."""
    from sssbench.ops.disk import pattern_points

    u, theta = pattern_points(pattern, n)
    rows = -(-n // PATTERN_ROW)
    plane = torch.zeros(4, rows * PATTERN_ROW, dtype=torch.float64)
    plane[0, :n] = u
    plane[1, :n] = torch.remainder(theta / (2 * math.pi), 1.0)
    plane[2, :n], plane[3, :n] = _split(1.0 - u)
    return plane.reshape(4, rows, PATTERN_ROW)


def _pattern_plane64(method, spec: DiskShader) -> torch.Tensor:
    """``(2, rows, PATTERN_ROW)`` float64 per sample: ``(u_i, θ_i)`` (radians, as
    :func:`~sssbench.ops.disk.pattern_points` gives them), or for HDRP ``(2π frac(i/φ), 0)``
    (``DiskSSS._gather_hdrp``'s angles), for :meth:`GLContext.texture_f64`."""
    from sssbench.ops.disk import GOLDEN_RATIO, pattern_points

    n = method.samples
    rows = -(-n // PATTERN_ROW)
    plane = torch.zeros(2, rows * PATTERN_ROW, dtype=torch.float64)
    if spec.hdrp:
        i = torch.arange(n, dtype=torch.float64)
        plane[0, :n] = 2 * math.pi * torch.frac(i / GOLDEN_RATIO)
    else:
        plane[0, :n], plane[1, :n] = pattern_points(method.pattern, n)
    return plane.reshape(2, rows, PATTERN_ROW)


def _frame_gbuffer(frame: Frame) -> GBuffer:
    return GBuffer(frame.diffuse[None], frame.depth[None], frame.fov_y, mask=frame.strength[None])


def _key(spec: DiskShader) -> str:
    """The prefix of a frame's disk textures (float64 and float32 geometry differ)."""
    return "disk64." if spec.fp64 else "disk."


def _textures(frame: Frame, method, specs: list[DiskShader]) -> None:
    """The disk's textures of ``frame`` (made once per frame object: the schedule's repeats
    reuse them): noise, pattern and areas shared, a radial table per profile."""
    t, g = frame.textures, frame.glc
    spec = specs[0]
    key = _key(spec)
    if f"{key}noise0" in t:
        return
    gb = _frame_gbuffer(frame)
    for f in range(method.frames):  # the operator's own per-pixel random numbers
        phase, shift = method.noise(gb, f, 0)
        if spec.fp64:  # exact doubles
            t[f"{key}noise{f}"] = g.texture_f64(torch.cat([phase[0], shift[0]], 0))
            continue
        hi, lo = _split(shift[0])
        t[f"{key}noise{f}"] = g.texture(torch.cat([phase[0], hi, lo, torch.zeros_like(hi)], 0))
    if spec.fp64:
        t[f"{key}pattern"] = g.texture_f64(_pattern_plane64(method, spec))
    else:
        t[f"{key}pattern"] = g.texture(_pattern_plane(method.pattern, method.samples))
    for k, s in enumerate(specs):
        sampler = method.kernels[k].sampler
        table = s.radial_table is not None
        if s.fp64:
            nodes = torch.stack([sampler.cdf, sampler.r])[:, None] if table else None
            t[f"{key}radial{k}"] = g.texture_f64(torch.zeros(2, 1, 1) if nodes is None else nodes)
        else:
            plane = _radial_plane(sampler) if table else torch.zeros(4, 1, 1)
            t[f"{key}radial{k}"] = g.texture(plane)
    if "profile_id" not in t:  # (a single profile: an unused 1-texel stand-in)
        t["profile_id"] = g.texture(torch.zeros(1, 1, 1))
    area = method.pixel_areas(gb)[0] if spec.surface_area else torch.zeros(1, 1, 1)
    t[f"{key}area"] = g.texture(area)


def draw_disk(frame: Frame, method, specs: list[DiskShader] | None = None) -> object:
    """All frames of the disk of ``method`` on ``frame``: per frame one draw per profile
    (each computing its own pixels), summed into the target ``"disk"`` by additive blending;
    the target texture."""
    specs = specs or disk_specs(method)
    _textures(frame, method, specs)
    glc, t = frame.glc, frame.textures
    key = _key(specs[0])
    mgl = glc.moderngl
    progs = [glc.program(disk_source(s)) for s in specs]
    dst = frame.target(DISK_PASS)
    frame.clear(dst)
    pm = 2.0 * math.tan(frame.fov_y / 2.0) / frame.h  # gbuffer.pixel_size_mm's factor
    for prog in progs:
        for k, v in {
            "pixelMmPerMm": pm,
            "pixelMmPerMmD": pm,
            "tanHalfFov": math.tan(frame.fov_y / 2.0),
            "frameWeight": 1.0 / method.frames,
        }.items():
            u = prog.get(k, None)
            if u is not None:
                u.value = v
    ctx = glc.ctx
    ctx.enable(mgl.BLEND)
    ctx.blend_func = (mgl.ONE, mgl.ONE)  # the frames' (and profiles') shares are summed
    try:
        for f in range(method.frames):
            for k, prog in enumerate(progs):
                frame._bind(prog, {
                    "colorTex": t["color"], "depthTex": t["depth"], "strengthTex": t["strength"],
                    "noiseTex": t[f"{key}noise{f}"], "patternTex": t[f"{key}pattern"],
                    "radialTex": t[f"{key}radial{k}"], "areaTex": t[f"{key}area"],
                    "profileTex": t["profile_id"],
                })  # fmt: skip
                frame._run(prog, dst, DISK_PASS, method.samples)
    finally:
        ctx.disable(mgl.BLEND)
    return dst


def disk_schedule(frame: Frame, method, gbuffer: GBuffer, wt: bool) -> object:
    """The disk's GL schedule for :func:`sssbench.gl.run_method` (``wt``, a width texture,
    does not apply: the disk has no per-pixel width)."""
    if wt:
        raise GLMethodError("DiskSSS takes no per-pixel width (curvature modulation)")
    check_profile_id(method, gbuffer)
    return draw_disk(frame, method)


def disk_pass(method, gbuffer: GBuffer) -> torch.Tensor:
    """:meth:`DiskSSS.forward` on GL (the ``"gl"`` backend's disk dispatch): per image upload,
    the frames' draws, read back; ``(B, 3, H, W)`` in the G-buffer's dtype, recorded as the
    pass ``"disk"``."""
    if torch.is_grad_enabled() and gbuffer.diffuse.requires_grad:
        raise ValueError(
            "the gl backend computes no gradients: run a DiskSSS that autograd records on "
            "backend 'native' or 'torch'"
        )
    specs = disk_specs(method)
    check_profile_id(method, gbuffer)
    glc = get_context()
    mask = gbuffer.mask_or_ones()
    method.last_counts = None  # the per-pixel counts stay on the device
    results = []
    with timed_pass(DISK_PASS, method.samples, int((mask > 0).sum())):
        for bi in range(gbuffer.diffuse.shape[0]):
            frame = Frame(
                glc,
                gbuffer.diffuse[bi].detach(),
                gbuffer.depth[bi],
                mask[bi],
                gbuffer.fov_y,
                profile_id=gbuffer.profile_id[bi] if method.per_pixel else None,
            )
            try:
                results.append(glc.read(draw_disk(frame, method, specs)))
            finally:
                for tex in frame.textures.values():
                    tex.release()
                for fb in frame._fbos.values():
                    fb.release()
    out = torch.stack(results)
    return out.to(dtype=gbuffer.dtype, device=gbuffer.device)

"""The GL backend (sssbench.gl): every covered method's shader result equals its torch result
to <= 1e-5 rel RMS on a flat, a tilted, a curved scene and across depth discontinuities, through
``run_method`` (the whole schedule on the device) and through ``backend("gl")`` (each
``separable_pass`` as the GL shader); GL timer queries give per-pass times and the renderer.

Skipped only when no headless GL context can be made (the reason names what to install)."""

from __future__ import annotations

import functools

import pytest
import torch

import data_synth
import sssbench
from sssbench import gl
from sssbench.ops import Stretch, SumOfGaussiansSSS, backend
from sssbench.run import registry

OK, WHY = gl.available()
pytestmark = pytest.mark.skipif(not OK, reason=f"no headless GL: {WHY}")

TOL = 1e-5
RES = (64, 64)

#: flat, tilted, curved (in front of a wall, mask 0 on it), depth discontinuities (the face)
SCENES = {
    "flat": ("step_edge", dict(pixel_mm=0.05)),
    "tilted": ("halo", dict(pixel_mm=0.05)),
    "curved": ("sphere", dict(radius=5.0, distance=25.0)),
    "discontinuity": ("face", dict(pixel_mm=0.1)),
}

METHODS = {
    "preintegrated": ("preintegrated", "skin_deon6", dict(samples=7)),
    "preintegrated_rotation": ("preintegrated", "skin_deon6",
                               dict(samples=7, params={"rotation": 0.3})),
    "jimenez2012": ("jimenez2012", "skin_deon6",
                    dict(samples=17, params={"preset": "shader_default", "width": 3.0})),
    "artist": ("artist", "skin_deon6", dict(samples=7, params={"preset": "production"})),
    "artist_lerp": ("artist", "skin_deon6", dict(
        samples=7, params={"preset": "production", "follow_surface": "lerp"})),
    "low_rank": ("low_rank", "skin_deon6", dict(samples=9, params={"rank": 3})),
    "sum_of_gaussians": ("sum_of_gaussians", "skin_jg10", dict(samples=7)),
}  # fmt: skip


def rel_rms(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a.double() - b.double()) ** 2).mean().sqrt() / (b.double() ** 2).mean().sqrt())


@functools.cache
def scene(key: str):
    name, kw = SCENES[key]
    return data_synth.make_scene(name, RES, **kw)


@functools.cache
def method(key: str):
    name, profile, kw = METHODS[key]
    return registry.build_method(name, registry.build_profile(profile), **kw)


def torch_result(m, g, **kw) -> torch.Tensor:
    with backend("torch"), torch.no_grad():
        return m(g, **kw)


@functools.cache
def reference(method_key: str, scene_key: str) -> torch.Tensor:
    return torch_result(method(method_key), scene(scene_key))


@pytest.mark.parametrize("scene_key", list(SCENES))
@pytest.mark.parametrize("method_key", list(METHODS))
def test_run_method_equals_torch(method_key, scene_key):
    g, m = scene(scene_key), method(method_key)
    ref = reference(method_key, scene_key)
    run = gl.run_method(m, g, repeats=0, warmup=0)
    assert run.image.shape == ref.shape and run.image.dtype == ref.dtype
    assert rel_rms(run.image, ref) <= TOL
    # the comparison means something: the method changes the image here
    assert rel_rms(g.diffuse, ref) > 1e-4


@pytest.mark.parametrize("scene_key", ["curved", "discontinuity"])
@pytest.mark.parametrize("method_key", ["preintegrated_rotation", "sum_of_gaussians", "low_rank"])
def test_backend_gl_dispatch_equals_torch(method_key, scene_key):
    """``sssbench.backend("gl")``: every separable_pass runs as the GL shader."""
    g, m = scene(scene_key), method(method_key)
    ref = reference(method_key, scene_key)
    with sssbench.backend("gl"), torch.no_grad():
        assert sssbench.get_backend() == "gl"
        out = m(g)
    assert rel_rms(out, ref) <= TOL


@pytest.mark.parametrize(
    "stretch", [Stretch(), Stretch(ssslevel=2.0, correction=800.0, maxdd=0.05)], ids=["jg10", "x2"]
)
def test_sum_of_gaussians_stretch_lod_and_strength(stretch):
    """JG10 stretch (003 §7.3.1), the depth LOD (§7.3.2) and a mask < 1 (strength s' = s·α)."""
    g = scene("discontinuity")
    g = g.replace(mask=g.mask_or_ones() * torch.linspace(0.0, 1.0, RES[1]).view(1, 1, 1, -1))
    m = SumOfGaussiansSSS(registry.build_profile("skin_jg10"), samples=7, stretch=stretch)
    ref = torch_result(m, g)
    assert rel_rms(gl.run_method(m, g, repeats=0, warmup=0).image, ref) <= TOL


def test_per_pixel_width_and_batch():
    """A per-pixel width texture (curvature modulation) and a batch of two images."""
    g1, g2 = scene("curved"), scene("discontinuity")
    g = sssbench.GBuffer(
        torch.cat([g1.diffuse, g2.diffuse]),
        torch.cat([g1.depth, g2.depth]),
        g1.fov_y,
        mask=torch.cat([g1.mask_or_ones(), g2.mask_or_ones()]),
    )
    width = 0.5 + torch.rand(2, 1, *RES, generator=torch.Generator().manual_seed(0))
    m = method("jimenez2012")
    ref = torch_result(m, g, width=width)
    run = gl.run_method(m, g, width=width, repeats=0, warmup=0)
    assert rel_rms(run.image, ref) <= TOL
    with sssbench.backend("gl"), torch.no_grad():
        assert rel_rms(m(g, width=width), ref) <= TOL


def test_pass_times_and_renderer():
    """GL_TIME_ELAPSED per pass (median of repeats), the renderer and the llvmpipe note."""
    g, m = scene("curved"), method("sum_of_gaussians")
    run = gl.run_method(m, g, repeats=3, warmup=1)
    names = [r.name for r in run.passes]
    assert names[:3] == ["sog1.x", "sog1.y", "sog1.blend"] or names[0].startswith("sog")
    assert all(ms > 0 for ms in run.pass_times_ms.values())
    assert run.renderer["renderer"] and run.renderer["version"]
    if "llvmpipe" in run.renderer["renderer"]:
        assert run.renderer["software"] and "software rasteriser" in run.renderer["note"]
    assert all(r.pixels > 0 and r.ms > 0 for r in run.passes)


def test_refused_options_name_themselves():
    g = scene("flat")
    m = registry.build_method(
        "preintegrated", registry.build_profile("skin_deon6"), params={"halo": "lab"}
    )
    with pytest.raises(gl.GLMethodError, match="halo"):
        gl.run_method(m, g)
    with pytest.raises(gl.GLMethodError, match="no schedule"):
        gl.run_method(registry.build_method("identity", None), g)
    with sssbench.backend("gl"), pytest.raises(ValueError, match="sample_weight"):
        m(g)


@pytest.mark.skipif(OK and "llvmpipe" not in WHY, reason="a GPU filters with 8-bit weights")
@pytest.mark.parametrize("method_key", ["preintegrated", "sum_of_gaussians"])
def test_hardware_filter_on_llvmpipe(method_key):
    """texture() with GL_LINEAR (SSSSBlurPS's SSSSSample): llvmpipe filters float textures in
    float, so it agrees with torch too."""
    g, m = scene("curved"), method(method_key)
    run = gl.run_method(m, g, repeats=0, warmup=0, hardware_filter=True)
    assert rel_rms(run.image, reference(method_key, "curved")) <= TOL

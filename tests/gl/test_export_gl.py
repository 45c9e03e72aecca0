"""The export carries everything the image depends on (sssbench/export.py, docs/gl.md): the
kernel that ``sssbench-export-kernel --format glsl`` writes, pasted into a port of 002's
``SSSSBlurPS`` as a user would, run by the GL driver, reproduces the torch operator on a curved
scene in front of a wall with follow-surface on; ``--format glsl-pass`` writes the shaders the
GL backend itself compiles and runs."""

from __future__ import annotations

import math
import re

import pytest
import torch

import data_synth
from sssbench import gl
from sssbench.export import main, split_passes
from sssbench.ops import backend
from sssbench.run import registry

OK, WHY = gl.available()
pytestmark = pytest.mark.skipif(not OK, reason=f"no headless GL: {WHY}")

TOL = 1e-5

#: 002 Appendix A, ``SSSSBlurPS``, as printed (HLSL)
PAPER_BLUR_PS = """float4 SSSSBlurPS(float2 texcoord, SSSSTexture2D colorTex,
                SSSSTexture2D depthTex, float sssWidth,
                float2 dir, bool initStencil) {

    // Fetch color of current pixel:
    float4 colorM = SSSSSamplePoint(colorTex, texcoord);

    // Initialize the stencil buffer in case it was not
    // already available:
    if (initStencil)
        if (SSSS_STRENGTH_SOURCE == 0.0) discard;

    // Fetch linear depth of current pixel:
    float depthM = SSSSSamplePoint(depthTex, texcoord).r;

    // Calculate the sssWidth scale (1.0 for a unit plane
    // sitting on the projection window):
    float distToProjWindow = 1.0 /
        tan(0.5 * radians(SSSS_FOVY));
    float scale = distToProjWindow / depthM;

    // Calculate the final step to fetch the surrounding
    // pixels:
    float2 finalStep = sssWidth * scale * dir;

    // Modulate it using the alpha channel:
    finalStep *= SSSS_STRENGTH_SOURCE;

    // Divide by 3 as the kernels range from -3 to 3:
    finalStep *= 1.0 / 3.0;

    // Accumulate the center sample:
    float4 colorBlurred = colorM;
    colorBlurred.rgb *= kernel[0].rgb;

    // Accumulate the other samples:
    SSSS_UNROLL
    for (int i = 1; i < SSSS_N_SAMPLES; i++) {
        // Fetch color and depth for current sample:
        float2 offset = texcoord + kernel[i].a * finalStep;
        float4 color = SSSSSample(colorTex, offset);

        #if SSSS_FOLLOW_SURFACE == 1
        // If the difference in depth is huge, we lerp
        // color back to "colorM":
        float depth = SSSSSample(depthTex, offset).r;
        float s = 300.0f * distToProjWindow *
            sssWidth * abs(depthM - depth);
            s = SSSSSaturate(s);
        color.rgb = SSSSLerp(color.rgb, colorM.rgb, s);
        #endif

        // Accumulate:
        colorBlurred.rgb += kernel[i].rgb * color.rgb;
    }
    return colorBlurred;
}
"""


def glsl_port(hlsl: str) -> str:
    """The paper's HLSL function in GLSL 330, line by line: its only HLSL-only words are the
    vector types ``float4`` and ``float2`` (the intrinsics are the SSSS* macros, which the
    GLSL harness below defines as SeparableSSS.h's GLSL path would)."""
    return re.sub(r"\bfloat2\b", "vec2", re.sub(r"\bfloat4\b", "vec4", hlsl))


#: 002 appendix, Appendix A, ``SSSSBlurPS``, ported to GLSL 330 (:func:`glsl_port`, HLSL
#: intrinsics as the SSSS* macros of SeparableSSS.h's GLSL path would define them). ``{KERNEL}``
#: is where the user pastes the exported file; the follow-surface line is the paper's, with its
#: ``300.0f * distToProjWindow * sssWidth`` replaced textually by the exported factor below.
SSSS_BLUR_PS = (
    """#version 330
#define SSSS_FOVY {FOVY}
#define SSSSTexture2D sampler2D
#define SSSSSamplePoint(tex, coord) texelFetch(tex, ivec2(coord * vec2(textureSize(tex, 0))), 0)
#define SSSSSample(tex, coord) texture(tex, coord)
#define SSSSSaturate(a) clamp(a, 0.0, 1.0)
#define SSSSLerp(a, b, t) mix(a, b, t)
#define SSSS_UNROLL
#define SSSS_STRENGTH_SOURCE (colorM.a)

{KERNEL}
#define SSSS_N_SAMPLES KERNEL_N_SAMPLES

uniform sampler2D colorTex;  // rgb irradiance, alpha the strength (002 §4)
uniform sampler2D depthTex;  // linear depth
uniform float sssWidth;
uniform vec2 dir;
uniform bool initStencil;
out vec4 fragColor;

"""
    + glsl_port(PAPER_BLUR_PS)
    + """
void main() {
    vec2 texcoord = gl_FragCoord.xy / vec2(textureSize(colorTex, 0));
    fragColor = SSSSBlurPS(texcoord, colorTex, depthTex, sssWidth, dir, initStencil);
}
"""
)

#: the contract (export header, docs/gl.md): SSSS_FOLLOW_SURFACE_FACTOR replaces this
PAPER_FACTOR = "300.0f * distToProjWindow *\n            sssWidth"


def rel_rms(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a.double() - b.double()) ** 2).mean().sqrt() / (b.double() ** 2).mean().sqrt())


def curved_scene():
    """A sphere in front of a wall (mask 0 on the wall): curved, with a depth discontinuity at
    its silhouette, where follow-surface decides the result."""
    return data_synth.make_scene("sphere", (96, 96), radius=5.0, distance=25.0)


CASES = {
    "preintegrated": ["method=preintegrated", "profile=skin_deon6", "samples=7"],
    "jimenez2012": ["method=jimenez2012", "samples=17"],
}


def _export(argv: list[str], fmt: str, tmp_path) -> str:
    out = tmp_path / f"k.{fmt}"
    assert main([*argv, "--format", fmt, "--out", str(out)]) == 0
    return out.read_text()


def _method(argv: list[str]):
    from sssbench.export import build_from_overrides

    return build_from_overrides(argv)[0]


def run_ssss_blur_ps(
    exported: str, gbuffer, shader: str = SSSS_BLUR_PS, sss_width: float | None = None
) -> torch.Tensor:
    """The user's way: paste the exported file into the port (``shader``: :data:`SSSS_BLUR_PS`
    or a user's edit of it), set sssWidth from the file's header (or ``sss_width``), render
    the horizontal then
    the vertical pass with GL_LINEAR / clamp-to-edge textures (SSSSSample), into targets
    holding the input where the stencil discards."""
    if sss_width is None:
        sss_width = float(re.search(r"sssWidth = ([0-9.eE+-]+) mm", exported).group(1))
    assert "#define SSSS_FOLLOW_SURFACE_FACTOR" in exported
    source = shader.replace("{KERNEL}", exported).replace(
        "{FOVY}", f"{math.degrees(gbuffer.fov_y):.9g}"
    )
    assert PAPER_FACTOR in source
    source = source.replace(PAPER_FACTOR, "SSSS_FOLLOW_SURFACE_FACTOR")
    glc = gl.get_context()
    prog = glc.program(source)
    _, _, h, w = gbuffer.diffuse.shape
    rgba = torch.cat([gbuffer.diffuse[0], gbuffer.mask_or_ones()[0]], 0)  # alpha: strength
    color = glc.texture(rgba)
    depth = glc.texture(gbuffer.depth[0])
    textures = [color, depth]
    try:
        src = color
        for direction in ((h / w, 0.0), (0.0, 1.0)):  # x: texcoords span W px, so × H/W
            dst = glc.texture(rgba)  # the stencil's discarded pixels keep the input
            textures.append(dst)
            fbo = glc.ctx.framebuffer(color_attachments=[dst])
            src.use(location=0)
            depth.use(location=1)
            prog["colorTex"].value, prog["depthTex"].value = 0, 1
            prog["sssWidth"].value = sss_width
            prog["dir"].value = direction
            prog["initStencil"].value = True
            fbo.use()
            glc.draw(prog)
            fbo.release()
            src = dst
        return glc.read(src).unsqueeze(0)
    finally:
        for t in textures:
            t.release()


@pytest.mark.parametrize("case", list(CASES))
def test_exported_kernel_in_ssss_blur_ps_reproduces_torch(case, tmp_path):
    argv = CASES[case]
    method = _method(argv)
    assert method.follow_surface == "lerp"
    g = curved_scene()
    with backend("torch"), torch.no_grad():
        ref = method(g)
    assert rel_rms(g.diffuse, ref) > 1e-3  # the blur and the silhouette matter here
    out = run_ssss_blur_ps(_export(argv, "glsl", tmp_path), g)
    assert rel_rms(out, ref) <= TOL
    # the paper's constant instead of the exported factor: far off (the audit's finding)
    text = _export(argv, "glsl", tmp_path)
    wrong = re.sub(r"#define SSSS_FOLLOW_SURFACE_FACTOR [^\n]+", "", text)
    sss_width = float(re.search(r"sssWidth = ([0-9.eE+-]+) mm", text).group(1))
    paper = 300.0 / math.tan(g.fov_y / 2) * sss_width
    wrong += f"\n#define SSSS_FOLLOW_SURFACE_FACTOR {paper:.9g}\n"
    assert rel_rms(run_ssss_blur_ps(wrong, g), ref) > 10 * TOL


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("res", [(64, 96), (96, 64)], ids=["wide", "tall"])
def test_exported_kernel_in_ssss_blur_ps_on_a_non_square_image(case, res, tmp_path):
    """The header's rule for a non-square image (docs/gl.md: the horizontal pass's ``dir`` is
    ``(H / W, 0)``, texture coordinates spanning W pixels across and H down) reproduces the
    torch operator, which steps in pixels, in either orientation."""
    argv = CASES[case]
    g = data_synth.make_scene("sphere", res, radius=5.0, distance=25.0)
    with backend("torch"), torch.no_grad():
        ref = _method(argv)(g)
    assert rel_rms(g.diffuse, ref) > 1e-3
    assert rel_rms(run_ssss_blur_ps(_export(argv, "glsl", tmp_path), g), ref) <= TOL


#: the paper's accumulation line in SSSSBlurPS, and a user's edit of it for the header's
#: ``SSSS_FOLLOW_SURFACE 2`` (000 eq. 7: "tap weight *= exp(-0.5 * (SSSS_FOLLOW_SURFACE_FACTOR *
#: |dz|)^2)", per channel with a vec3 factor), written from the export header's words alone
PAPER_ACCUMULATE = "        colorBlurred.rgb += kernel[i].rgb * color.rgb;"
GAUSSIAN_ACCUMULATE = """        #if SSSS_FOLLOW_SURFACE == 2
        float depthS = SSSSSample(depthTex, offset).r;
        vec3 d = SSSS_FOLLOW_SURFACE_FACTOR * abs(depthM - depthS);
        colorBlurred.rgb += kernel[i].rgb * exp(-0.5 * d * d) * color.rgb;
        #else
        colorBlurred.rgb += kernel[i].rgb * color.rgb;
        #endif"""


@pytest.mark.parametrize(
    ("argv", "d_type"),
    [
        (["method=artist", "samples=7"], "vec3"),
        (CASES["preintegrated"] + ["method.params.follow_surface=gaussian"], "float"),
    ],
    ids=["artist", "preintegrated"],
)
def test_gaussian_follow_surface_export_in_ssss_blur_ps(argv, d_type, tmp_path):
    """000 eq. 7's follow-surface (``SSSS_FOLLOW_SURFACE 2``; the artist model's default, a
    per-channel ``vec3`` factor; the pre-integrated kernel's option, a scalar one): the paper's
    shader with the one edit the export header describes, ``d`` of the type it names,
    reproduces the torch operator on the curved scene; the shader without it (the paper's
    ``#if SSSS_FOLLOW_SURFACE == 1`` skips every depth test) is far off."""
    method = _method(argv)
    assert method.follow_surface == "gaussian"
    text = _export(argv, "glsl", tmp_path)
    assert "#define SSSS_FOLLOW_SURFACE 2" in text
    named = "(float3 / vec3 d, per channel)" if d_type == "vec3" else "(float d)"
    assert named in text
    g = curved_scene()
    with backend("torch"), torch.no_grad():
        ref = method(g)
    assert rel_rms(g.diffuse, ref) > 1e-3
    assert PAPER_ACCUMULATE in SSSS_BLUR_PS
    edit = GAUSSIAN_ACCUMULATE.replace("vec3 d =", f"{d_type} d =")
    edited = SSSS_BLUR_PS.replace(PAPER_ACCUMULATE, edit)
    assert rel_rms(run_ssss_blur_ps(text, g, edited), ref) <= TOL
    assert rel_rms(run_ssss_blur_ps(text, g), ref) > 10 * TOL


@pytest.mark.parametrize("case", list(CASES))
def test_exported_kernel_with_depth_in_metres(case, tmp_path):
    """The header's rule for a depth buffer in metres (sssWidth and depth share one unit: its
    metres line, the follow-surface factor times 1000) gives the same image as the torch
    operator on the G-buffer in mm."""
    argv = CASES[case]
    g = curved_scene()
    with backend("torch"), torch.no_grad():
        ref = _method(argv)(g)
    text = _export(argv, "glsl", tmp_path)
    metres = float(re.search(r"with depth in metres pass\n// sssWidth = ([0-9.eE+-]+),", text)[1])
    factor = float(re.search(r"#define SSSS_FOLLOW_SURFACE_FACTOR ([0-9.eE+-]+)\n", text)[1])
    in_metres = re.sub(
        r"#define SSSS_FOLLOW_SURFACE_FACTOR [^\n]+",
        f"#define SSSS_FOLLOW_SURFACE_FACTOR {factor * 1000:.9g}",
        text,
    )
    g_m = g.replace(depth=g.depth / 1000)
    assert rel_rms(run_ssss_blur_ps(in_metres, g_m, sss_width=metres), ref) <= TOL
    # the mm figure with a depth in metres: far off
    assert rel_rms(run_ssss_blur_ps(in_metres, g_m), ref) > 10 * TOL


def _artist_lerp_case(fmt: str) -> tuple[str, object, torch.Tensor]:
    """The artist model with the lerp follow-surface (a per-channel factor; the Python API's
    ``follow_surface="lerp"``): its export in ``fmt`` as the command line writes it (checked:
    the lerp, a per-channel factor and the header's words on declaring ``s``), the curved
    scene and the torch operator's image of it."""
    from sssbench.export import default_sss_width, method_constants, method_kernels, shader_source
    from sssbench.ops import ArtistSSS

    method = ArtistSSS.preset("multi_layer_close_fit", samples=7, follow_surface="lerp")
    kernels = method_kernels(method)
    width = default_sss_width(kernels, method)
    constants = method_constants(method)
    text = shader_source(kernels, fmt, width, header="artist", constants=constants)
    vec3 = "float3" if fmt == "hlsl" else "vec3"
    assert "#define SSSS_FOLLOW_SURFACE 1" in text
    assert f"#define SSSS_FOLLOW_SURFACE_FACTOR {vec3}(" in text
    assert "declare that line's s as float3 / vec3" in text
    g = curved_scene()
    with backend("torch"), torch.no_grad():
        ref = method(g)
    assert rel_rms(g.diffuse, ref) > 1e-3
    return text, g, ref


#: the paper's follow-surface declaration (a scalar s), which a per-channel factor changes
PAPER_S = "float s = 300.0f"


def test_per_channel_lerp_export_with_the_vec3_the_header_names(tmp_path):
    """A per-channel factor (``vec3``): the header says to declare the follow-surface line's
    ``s`` as ``vec3``; with that one change the port's image is the torch operator's, and
    without it GLSL refuses the paper's ``float s`` (no silent first-channel result)."""
    text, g, ref = _artist_lerp_case("glsl")
    assert PAPER_S in SSSS_BLUR_PS
    edited = SSSS_BLUR_PS.replace(PAPER_S, "vec3 s = 300.0f")
    assert rel_rms(run_ssss_blur_ps(text, g, edited), ref) <= TOL
    with pytest.raises(Exception, match="(?i)vec3|float|conver|type"):
        run_ssss_blur_ps(text, g)


@pytest.mark.parametrize(
    "argv",
    [
        CASES["preintegrated"],
        CASES["jimenez2012"],
        ["method=artist", "samples=7"],
        ["method=preintegrated", "samples=7", "method.params.follow_surface=null"],
    ],
    ids=["preintegrated", "jimenez2012", "artist", "no-follow"],
)
def test_glsl_pass_is_what_the_backend_runs(argv, tmp_path):
    """``--format glsl-pass``: the GL backend compiles these very sources for the method, and
    running the exported file (x then y) gives the torch operator's image."""
    method = _method(argv)
    passes = split_passes(_export(argv, "glsl-pass", tmp_path))
    assert len(passes) == 1
    (source,) = passes.values()
    assert source.startswith("#version 330")
    g = curved_scene()
    with backend("torch"), torch.no_grad():
        ref = method(g)
    out = gl.run_pass_sources([(source, "x"), (source, "y")], g)
    assert rel_rms(out, ref) <= TOL

    def code(s: str) -> str:
        return "\n".join(line for line in s.splitlines() if not line.startswith("//"))

    gl.run_method(method, g, repeats=0, warmup=0)
    compiled = {code(frag) for _, frag in gl.get_context()._programs}
    assert code(source) in compiled


def test_sum_of_gaussians_export_carries_schedule_blend_and_lod(tmp_path):
    argv = ["method=sum_of_gaussians", "profile=skin_jg10", "samples=7"]
    method = _method(argv)
    text = _export(argv, "hlsl", tmp_path)
    for name in ("SSSS_FOLLOW_SURFACE_FACTOR", "SSSS_LOD_THRESHOLD", "SSSS_STRETCH"):
        assert f"#define {name}" in text
    assert "pass schedule" in text and "Listing 7.2" in text
    passes = split_passes(_export(argv, "glsl-pass", tmp_path))
    names = [f"sog{i}" for i, s in enumerate(method.steps) if s.kernel is not None]
    assert list(passes) == names
    for name, src in passes.items():
        assert "#define SSSS_LOD 1" in src and "w' = " in src, name
    g = curved_scene()
    gl.run_method(method, g, repeats=0, warmup=0)
    compiled = {frag for _, frag in gl.get_context()._programs}

    def code(s: str) -> str:
        return "\n".join(line for line in s.splitlines() if not line.startswith("//"))

    compiled = {code(c) for c in compiled}
    assert all(code(src) in compiled for src in passes.values())


def test_existing_formats_keep_their_names(tmp_path):
    """hlsl / glsl / json keep ``kernel`` / ``KERNEL_N_SAMPLES`` and the JSON keeps its kernels
    (new content: the constants, under new names)."""
    argv = CASES["preintegrated"]
    glsl = _export(argv, "glsl", tmp_path)
    assert "#define KERNEL_N_SAMPLES 7" in glsl and "const vec4 kernel[7]" in glsl
    import json

    payload = json.loads(_export(argv, "json", tmp_path))
    assert payload["kernels"][0]["name"] == "preintegrated"
    names = [c["name"] for c in payload["constants"]]
    assert "SSSS_FOLLOW_SURFACE_FACTOR" in names
    factor = next(c["value"] for c in payload["constants"] if c["name"] == names[1])
    method = _method(argv)
    assert factor == pytest.approx(1.0 / method.surface_scale, rel=1e-7)
    assert registry is not None

"""The exports of several kernels where users run them: the sum of Gaussians' and the SVD
rank-N ``glsl`` files pasted into the port of 002's ``SSSSBlurPS`` (tests/gl/test_export_gl.py),
one shader per kernel as the file's header says, driven by the schedule its header writes
(003 §7.3.3's blend with ``glBlendColor``, 003 §7.3.2's LOD as the header's edit, 000 eq. 2's
sum by additive blending), reproduce the torch operator on a curved scene whose stencil cuts
across one surface; each header rule left out is far off."""

from __future__ import annotations

import json
import math
import re
import shutil

import pytest
import torch

import data_synth
from sssbench import gl
from sssbench.gl._run import GL_CONSTANT_COLOR, GL_ONE_MINUS_CONSTANT_COLOR, _blend_color
from sssbench.ops import backend
from tests.gl.test_export_gl import (
    PAPER_BLUR_PS,
    PAPER_FACTOR,
    SSSS_BLUR_PS,
    TOL,
    _export,
    _method,
    rel_rms,
)

OK, WHY = gl.available()
pytestmark = pytest.mark.skipif(not OK, reason=f"no headless GL: {WHY}")

#: the port's line after the pasted file, which a file of several kernels replaces by the two
#: lines its header gives
ONE_KERNEL = "#define SSSS_N_SAMPLES KERNEL_N_SAMPLES\n"
#: the paper's scale line, after which the header's LOD test goes
SCALE = "    float scale = distToProjWindow / depthM;\n"

#: a plain copy of a texture (the copies the header asks for, the rank-N composite and 003
#: Listing 7.2's blend draw, its blend state set outside), discarding where the mask is 0
#: (``STENCIL``) and where the header's LOD test fails (``LOD_SIGMA``)
COPY = """#version 330
#define SSSS_FOVY {FOVY}
{DEFINES}
uniform sampler2D colorTex;  // what is copied
uniform sampler2D maskTex;   // the G-buffer's colour: alpha the mask
uniform sampler2D depthTex;
out vec4 fragColor;
void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    float mask = texelFetch(maskTex, pix, 0).a;
#ifdef STENCIL
    if (mask == 0.0) discard;
#endif
#ifdef LOD_SIGMA
    float depthM = texelFetch(depthTex, pix, 0).r;
    float distToProjWindow = 1.0 / tan(0.5 * radians(SSSS_FOVY));
    float scale = distToProjWindow / depthM;
    float H = float(textureSize(colorTex, 0).y);
    if (LOD_SIGMA * LEVEL * 0.5 * H * scale * mask < SSSS_LOD_THRESHOLD) discard;
#endif
    fragColor = texelFetch(colorTex, pix, 0);
}
"""


def stencil_scene(distance: float = 25.0):
    """A sphere in front of a wall whose stencil also cuts the sphere along rows 40-51 (mask 0
    on one surface: the y passes' taps reach those pixels at nearly the same depth, so what a
    target holds there counts)."""
    g = data_synth.make_scene("sphere", (96, 96), radius=10.0, distance=distance)
    mask = g.mask.clone()
    mask[..., 40:52, :] = 0
    return g.replace(mask=mask)


def selection(text: str, ident: str) -> str:
    """The two lines the header gives for running kernel ``ident`` through ``SSSSBlurPS``
    (checked against the header's own example for the first kernel)."""
    example = re.search(r"//   #define kernel (\w+)\n//   #define SSSS_N_SAMPLES (\w+)\n", text)
    assert example, "the header names how to select a kernel"
    assert example[2] == f"{example[1].upper()}_N_SAMPLES"
    return f"#define kernel {ident}\n#define SSSS_N_SAMPLES {ident.upper()}_N_SAMPLES\n"


class Client:
    """The user's side: GL textures of one G-buffer, ``SSSSBlurPS`` compiled per kernel of an
    exported file (with the header's selection lines and optional edits), copies and blends."""

    def __init__(self, text: str, g, tmp_path=None, edit=None) -> None:
        self.text, self.g, self.tmp_path = text, g, tmp_path  # tmp_path: HLSL
        self.edit = edit  # a user's edit of the paper's GLSL port (str -> str), or None
        self.programs: dict = {}
        self.glc = gl.get_context()
        _, _, self.h, self.w = g.diffuse.shape
        self.rgba = torch.cat([g.diffuse[0], g.mask_or_ones()[0]], 0)  # alpha: strength
        self.width = float(re.search(r"sssWidth = ([0-9.eE+-]+) mm", text)[1])
        self.fovy = f"{math.degrees(g.fov_y):.9g}"
        # the LOD's ssslevel: SSSS_STRETCH_SSSLEVEL with the stretch, else 1 (the header)
        level = re.search(r"#define SSSS_STRETCH_SSSLEVEL ([^\n]+)\n", text)
        self.level = level[1] if "#define SSSS_STRETCH 1" in text else "1.0"
        self.textures: list = []
        self.color = self.texture(self.rgba)
        self.depth = self.texture(g.depth[0])

    def texture(self, plane: torch.Tensor):
        tex = self.glc.texture(plane)
        self.textures.append(tex)
        return tex

    def release(self) -> None:
        for t in self.textures:
            t.release()

    def blur_program(self, ident: str | None, lod_sigma: str | None, axis: str, init_stencil: bool):
        """``SSSSBlurPS`` for kernel ``ident`` of the file (``None``: its one ``kernel``), with
        the header's LOD line for ``lod_sigma``: GLSL, the port (uniforms set per draw), or
        HLSL, the paper's text in tests/gl/test_export_hlsl.py's harness (the kernel arrays
        made ``static const`` as the header says), compiled by glslang and SPIRV-Cross per
        pass (``axis`` and ``init_stencil`` as defines)."""
        hlsl = self.tmp_path is not None
        key = (ident, lod_sigma) + ((axis, init_stencil) if hlsl else ())
        if key in self.programs:
            return self.programs[key]
        if hlsl:
            from tests.gl.test_export_hlsl import HARNESS, compile_hlsl

            assert "DIR, true)" in HARNESS
            source = HARNESS.replace("DIR, true)", "DIR, INIT_STENCIL)").replace(
                "{BLUR}", PAPER_BLUR_PS
            )
            text = re.sub(r"\nfloat4 (kernel\w*)\[\] = \{", r"\nstatic const float4 \1[] = {",
                          self.text)  # fmt: skip
            height = "SIZE_Y"
        else:
            source, text, height = SSSS_BLUR_PS, self.text, "float(textureSize(colorTex, 0).y)"
            if self.edit is not None:
                source = self.edit(source)
        assert ONE_KERNEL in source and PAPER_FACTOR in source and SCALE in source
        if ident is not None:
            source = source.replace(ONE_KERNEL, selection(self.text, ident))
        source = source.replace(PAPER_FACTOR, "SSSS_FOLLOW_SURFACE_FACTOR")
        if lod_sigma is not None:  # the header's LOD line, as written there
            test = re.search(r"//   (if \(sigma .*)\n//   (.*\) discard;)\n", self.text)
            assert test, "the header gives the LOD test"
            line = (test[1] + " " + test[2].strip()).replace("sigma", lod_sigma, 1)
            line = line.replace(" H ", f" {height} ")
            line = line.replace("ssslevel", self.level)
            source = source.replace(SCALE, SCALE + "    " + line + "\n")
        source = source.replace("{KERNEL}", text).replace("{FOVY}", self.fovy)
        if hlsl:
            direction = self.direction(axis)
            defines = {
                "SIZE_X": f"{self.w}.0", "SIZE_Y": f"{self.h}.0",
                "SSS_WIDTH": repr(self.width), "INIT_STENCIL": str(init_stencil).lower(),
                "DIR": f"float2({direction[0]!r},{direction[1]!r})",
            }  # fmt: skip
            source = compile_hlsl(source, defines, self.tmp_path)
        prog = self.programs[key] = self.glc.program(source)
        return prog

    def draw(self, prog, dst, units: dict, uniforms: dict, blend=None) -> None:
        ctx = self.glc.ctx
        for i, (name, tex) in enumerate(units.items()):
            tex.use(location=i)
            for member in prog:  # GLSL: the name; SPIRV-Cross: SPIRV_Cross_Combined<name>...
                if member == name or member.startswith(f"SPIRV_Cross_Combined{name}"):
                    prog[member].value = i
        for name, value in uniforms.items():
            if name in prog:
                prog[name].value = value
        fbo = ctx.framebuffer(color_attachments=[dst])
        if blend is not None:
            ctx.enable(self.glc.moderngl.BLEND)
            if blend == "add":  # 000 eq. 2: ONE, ONE
                ctx.blend_func = (self.glc.moderngl.ONE, self.glc.moderngl.ONE)
            else:  # 003 Listing 7.2: src * w' + dst * (1 - w')
                ctx.blend_func = (GL_CONSTANT_COLOR, GL_ONE_MINUS_CONSTANT_COLOR)
                _blend_color(ctx, blend)
        try:
            fbo.use()
            self.glc.draw(prog)
        finally:
            fbo.release()
            if blend is not None:
                ctx.disable(self.glc.moderngl.BLEND)

    def direction(self, axis: str) -> tuple[float, float]:
        """The header's ``dir``: ``(H / W, 0)`` across, ``(0, 1)`` down."""
        return (self.h / self.w, 0.0) if axis == "x" else (0.0, 1.0)

    def blur(
        self, ident: str | None, src, dst, axis: str, init_stencil: bool = True, blend=None,
        lod_sigma: str | None = None,
    ) -> None:  # fmt: skip
        """One ``SSSSBlurPS`` pass of kernel ``ident`` ``src`` -> ``dst``."""
        prog = self.blur_program(ident, lod_sigma, axis, init_stencil)
        uniforms = {"sssWidth": self.width, "dir": self.direction(axis),
                    "initStencil": init_stencil}  # fmt: skip
        self.draw(prog, dst, {"colorTex": src, "depthTex": self.depth}, uniforms, blend)

    def copy(
        self, src, dst, stencil: bool = False, lod_sigma: str | None = None, blend=None
    ) -> None:
        """``src`` -> ``dst`` by :data:`COPY` (``stencil``, ``lod_sigma``: its discards)."""
        defines = "#define STENCIL\n" if stencil else ""
        if lod_sigma is not None:
            defines += f"#define LOD_SIGMA {lod_sigma}\n#define LEVEL {self.level}\n"
            defines += re.search(r"#define SSSS_LOD_THRESHOLD [^\n]+\n", self.text)[0]
        prog = self.glc.program(COPY.replace("{FOVY}", self.fovy).replace("{DEFINES}", defines))
        units = {"colorTex": src, "maskTex": self.color, "depthTex": self.depth}
        self.draw(prog, dst, units, {}, blend)

    def read(self, tex) -> torch.Tensor:
        return self.glc.read(tex).unsqueeze(0)


def run_sum_of_gaussians(
    text: str, g, lod: bool = True, copy_first: bool = True, tmp_path=None, edit=None
) -> torch.Tensor:
    """003 §7.3.3 as the header's schedule says: RTF = RT1 = the input; per step the x pass
    RT1 -> RT2 and the y pass RT2 -> RT1 (each target first holding its pass's input:
    ``copy_first``; else RT2 starts cleared to black), then RT1 blended into RTF with the
    step's ``w'`` where its pass ran. ``lod``: the header's LOD test in the pass and blend.
    ``tmp_path``: ``text`` is the HLSL file, compiled there; ``edit``: see :class:`Client`."""
    c = Client(text, g, tmp_path, edit)
    try:
        rt1, rtf = c.texture(c.rgba), c.texture(c.rgba)
        rt2 = c.texture(c.rgba * 0)
        steps = re.findall(r"^//   (sog\d+): sigma [^\n]*taps (kernel_sog\d+)$", text, re.M)
        assert steps
        for _, ident in steps:
            sigma = None
            if lod:
                sigma = re.search(rf"#define {ident.upper()}_SIGMA ([^\n]+)\n", text)[1]
            blend = re.search(rf"const (?:vec3|float3) {ident}_blend = \w+\(([^)]*)\);", text)[1]
            weight = tuple(float(v) for v in blend.split(","))
            if copy_first:
                c.copy(rt1, rt2)
            c.blur(ident, rt1, rt2, "x", lod_sigma=sigma)
            if copy_first:
                c.copy(rt2, rt1)
            c.blur(ident, rt2, rt1, "y", lod_sigma=sigma)
            c.copy(rt1, rtf, stencil=True, lod_sigma=sigma, blend=weight)
        return c.read(rtf)
    finally:
        c.release()


def run_low_rank(text: str, g, x_stencil: bool = False, tmp_path=None) -> torch.Tensor:
    """000 eq. 2 as the header's schedule says: per term the x pass (initStencil false and no
    stencil test; ``x_stencil``: with the paper's discard, its target holding the input) and
    the y pass summed into one target by additive blending; then the input where the mask
    is 0. ``tmp_path``: ``text`` is the HLSL file, compiled there."""
    c = Client(text, g, tmp_path)
    try:
        tmp, total, out = c.texture(c.rgba), c.texture(c.rgba * 0), c.texture(c.rgba)
        terms = re.findall(r"^// (low_rank\d+)\.x: \d+ taps", text, re.M)
        assert terms
        for term in terms:
            c.copy(c.color, tmp)  # the x pass's input, where it computes no pixel
            c.blur(f"kernel_{term}_x", c.color, tmp, "x", init_stencil=x_stencil)
            c.blur(f"kernel_{term}_y", tmp, total, "y", blend="add")
        c.copy(total, out, stencil=True)  # the sum where the mask is not 0
        return c.read(out)
    finally:
        c.release()


SOG = ["method=sum_of_gaussians", "profile=skin_jg10", "samples=7"]
LOW_RANK = ["method=low_rank", "profile=skin_deon6", "samples=9"]


def _reference(argv: list[str], g) -> torch.Tensor:
    with backend("torch"), torch.no_grad():
        ref = _method(argv)(g)
    assert rel_rms(g.diffuse, ref) > 1e-3  # the blur and the stencil matter here
    return ref


def _culled(argv: list[str], g) -> list[float]:
    """Per blurred step, the fraction of the stencil's pixels the LOD culls (torch's mask)."""
    method = _method(argv)
    inside = g.mask > 0
    fractions = []
    for step in method.steps:
        if step.kernel is not None:
            lod = method._lod_mask(g, math.sqrt(step.increment))
            fractions.append(float(((lod == 0) & inside).sum() / inside.sum()))
    return fractions


@pytest.mark.parametrize(
    "argv, distance",
    [
        (SOG, 42.0),
        (SOG, 100.0),
        (["method=sum_of_gaussians", "profile=skin_deon6", "samples=7"], 42.0),
        (SOG + ["method.params.lod=false"], 42.0),
    ],
    ids=["jg10", "jg10-far", "deon6", "no-lod"],
)
def test_sum_of_gaussians_export_through_ssss_blur_ps(argv, distance, tmp_path):
    """Each step's kernel through the paper's pass, the header's schedule, blend and LOD: the
    torch image; at 42 mm the LOD culls part of the first step's pixels, at 100 mm all of
    them and part of the second step's (checked)."""
    g = stencil_scene(distance)
    text = _export(argv, "glsl", tmp_path)
    ref = _reference(argv, g)
    lod = "method.params.lod=false" not in argv
    if lod:
        culled = _culled(argv, g)
        partly = culled.index(next(f for f in culled if f < 1.0))  # the first step that runs
        assert partly == (0 if distance < 50 else 1) and 0.2 < culled[partly] < 0.8, culled
    assert rel_rms(run_sum_of_gaussians(text, g, lod=lod), ref) <= TOL


def test_sum_of_gaussians_export_without_the_header_rules_is_far_off(tmp_path):
    """Without the header's LOD line, or with RT2 cleared to black instead of holding its
    pass's input (the stencil's rows cut the sphere), the image is far off."""
    g = stencil_scene(42.0)
    text = _export(SOG, "glsl", tmp_path)
    ref = _reference(SOG, g)
    assert rel_rms(run_sum_of_gaussians(text, g, lod=False), ref) > 10 * TOL
    assert rel_rms(run_sum_of_gaussians(text, g, copy_first=False), ref) > 10 * TOL


def test_low_rank_export_through_ssss_blur_ps(tmp_path):
    """Each term's x and y kernel through the paper's pass, the header's schedule: the torch
    image; the x pass with the paper's stencil discard instead is far off."""
    g = stencil_scene()
    text = _export(LOW_RANK, "glsl", tmp_path)
    ref = _reference(LOW_RANK, g)
    assert rel_rms(run_low_rank(text, g), ref) <= TOL
    assert rel_rms(run_low_rank(text, g, x_stencil=True), ref) > 10 * TOL


#: the paper's line before which the header's stretch factor multiplies ``finalStep``
DIVIDE = "    // Divide by 3 as the kernels range from -3 to 3:\n"


def stretch_edit(one_sided: bool = True):
    """The user's edit for ``SSSS_STRETCH 1``, written from the header's words: ``finalStep``
    times ``ssslevel · depth / (depth + correction · min(|∂depth/∂axis|, maxdd))``, the
    derivative per pixel along the pass's axis, central, one-sided at the image's first and
    last pixel (``one_sided=False``: central everywhere, the border's texel repeated)."""
    border = (
        "dd = i == 0 ? dp - depthM : i == n - 1 ? depthM - dm : (dp - dm) / 2.0;"
        if one_sided
        else "dd = (dp - dm) / 2.0;"
    )
    lines = f"""    ivec2 size = textureSize(depthTex, 0);
    bool across = dir.x != 0.0;
    vec2 texel = across ? vec2(1.0 / float(size.x), 0.0) : vec2(0.0, 1.0 / float(size.y));
    int n = across ? size.x : size.y;
    int i = int((across ? texcoord.x : texcoord.y) * float(n));
    float dp = SSSSSamplePoint(depthTex, (texcoord + texel * float(i < n - 1))).r;
    float dm = SSSSSamplePoint(depthTex, (texcoord - texel * float(i > 0))).r;
    float dd;
    {border}
    finalStep *= SSSS_STRETCH_SSSLEVEL * depthM /
        (depthM + SSSS_STRETCH_CORRECTION * min(abs(dd), SSSS_STRETCH_MAXDD));
"""

    def edit(source: str) -> str:
        assert DIVIDE in source
        return source.replace(DIVIDE, lines + DIVIDE)

    return edit


@pytest.mark.parametrize("lod", [True, False], ids=["lod", "no-lod"])
def test_sum_of_gaussians_stretch_export_through_ssss_blur_ps(lod, tmp_path):
    """The JG10 stretch (``SSSS_STRETCH 1``, the Python API's ``stretch=``, exported by
    :func:`~sssbench.export.shader_source` with :func:`~sssbench.export.method_constants`):
    the paper's pass with the edit the header describes equals the torch image on a sphere
    filling the frame (its depth slopes reach the border); without the edit, or with the
    central difference also at the border, far off."""
    from sssbench.export import default_sss_width, method_constants, method_kernels, shader_source
    from sssbench.ops import SumOfGaussiansSSS
    from sssbench.ops.sum_of_gaussians import jg10_stretch
    from sssbench.profiles import SumOfGaussians

    g = stencil_scene(42.0)
    method = SumOfGaussiansSSS(
        SumOfGaussians.from_table("skin_jg10"), 7, stretch=jg10_stretch(96), lod=lod
    )
    kernels = method_kernels(method)
    width = default_sss_width(kernels, method)
    text = shader_source(kernels, "glsl", width, constants=method_constants(method))
    assert "#define SSSS_STRETCH 1" in text and "one-sided at the image's first" in text
    with backend("torch"), torch.no_grad():
        ref = method(g)
    assert rel_rms(run_sum_of_gaussians(text, g, lod=lod, edit=stretch_edit()), ref) <= TOL
    assert rel_rms(run_sum_of_gaussians(text, g, lod=lod), ref) > 10 * TOL
    central = run_sum_of_gaussians(text, g, lod=lod, edit=stretch_edit(one_sided=False))
    assert rel_rms(central, ref) > 10 * TOL


TOOLS = [t for t in ("glslangValidator", "spirv-cross") if shutil.which(t) is None]


@pytest.mark.skipif(bool(TOOLS), reason=f"no {' / '.join(TOOLS)} (Debian glslang-tools, "
                                         "spirv-cross)")  # fmt: skip
@pytest.mark.parametrize("method", ["sum_of_gaussians", "low_rank"])
def test_multi_kernel_hlsl_export_through_the_papers_ssss_blur_ps(method, tmp_path):
    """The ``hlsl`` files where D3D users run them: the paper's HLSL ``SSSSBlurPS`` per kernel
    (tests/gl/test_export_hlsl.py's harness: glslang's HLSL front end, SPIRV-Cross, the
    driver), the same schedules: the torch image."""
    argv, g = (SOG, stencil_scene(42.0)) if method == "sum_of_gaussians" else (
        LOW_RANK, stencil_scene())  # fmt: skip
    text = _export(argv, "hlsl", tmp_path)
    ref = _reference(argv, g)
    run = run_sum_of_gaussians if method == "sum_of_gaussians" else run_low_rank
    assert rel_rms(run(text, g, tmp_path=tmp_path), ref) <= TOL


def test_single_kernel_export_needs_its_x_target_to_hold_the_input(tmp_path):
    """The rule every header states (``SSSS_SKIPPED_PIXELS``): the pre-integrated kernel through
    the paper's pass with the x pass's target first holding the input equals the torch image;
    cleared to black, far off where the stencil cuts one surface."""
    argv = ["method=preintegrated", "profile=skin_deon6", "samples=7"]
    g = stencil_scene()
    text = _export(argv, "glsl", tmp_path)
    assert "// render targets: where a pass computes no pixel" in text
    ref = _reference(argv, g)
    c = Client(text, g)
    try:
        for start in (c.rgba, c.rgba * 0):
            tmp, out = c.texture(start), c.texture(c.rgba)
            c.blur(None, c.color, tmp, "x")
            c.blur(None, tmp, out, "y")
            err = rel_rms(c.read(out), ref)
            assert err <= TOL if start is c.rgba else err > 10 * TOL
    finally:
        c.release()


def test_multi_kernel_json_carries_the_sigmas_and_rules(tmp_path):
    """The JSON of the sum of Gaussians carries each step's sigma (the torch LOD's, to the 9
    digits written) and the rules, under new names; the existing names keep their places."""
    method = _method(SOG)
    payload = json.loads(_export(SOG, "json", tmp_path))
    constants = {c["name"]: c for c in payload["constants"]}
    names = [c["name"] for c in payload["constants"]]
    assert names[:3] == [
        "SSSS_FOLLOW_SURFACE", "SSSS_FOLLOW_SURFACE_FACTOR", "SSSS_STRENGTH_SOURCE_IS_MASK"
    ]  # fmt: skip
    for i, step in enumerate(method.steps):
        if step.kernel is not None:
            sigma = constants[f"KERNEL_SOG{i}_SIGMA"]["value"]
            assert sigma == pytest.approx(math.sqrt(step.increment), rel=1e-8)
    assert "discard" in constants["SSSS_LOD_IN_SSSSBLURPS"]["comment"]
    assert constants["SSSS_SKIPPED_PIXELS"]["value"] is None

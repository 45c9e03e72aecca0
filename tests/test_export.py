"""``sssbench-export-kernel``: the emitted HLSL / GLSL arrays parse back to the method's taps,
the JSON round trip is exact, bad arguments get one clear line (sssbench/export.py)."""

from __future__ import annotations

import json
import re

import pytest
import torch

from sssbench.export import (
    kernels_json,
    load_kernels,
    main,
    method_kernels,
    shader_source,
)
from sssbench.run import registry

# --------------------------------------------------------------------------- a small parser
_NUM = r"[-+0-9.eE]+"


def parse_arrays(text: str, language: str) -> dict[str, torch.Tensor]:
    """Every ``float4 name[] = {...};`` (HLSL) or ``const vec4 name[N] = vec4[N](...);``
    (GLSL) array as a ``(K, 4)`` float64 tensor, in file order of its taps (comments
    skipped, as the compiler does)."""
    text = re.sub(r"//[^\n]*", "", text)
    if language == "hlsl":
        arrays = re.findall(r"float4\s+(\w+)\[\]\s*=\s*\{(.*?)\};", text, re.S)
        item = r"float4\(([^)]*)\)"
    else:
        found = re.findall(
            r"const\s+vec4\s+(\w+)\[(\d+)\]\s*=\s*vec4\[(\d+)\]\((.*?)\);", text, re.S
        )
        for _, n1, n2, body in found:
            assert n1 == n2 == str(len(re.findall(r"vec4\(", body)))
        arrays = [(name, body) for name, _, _, body in found]
        item = r"vec4\(([^)]*)\)"
    out = {}
    for name, body in arrays:
        rows = []
        for args in re.findall(item, body):
            values = [v.strip() for v in args.split(",")]
            assert len(values) == 4 and all(re.fullmatch(_NUM, v) for v in values), args
            rows.append([float(v) for v in values])
        out[name] = torch.tensor(rows, dtype=torch.float64)
    return out


def _defines(text: str) -> dict[str, int]:
    return {k: int(v) for k, v in re.findall(r"#define\s+(\w+)_N_SAMPLES\s+(\d+)", text)}


def _method(name: str, **kw):
    profile = registry.build_profile(kw.pop("profile", "skin_deon6"))
    params = kw.pop("params", None)
    return registry.build_method(name, profile, params=params, **kw)


SEPARABLE = [
    ("preintegrated", dict(samples=7, sampling="importance")),
    ("preintegrated", dict(samples=8, sampling="uniform")),
    ("sum_of_gaussians", dict(samples=7, profile="skin_jg10")),
    ("low_rank", dict(samples=9, params={"rank": 2})),
    ("artist", dict(samples=7, params={"preset": "production"})),
    ("jimenez2012", dict(samples=17, params={"preset": "shader_default", "width": 3.0})),
]
# --------------------------------------------------------------------------- shader arrays


@pytest.mark.parametrize("language", ["hlsl", "glsl"])
@pytest.mark.parametrize(
    "name,kw", SEPARABLE, ids=[f"{n}-{i}" for i, (n, _) in enumerate(SEPARABLE)]
)
def test_shader_arrays_parse_back_to_the_kernels(name, kw, language):
    method = _method(name, **kw)
    kernels = method_kernels(method)
    sss_width = 1.25  # mm: the tap then lands w · 1.25 · 2/3 mm away (002 appendix shader)
    text = shader_source(kernels, language, sss_width)
    arrays = parse_arrays(text, language)
    assert len(arrays) == len(kernels)
    counts = _defines(text)
    for nk, (ident, rows) in zip(kernels, arrays.items(), strict=True):
        assert counts[ident.upper()] == len(nk.kernel) == rows.shape[0]
        # the shader reads kernel[0] as the unshifted centre tap (002 appendix: colorM)
        has_centre = bool((nk.kernel.offsets.abs() < 1e-9 * nk.kernel.extent).any())
        assert has_centre == (abs(float(rows[0, 3])) < 1e-9 * float(rows[:, 3].abs().max()))
        order = torch.argsort(rows[:, 3], stable=True)
        w, weights = rows[order, 3], rows[order, :3]
        offsets_mm = nk.kernel.offsets.double() * nk.unit_mm
        # w · sssWidth · 2/3 is the world offset (finalStep /3 in texture units spanning 2)
        torch.testing.assert_close(w * sss_width * 2 / 3, offsets_mm, rtol=5e-9, atol=1e-12)
        torch.testing.assert_close(weights, nk.kernel.weights.double(), rtol=5e-9, atol=1e-15)


def test_w_in_mm_with_sss_width_one_and_a_half():
    method = _method("preintegrated", samples=7, sampling="importance")
    (nk,) = method_kernels(method)
    rows = parse_arrays(shader_source([nk], "hlsl", 1.5), "hlsl")["kernel"]
    torch.testing.assert_close(rows[:, 3].sort().values, nk.kernel.offsets, rtol=5e-9, atol=0.0)


@pytest.mark.parametrize("samples,kernel_range", [(17, 2.0), (33, 3.0)])
def test_2012_kernel_at_its_own_width_has_the_shader_builders_range(
    samples, kernel_range, tmp_path
):
    """At sssWidth = the method's width, w is the 2012 kernel builder's offset: range 2, or
    3 above 20 samples (002 appendix's SeparableSSS kernel builder)."""
    out = tmp_path / "k.glsl"
    argv = ["method=jimenez2012", f"samples={samples}", "method.params.width=2.5"]
    assert main([*argv, "--format", "glsl", "--out", str(out)]) == 0
    text = out.read_text()
    rows = parse_arrays(text, "glsl")["kernel"]
    assert float(rows[:, 3].abs().max()) == pytest.approx(kernel_range, rel=1e-9)
    assert "sssWidth = 2.5 mm" in text
    assert float(rows[0, 3]) == 0.0  # centre first


def test_default_sss_width_puts_the_widest_tap_at_the_listings_range(tmp_path):
    out = tmp_path / "k.hlsl"
    argv = ["method=preintegrated", "profile=skin_deon6", "samples=7", "sampling=importance"]
    assert main([*argv, "--format", "hlsl", "--out", str(out)]) == 0
    rows = parse_arrays(out.read_text(), "hlsl")["kernel"]
    # "the kernels range from -3 to 3" (002 appendix)
    assert float(rows[:, 3].max()) == pytest.approx(3.0, rel=1e-9)
    assert float(rows[:, 3].min()) == pytest.approx(-3.0, rel=1e-9)
    # weights sum to 1 per channel (the method's normalised kernel, printed to 9 digits)
    torch.testing.assert_close(rows[:, :3].sum(0), torch.ones(3, dtype=torch.float64))


def test_every_kernel_of_a_method_is_named():
    sog = _method("sum_of_gaussians", samples=5, profile="skin_jg10")
    names = [k.name for k in method_kernels(sog)]
    assert names == [f"sog{i}" for i, s in enumerate(sog.steps) if s.kernel is not None]
    assert len(names) == 4  # skin_jg10: 4 Gaussians (003 Table 7.1), each blurred here
    text = shader_source(method_kernels(sog), "hlsl", 1.0)
    blends = re.findall(r"float3 kernel_(sog\d)_blend = float3\(([^)]*)\);", text)
    assert [b[0] for b in blends] == names
    for (_, args), step in zip(blends, sog.steps, strict=True):
        values = torch.tensor([float(v) for v in args.split(",")], dtype=torch.float64)
        torch.testing.assert_close(values, step.blend.double(), rtol=5e-9, atol=0.0)
    rank = _method("low_rank", samples=7, params={"rank": 3})
    assert [k.name for k in method_kernels(rank)] == [
        f"low_rank{i}.{a}" for i in range(3) for a in "xy"
    ]


# --------------------------------------------------------------------------- JSON
@pytest.mark.parametrize(
    "name,kw", SEPARABLE, ids=[f"{n}-{i}" for i, (n, _) in enumerate(SEPARABLE)]
)
def test_json_round_trip_is_exact(name, kw):
    kernels = method_kernels(_method(name, **kw))
    back = load_kernels(kernels_json(kernels, 2.0))
    assert [k.name for k in back] == [k.name for k in kernels]
    for a, b in zip(kernels, back, strict=True):
        assert a.unit_mm == b.unit_mm and a.extras == b.extras
        assert a.kernel.offsets.dtype == b.kernel.offsets.dtype
        assert torch.equal(a.kernel.offsets, b.kernel.offsets)
        assert torch.equal(a.kernel.weights, b.kernel.weights)


def test_json_file_from_the_command_line(tmp_path):
    out = tmp_path / "k.json"
    argv = ["method=preintegrated", "samples=5", "sampling=power", "--format", "json"]
    assert main([*argv, "--out", str(out)]) == 0
    payload = json.loads(out.read_text())
    assert (payload["method"], payload["samples"], payload["sampling"]) == (
        "preintegrated",
        5,
        "power",
    )
    (nk,) = load_kernels(out)
    method = _method("preintegrated", profile="skin_jg10", samples=5, sampling="power")
    assert torch.equal(nk.kernel.offsets, method.kernel.offsets)
    assert torch.equal(nk.kernel.weights, method.kernel.weights)


# --------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "argv,message",
    [
        (["method=disk"], "method disk has no separable kernel"),
        (["method=reference"], "method reference has no separable kernel"),
        (["method=identity"], "method identity has no separable kernel"),
        (["method=nope"], "unknown method 'nope'"),
        (["methd=preintegrated"], "unknown key 'methd'"),
        (
            ["--format", "xml"],
            "--format must be one of ['hlsl', 'glsl', 'json', 'glsl-pass'], got 'xml'",
        ),
        (["--sss-width", "0"], "--sss-width must be in"),
        (["samples=0"], "samples"),
        (["sampling=optimised"], "+method.params.pixel_mm"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(argv, message, capsys, tmp_path):
    out = tmp_path / "never.txt"
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sssbench-export-kernel: ") and message in err
    assert len(err.splitlines()) == 1
    assert not out.exists()


def test_library_errors_name_the_argument():
    (nk,) = method_kernels(_method("preintegrated"))
    with pytest.raises(ValueError, match="language must be one of"):
        shader_source([nk], "metal", 1.0)
    with pytest.raises(ValueError, match="sss_width_mm must be in"):
        shader_source([nk], "hlsl", -1.0)
    with pytest.raises(ValueError, match="kernels must hold at least one"):
        shader_source([], "hlsl", 1.0)
    with pytest.raises(ValueError, match="sssbench kernel JSON"):
        load_kernels('{"kernels": []}')
    with pytest.raises(ValueError, match="invalid JSON"):
        load_kernels("not json")


def test_centre_first_then_ascending_as_the_shader_builder():
    """SeparableSSS.h's kernel builder moves the 0 offset to the front and keeps the others
    in ascending order (002 appendix: kernel[0] is the unshifted centre sample)."""
    from sssbench.export import NamedKernel, shader_order
    from sssbench.kernels import Kernel1D

    w = torch.tensor([[0.1] * 3, [0.2] * 3, [0.4] * 3, [0.2] * 3, [0.1] * 3], dtype=torch.float64)
    k = Kernel1D(torch.tensor([-2.0, -1.0, 0.0, 1.0, 2.0], dtype=torch.float64), w)
    assert shader_order(k) == ([2, 0, 1, 3, 4], True)
    even = Kernel1D(torch.tensor([-1.5, -0.5, 0.5, 1.5]), torch.full((4, 3), 0.25))
    assert shader_order(even) == ([0, 1, 2, 3], False)
    one = Kernel1D(torch.zeros(1), torch.ones(1, 3))
    rows = parse_arrays(shader_source([NamedKernel("one", one)], "glsl", 1.0), "glsl")["kernel"]
    assert rows.tolist() == [[1.0, 1.0, 1.0, 0.0]]
    # mixed dtypes survive the JSON round trip
    mixed = Kernel1D(torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64), torch.full((3, 3), 1 / 3))
    (back,) = load_kernels(kernels_json([NamedKernel("m", mixed)], 1.0))
    assert back.kernel.weights.dtype == torch.float32
    assert torch.equal(back.kernel.weights, mixed.weights)
    assert torch.equal(back.kernel.offsets, mixed.offsets)

"""A catalogue of bad inputs (issue 8, DESIGN §2).

Every public function validates at the boundary: each case below asserts the exception type and
that the message names the argument and what was expected (a range, a shape, a dtype, the valid
names). ``CASES`` rows are ``(id, thunk, exception, [fragments])``; every fragment must occur in
the message (plain substrings, not regexes).

Operators that are still being written elsewhere are imported lazily (:func:`_op`): a case is
skipped while its class does not exist yet, and marked ``xfail(strict=True)`` where the class
exists but has no check yet (listed in ``XFAIL``).
"""

from __future__ import annotations

import importlib
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.kernels import (
    MAX_SAMPLES,
    Kernel1D,
    artist,
    guided,
    jimenez2012,
    low_rank,
    preintegrated,
    tap_positions,
)
from sssbench.ops import PreintegratedSSS, ReferenceSSS, random_rotation, separable_pass
from sssbench.profiles import BurleyNormalized, Dipole, Layer, SumOfGaussians, compose_layers
from sssbench.profiles.empirical import c_curves, empirical_pole_fit

REPO = Path(__file__).resolve().parents[2]
H = W = 8
PI = "3.14159"  # how check_scalar prints pi (:g)


def _buf(dtype=torch.float32, **changes) -> GBuffer:
    fields = {
        "diffuse": torch.rand(1, 3, H, W, dtype=dtype),
        "depth": torch.full((1, 1, H, W), 500.0, dtype=dtype),
        "fov_y": 0.5,
    }
    fields.update(changes)
    return GBuffer(**fields)


def _img(value=1.0, dtype=torch.float32, shape=(1, 3, H, W)) -> torch.Tensor:
    return torch.full(shape, value, dtype=dtype)


def _with(value: float, field: str = "diffuse", channels: int = 3) -> Callable[[], object]:
    """A G-buffer with ``value`` at one pixel of ``field``."""

    def thunk() -> GBuffer:
        base = 500.0 if field == "depth" else 0.5
        t = torch.full((1, channels, H, W), base)
        t[0, 0, 3, 4] = value
        return _buf(**{field: t})

    return thunk


SOG = SumOfGaussians(torch.tensor([1.0]), torch.ones(1, 3))
KERNEL = preintegrated(SOG, 3)


def _layer(r: float, v: float = 0.1) -> Layer:
    z = torch.zeros(2, 3, dtype=torch.float64)
    rp = z.clone()
    rp[1] = r
    return Layer(rp, rp.clone(), z.clone(), z.clone(), v)


def _op(module: str, name: str) -> type:
    """A class from an operator module that may still be in progress (skip if absent)."""
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the state of the tree
        pytest.skip(f"{module} not importable yet: {exc}")
    cls = getattr(mod, name, None)
    if cls is None:  # pragma: no cover
        pytest.skip(f"{module}.{name} not written yet")
    return cls


def _translucency_without_thickness():
    cls = _op("sssbench.ops.translucency", "Translucency")
    g = _buf(normal=_img(0.0).index_fill(1, torch.tensor([2]), 1.0), light_dir=torch.ones(1, 3))
    return cls("skin_deon6")(g)


def _curvature_without_normal():
    cls = _op("sssbench.ops.curvature", "CurvatureModulation")
    return cls()(_buf())


def _sog_sss(**kwargs):
    cls = _op("sssbench.ops.sum_of_gaussians", "SumOfGaussiansSSS")
    return cls(SumOfGaussians.from_table("skin_jg10"), **kwargs)


def _method_op(module: str, name: str, *args, **kwargs):
    return _op(module, name)(*args, **kwargs)


def _texturing_without_albedo():
    cls = _op("sssbench.ops.texturing", "Texturing")
    g = _buf()
    return cls("post")(g.diffuse, g)


# (id, thunk, exception type, fragments that must all appear in the message)
CASES: list[tuple[str, Callable[[], object], type, list[str]]] = [
    # ---- G-buffer: non-finite values in every field
    ("nan_diffuse", _with(math.nan), ValueError, ["diffuse", "NaN or Inf", "finite"]),
    ("inf_diffuse", _with(math.inf), ValueError, ["diffuse", "finite"]),
    ("nan_depth", _with(math.nan, "depth", 1), ValueError, ["depth", "finite"]),
    ("inf_depth", _with(math.inf, "depth", 1), ValueError, ["depth", "finite"]),
    ("nan_albedo", _with(math.nan, "albedo"), ValueError, ["albedo", "finite"]),
    ("nan_specular", _with(math.nan, "specular"), ValueError, ["specular", "finite"]),
    ("inf_normal", _with(-math.inf, "normal"), ValueError, ["normal", "finite"]),
    ("nan_mask", _with(math.nan, "mask", 1), ValueError, ["mask", "finite"]),
    ("nan_thickness", _with(math.nan, "thickness", 1), ValueError, ["thickness", "finite"]),
    (
        "nan_light_dir",
        lambda: _buf(light_dir=torch.tensor([[0.0, math.nan, 1.0]])),
        ValueError,
        ["light_dir", "finite"],
    ),
    # ---- depth: zero, negative
    ("zero_depth", _with(0.0, "depth", 1), ValueError, ["depth", "(0, inf)"]),
    ("negative_depth", _with(-1.0, "depth", 1), ValueError, ["depth", "(0, inf)"]),
    # ---- other ranges of G-buffer fields
    ("negative_diffuse", _with(-0.1), ValueError, ["diffuse", "[0, inf)"]),
    ("mask_above_1", _with(1.5, "mask", 1), ValueError, ["mask", "[0, 1]", "1.5"]),
    ("mask_below_0", _with(-0.5, "mask", 1), ValueError, ["mask", "[0, 1]", "-0.5"]),
    ("albedo_above_1", _with(2.0, "albedo"), ValueError, ["albedo", "[0, 1]"]),
    ("negative_thickness", _with(-1.0, "thickness", 1), ValueError, ["thickness", "[0, inf)"]),
    # ---- shapes and batch sizes
    (
        "mask_shape",
        lambda: _buf(mask=torch.ones(1, 1, H, W + 1)),
        ValueError,
        ["mask", f"(1, 1, {H}, {W})", f"(1, 1, {H}, {W + 1})"],
    ),
    (
        "depth_batch",
        lambda: _buf(depth=torch.full((2, 1, H, W), 500.0)),
        ValueError,
        ["depth", f"(1, 1, {H}, {W})", "(2, 1"],
    ),
    (
        "diffuse_channels",
        lambda: _buf(diffuse=torch.rand(1, 4, H, W)),
        ValueError,
        ["diffuse", "3 channels", "(1, 4"],
    ),
    ("diffuse_rank", lambda: _buf(diffuse=torch.rand(3, H, W)), ValueError, ["diffuse", "4 dim"]),
    (
        "light_dir_shape",
        lambda: _buf(light_dir=torch.ones(1, 4)),
        ValueError,
        ["light_dir", "(1, 3)", "(1, 4)"],
    ),
    # ---- dtypes
    (
        "int_diffuse",
        lambda: _buf(diffuse=torch.ones(1, 3, H, W, dtype=torch.int64)),
        TypeError,
        ["diffuse", "float32 or float64", "int64"],
    ),
    (
        "uint8_diffuse",
        lambda: _buf(diffuse=torch.ones(1, 3, H, W, dtype=torch.uint8)),
        TypeError,
        ["diffuse", "float32 or float64", "uint8"],
    ),
    (
        "complex_depth",
        lambda: _buf(depth=torch.ones(1, 1, H, W, dtype=torch.complex64)),
        TypeError,
        ["depth", "float32 or float64", "complex64"],
    ),
    (
        "mixed_dtypes",
        lambda: _buf(depth=torch.full((1, 1, H, W), 500.0, dtype=torch.float64)),
        TypeError,
        ["depth", "float64", "float32", "dtype"],
    ),
    (
        "numpy_diffuse",
        lambda: _buf(diffuse=torch.rand(1, 3, H, W).numpy()),
        TypeError,
        ["diffuse", "torch.Tensor", "ndarray"],
    ),
    # ---- fov_y outside (0, pi)
    ("fov_zero", lambda: _buf(fov_y=0.0), ValueError, ["fov_y", f"(0, {PI})", "0"]),
    ("fov_negative", lambda: _buf(fov_y=-0.3), ValueError, ["fov_y", f"(0, {PI})", "-0.3"]),
    ("fov_pi", lambda: _buf(fov_y=math.pi), ValueError, ["fov_y", f"(0, {PI})"]),
    ("fov_above_pi", lambda: _buf(fov_y=4.0), ValueError, ["fov_y", f"(0, {PI})", "4"]),
    ("fov_nan", lambda: _buf(fov_y=math.nan), ValueError, ["fov_y", f"(0, {PI})", "nan"]),
    ("fov_string", lambda: _buf(fov_y="0.5"), TypeError, ["fov_y", "real number", "str"]),
    (
        "fov_degenerate_float32",
        lambda: _buf(fov_y=1e-40),
        ValueError,
        ["fov_y", "pixel footprint", "float32", "float64"],
    ),
    # ---- samples: < 1, non-integer, above MAX_SAMPLES
    ("samples_zero", lambda: preintegrated(SOG, 0), ValueError, ["samples", f"[1, {MAX_SAMPLES}]"]),
    ("samples_neg", lambda: artist(0.1, 0.5, 0.5, 5.0, -3), ValueError, ["samples", "[1, "]),
    (
        "samples_float",
        lambda: preintegrated(SOG, 2.5),
        TypeError,
        ["samples", "integer", f"[1, {MAX_SAMPLES}]", "2.5"],
    ),
    ("samples_bool", lambda: preintegrated(SOG, True), TypeError, ["samples", "integer", "bool"]),
    (
        "samples_above_max",
        lambda: jimenez2012(0.5, 0.5, MAX_SAMPLES + 1),
        ValueError,
        ["samples", f"[1, {MAX_SAMPLES}]", str(MAX_SAMPLES + 1)],
    ),
    (
        "samples_tap_positions",
        lambda: tap_positions(0, "uniform", 1.0),
        ValueError,
        ["samples", f"[1, {MAX_SAMPLES}]"],
    ),
    (
        "samples_module",
        lambda: PreintegratedSSS(SOG, samples=MAX_SAMPLES + 7),
        ValueError,
        ["samples", f"[1, {MAX_SAMPLES}]"],
    ),
    # ---- variances, widths, scales: zero or negative
    (
        "sog_negative_variance",
        lambda: SumOfGaussians(torch.tensor([-1.0, 2.0]), torch.ones(2, 3)),
        ValueError,
        ["variances", "[1e-12, 1e+12] mm²", "-1"],
    ),
    (
        "sog_zero_variance",
        lambda: SumOfGaussians(torch.tensor([0.0]), torch.ones(1, 3)),
        ValueError,
        ["variances", "[1e-12, 1e+12] mm²"],
    ),
    (
        "sog_nan_variance",
        lambda: SumOfGaussians(torch.tensor([math.nan]), torch.ones(1, 3)),
        ValueError,
        ["variances", "finite"],
    ),
    (
        "sog_weights_shape",
        lambda: SumOfGaussians(torch.tensor([1.0, 2.0]), torch.ones(2, 2)),
        ValueError,
        ["weights", "(2, 3)", "(2, 2)"],
    ),
    (
        "artist_zero_scale",
        lambda: artist(0.1, 0.5, 0.5, 0.0, 7),
        ValueError,
        ["scale", "[1e-06, 1e+06] mm"],
    ),
    (
        "artist_negative_scale",
        lambda: artist(0.1, 0.5, 0.5, -2.0, 7),
        ValueError,
        ["scale", "[1e-06, 1e+06] mm", "-2"],
    ),
    ("artist_near_above_1", lambda: artist(1.5, 0.5, 0.5, 5.0, 7), ValueError, ["near", "[0, 1]"]),
    (
        "artist_weight_below_0",
        lambda: artist(0.1, 0.5, -0.1, 5, 7),
        ValueError,
        ["weight", "[0, 1]"],
    ),
    (
        "pass_zero_width",
        lambda: separable_pass(_img(), KERNEL, "x", _buf(), width=0.0),
        ValueError,
        ["width", "(0, inf)"],
    ),
    (
        "pass_negative_width_map",
        lambda: separable_pass(_img(), KERNEL, "x", _buf(), width=-torch.ones(1, 1, H, W)),
        ValueError,
        ["width", ">= 0"],
    ),
    (
        "pass_surface_scale_missing",
        lambda: separable_pass(_img(), KERNEL, "x", _buf(), follow_surface="lerp"),
        ValueError,
        ["surface_scale", "> 0", "follow_surface"],
    ),
    (
        "pass_negative_surface_scale",
        lambda: separable_pass(
            _img(), KERNEL, "x", _buf(), follow_surface="gaussian", surface_scale=-1.0
        ),
        ValueError,
        ["surface_scale", "(0, inf)"],
    ),
    ("kernel_scaled_zero", lambda: KERNEL.scaled(0.0), ValueError, ["factor", "[1e-06, 1e+06]"]),
    (
        "dipole_negative_sigma_a",
        lambda: Dipole(1.0, -0.1),
        ValueError,
        ["sigma_a", "in [0, 1e+06] mm⁻¹"],
    ),
    (
        "dipole_zero_sigma_s",
        lambda: Dipole(0.0, 0.1),
        ValueError,
        ["sigma_s_prime", "[1e-06, 1e+06] mm⁻¹"],
    ),
    ("dipole_eta", lambda: Dipole(1.0, 0.1, eta=0.5), ValueError, ["eta", "[1, 3]"]),
    ("burley_zero_d", lambda: BurleyNormalized(0.0, 0.5), ValueError, ["d", "[1e-06, 1e+06] mm"]),
    ("burley_albedo", lambda: BurleyNormalized(1.0, 1.2), ValueError, ["albedo", "[0, 1]"]),
    (
        "pole_fit_zero_z",
        lambda: empirical_pole_fit(0.5, 0.0),
        ValueError,
        ["z", "[1e-06, 1e+06] mm"],
    ),
    ("c_curves_negative", lambda: c_curves(-1e-3), ValueError, ["x", ">= 0"]),
    ("layer_zero_v", lambda: _layer(0.5, v=0.0), ValueError, ["v", "[1e-12, 1e+12] mm²"]),
    (
        "layers_divergent",
        lambda: compose_layers(_layer(1.0), _layer(1.0)),
        ValueError,
        ["R2d+ * R1d-", "< 1", "1.0"],
    ),
    (
        "low_rank_rank_zero",
        lambda: low_rank(SOG, 0, extent=3.0, n=11),
        ValueError,
        ["rank", "[1, 11]"],
    ),
    (
        "low_rank_extent",
        lambda: low_rank(SOG, 1, extent=-3.0, n=11),
        ValueError,
        ["extent", "[1e-06, 1e+06] mm"],
    ),
    ("guided_k", lambda: guided(SOG, 5.0, samples=5, n=11), ValueError, ["k", "[0, 4]"]),
    ("rotation_radius", lambda: random_rotation(_buf(), 1.5), ValueError, ["radius", "[0, 1]"]),
    ("reference_tol", lambda: ReferenceSSS(SOG, tol=0.0), ValueError, ["tol", "(0, 1)"]),
    # ---- strength outside [0, 1]
    (
        "strength_above_1",
        lambda: jimenez2012(1.2, 0.5, 7),
        ValueError,
        ["strength", "[0, 1]", "1.2"],
    ),
    ("strength_below_0", lambda: jimenez2012(-0.2, 0.5, 7), ValueError, ["strength", "[0, 1]"]),
    (
        "strength_per_channel",
        lambda: jimenez2012((0.5, 0.5, 1.01), 0.5, 7),
        ValueError,
        ["strength", "[0, 1]", "1.01"],
    ),
    ("falloff_negative", lambda: jimenez2012(0.5, -0.1, 7), ValueError, ["falloff", "[0, 1e+06]"]),
    # ---- unknown names
    (
        "unknown_material",
        lambda: Dipole.from_material("unobtainium"),
        ValueError,
        ["name", "one of", "marble", "unobtainium"],
    ),
    (
        "unknown_table",
        lambda: SumOfGaussians.from_table("skin_nope"),
        ValueError,
        ["name", "one of", "skin_jg10", "skin_nope"],
    ),
    (
        "unknown_sampling",
        lambda: preintegrated(SOG, 7, "random"),
        ValueError,
        ["sampling", "one of", "importance", "random"],
    ),
    (
        "unknown_direction",
        lambda: separable_pass(_img(), KERNEL, "z", _buf()),
        ValueError,
        ["direction", "one of", "'z'"],
    ),
    (
        "unknown_follow_surface",
        lambda: PreintegratedSSS(SOG, follow_surface="smooth"),
        ValueError,
        ["follow_surface", "one of", "smooth"],
    ),
    (
        "unknown_reference_method",
        lambda: ReferenceSSS(SOG, method="mc"),
        ValueError,
        ["method", "one of", "fft", "'mc'"],
    ),
    (
        "unknown_app_method",
        lambda: importlib.import_module("sssbench.run.registry").method_class("nope"),
        ValueError,
        ["method", "one of", "preintegrated", "nope"],
    ),
    (
        "unknown_scene",
        lambda: importlib.import_module("data_synth").make_scene("moon", (8, 8)),
        ValueError,
        ["name", "one of", "sphere", "moon"],
    ),
    (
        "unknown_scene_param",
        lambda: importlib.import_module("data_synth").make_scene("sphere", (8, 8), radius_x=1),
        ValueError,
        ["radius_x", "valid parameters"],
    ),
    # ---- Kernel1D
    (
        "kernel_unsorted",
        lambda: Kernel1D(torch.tensor([0.0, -1.0, 1.0]), torch.full((3, 3), 1 / 3)),
        ValueError,
        ["offsets", "sorted ascending", "[0.0, -1.0, 1.0]"],
    ),
    (
        "kernel_weights_shape",
        lambda: Kernel1D(torch.tensor([-1.0, 0.0, 1.0]), torch.full((3, 2), 0.5)),
        ValueError,
        ["weights", "(3, 3)", "(3, 2)"],
    ),
    (
        "kernel_weights_rows",
        lambda: Kernel1D(torch.tensor([-1.0, 0.0, 1.0]), torch.full((4, 3), 0.25)),
        ValueError,
        ["weights", "(3, 3)", "(4, 3)"],
    ),
    (
        "kernel_nan_weight",
        lambda: Kernel1D(torch.tensor([0.0]), torch.tensor([[1.0, math.nan, 1.0]])),
        ValueError,
        ["weights", "finite"],
    ),
    (
        "kernel_empty",
        lambda: Kernel1D(torch.zeros(0), torch.zeros(0, 3)),
        ValueError,
        ["offsets", "at least one tap"],
    ),
    (
        "kernel_int_offsets",
        lambda: Kernel1D(torch.tensor([0]), torch.ones(1, 3)),
        TypeError,
        ["offsets", "float32 or float64", "int64"],
    ),
    # ---- separable_pass inputs
    (
        "pass_image_shape",
        lambda: separable_pass(_img(shape=(1, 3, H, W + 2)), KERNEL, "x", _buf()),
        ValueError,
        ["image", f"(1, 3, {H}, {W})", f"(1, 3, {H}, {W + 2})"],
    ),
    (
        "pass_image_dtype",
        lambda: separable_pass(_img(dtype=torch.float64), KERNEL, "y", _buf()),
        TypeError,
        ["image", "float64", "float32"],
    ),
    (
        "pass_nan_image",
        lambda: separable_pass(_img(math.nan), KERNEL, "x", _buf()),
        ValueError,
        ["image", "finite"],
    ),
    (
        "pass_not_a_kernel",
        lambda: separable_pass(_img(), [0.25, 0.5, 0.25], "x", _buf()),
        TypeError,
        ["kernel", "Kernel1D", "list"],
    ),
    # ---- missing fields an operator needs
    (
        "translucency_without_thickness",
        _translucency_without_thickness,
        ValueError,
        ["thickness", "None"],
    ),
    ("curvature_without_normal", _curvature_without_normal, ValueError, ["normal", "None"]),
    ("texturing_without_albedo", _texturing_without_albedo, ValueError, ["albedo", "None"]),
    # ---- the in-progress methods' own arguments
    (
        "sog_sss_samples",
        lambda: _sog_sss(samples=0),
        ValueError,
        ["samples", f"[1, {MAX_SAMPLES}]"],
    ),
    (
        "sog_sss_negative_weights",
        lambda: _sog_sss(samples=3).__class__(
            SumOfGaussians(torch.tensor([1.0, 2.0]), torch.tensor([[1.0] * 3, [-0.5] * 3])), 3
        ),
        ValueError,
        ["weights", ">= 0"],
    ),
    (
        "translucency_range",
        lambda: _method_op("sssbench.ops.translucency", "Translucency", "skin_deon6", 1.5),
        ValueError,
        ["translucency", "[0, 1)", "1.5"],
    ),
    (
        "curvature_minimum",
        lambda: _method_op("sssbench.ops.curvature", "CurvatureModulation", minimum=2.0),
        ValueError,
        ["minimum", "[0, 1]"],
    ),
    (
        "artist_sss_samples",
        lambda: _method_op("sssbench.ops.artist", "ArtistSSS", 0.1, 0.5, 0.5, 5.0, samples=0),
        ValueError,
        ["samples", f"[1, {MAX_SAMPLES}]"],
    ),
    (
        "artist_sss_near",
        lambda: _method_op("sssbench.ops.artist", "ArtistSSS", 1.5, 0.5, 0.5, 5.0),
        ValueError,
        ["near", "[0, 1]"],
    ),
    (
        "jimenez2012_sss_strength",
        lambda: _method_op("sssbench.ops.jimenez2012", "Jimenez2012SSS", 1.2, 0.5, 2.0),
        ValueError,
        ["strength", "[0, 1]", "1.2"],
    ),
    (
        "jimenez2012_sss_width",
        lambda: _method_op("sssbench.ops.jimenez2012", "Jimenez2012SSS", 0.5, 0.5, 0.0),
        ValueError,
        ["width", "[1e-06, 1e+06] mm"],
    ),
    (
        "jimenez2012_sss_samples",
        lambda: _method_op("sssbench.ops.jimenez2012", "Jimenez2012SSS", 0.5, 0.5, 2.0, samples=0),
        ValueError,
        ["samples", f"[1, {MAX_SAMPLES}]"],
    ),
    (
        "low_rank_sss_rank",
        lambda: _method_op("sssbench.ops.low_rank", "LowRankSSS", SOG, rank=0, n=11),
        ValueError,
        ["rank", "[1, 11]"],
    ),
]

#: cases that fail because an in-progress operator has no check yet: id -> reason
XFAIL: dict[str, str] = {}


def _params():
    for case_id, thunk, exc, fragments in CASES:
        marks = []
        if case_id in XFAIL:
            marks.append(pytest.mark.xfail(strict=True, reason=XFAIL[case_id]))
        yield pytest.param(thunk, exc, fragments, id=case_id, marks=marks)


def test_catalogue_is_large_enough():
    assert len(CASES) >= 25
    assert len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.parametrize(("thunk", "exc", "fragments"), list(_params()))
def test_bad_input_raises_with_named_argument(thunk, exc, fragments):
    with pytest.raises(exc) as info:
        thunk()
    assert type(info.value) is exc or isinstance(info.value, exc)
    message = str(info.value)
    missing = [f for f in fragments if f not in message]
    assert not missing, f"message {message!r} lacks {missing}"
    assert "\n" not in message.strip(), "messages are one line"


# ----------------------------------------------------------------------------- the Hydra edge
def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["HYDRA_FULL_ERROR"] = "0"
    return env


def _sssbench(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [
        sys.executable,
        "-m",
        "sssbench",
        *args,
        "hydra.run.dir=" + str(tmp_path / "run"),
        "hydra.sweep.dir=" + str(tmp_path / "sweep"),
        "store=" + str(tmp_path / "store.sqlite"),
    ]
    return subprocess.run(
        cmd, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("override", "fragments"),
    [
        ("method=nope", ["unknown method 'nope'", "preintegrated"]),
        ("scene=moon", ["unknown scene 'moon'", "sphere"]),
        ("profile=skin_nope", ["unknown profile 'skin_nope'", "skin_jg10"]),
        ("sampling=random", ["unknown sampling 'random'", "importance"]),
    ],
)
def test_bad_hydra_override_is_one_line(tmp_path, override, fragments):
    proc = _sssbench(tmp_path, override)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    for f in fragments:
        assert f in lines[0], lines[0]
    assert "Traceback" not in proc.stderr + proc.stdout
    assert not (tmp_path / "store.sqlite").exists(), "nothing ran"

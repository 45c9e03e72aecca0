"""Failure classes of the gather primitive that hostile inputs reach (each test failed on the
code before the fix): in-place writes autograd or the other backend cannot see, aliasing and
self-overlapping memory, stale caches, overflowing tap positions, a broken native library, and
what the fallback warning promises.

References are independent of the code under test where they can be: a fresh G-buffer built
from cloned tensors (no cache to hit), the float64 torch loop on the float32-rounded inputs
(docs/numerics.md), and the closed forms of a pass whose taps all land on the border.
"""

import math
import warnings

import numpy as np
import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D
from sssbench.ops import Rotation, Stretch, backend, native, separable_pass
from sssbench.ops.gather import BACKEND_AGREEMENT

NATIVE = pytest.mark.skipif(native.library() is None, reason="no C compiler")
BACKENDS = [pytest.param("native", marks=NATIVE), "torch"]


def scene(seed=0, h=14, w=17, dtype=torch.float32, b=1):
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(b, 3, h, w, generator=g, dtype=dtype)
    depth = 60 + 20 * torch.rand(b, 1, h, w, generator=g, dtype=dtype)
    mask = torch.rand(b, 1, h, w, generator=g, dtype=dtype)
    mask = mask * (torch.rand(b, 1, h, w, generator=g, dtype=dtype) < 0.7)
    return GBuffer(img, depth, 0.7, mask=mask)


def kernel(taps=7, dtype=torch.float64):
    offsets = torch.linspace(-3.0, 3.0, taps, dtype=dtype)
    weights = torch.exp(-0.5 * offsets[:, None] ** 2 / torch.tensor([0.5, 1.5, 3.0], dtype=dtype))
    return Kernel1D(offsets, weights / weights.sum(0))


def fresh(g: GBuffer) -> GBuffer:
    """The same G-buffer from new tensors: nothing cached for them."""
    return GBuffer(g.diffuse.clone(), g.depth.clone(), g.fov_y, mask=g.mask.clone())


# ---- inference tensors: both backends behave the same ----------------------------------


@pytest.mark.parametrize("name", BACKENDS)
def test_inference_tensor_in_place_outside_inference_mode_is_refused_by_both(name):
    with torch.inference_mode():
        g = scene()
        work = g.diffuse.clone()
    with backend(name), pytest.raises(ValueError, match="inference tensor"):
        separable_pass(work, kernel(), "x", g, inplace=True)


@pytest.mark.parametrize("name", BACKENDS)
def test_inference_tensor_in_place_inside_inference_mode_equals_the_copy(name):
    g = scene()
    ref = separable_pass(g.diffuse, kernel(), "y", fresh(g))
    with torch.inference_mode(), backend(name):
        gi = fresh(g)
        work = gi.diffuse.clone()
        out = separable_pass(work, kernel(), "y", gi, inplace=True)
    assert out is work
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-6)


# ---- aliasing and overlapping memory --------------------------------------------------


def _aliased(kind: str) -> GBuffer:
    g = scene()
    if kind == "depth":  # depth is a view of diffuse's memory
        diffuse = torch.cat([g.depth.expand(1, 1, 14, 17), g.diffuse[:, 1:]], 1).contiguous()
        return GBuffer(diffuse, diffuse[:, :1], g.fov_y, mask=g.mask)
    diffuse = g.diffuse.clone()  # mask shares diffuse's memory (its red channel)
    return GBuffer(diffuse, g.depth, g.fov_y, mask=diffuse[:, :1])


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("field", ["depth", "mask"])
def test_in_place_on_memory_a_field_aliases_is_refused(name, field):
    g = _aliased(field)
    before = g.diffuse.clone()
    with (
        backend(name),
        pytest.raises(ValueError, match=f"image shares memory with gbuffer.{field}"),
    ):
        separable_pass(g.diffuse, kernel(), "x", g, inplace=True)
    assert torch.equal(g.diffuse, before)  # refused before writing anything
    # the copying call reads only: it equals the pass on separate copies
    ref = separable_pass(g.diffuse.clone(), kernel(), "x", fresh(g))
    with backend(name):
        got = separable_pass(g.diffuse, kernel(), "x", g)
    torch.testing.assert_close(got, ref, rtol=0, atol=1e-6)


@pytest.mark.parametrize("field", ["depth", "mask"])
def test_method_in_place_on_aliased_fields_names_both(field):
    from sssbench.ops import PreintegratedSSS
    from sssbench.profiles import SumOfGaussians

    op = PreintegratedSSS(SumOfGaussians.from_table("skin_deon6"), 7)
    g = _aliased(field)
    with pytest.raises(ValueError, match=f"gbuffer.diffuse shares memory with gbuffer.{field}"):
        op(g, inplace=True)


@pytest.mark.parametrize("name", BACKENDS)
def test_expanded_image_in_place_is_refused_and_the_copy_works(name):
    g = scene()
    flat = g.diffuse[:, :, :1, :].expand(1, 3, 14, 17)  # every row the same memory
    ge = GBuffer(flat, g.depth, g.fov_y, mask=g.mask)
    with backend(name), pytest.raises(ValueError, match="image has elements sharing memory"):
        separable_pass(flat, kernel(), "x", ge, inplace=True)
    with backend(name):
        got = separable_pass(flat, kernel(), "x", ge)
    ref = separable_pass(flat.contiguous(), kernel(), "x", fresh(ge))
    torch.testing.assert_close(got, ref, rtol=0, atol=1e-6)


def test_method_in_place_on_an_expanded_diffuse_names_it():
    from sssbench.ops import PreintegratedSSS
    from sssbench.profiles import SumOfGaussians

    g = scene()
    ge = g.replace(diffuse=g.diffuse[:, :, :1, :].expand(1, 3, 14, 17))
    op = PreintegratedSSS(SumOfGaussians.from_table("skin_deon6"), 7)
    with pytest.raises(ValueError, match="gbuffer.diffuse has elements sharing memory"):
        op(ge, inplace=True)
    out = op(ge)  # the copying call works
    torch.testing.assert_close(out, op(fresh(ge)), rtol=0, atol=0)


# ---- stale caches ---------------------------------------------------------------------


def _write_mask(g: GBuffer, how: str, new: torch.Tensor) -> None:
    if how == "data":
        g.mask.data.copy_(new)
    elif how == "numpy":
        g.mask.numpy()[...] = new.numpy()
    else:  # under inference mode: an inference tensor has no version counter
        with torch.inference_mode():
            g.mask.copy_(new)


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("how", ["data", "numpy", "inference"])
def test_a_mask_written_without_a_version_bump_is_not_served_from_a_stale_cache(name, how):
    """First call: mask all zero (nothing to blur); the mask is then filled in without a
    version bump; the second call must blur exactly like a fresh G-buffer with that mask."""
    g0 = scene()
    if how == "inference":
        with torch.inference_mode():
            g = GBuffer(
                g0.diffuse.clone(), g0.depth.clone(), g0.fov_y, mask=torch.zeros_like(g0.mask)
            )
    else:
        g = GBuffer(g0.diffuse, g0.depth, g0.fov_y, mask=torch.zeros_like(g0.mask))
    with backend(name):
        first = separable_pass(g.diffuse, kernel(), "x", g)
        assert torch.equal(first, g.diffuse)  # all masked out
        _write_mask(g, how, g0.mask)
        second = separable_pass(g.diffuse, kernel(), "x", g)
    ref = separable_pass(g0.diffuse.clone(), kernel(), "x", fresh(g0))
    assert not torch.equal(ref, g0.diffuse)
    torch.testing.assert_close(second, ref, rtol=0, atol=1e-6)


# ---- tap positions and scales that overflow ------------------------------------------


def _f32_vs_f64(name, g32, k, direction, **kw):
    """The pass in float32 on ``name`` against the float64 torch loop on the float32-rounded
    inputs, relative to max |input| (docs/numerics.md: max(1e-5, K · 2⁻²⁴))."""
    with backend(name):
        got = separable_pass(g32.diffuse, k, direction, g32, **kw)
    g64 = g32.to(torch.float64)
    kw64 = {key: (v.double() if isinstance(v, torch.Tensor) else v) for key, v in kw.items()}
    if isinstance(kw64.get("rotation"), Rotation):
        r = kw64["rotation"]
        kw64["rotation"] = Rotation(r.angles.double(), r.radius)
    with backend("torch"):
        ref = separable_pass(g64.diffuse, k, direction, g64, **kw64)
    assert torch.isfinite(got).all()
    err = float((got.double() - ref).abs().max()) / float(g64.diffuse.abs().max())
    assert err <= max(1e-5, len(k) * 2.0**-24), err
    return got, ref


HUGE = [
    dict(width=1e30, stretch=Stretch(ssslevel=1e30)),  # f / z · width overflows float32
    dict(width=1e38),
    dict(follow_surface="lerp", surface_scale=1e-30),
    dict(follow_surface="lerp", surface_scale=1e-40),  # 1 / s overflows float32
    dict(follow_surface="gaussian", surface_scale=1e-40),
    dict(stretch=Stretch(ssslevel=1e30, correction=1e300, maxdd=1e300)),
]


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("kw", HUGE, ids=lambda kw: "-".join(kw))
@pytest.mark.parametrize("direction", ["x", "y"])
def test_huge_and_tiny_scalars_agree_with_float64(name, kw, direction):
    _f32_vs_f64(name, scene(), kernel(), direction, **kw)


@pytest.mark.parametrize("name", BACKENDS)
def test_per_pixel_width_of_zero_next_to_an_overflowing_scale(name):
    """``inf · 0``: a per-pixel width of 0 (no blur) where the pixels-per-mm overflows."""
    g = scene()
    width = torch.full_like(g.depth, 1e30)
    width[..., ::2] = 0.0
    got, _ = _f32_vs_f64(name, g, kernel(), "x", width=width, stretch=Stretch(ssslevel=1e30))
    still = (width == 0) & (g.mask > 0)  # weights sum to 1: an unblurred pixel is unchanged
    torch.testing.assert_close(
        got.masked_select(still.expand_as(got)),
        g.diffuse.masked_select(still.expand_as(got)),
        rtol=1e-6,
        atol=1e-6,
    )


def test_every_tap_on_the_border_is_the_closed_form():
    """With an overflowing scale, tap k < 0 reads column 0, tap k > 0 the last column and the
    centre tap the pixel itself: out = Σ_{k<0} w_k I[0] + w_0 I[c] + Σ_{k>0} w_k I[W−1]."""
    g = scene(dtype=torch.float64)
    k = kernel()
    for name in ["torch"] + (["native"] if native.library() is not None else []):
        with backend(name):
            out = separable_pass(g.diffuse, k, "x", g, width=1e300, use_mask=False)
        w = k.weights
        left, centre, right = w[:3].sum(0), w[3], w[4:].sum(0)
        img = g.diffuse[0]
        expected = (
            left[:, None, None] * img[:, :, :1]
            + centre[:, None, None] * img
            + right[:, None, None] * img[:, :, -1:]
        )
        torch.testing.assert_close(out[0], expected, rtol=1e-12, atol=1e-12)


def test_rotated_taps_with_an_overflowing_scale_stay_in_the_image():
    g = scene()
    angles = torch.zeros_like(g.depth)
    angles[..., 1::2] = math.pi / 2  # axis-aligned both ways: a 0 · inf per tap
    rot = Rotation(angles, radius=1.0)
    _f32_vs_f64("torch", g, kernel(), "x", width=1e30, stretch=Stretch(ssslevel=1e30),
                rotation=rot)  # fmt: skip


def test_offsets_beyond_float32_are_taps_on_the_border():
    """A float64 kernel with offsets beyond float32's range (a huge variance) in a float32
    pass: every non-centre tap lands on the border, as in float64."""
    offsets = torch.tensor([-1e300, 0.0, 1e300], dtype=torch.float64)
    k = Kernel1D(offsets, torch.full((3, 3), 1 / 3, dtype=torch.float64))
    g = scene()
    for name in ["torch"] + (["native"] if native.library() is not None else []):
        _f32_vs_f64(name, g, k, "y", width=torch.where(g.depth > 70, 0.0, 1.0))


@pytest.mark.parametrize(
    "kw, field",
    [
        (dict(stretch=Stretch(ssslevel=1e308)), "stretch.ssslevel"),  # f_px overflows
        (dict(width=float("inf")), "width"),
        (dict(width=float("nan")), "width"),
        (dict(follow_surface="lerp", surface_scale=float("nan")), "surface_scale"),
        (dict(follow_surface="lerp", surface_scale=0.0), "surface_scale"),
        (dict(rotation="rot"), "rotation"),
        (dict(stretch=(1.0, 800.0, 0.23)), "stretch"),
    ],
)
def test_bad_stretch_rotation_and_scalars_are_named(kw, field):
    g = scene()
    exc = TypeError if field in ("rotation", "stretch") else ValueError
    with pytest.raises(exc, match=field.replace(".", r"\.")):
        separable_pass(g.diffuse, kernel(), "x", g, **kw)


@pytest.mark.parametrize(
    "kw, field",
    [
        (dict(ssslevel=float("nan")), "ssslevel"),
        (dict(ssslevel=0.0), "ssslevel"),
        (dict(correction=float("inf")), "correction"),
        (dict(correction=-1.0), "correction"),
        (dict(maxdd=float("nan")), "maxdd"),
    ],
)
def test_bad_stretch_is_named_on_construction(kw, field):
    # on construction (issue 29, class 14), not by a pass that level of detail may skip
    with pytest.raises(ValueError, match=field):
        Stretch(**kw)


@pytest.mark.parametrize("radius", [float("nan"), float("inf"), -0.1, 1.5])
def test_bad_rotation_radius_is_named(radius):
    g = scene()
    with pytest.raises(ValueError, match=r"radius"):
        Rotation(torch.zeros_like(g.depth), radius)


def test_non_finite_rotation_angles_are_named():
    g = scene()
    angles = torch.zeros_like(g.depth)
    angles[0, 0, 2, 2] = float("nan")
    with pytest.raises(ValueError, match=r"angles"):
        Rotation(angles)


# ---- a broken native library --------------------------------------------------------


@pytest.mark.parametrize("flaw", ["missing symbols", "not a library"])
def test_a_broken_cached_library_falls_back_with_one_warning(monkeypatch, tmp_path, flaw):
    """A cached library that lacks a symbol or is not a shared object: one warning, then the
    torch loop on every call (no exception, no further warning)."""
    bad = tmp_path / "bad.so"
    if flaw == "not a library":
        bad.write_bytes(b"\x7fELF but truncated")
    else:
        import subprocess

        cc = native._compiler()
        if cc is None:
            pytest.skip("no C compiler")
        src = tmp_path / "empty.c"
        src.write_text("int unrelated(void) { return 0; }\n")
        subprocess.run([cc, "-shared", "-fPIC", "-o", str(bad), str(src)], check=True)
    monkeypatch.setattr(native, "_STATE", {"lib": None, "tried": False})
    monkeypatch.setattr(native, "_build", lambda cc, fresh=False: bad)
    g = scene()
    with backend("torch"):
        ref = separable_pass(g.diffuse, kernel(), "x", g)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outs = [separable_pass(g.diffuse, kernel(), "x", g) for _ in range(3)]
    unavailable = [w for w in caught if "native gather unavailable" in str(w.message)]
    assert len(unavailable) == 1
    for out in outs:
        assert torch.equal(out, ref)


# ---- what the fallback warning promises ---------------------------------------------


def test_the_fallback_warning_states_the_tested_agreement():
    assert "bitwise equal" in native.FALLBACK_NOTE and "bitwise equal" in BACKEND_AGREEMENT
    assert "same results" not in native.FALLBACK_NOTE


@NATIVE
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"follow_surface": "lerp", "surface_scale": 3.0},
        {"follow_surface": "lerp", "surface_scale": torch.tensor([1.0, 4.0, 20.0])},
        {"stretch": Stretch(), "follow_surface": "lerp", "surface_scale": 0.7},
        {"width": 2.5, "use_mask": False},
    ],
    ids=["plain", "lerp", "lerp-per-channel", "stretch-lerp", "width-nomask"],
)
@pytest.mark.parametrize("level", native.SIMD_LEVELS)
def test_native_and_torch_loop_are_bitwise_equal_but_for_exp(dtype, kw, level):
    """The claim of BACKEND_AGREEMENT (and the fallback warning): bitwise, float32 and float64,
    without the gaussian's exp, both axes, random per-pixel width, batch of two; at every
    instruction-set level of the C loop (a level the CPU lacks is skipped)."""
    if level not in native.simd_levels():
        pytest.skip(f"this CPU has no {level}")
    g = scene(seed=4, h=40, w=53, dtype=dtype, b=2)
    kw = {k: (v.to(dtype) if isinstance(v, torch.Tensor) else v) for k, v in kw.items()}
    if "width" not in kw:
        kw["width"] = 0.2 + 3 * torch.rand(2, 1, 40, 53, dtype=dtype)
    for direction in ("x", "y"):
        with backend("torch"):
            ref = separable_pass(g.diffuse, kernel(9), direction, g, **kw)
        with backend("native"), native.simd(level):
            got = separable_pass(g.diffuse, kernel(9), direction, g, **kw)
        assert torch.equal(got, ref), float((got - ref).abs().max())


@NATIVE
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("level", native.SIMD_LEVELS)
def test_native_and_torch_loop_with_gaussian_agree_to_the_stated_tolerance(dtype, level):
    if level not in native.simd_levels():
        pytest.skip(f"this CPU has no {level}")
    g = scene(seed=5, h=40, w=53, dtype=dtype)
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    for direction in ("x", "y"):
        outs = []
        for name in ("torch", "native"):
            with backend(name), native.simd(level):
                out = separable_pass(
                    g.diffuse, kernel(9), direction, g, follow_surface="gaussian", surface_scale=2.0
                )
                outs.append(out)
        err = float((outs[0] - outs[1]).abs().max()) / float(g.diffuse.abs().max())
        assert err <= tol, err


def test_memo_compares_bits():
    """The memo's check is bitwise: NaN equals itself, -0.0 differs from 0.0."""
    from sssbench._memo import memoised

    t = torch.tensor([0.0, float("nan")])
    assert memoised((t,), "probe-bits", lambda: 1) == 1
    t.numpy()[0] = -0.0
    assert memoised((t,), "probe-bits", lambda: 2) == 2
    assert memoised((t,), "probe-bits", lambda: 3) == 2
    assert np.isnan(t.numpy()[1])

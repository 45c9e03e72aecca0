"""API-wide property-based fuzzer (hypothesis): every public operator and builder × options ×
shapes from 1×1 to 24×24 × float32/float64 × memory layouts × extreme scalars × in-place and
autograd.

Invariants (each in its own test function, so a failure names the class it belongs to):

- **valid or named** — a call either raises ``ValueError`` / ``TypeError`` whose message names
  the argument that was given an absurd value, or returns a finite result of the documented
  shape and dtype; a normalised non-negative method's output stays within ``[0, max input]``
  (a convex combination of the input: conservation, not a number of the code);
- **float32 ≈ float64** within ``docs/numerics.md``'s tolerance per pass:
  ``max(1e-5, K·2⁻²⁴)`` relative to the largest input, plus ``4 · ulp32(max depth) /
  surface_scale`` with follow-surface;
- **layout** — views, slices, channels-last, transposed strides and expanded tensors give the
  contiguous result;
- **in-place** — ``forward(..., inplace=True)`` equals the copying call;
- **backends** — the native and the torch tap loops agree (1e-12 / 1e-5 per pass, numerics.md);
- **gradients** — the torch loop's gradients are finite, and equal finite differences on tiny
  images (every method is linear in ``diffuse``: float64 ``gradcheck`` is exact up to rounding);
- **the disk** (``DiskSSS``, both estimators; section 9) — valid or named, float32 ≈ float64,
  layout invariance, in-place = copy, an image in a batch equals it alone, and every bit of
  the seed changes the noise.

Profiles (``tests/reliability/conftest.py``): ``ci`` by default, ``HYPOTHESIS_PROFILE=long`` for
a long randomised search; see ``docs/reliability.md``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import pytest
import torch
from hypothesis import assume, given, note, settings
from hypothesis import strategies as st

import sssbench
from sssbench import GBuffer
from sssbench.kernels import (
    Kernel1D,
    artist,
    cell_centres,
    guided,
    jimenez2012,
    kernel_matrix,
    low_rank,
    preintegrated,
    tap_positions,
)
from sssbench.ops import (
    ArtistSSS,
    CurvatureModulation,
    DiskSSS,
    Jimenez2012SSS,
    LowRankSSS,
    PreintegratedSSS,
    ReferenceSSS,
    SumOfGaussiansSSS,
    Texturing,
    Translucency,
    halo_guide,
    halo_weight,
    jg10_stretch,
    lab_guide,
    range_weight,
    record_passes,
)
from sssbench.profiles import BurleyNormalized, Dipole, SumOfGaussians
from sssbench.profiles.empirical import empirical_dipole_fit, empirical_pole_fit

FUZZ = settings.get_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def fuzz(weight: float = 1.0) -> settings:
    """The profile's settings with ``weight`` × its examples (slow properties get fewer)."""
    return settings(FUZZ, max_examples=max(2, round(FUZZ.max_examples * weight)))


def backend(name: str) -> contextlib.AbstractContextManager:
    """The gather backend as a context (:func:`sssbench.backend`)."""
    return sssbench.backend(name)


torch.set_num_threads(1)

# ----------------------------------------------------------------------------- values
NAN, INF = math.nan, math.inf
#: absurd values for any scalar argument: NaN, ±inf, 0, negative, magnitudes that over- or
#: underflow float32 in the passes, wrong types
EXTREMES = [NAN, INF, -INF, 0.0, -1.0, 1e-300, 1e-30, 1e-7, 1e7, 1e30, 1e300, True, "1", None]
SIDES = st.sampled_from([1, 1, 2, 3, 5, 8, 13, 24])
DTYPES = st.sampled_from([torch.float32, torch.float64])

SOG_PROFILES = {n: SumOfGaussians.from_table(n) for n in ("skin_jg10", "skin_deon6", "marble_jg10")}
PROFILES = {
    **SOG_PROFILES,
    "burley": BurleyNormalized([1.0, 0.5, 0.25], [0.8, 0.6, 0.4]),
    "marble": Dipole.from_material("marble"),
    "ketchup": Dipole.from_material("ketchup"),
    "empirical_skin1": empirical_dipole_fit("skin1"),
}


# ----------------------------------------------------------------------------- scenes
@st.composite
def scenes(draw, max_side: int = 24, dtype: torch.dtype | None = None) -> GBuffer:
    """A G-buffer with every field: depth flat, sloped, stepped or noisy at 1e-3 … 1e6 mm,
    masks none / binary / fractional / empty, normals facing the camera within ~60°."""
    b = draw(st.integers(1, 2))
    h = min(draw(SIDES), max_side)
    w = min(draw(SIDES), max_side)
    dtype = dtype or draw(DTYPES)
    gen = torch.Generator().manual_seed(draw(st.integers(0, 2**16)))
    z0 = draw(st.sampled_from([1e-3, 1.0, 40.0, 300.0, 5e3, 1e6]))
    fov = draw(st.sampled_from([1e-3, 0.3, 0.8, 2.5]))
    kind = draw(st.sampled_from(["flat", "slope", "steps", "noise"]))
    rows = torch.arange(h, dtype=torch.float64).view(1, 1, h, 1)
    cols = torch.arange(w, dtype=torch.float64).view(1, 1, 1, w)
    depth = torch.full((b, 1, h, w), z0, dtype=torch.float64)
    if kind == "slope":
        depth = depth * (1 + 0.05 * (rows + cols) / (h + w))
    elif kind == "steps":
        depth = depth * torch.where(cols < w / 2, 1.0, 1.5)
    elif kind == "noise":
        depth = depth * (1 + 0.2 * torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64))
    mask_kind = draw(st.sampled_from(["none", "ones", "binary", "fractional", "empty"]))
    mask = {
        "none": None,
        "ones": torch.ones(b, 1, h, w, dtype=torch.float64),
        "binary": (torch.rand(b, 1, h, w, generator=gen) > 0.4).double(),
        "fractional": torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64),
        "empty": torch.zeros(b, 1, h, w, dtype=torch.float64),
    }[mask_kind]
    scale = draw(st.sampled_from([1e-6, 1.0, 1e3]))
    diffuse = scale * torch.rand(b, 3, h, w, generator=gen, dtype=torch.float64)
    tilt = torch.rand(b, 2, h, w, generator=gen, dtype=torch.float64) - 0.5
    normal = torch.cat([tilt * 2, torch.ones(b, 1, h, w, dtype=torch.float64)], 1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    light = torch.randn(b, 3, generator=gen, dtype=torch.float64)
    light = light / light.norm(dim=1, keepdim=True).clamp_min(1e-3)
    g = GBuffer(
        diffuse,
        depth,
        fov,
        albedo=torch.rand(b, 3, h, w, generator=gen, dtype=torch.float64),
        normal=normal,
        mask=mask,
        thickness=10 * torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64),
        light_dir=light,
    )
    return g.to(dtype)


def as_float64(g: GBuffer) -> GBuffer:
    """The float32 G-buffer's values in float64 (so a comparison measures the arithmetic)."""
    return g.to(torch.float64)


# ----------------------------------------------------------------------------- operators
@dataclass
class Spec:
    """An operator to build: ``factory(**kwargs)``; ``scalars``: its scalar arguments (the
    ones extreme values are injected into); ``normalised``: its output is a convex
    combination of the input (non-negative kernel summing to one)."""

    name: str
    factory: Callable[..., object]
    kwargs: dict
    scalars: tuple[str, ...]
    normalised: bool = True
    gather: bool = True

    def build(self) -> object:
        return self.factory(**self.kwargs)


FOLLOW = st.sampled_from([None, "lerp", "gaussian"])
ROTATION = st.sampled_from([None, None, 0.1, 0.3])
SAMPLES = st.sampled_from([1, 2, 3, 7, 9])
SAMPLING = st.sampled_from(["uniform", "power", "importance"])


def _preintegrated(d) -> Spec:
    halo = d(st.sampled_from([None, None, "lab", "bilateral"]))
    kw = dict(
        profile=PROFILES[d(st.sampled_from(sorted(PROFILES)))],
        samples=d(SAMPLES),
        sampling=d(SAMPLING),
        follow_surface=d(FOLLOW),
        rotation=d(ROTATION),
        seed=d(st.integers(0, 3)),
        halo=halo,
        halo_sigma=d(st.sampled_from([None, 0.5, 20.0])) if halo else None,
    )
    return Spec(
        "preintegrated", PreintegratedSSS, kw, ("samples", "rotation", "seed", "halo_sigma")
    )


def _sum_of_gaussians(d, h: int) -> Spec:
    kw = dict(
        profile=SOG_PROFILES[d(st.sampled_from(sorted(SOG_PROFILES)))],
        samples=d(SAMPLES),
        sampling=d(SAMPLING),
        stretch=d(st.sampled_from([None, jg10_stretch(h)])),
        lod=d(st.booleans()),
        lod_threshold=d(st.sampled_from([0.0, 0.5, 2.0])),
        unblurred_first=d(st.sampled_from([None, True, False])),
        follow_surface=d(FOLLOW),
        surface_scale=d(st.sampled_from([None, 0.5, 30.0])),
        rotation=d(ROTATION),
        extent_sigmas=d(st.sampled_from([1.0, 3.0, 5.0])),
    )
    scalars = ("samples", "lod_threshold", "surface_scale", "rotation", "extent_sigmas")
    return Spec("sum_of_gaussians", SumOfGaussiansSSS, kw, scalars)


def _low_rank(d) -> Spec:
    n = d(st.sampled_from([1, 3, 5, 9]))
    kw = dict(
        profile=PROFILES[d(st.sampled_from(sorted(SOG_PROFILES) + ["burley"]))],
        rank=d(st.integers(1, n)),
        n=n,
        extent=d(st.sampled_from([0.5, 3.0, 20.0])),
        follow_surface=d(FOLLOW),
        rotation=d(ROTATION),
    )
    return Spec("low_rank", LowRankSSS, kw, ("rank", "n", "extent", "rotation"), normalised=False)


def _artist(d) -> Spec:
    kw = dict(
        near=d(st.sampled_from([0.0, 0.05, (0.077, 0.034, 0.02)])),
        far=d(st.sampled_from([0.0, 0.5, (1.0, 0.45, 0.25)])),
        weight=d(st.sampled_from([0.0, 0.5, 1.0])),
        scale=d(st.sampled_from([0.1, 9.9, 200.0])),
        samples=d(SAMPLES),
        sampling=d(SAMPLING),
        follow_surface=d(st.sampled_from([None, "lerp", "gaussian"])),
        rotation=d(ROTATION),
    )
    return Spec("artist", ArtistSSS, kw, ("near", "far", "weight", "scale", "samples", "rotation"))


def _jimenez(d) -> Spec:
    kw = dict(
        strength=d(st.sampled_from([0.0, 0.5, 1.0, (0.48, 0.41, 0.28)])),
        falloff=d(st.sampled_from([0.0, 0.3, (1.0, 0.37, 0.3)])),
        width=d(st.sampled_from([0.01, 3.0, 100.0])),
        samples=d(st.sampled_from([1, 2, 9, 17, 33])),
        follow_surface=d(st.booleans()),
        surface_scale=d(st.sampled_from([None, 1.0])),
        quadrature=d(st.sampled_from(["shader", "integrated"])),
        rotation=d(ROTATION),
    )
    scalars = ("strength", "falloff", "width", "samples", "surface_scale", "rotation")
    return Spec("jimenez2012", Jimenez2012SSS, kw, scalars)


def _reference(d, profiles: tuple[str, ...] = ("skin_jg10", "marble_jg10")) -> Spec:
    kw = dict(
        profile=PROFILES[d(st.sampled_from(profiles))],
        tol=d(st.sampled_from([1e-2, 1e-4])),
    )
    return Spec("reference", ReferenceSSS, kw, ("tol",), gather=False)


METHODS = ["preintegrated", "sum_of_gaussians", "low_rank", "artist", "jimenez2012", "reference"]
GATHER_METHODS = METHODS[:-1]


def method_spec(d, name: str, h: int) -> Spec:
    if name == "sum_of_gaussians":
        return _sum_of_gaussians(d, h)
    return {
        "preintegrated": _preintegrated,
        "low_rank": _low_rank,
        "artist": _artist,
        "jimenez2012": _jimenez,
        "reference": _reference,
    }[name](d)


def forward_options(d, spec: Spec, g: GBuffer) -> dict:
    """Per-call inputs: a per-pixel width multiplier (curvature modulation)."""
    if spec.gather and d(st.booleans()):
        b, h, w = g.shape
        gen = torch.Generator().manual_seed(d(st.integers(0, 99)))
        return {"width": 2 * torch.rand(b, 1, h, w, generator=gen, dtype=g.dtype)}
    return {}


def run(op: object, g: GBuffer, **kw) -> torch.Tensor:
    return op(g, **kw)


def assert_names(exc: BaseException, name: str) -> None:
    msg = str(exc)
    assert name in msg, f"{type(exc).__name__} does not name {name!r}: {msg}"


def call_or_named_error(d, call: Callable[..., object], kw: dict, scalars, label: str = ""):
    """``call(**kw)`` after maybe replacing one of ``scalars`` with an extreme value: its
    result, or ``None`` when it raised a ``ValueError`` / ``TypeError`` naming that argument (a
    call without an injected value must not raise)."""
    injected = d(st.sampled_from([None, *scalars])) if scalars else None
    if injected is not None:
        kw[injected] = d(st.sampled_from(EXTREMES))
    note(f"{label} {kw} injected={injected}")
    try:
        return call(**kw)
    except (ValueError, TypeError) as exc:
        assert injected is not None, f"valid call refused: {exc}"
        assert_names(exc, injected)
        return None


def check_output(out: torch.Tensor, g: GBuffer, spec: Spec) -> None:
    """Finite, shaped, typed; a normalised method's output within the input's range."""
    assert out.shape == g.diffuse.shape and out.dtype == g.dtype
    assert bool(torch.isfinite(out).all()), "non-finite output"
    if spec.normalised:
        peak = float(g.diffuse.max())
        tol = 1e-4 if g.dtype == torch.float32 else 1e-10
        assert float(out.min()) >= -tol * peak, float(out.min())
        assert float(out.max()) <= peak * (1 + tol) + 1e-30, (float(out.max()), peak)


# ----------------------------------------------------------------------------- 1. valid or named
@fuzz(2.0)
@given(data=st.data(), g=scenes())
def test_fuzz_methods_valid_or_named_error(data, g):
    d = data.draw
    spec = method_spec(d, d(st.sampled_from(METHODS)), g.shape[1])
    if spec.name == "reference":
        assume(max(g.shape[1:]) <= 13)
    opts = forward_options(d, spec, g)

    def call(**kw):
        return run(spec.factory(**kw), g, **opts)

    out = call_or_named_error(d, call, spec.kwargs, spec.scalars, spec.name)
    if out is not None:
        check_output(out, g, spec)


@fuzz(0.5)
@given(data=st.data(), g=scenes(max_side=8))
def test_fuzz_reference_with_numeric_profiles(data, g):
    spec = _reference(data.draw, ("burley", "marble", "ketchup"))
    note(f"{spec.kwargs}")
    check_output(run(spec.build(), g), g, spec)


# ----------------------------------------------------------------------------- 2. float32 ≈ float64
def pass_tolerance(records, spec: Spec, op: object, g: GBuffer) -> float:
    """docs/numerics.md: per pass ``max(1e-5, K 2⁻²⁴)``, plus ``4 ulp32(max depth) /
    surface_scale`` with follow-surface; summed over the passes (the errors add), times the
    kernel's absolute mass for the signed SVD terms."""
    follow = 0.0
    if getattr(op, "follow_surface", None) is not None:
        scale = op.surface_scale
        smin = float(scale.min()) if isinstance(scale, torch.Tensor) else float(scale)
        zmax = float(g.depth.max())
        ulp = 2.0 ** (math.floor(math.log2(zmax)) - 23)
        follow = 4 * ulp / smin
    mass = 1.0
    if spec.name == "low_rank":
        mass = max(
            float(h.weights.abs().sum(0).max() * v.weights.abs().sum(0).max())
            for h, v in op.kernel.terms
        )
        mass *= len(op.kernel.terms)
    return sum(max(1e-5, r.samples * 2.0**-24) + follow for r in records) * mass


@fuzz(1.5)
@given(data=st.data(), g=scenes(dtype=torch.float32))
def test_fuzz_float32_matches_float64(data, g):
    d = data.draw
    spec = method_spec(d, d(st.sampled_from(GATHER_METHODS)), g.shape[1])
    if spec.name == "sum_of_gaussians":
        spec.kwargs["lod"] = False  # a pixel on the LOD threshold flips with the dtype
    op = spec.build()
    opts = forward_options(d, spec, g)
    with torch.no_grad(), record_passes() as records:
        out32 = run(op, g, **opts)
    g64 = as_float64(g)
    opts64 = {k: v.double() for k, v in opts.items()}
    with torch.no_grad():
        out64 = run(op, g64, **opts64)
    tol = pass_tolerance(records, spec, op, g)
    err = float((out32.double() - out64).abs().max()) / max(float(g64.diffuse.max()), 1e-300)
    note(f"{spec.name} {spec.kwargs} passes={len(records)} err={err:.3g} tol={tol:.3g}")
    assert err <= tol


# ----------------------------------------------------------------------------- 3. layouts
def relayout(t: torch.Tensor | None, how: str) -> torch.Tensor | None:
    """The same values in another memory layout."""
    if t is None:
        return None
    if how == "channels_last":
        return t.contiguous(memory_format=torch.channels_last)
    if how == "slice":  # a view into a larger buffer
        b, c, h, w = t.shape
        big = torch.full((b + 1, c + 2, h + 3, w + 2), 7.0, dtype=t.dtype)
        big[1:, 1 : c + 1, 2 : h + 2, 1 : w + 1] = t
        return big[1:, 1 : c + 1, 2 : h + 2, 1 : w + 1]
    if how == "transposed":
        return t.transpose(2, 3).contiguous().transpose(2, 3)
    if how == "expanded" and t.shape[0] == 1:  # one image broadcast to the batch
        return t.expand(2, *t.shape[1:])
    return t


def with_layout(g: GBuffer, how: str) -> GBuffer:
    """``g`` with its tensors in layout ``how``; ``broadcast`` (each image's first row
    expanded down the image: stride 0) and ``aliased`` (``diffuse`` *is* ``albedo``) change the
    values, so compare with :func:`contiguous` of the result."""
    fields = {k: getattr(g, k) for k in g.__dataclass_fields__}
    if how == "aliased":
        fields["diffuse"] = fields["albedo"]
        return GBuffer(**fields)
    if how == "broadcast":
        for k in ("diffuse", "albedo", "depth", "mask"):
            if fields[k] is not None:
                fields[k] = fields[k][:, :, :1].expand_as(fields[k])
        return GBuffer(**fields)
    if how == "expanded":
        if g.shape[0] != 1:
            return g
        fields["light_dir"] = fields["light_dir"].expand(2, 3)
    return GBuffer(
        **{
            k: relayout(v, how) if k != "light_dir" and isinstance(v, torch.Tensor) else v
            for k, v in fields.items()
        }
    )


def contiguous(g: GBuffer) -> GBuffer:
    """The same values, every tensor its own contiguous memory."""
    fields = {k: getattr(g, k) for k in g.__dataclass_fields__}
    return GBuffer(
        **{
            k: v.clone(memory_format=torch.contiguous_format) if isinstance(v, torch.Tensor) else v
            for k, v in fields.items()
        }
    )


LAYOUTS = st.sampled_from(
    ["channels_last", "slice", "transposed", "expanded", "broadcast", "aliased"]
)


@fuzz(1.5)
@given(data=st.data(), g=scenes(), how=LAYOUTS)
def test_fuzz_layout_invariance(data, g, how):
    d = data.draw
    spec = method_spec(d, d(st.sampled_from(GATHER_METHODS)), g.shape[1])
    op = spec.build()
    moved = with_layout(g, how)
    base = contiguous(moved)
    with torch.no_grad():
        expected = run(op, base)
        out = run(op, moved)
    note(f"{spec.name} {spec.kwargs} layout={how}")
    assert torch.equal(out, expected), float((out - expected).abs().max())


# ----------------------------------------------------------------------------- 4. in place
def check_inplace(data, g: GBuffer, how: str, may_refuse: bool = True) -> None:
    """``forward(inplace=True)`` on ``g`` in layout ``how`` equals the copying call on the same
    values in contiguous memory, writes the target's ``diffuse`` and nothing else. A refusal
    must say why, and is allowed only when ``may_refuse`` (memory really shared): a plain view
    that owns its memory — a window into a larger buffer, channels-last, transposed — is written
    in place (issue 29, class 15: "cannot tell" is not "shares")."""
    d = data.draw
    spec = method_spec(d, d(st.sampled_from(GATHER_METHODS)), g.shape[1])
    op = spec.build()
    opts = forward_options(d, spec, g)
    note(f"{spec.name} {spec.kwargs} layout={how}")
    original = g.diffuse.clone()
    target = with_layout(contiguous(g), how)
    if target.shape != g.shape:
        return  # an expanded batch has no memory of its own per image to write into
    base = contiguous(target)
    with torch.no_grad():
        expected = run(op, base, **opts)
        before = target.diffuse.clone()
        try:
            out = run(op, target, inplace=True, **opts)
        except (ValueError, TypeError) as exc:  # a refusal is allowed, if it says why
            assert may_refuse, f"a safe in-place call ({how}) refused: {exc}"
            assert "inplace" in str(exc) or "diffuse" in str(exc), str(exc)
            assert torch.equal(target.diffuse, before), "refused, but wrote anyway"
            return
    assert out.data_ptr() == target.diffuse.data_ptr()
    assert torch.equal(out, expected), float((out - expected).abs().max())
    assert torch.equal(g.diffuse, original)  # only the target was written


@fuzz(1.5)
@given(
    data=st.data(),
    g=scenes(),
    how=st.sampled_from(["contiguous", "channels_last", "slice", "transposed"]),
)
def test_fuzz_inplace_matches_copy(data, g, how):
    check_inplace(data, g, how, may_refuse=False)


@fuzz(1.0)
@given(data=st.data(), g=scenes(), how=st.sampled_from(["broadcast", "aliased"]))
def test_fuzz_inplace_on_aliased_or_broadcast_fields(data, g, how):
    check_inplace(data, g, how)


# ----------------------------------------------------------------------------- 5. backends
@fuzz(1.5)
@given(data=st.data(), g=scenes())
def test_fuzz_backends_agree(data, g):
    d = data.draw
    spec = method_spec(d, d(st.sampled_from(GATHER_METHODS)), g.shape[1])
    op = spec.build()
    opts = forward_options(d, spec, g)
    with torch.no_grad():
        with backend("torch"), record_passes() as records:
            slow = run(op, g, **opts)
        with backend("native"):
            fast = run(op, g, **opts)
    per_pass = 1e-5 if g.dtype == torch.float32 else 1e-12  # docs/numerics.md
    tol = per_pass * max(1, len(records)) * max(float(g.diffuse.max()), 1e-300)
    note(f"{spec.name} {spec.kwargs} passes={len(records)}")
    assert float((slow - fast).abs().max()) <= tol


# ----------------------------------------------------------------------------- 6. gradients
@fuzz(1.0)
@given(data=st.data(), g=scenes(max_side=8, dtype=torch.float64))
def test_fuzz_gradients_finite_and_exact(data, g):
    d = data.draw
    spec = method_spec(d, d(st.sampled_from(GATHER_METHODS)), g.shape[1])
    op = spec.build()
    note(f"{spec.name} {spec.kwargs}")
    diffuse = g.diffuse.clone().requires_grad_(True)
    width = torch.rand(g.shape[0], 1, *g.shape[1:], dtype=g.dtype) + 0.5
    width.requires_grad_(True)
    kw = {"width": width} if spec.gather else {}
    with backend("torch"):
        out = run(op, g.replace(diffuse=diffuse), **kw)
        weights = torch.rand_like(out)
        gd, gw = torch.autograd.grad((out * weights).sum(), [diffuse, width], allow_unused=True)
        assert bool(torch.isfinite(gd).all())
        if gw is not None:
            assert bool(torch.isfinite(gw).all())
        if g.diffuse.numel() <= 3 * 16:  # linear in diffuse: finite differences are exact
            torch.autograd.gradcheck(
                lambda x: run(op, g.replace(diffuse=x)), ((g.diffuse + 1.0).requires_grad_(),)
            )


# ----------------------------------------------------------------------------- 7. builders
def _profile_case(d) -> tuple[Callable[[], object], tuple[str, ...], dict]:
    which = d(st.sampled_from(["sog", "burley", "dipole", "pole"]))
    if which == "sog":
        kw = {"variances": d(st.sampled_from([1e-6, 0.5, 1e4])), "weights": 0.5}

        def sog(variances, weights):  # numbers become (2,) / (2, 3) float64, others pass as is
            num = (int, float)
            v = torch.tensor([variances, 2.0 * variances]) if type(variances) in num else variances
            w = (
                torch.full((2, 3), float(weights), dtype=torch.float64)
                if type(weights) in num
                else weights
            )
            return SumOfGaussians(v.double() if isinstance(v, torch.Tensor) else v, w)

        return sog, ("variances", "weights"), kw
    if which == "burley":
        kw = {"d": d(st.sampled_from([1e-3, 1.0, 1e3])), "albedo": d(st.sampled_from([0.0, 0.5]))}
        return BurleyNormalized, ("d", "albedo"), kw
    if which == "dipole":
        kw = {
            "sigma_s_prime": d(st.sampled_from([0.01, 1.0, 100.0])),
            "sigma_a": d(st.sampled_from([0.0, 0.01, 10.0])),
            "eta": d(st.sampled_from([1.0, 1.3, 3.0])),
        }
        return Dipole, ("sigma_s_prime", "sigma_a", "eta"), kw
    kw = {"sigma_tr": d(st.sampled_from([0.0, 0.1, 10.0])), "z": d(st.sampled_from([0.01, 1.0]))}
    return empirical_pole_fit, ("sigma_tr", "z"), kw


@fuzz(2.0)
@given(data=st.data())
def test_fuzz_profiles_valid_or_named_error(data):
    d = data.draw
    factory, scalars, kw = _profile_case(d)
    p = call_or_named_error(d, factory, kw, scalars)
    if p is None:
        return
    total = p.total()
    assert bool(torch.isfinite(total).all())  # fitted weights may be negative
    if bool((total > 0).all()):
        r = p.radius(1e-2)
        assert math.isfinite(r) and r >= 0
        inf = torch.tensor([-math.inf, math.inf], dtype=torch.float64)
        ends = p.preintegrated_cdf(inf)
        assert torch.allclose(ends[1] - ends[0], total, rtol=1e-6)


def _kernel_case(d) -> tuple[Callable[[], Kernel1D], tuple[str, ...], dict, bool]:
    """(builder, scalar names, kwargs, normalised)."""
    which = d(
        st.sampled_from(["preintegrated", "artist", "jimenez2012", "low_rank", "guided", "taps"])
    )
    prof = PROFILES[d(st.sampled_from(sorted(SOG_PROFILES) + ["burley"]))]
    if which == "preintegrated":
        kw = {
            "samples": d(SAMPLES),
            "sampling": d(SAMPLING),
            "extent": d(st.sampled_from([None, 2.0])),
        }
        return (lambda **k: preintegrated(prof, **k)), ("samples", "extent"), kw, True
    if which == "artist":
        kw = {
            "near": 0.1,
            "far": 0.5,
            "weight": 0.5,
            "scale": d(st.sampled_from([0.1, 10.0])),
            "samples": d(SAMPLES),
            "sampling": d(SAMPLING),
        }
        return artist, ("near", "far", "weight", "scale", "samples"), kw, True
    if which == "jimenez2012":
        kw = {
            "strength": 0.5,
            "falloff": d(st.sampled_from([0.0, 0.4, 1e3])),
            "samples": d(st.sampled_from([1, 2, 9, 33])),
        }
        return jimenez2012, ("strength", "falloff", "samples"), kw, True
    if which == "guided":
        kw = {
            "k": d(st.sampled_from([0.0, 2.0, 4.0])),
            "b": d(st.sampled_from([1.0, 50.0])),
            "extent": 3.0,
            "n": d(st.sampled_from([3, 9])),
        }
        return (lambda **k: guided(prof, **k)), ("k", "b", "extent", "n"), kw, True
    if which == "low_rank":
        kw = {"rank": d(st.integers(1, 3)), "extent": d(st.sampled_from([1.0, 5.0])), "n": 5}
        return ((lambda **k: low_rank(prof, **k).terms[0][0]), ("rank", "extent", "n"), kw, False)
    kw = {
        "samples": d(SAMPLES),
        "sampling": d(st.sampled_from(["uniform", "power"])),
        "extent": d(st.sampled_from([1e-6, 1.0, 1e6])),
        "exponent": d(st.sampled_from([0.5, 2.0])),
    }

    def taps(**k) -> Kernel1D:
        c, e = tap_positions(**k)
        assert bool((e[1:] >= e[:-1]).all())
        return Kernel1D(c, torch.full((c.numel(), 3), 1.0 / c.numel(), dtype=torch.float64))

    return taps, ("samples", "extent", "exponent"), kw, True


@fuzz(2.0)
@given(data=st.data())
def test_fuzz_kernels_valid_or_named_error(data):
    d = data.draw
    builder, scalars, kw, normalised = _kernel_case(d)
    k = call_or_named_error(d, builder, kw, scalars)
    if k is None:
        return
    assert isinstance(k, Kernel1D)
    assert bool(torch.isfinite(k.offsets).all() and torch.isfinite(k.weights).all())
    assert bool((k.offsets[1:] >= k.offsets[:-1]).all())
    if normalised:
        assert torch.allclose(k.sum(), torch.ones(3, dtype=k.weights.dtype), atol=1e-12)
        assert torch.allclose(k.offsets, -k.offsets.flip(0), atol=1e-12 * max(1.0, k.extent))


@fuzz(1.0)
@given(data=st.data())
def test_fuzz_kernel_matrix_and_cells(data):
    d = data.draw
    extent = d(st.sampled_from([1e-6, 0.3, 10.0, 1e6, *EXTREMES]))
    n = d(st.sampled_from([1, 2, 5, 0, 2050, 1.5]))
    prof = PROFILES[d(st.sampled_from(sorted(SOG_PROFILES)))]
    try:
        c = cell_centres(extent, n)
        m = kernel_matrix(prof, extent, n)
    except (ValueError, TypeError) as exc:
        assert "extent" in str(exc) or " n " in f" {exc}" or str(exc).startswith("n ")
        return
    assert torch.allclose(c, -c.flip(0), atol=1e-12 * extent)
    assert bool(torch.isfinite(m).all()) and bool((m >= 0).all())
    assert bool((m.sum((1, 2)) <= prof.total() * (1 + 1e-9)).all())  # energy inside the square


# ----------------------------------------------------------------------------- 8. extensions
@fuzz(2.0)
@given(data=st.data(), g=scenes())
def test_fuzz_extensions_valid_or_named_error(data, g):
    d = data.draw
    which = d(st.sampled_from(["translucency", "curvature", "texturing", "halo", "range"]))
    if which == "translucency":
        kw = {
            "profile": d(st.sampled_from(["skin_deon6", "skin_jg10"])),
            "translucency": d(st.sampled_from([0.0, 0.5, 0.99])),
            "width": d(st.sampled_from([0.1, 8.25, 100.0])),
            "form": d(st.sampled_from(["jimenez2012", "deon"])),
            "intensity": d(st.sampled_from([0.0, 1.0, 1e3])),
        }
        scalars = ("translucency", "width", "intensity")

        def call(**k):
            return Translucency(**k)(g)

    elif which == "curvature":
        kw = {
            "strategy": d(st.sampled_from(["increase", "reduce", "reduce_min"])),
            "reference": d(st.sampled_from([0.01, 0.05, 1.0])),
            "gain": d(st.sampled_from([0.0, 1.0, 10.0])),
            "minimum": d(st.sampled_from([0.0, 0.5, 1.0])),
            "mode": d(st.sampled_from(["divergence", "magnitude"])),
            "smooth": d(st.sampled_from([1, 3, 5, 25])),
        }
        scalars = ("reference", "gain", "minimum", "smooth")

        def call(**k):
            return CurvatureModulation(**k)(g)

    elif which == "texturing":
        kw = {"mode": d(st.sampled_from(["pre", "post", "sqrt"]))}
        scalars = ()

        def call(**k):
            t = Texturing(**k)
            out = t(g.diffuse, g)
            # closed form: both halves without a blur are albedo · image where mask > 0
            active = g.mask_or_ones() > 0
            expect = torch.where(active, g.albedo * g.diffuse, g.diffuse)
            assert torch.allclose(out, expect, rtol=1e-5 if g.dtype == torch.float32 else 1e-12)
            return out

    elif which == "halo":
        kw = {
            "kind": d(st.sampled_from(["bilateral", "lab"])),
            "sigma": d(st.sampled_from([None, 0.1, 10.0])),
            "min_cos": d(st.sampled_from([1e-3, 0.02, 1.0])),
        }
        scalars = ("sigma", "min_cos")

        def call(kind, sigma, min_cos):
            opts = {"min_cos": min_cos} if kind == "bilateral" else {}
            if kind == "lab" and min_cos != 0.02:  # lab takes no min_cos: exercise lab_guide
                return lab_guide(g)
            guide, f = halo_weight(g, kind, sigma, **opts)
            n = guide.shape[1]
            wts = f(guide[0].reshape(n, -1).T, guide[0].reshape(n, -1).T.flip(0))
            assert bool(((wts >= 0) & (wts <= 1)).all())
            return guide if kind == "lab" else halo_guide(g, min_cos=min_cos)

    else:
        kw = {"sigma": d(st.sampled_from([1e-3, 1.0, 1e3]))}
        scalars = ("sigma",)

        def call(sigma):
            return range_weight(sigma)(g.diffuse[0].reshape(3, -1).T, g.albedo[0].reshape(3, -1).T)

    out = call_or_named_error(d, call, kw, scalars, which)
    if out is None:
        return
    assert bool(torch.isfinite(out).all())
    if which in ("translucency", "curvature", "range"):
        assert bool((out >= 0).all())


# ----------------------------------------------------------------------------- 8. new surfaces
# Issue 29: files, Monte Carlo, optimised kernels, the exporter and the report under the same
# hostile inputs (the disk has its own properties). Each call is a named error (one line) or a
# valid result; nothing else reaches stdout / stderr.
SEEDS = [0, 1, 2**31, 2**32 - 1, 2**32, 2**32 + 1, 2**63, 2**64, -1, True, 1.0, "1", None]


def one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert msg and "\n" not in msg, f"not one line: {msg!r}"
    return msg


@contextlib.contextmanager
def silent_fds():
    """Fail if anything is written to file descriptors 1 or 2 (the OpenEXR binding's own
    warnings, a traceback printed by a console script)."""
    import sys
    import tempfile

    with tempfile.TemporaryFile() as tmp:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        saved = {fd: os.dup(fd) for fd in (1, 2)}
        for fd in saved:
            os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            for stream in (sys.stdout, sys.stderr):
                stream.flush()
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
        tmp.seek(0)
        written = tmp.read().decode("utf-8", "replace")
    assert written == "", f"written to stdout/stderr: {written[:300]!r}"


@fuzz(1.0)
@given(data=st.data(), g=scenes(max_side=8))
def test_fuzz_io_round_trip_and_damage(data, g):
    """Every field through ``.exr`` / ``.npz`` bit for bit (float32; float64 in npz; a float64
    EXR refused naming its rounding); a damaged copy (truncated, bytes overwritten, a huge
    data window) is a one-line ``ValueError`` or reads as a valid G-buffer, printing nothing."""
    import struct
    import tempfile
    from dataclasses import fields as dataclass_fields

    from sssbench.io import read_gbuffer, write_gbuffer

    d = data.draw
    g = GBuffer(**{f.name: getattr(g, f.name) for f in dataclass_fields(GBuffer)}
                | {"diffuse": g.diffuse[:1], "depth": g.depth[:1], "albedo": g.albedo[:1],
                   "normal": g.normal[:1], "thickness": g.thickness[:1],
                   "mask": None if g.mask is None else g.mask[:1],
                   "light_dir": g.light_dir[:1],
                   "profile_id": torch.randint(0, 5, g.depth[:1].shape)})  # fmt: skip
    suffix = d(st.sampled_from([".exr", ".npz"]))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "g" + suffix)
        if suffix == ".exr" and g.dtype == torch.float64:
            with pytest.raises(ValueError, match="allow_rounding"):
                write_gbuffer(path, g)
            return
        write_gbuffer(path, g)
        with silent_fds():
            back = read_gbuffer(path)
        for f in dataclass_fields(GBuffer):
            a, b = getattr(g, f.name), getattr(back, f.name)
            assert (a is None) == (b is None), f.name
            if isinstance(a, torch.Tensor):
                assert torch.equal(a.to(b.dtype), b), f.name
            else:
                assert a == b, f.name
        raw = open(path, "rb").read()
        damage = d(st.sampled_from(["truncate", "overwrite", "huge"]))
        # positions as fractions: the file's length is not the same from run to run (the
        # version string, zip timestamps), and hypothesis needs the same draws
        at = d(st.integers(0, 999)) * len(raw) // 1000
        if damage == "truncate":
            raw = raw[:at]
        elif damage == "overwrite":
            raw = raw[:at] + bytes(d(st.binary(min_size=1, max_size=16))) + raw[at + 16 :]
        elif suffix == ".exr":
            tag = b"dataWindow\0box2i\0"
            at = raw.index(tag) + len(tag) + 4
            side = d(st.sampled_from([2**15, 2**16, 2**20]))
            raw = raw[:at] + struct.pack("<4i", 0, 0, side - 1, side - 1) + raw[at + 16 :]
        open(path, "wb").write(raw)
        note(f"{suffix} {damage} {len(raw)} bytes")
        with silent_fds():
            try:
                read_gbuffer(path)
            except (ValueError, OSError) as exc:
                one_line(exc)


@fuzz(1.0)
@given(data=st.data())
def test_fuzz_monte_carlo_valid_or_named_error(data):
    """The photon walk (half-space or slab) with extreme albedo, anisotropy, η, photons and
    seeds: a named one-line error or finite non-negative tallies; a seed is honoured in full
    or refused (the same seed plus 2³², which the generator would fold onto it, is refused)."""
    from sssbench.mc.walk import walk

    d = data.draw
    kw = dict(
        albedo=d(st.sampled_from([0.0, 0.3, 0.9, 0.999])),
        photons=d(st.sampled_from([2, 17, 200])),
        g=d(st.sampled_from([0.0, 0.5, -0.5])),
        eta=d(st.sampled_from([1.0, 1.4])),
        thickness=d(st.sampled_from([math.inf, 0.5, 5.0])),
        seed=d(st.sampled_from(SEEDS[:4])),
        progress=False,
    )
    if d(st.booleans()):
        kw["seed"] = d(st.sampled_from(SEEDS))
        injected = "seed"
    else:
        injected = d(
            st.sampled_from(
                [
                    None,
                    "albedo",
                    "photons",
                    "g",
                    "eta",
                    "thickness",
                    "roulette_radius",
                    "kill_radius",
                ]
            )
        )
        if injected is not None:
            kw[injected] = d(st.sampled_from(EXTREMES))
    note(f"{kw} injected={injected}")
    try:
        t = walk(**kw)
    except (ValueError, TypeError) as exc:
        assert injected is not None, f"valid walk refused: {exc}"
        assert_names(exc, injected)
        one_line(exc)
        return
    top = t.estimate("top")
    assert all(math.isfinite(float(v)) and float(v) >= 0 for v in top), top
    # the seed it honoured, folded above 32 bits, would give the same photons: refused
    with pytest.raises(ValueError, match="seed"):
        walk(**(kw | {"seed": int(kw["seed"]) + 2**32}))


@fuzz(0.5)
@given(data=st.data(), arg=st.sampled_from(["seed", "photons", "batches", "workers", "material"]))
def test_fuzz_scene_monte_carlo_refuses_before_walking(data, arg):
    """``scene_mc`` refuses an absurd argument by its own name, before any photon is walked
    (the walks are stubbed out to prove it), and a medium that scatters nothing back is an
    error, never an all-NaN image."""
    import data_synth
    import sssbench.mc.scene as scene

    d = data.draw
    value = d(st.sampled_from(SEEDS if arg == "seed" else EXTREMES))
    if arg == "material":
        value = d(st.sampled_from([(0.0, 1.0), ((1.0, 0.0, 1.0), 1.0), "nope", 3, None]))
    kw = {"photons": 60, "batches": 2, "workers": 1, "seed": 0, "cache": False, "progress": False}
    material = value if arg == "material" else "skin1"
    if arg != "material":
        kw[arg] = value
    valid = (
        arg == "seed"
        and isinstance(value, int)
        and not isinstance(value, bool)
        and (0 <= value < 2**32)
    )
    assume(not valid and not (arg in ("photons", "workers") and value is None))  # defaults
    g = data_synth.make_scene("step_edge", (6, 6), fields=[])
    note(f"{arg}={value!r}")

    def no_walk(*a, **k):
        raise AssertionError("walked before refusing")

    saved = scene._run_batches, scene._albedo
    scene._run_batches = scene._albedo = no_walk
    try:
        with pytest.raises((ValueError, TypeError)) as info:
            scene.scene_mc("step_edge", g, {}, material, **kw)
    finally:
        scene._run_batches, scene._albedo = saved
    msg = one_line(info.value)
    assert arg in msg or (arg == "material" and "sigma_s_prime" in msg), msg


@fuzz(1.0)
@given(data=st.data())
def test_fuzz_optimised_kernel_loss_and_arguments(data):
    """The fit's loss has finite value and gradient wherever it is defined — also where the
    result matches the reference exactly (a term at 0); ``optimise`` refuses absurd arguments
    by name before any scene is built."""
    from sssbench.tune import optimise as opt

    d = data.draw
    h, w = d(SIDES), d(SIDES)
    gen = torch.Generator().manual_seed(d(st.integers(0, 99)))
    ref = torch.rand(1, 3, h, w, generator=gen, dtype=torch.float64)
    kind = d(st.sampled_from(["exact", "near", "far", "partly"]))
    half = torch.rand(1, 1, h, w, generator=gen) > 0.5
    res = {
        "exact": ref.clone(),
        "near": ref * (1 + 1e-12),
        "far": 3 * ref,
        "partly": torch.where(half, ref, 0.0),
    }[kind]
    res.requires_grad_(True)
    mask = d(st.sampled_from([None, "half"]))
    m = None if mask is None else (torch.arange(w) < max(1, w // 2)).double().expand(1, 1, h, w)
    loss = opt.rel_rms_loss(res, ref, m)
    loss.backward()
    note(f"{kind} mask={mask} loss={float(loss.detach())}")
    assert math.isfinite(float(loss.detach())) and bool(torch.isfinite(res.grad).all())

    arg = d(st.sampled_from(["taps", "pixel_mm", "steps", "lr", "method", "training"]))
    value = d(st.sampled_from(EXTREMES + ["nope", -3, 10**6]))
    kw = {"taps": 3, "pixel_mm": 1.0, "steps": 0, "lr": 0.05, "method": "preintegrated"}
    kw[arg] = value

    class Accepted(Exception):
        """The arguments passed every check: the fit would start here (not run: too slow)."""

    def accepted(self, pixel_mm):
        raise Accepted

    saved = opt.TrainingScene.build
    opt.TrainingScene.build = accepted
    try:
        opt.optimise(SOG_PROFILES["skin_jg10"], cache=False, **kw)
    except (ValueError, TypeError) as exc:
        assert_names(exc, arg)
        one_line(exc)
    except Accepted:
        pass  # a valid value (e.g. steps=10**6, lr=1e7): accepted
    finally:
        opt.TrainingScene.build = saved


EXPORT_METHODS = ["preintegrated", "sum_of_gaussians", "artist", "jimenez2012", "disk", "nope"]


@fuzz(0.5)
@given(data=st.data())
def test_fuzz_exporter_exits_0_or_2_with_one_line(data):
    """``sssbench-export-kernel`` with random overrides, widths, formats and ``--out`` targets
    (a file, a directory, a path under a file): exit 0 with the kernels, or exit 2 with one
    stderr line — never a traceback."""
    import io
    import sys
    import tempfile

    from sssbench.export import main

    d = data.draw
    argv = [
        f"method={d(st.sampled_from(EXPORT_METHODS))}",
        f"samples={d(st.sampled_from([1, 5, 9, 0, -3, 'x']))}",
        "--format", d(st.sampled_from(["glsl", "hlsl", "json", "xml"])),
    ]  # fmt: skip
    if d(st.booleans()):
        argv += ["--sss-width", str(d(st.sampled_from([1.0, 0.0, -1.0, 1e30, "nan"])))]
    with tempfile.TemporaryDirectory() as tmp:
        open(os.path.join(tmp, "file"), "w").close()
        out = d(st.sampled_from(["ok.txt", ".", "file/k.glsl", "missing/k.glsl"]))
        argv += ["--out", os.path.join(tmp, out)]
        note(f"{argv}")
        err, stdout = io.StringIO(), io.StringIO()
        saved = sys.stderr, sys.stdout
        sys.stderr, sys.stdout = err, stdout
        try:
            code = main(argv)
        finally:
            sys.stderr, sys.stdout = saved
    lines = err.getvalue().strip().splitlines()
    assert code in (0, 2), code
    assert (code == 0) == (lines == []), (code, lines)
    if code == 2:
        assert len(lines) == 1 and lines[0].startswith("sssbench-export-kernel: "), lines


@fuzz(0.3)
@given(data=st.data())
def test_fuzz_report_never_writes_its_store(data):
    """``sssbench-report`` on a store with random rows (ok / failed, NaN or missing metrics,
    duplicate ok rows of an old store without the one-ok index, WAL or rollback journal): exit
    0 and the store byte for byte what it was, or exit 2 with one line."""
    import io
    import sqlite3
    import sys
    import tempfile

    from sssbench import report
    from sssbench.store.tracking import _SCHEMA, RunRecord, RunStore

    d = data.draw
    old = d(st.booleans())
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "s.sqlite")
        row = st.tuples(
            st.sampled_from(["ok", "failed"]),
            st.integers(0, 2),
            st.sampled_from([0.1, math.nan, None]),
        )
        rows = d(st.lists(row, max_size=5))
        if old:
            schema = ";".join(x for x in _SCHEMA.split(";") if "runs_one_ok" not in x)
            with sqlite3.connect(path) as conn:
                conn.execute(f"PRAGMA journal_mode = {d(st.sampled_from(['delete', 'wal']))}")
                conn.executescript(schema)
                for status, point, value in rows:
                    conn.execute(
                        "INSERT INTO runs (config_hash, config_json, scene, method, status, "
                        "started_at, finished_at, rel_rms) VALUES (?, ?, 's', 'm', ?, 't', 't', ?)",
                        (f"h{point}", json.dumps({"scene": "s", "method": "m", "p": point}),
                         status, value),
                    )  # fmt: skip
            conn.close()
        else:
            store = RunStore(path)
            for status, point, value in rows:
                run = RunRecord(
                    config={"scene": "s", "method": "m", "p": point},
                    status=status,
                    error=None if status == "ok" else "x",
                    metrics={} if value is None else {"rel_rms": value},
                )
                store.record(run)
        files = sorted(os.listdir(tmp))
        before = {f: open(os.path.join(tmp, f), "rb").read() for f in files}
        note(f"old={old} rows={rows}")
        err = io.StringIO()
        saved = sys.stderr
        sys.stderr = err
        try:
            code = report.main([path, "--out", os.path.join(tmp, "out")])
        finally:
            sys.stderr = saved
        after = {f: open(os.path.join(tmp, f), "rb").read() for f in files}
        assert sorted(x for x in os.listdir(tmp) if x != "out") == files
    assert after == before, "the report changed its store"
    lines = err.getvalue().strip().splitlines()
    assert code == 0 or (code == 2 and len(lines) == 1), (code, lines)


@pytest.mark.parametrize("name", ["ci", "long"])
def test_profiles_are_registered(name):
    p = settings.get_profile(name)
    assert p.deadline is None and p.database is None
    assert p.max_examples >= settings.get_profile("ci").max_examples
    assert name != "ci" or p.derandomize


# ----------------------------------------------------------------------------- 9. the disk
DISK_PROFILES = ("skin_deon6", "skin_jg10", "burley", "marble", "empirical_skin1")


def _disk(d, exact: bool = False) -> Spec:
    """A :class:`DiskSSS` with random options; ``exact``: none whose result depends on a
    threshold of the estimate (the adaptive count: a pixel on it flips with the dtype)."""
    estimator = d(st.sampled_from(["sssbench", "hdrp"]))
    names = d(st.sampled_from([[n] for n in DISK_PROFILES] + [["skin_deon6", "burley"]]))
    kw = dict(
        profile=PROFILES[names[0]] if len(names) == 1 else [PROFILES[n] for n in names],
        samples=d(st.sampled_from([1, 3, 8, 17])),
        rotation=d(st.sampled_from(["hash", "ign", "blue_noise", "none"])),
        frames=d(st.sampled_from([1, 2])),
        seed=d(st.sampled_from([0, 7, 2**33 + 7, 2**63 - 1])),
        estimator=estimator,
    )
    if len(names) > 1:
        kw["cross_profile"] = d(st.sampled_from(["reject", "accept"]))
    if estimator == "sssbench":
        kw.update(
            pattern=d(st.sampled_from(["fibonacci", "r2"])),
            normalise=d(st.booleans()),
            jitter_radius=d(st.sampled_from([None, True, False])),
            fetch=d(st.sampled_from(["point", "bilinear"])),
            surface_area=d(st.booleans()),
        )
        if not exact and d(st.booleans()):
            kw["adaptive"] = (2, 8)
            kw["adaptive_target"] = d(st.sampled_from([0.01, 0.5]))
    scalars = ("samples", "frames", "seed") + (("adaptive_target",) if "adaptive" in kw else ())
    normalised = kw.get("normalise", True)
    return Spec("disk", DiskSSS, kw, scalars, normalised=normalised, gather=False)


def disk_scene(g: GBuffer, spec: Spec) -> GBuffer:
    """``g`` with a ``profile_id`` when the disk has a list of profiles."""
    if isinstance(spec.kwargs["profile"], list):
        b, h, w = g.shape
        ids = (torch.arange(w).view(1, 1, 1, w) >= w // 2).to(torch.int64)
        return g.replace(profile_id=ids.expand(b, 1, h, w).contiguous())
    return g


@fuzz(1.5)
@given(data=st.data(), g=scenes(max_side=13))
def test_fuzz_disk_valid_or_named_error(data, g):
    d = data.draw
    spec = _disk(d)
    g = disk_scene(g, spec)

    def call(**kw):
        return spec.factory(**kw)(g)

    out = call_or_named_error(d, call, spec.kwargs, spec.scalars, spec.name)
    if out is not None:
        check_output(out, g, spec)


@fuzz(1.0)
@given(data=st.data(), g=scenes(max_side=13, dtype=torch.float32))
def test_fuzz_disk_float32_matches_float64(data, g):
    spec = _disk(data.draw, exact=True)
    g = disk_scene(g, spec)
    op = spec.build()
    with torch.no_grad(), record_passes() as records:
        out32 = op(g)
    with torch.no_grad():
        out64 = op(as_float64(g))
    # per pass max(1e-5, K 2⁻²⁴) (docs/numerics.md); the plain Monte Carlo mean (normalise
    # off) is not a convex combination: its error is relative to its own largest value
    tol = sum(max(1e-5, r.samples * 2.0**-24) for r in records) / max(1, spec.kwargs["frames"])
    scale = max(float(g.diffuse.double().abs().max()), float(out64.abs().max()), 1e-300)
    err = float((out32.double() - out64).abs().max()) / scale
    note(f"{spec.kwargs} passes={len(records)} err={err:.3g} tol={tol:.3g}")
    assert err <= max(tol, 1e-5)


@fuzz(1.0)
@given(data=st.data(), g=scenes(max_side=13), how=LAYOUTS)
def test_fuzz_disk_layout_invariance(data, g, how):
    spec = _disk(data.draw)
    moved = disk_scene(with_layout(g, how), spec)
    base = contiguous(moved)
    op = spec.build()
    note(f"{spec.kwargs} layout={how}")
    assert torch.equal(op(moved), op(base))


@fuzz(1.0)
@given(data=st.data(), g=scenes(max_side=13), how=st.sampled_from(["contiguous", "slice"]))
def test_fuzz_disk_inplace_matches_copy(data, g, how):
    spec = _disk(data.draw)
    target = disk_scene(with_layout(contiguous(g), how), spec)
    op = spec.build()
    expected = op(contiguous(target))
    out = op(target, inplace=True)
    assert out.data_ptr() == target.diffuse.data_ptr()
    assert torch.equal(out, expected)


@fuzz(1.0)
@given(data=st.data(), g=scenes(max_side=13))
def test_fuzz_disk_image_in_a_batch_equals_it_alone(data, g):
    spec = _disk(data.draw)
    g = disk_scene(g, spec)
    op = spec.build()
    together = op(g)
    fields = {k: getattr(g, k) for k in g.__dataclass_fields__}
    for i in range(g.shape[0]):
        one = {
            k: v[i : i + 1] if isinstance(v, torch.Tensor) and k != "light_dir" else v
            for k, v in fields.items()
        }
        one["light_dir"] = None if g.light_dir is None else g.light_dir[i : i + 1]
        note(f"{spec.kwargs} image {i}")
        alone = op(GBuffer(**one))
        # to rounding: torch's vectorised exp / sqrt may round a tensor's tail lanes apart
        tol = (1e-12 if g.dtype == torch.float64 else 1e-5) * max(float(alone.abs().max()), 1e-300)
        assert float((alone - together[i : i + 1]).abs().max()) <= tol


@fuzz(2.0)
@given(seed=st.integers(0, 2**63 - 1), bit=st.integers(0, 62), frame=st.integers(0, 99))
def test_fuzz_disk_every_seed_bit_counts(seed, bit, frame):
    # the per-pixel noise of seed s and of s with one bit flipped differ (the key folding is a
    # bijection per 32-bit half, docs/reliability.md), for the hash and for IGN's frame offset
    from sssbench.ops.disk import _ign_frame, hash_uniform

    other = seed ^ (1 << bit)
    pixels = torch.arange(64)
    assert not torch.equal(
        hash_uniform(pixels, seed, frame, 0), hash_uniform(pixels, other, frame, 0)
    )
    assert _ign_frame(seed, frame, 0) != _ign_frame(other, frame, 0)

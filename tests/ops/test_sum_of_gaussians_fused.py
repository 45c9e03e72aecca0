"""The sweep of several weight sets over shared taps (``separable_sweep``) and the method built
on it (``sum_of_gaussians_fused``).

The sweep is checked against its definition: ``S`` separate single-set
:func:`~sssbench.ops.separable_pass` calls (and their sum with the coefficients, in set
order), on the same backend and instruction-set level (the ``simd`` fixture of
``test_gather_backends``), bitwise in every follow-surface mode (the same operations in the
same order per set, the gaussian's exp included since both run the same code); the native
sweep against the torch loop's sweep (two implementations) as ``BACKEND_AGREEMENT`` states.
The method is checked against an independent slow implementation: the dense 1D interpolation
matrices of its taps on a flat plane, ``Σ_s c_s B_s X A_sᵀ`` per channel in float64.
"""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D
from sssbench.kernels.preintegrated import preintegrated, profile_cells, shared_gaussian_taps
from sssbench.ops import FusedSumOfGaussiansSSS, native, separable_pass, separable_sweep
from sssbench.ops.gather import MAX_SETS, backend
from sssbench.profiles import SumOfGaussians

LEVELS = native.simd_levels() or ("scalar",)
SKIN = SumOfGaussians.from_table("skin_deon6")
needs_native = pytest.mark.skipif(native.library() is None, reason="no C compiler")


@pytest.fixture(params=LEVELS)
def simd(request):
    """Run the test's native passes at each supported instruction-set level."""
    with native.simd(request.param):
        yield request.param


def scene(seed=0, b=1, h=23, w=31, dtype=torch.float64, cover=0.7, bottom=0):
    """Random image, depth with slopes and a step (a silhouette), random mask strength with
    holes; ``bottom`` rows at the bottom masked out (the fan-in then reads its strips'
    windows in place, which it does only away from the image's last rows)."""
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(b, 3, h, w, generator=g, dtype=dtype)
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij"
    )
    depth = 60 + 0.8 * xx + 0.3 * yy + 25.0 * (xx > w / 2) + 10.0 * (yy > h / 3)
    depth = depth.expand(b, 1, h, w) + 3 * torch.rand(b, 1, h, w, generator=g, dtype=dtype)
    mask = torch.rand(b, 1, h, w, generator=g, dtype=dtype)
    mask = mask * (torch.rand(b, 1, h, w, generator=g, dtype=dtype) < cover)
    if bottom:
        mask[..., h - bottom :, :] = 0
    return GBuffer(img, depth.contiguous(), 0.7, mask=mask)


def kernels(n_sets=3, taps=7, reach=4.0):
    """``n_sets`` weight sets (Gaussians of different widths, one per channel triple) at the
    same offsets; the widest reaches past the border of the small scenes."""
    offsets = torch.linspace(-reach, reach, taps, dtype=torch.float64)
    out = []
    for s in range(n_sets):
        var = torch.tensor([0.3, 1.0, 2.5], dtype=torch.float64) * (1 + 2 * s)
        wt = torch.exp(-0.5 * offsets[:, None] ** 2 / var)
        out.append(Kernel1D(offsets, wt / wt.sum(0)))
    return out


def separate(images, ks, direction, g, coefficients=None, **kw):
    """The definition: one separable_pass per set (and the sum ``0 + c_0 r_0 + c_1 r_1 + …``)."""
    if coefficients is None:
        return torch.stack([separable_pass(images, k, direction, g, **kw) for k in ks])
    total = torch.zeros_like(images[0])
    for img, k, c in zip(images, ks, coefficients, strict=True):
        total = total + c.view(1, 3, 1, 1) * separable_pass(img, k, direction, g, **kw)
    return total


OPTIONS = [
    {},
    {"follow_surface": "lerp", "surface_scale": 4.0},
    {"follow_surface": "gaussian", "surface_scale": 2.5},
    {"follow_surface": "lerp", "surface_scale": torch.tensor([1.0, 4.0, 20.0])},
    {"use_mask": False},
]


CASES = {
    "small": dict(),  # taps clamp at the borders
    "sparse-in-place": dict(h=30, w=150, cover=0.1, bottom=8),  # narrow strips, read in place
    "21-taps": dict(h=40, w=50, cover=0.9, bottom=8, taps=21, reach=2.0),  # two tap chunks
}
#: every option on the first two cases; the two-chunk case with the three follow modes
CASE_OPTIONS = [
    pytest.param(CASES[c], o, id=f"{c}-{'-'.join(o) or 'plain'}")
    for c in CASES
    for o in (OPTIONS if c != "21-taps" else OPTIONS[:3])
]


@needs_native
@pytest.mark.parametrize("n_sets", [4, 1])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("direction", ["x", "y"])
@pytest.mark.parametrize(("case", "options"), CASE_OPTIONS)
def test_sweep_is_the_separate_passes_bitwise(simd, dtype, direction, case, options, n_sets):
    case = dict(case)
    taps, reach = case.pop("taps", 7), case.pop("reach", 4.0)
    g = scene(b=2, dtype=dtype, **case)
    ks = kernels(n_sets, taps, reach)
    coef = torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.1, 0.2], [0.3, 0.3, 0.1], [0.2, 0.4, 0.4]])
    coef = coef[:n_sets].to(dtype)
    with backend("native"):
        fan_out = separable_sweep(g.diffuse, ks, direction, g, **options)
        assert torch.equal(fan_out, separate(g.diffuse, ks, direction, g, **options))
        # the fan-in of n_sets different images (not the fan-out's: each set its own input)
        images = torch.rand(n_sets, *g.diffuse.shape, dtype=dtype, generator=torch.Generator())
        fan_in = separable_sweep(images, ks, direction, g, coefficients=coef, **options)
        assert torch.equal(fan_in, separate(images, ks, direction, g, coef, **options))
    with backend("torch"):  # the specification, another implementation
        spec_out = separable_sweep(g.diffuse, ks, direction, g, **options)
        spec_in = separable_sweep(images, ks, direction, g, coefficients=coef, **options)
    if options.get("follow_surface") == "gaussian":  # BACKEND_AGREEMENT: the exp differs
        atol = 1e-6 if dtype == torch.float32 else 1e-14
        torch.testing.assert_close(fan_out, spec_out, rtol=0, atol=atol)
        torch.testing.assert_close(fan_in, spec_in, rtol=0, atol=4 * atol)
    else:
        assert torch.equal(fan_out, spec_out) and torch.equal(fan_in, spec_in)


@needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sweep_with_a_per_pixel_width_threads_and_a_target(simd, dtype):
    """A per-pixel width; a dense 240×200 image (two threads); the fan-in into a target
    changes its active pixels only; the fan-out into a workspace overwrites all of it."""
    g = scene(h=200, w=200, dtype=dtype, cover=0.95, bottom=6)
    width = 0.5 + torch.rand(g.depth.shape, dtype=dtype, generator=torch.Generator())
    ks, coef = kernels(3), torch.full((3, 3), 1 / 3, dtype=dtype)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with backend("native"):
            opts = dict(width=width, follow_surface="lerp", surface_scale=3.0)
            workspace = torch.full((3, *g.diffuse.shape), float("nan"), dtype=dtype)
            xs = separable_sweep(g.diffuse, ks, "x", g, out=workspace, **opts)
            assert xs is workspace and torch.equal(xs, separate(g.diffuse, ks, "x", g, **opts))
            target = torch.full_like(g.diffuse, -7.0)
            got = separable_sweep(xs, ks, "y", g, coefficients=coef, out=target, **opts)
    finally:
        torch.set_num_threads(threads)
    want = separate(xs, ks, "y", g, coef, **opts)
    active = (g.mask > 0).expand_as(target)
    assert got is target
    assert torch.equal(got[active], want[active]) and bool((got[~active] == -7.0).all())


@needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("direction", ["x", "y"])
def test_a_one_set_fan_in_is_its_coefficient_times_the_pass(simd, dtype, direction):
    """A fan-in of a single set is ``0 + c_0 · pass_0`` at the active pixels, as any fan-in
    (the native loop ran it as a plain pass until 2026-12-06, leaving ``c_0`` out)."""
    g = scene(b=2, dtype=dtype)
    (k,) = kernels(1)
    coef = torch.tensor([[0.5, 2.0, -3.0]], dtype=dtype)
    images = torch.rand(1, *g.diffuse.shape, dtype=dtype, generator=torch.Generator())
    opts = {"follow_surface": "lerp", "surface_scale": 4.0}
    with backend("native"):
        got = separable_sweep(images, [k], direction, g, coefficients=coef, **opts)
        want = separate(images, [k], direction, g, coef, **opts)
    with backend("torch"):
        spec = separable_sweep(images, [k], direction, g, coefficients=coef, **opts)
    assert torch.equal(got, want) and torch.equal(got, spec)


@needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("direction", ["x", "y"])
@pytest.mark.parametrize(("case", "options"), CASE_OPTIONS[:2] + CASE_OPTIONS[5:7])
def test_a_fan_in_reads_the_inactive_pixels_from_inactive_from(
    simd, dtype, direction, case, options
):
    """``inactive_from``: every set's image at the inactive pixels is that image's, whatever
    ``images`` holds there (NaN here): the fan-in of ``torch.where(active, images,
    inactive_from)``, bitwise, in place (``out`` itself) and not; and the fan-out with
    ``keep_inactive=False`` leaves ``out``'s inactive pixels as they were. With the two, the
    fused method's sweeps copy no inactive pixel into its per-Gaussian images."""
    case = dict(case)
    taps, reach = case.pop("taps", 7), case.pop("reach", 4.0)
    g = scene(b=2, dtype=dtype, **case)
    ks = kernels(3, taps, reach)
    coef = torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.1, 0.2], [0.3, 0.3, 0.1]], dtype=dtype)
    gen = torch.Generator().manual_seed(3)
    clean = torch.rand(3, *g.diffuse.shape, dtype=dtype, generator=gen)
    rest = torch.rand(g.diffuse.shape, dtype=dtype, generator=gen)
    use_mask = options.get("use_mask", True)
    active = (g.mask > 0) if use_mask else torch.ones_like(g.mask, dtype=torch.bool)
    clean = torch.where(active, clean, rest)  # what every set holds at the inactive pixels
    dirty = torch.where(active, clean, float("nan"))
    for name in ("native", "torch"):
        with backend(name):
            want = separable_sweep(clean, ks, direction, g, coefficients=coef,
                                   out=rest.clone(), **options)  # fmt: skip
            got = separable_sweep(dirty, ks, direction, g, coefficients=coef, out=rest.clone(),
                                  inactive_from=rest, **options)  # fmt: skip
            target = rest.clone()  # in place: the inactive pixels read from the target
            mine = separable_sweep(dirty, ks, direction, g, coefficients=coef, out=target,
                                   inactive_from=target, **options)  # fmt: skip
        if options.get("follow_surface") != "gaussian" or name == "native":
            assert torch.equal(got, want) and torch.equal(mine, want), name
        else:  # the torch loop's where: the same values, its own exp as before
            torch.testing.assert_close(got, want, rtol=0, atol=0)
    with backend("native"):
        out = torch.full((3, *g.diffuse.shape), -7.0, dtype=dtype)
        fan_out = separable_sweep(g.diffuse, ks, direction, g, out=out, keep_inactive=False,
                                  **options)  # fmt: skip
        full = separable_sweep(g.diffuse, ks, direction, g, **options)
    on = active.expand_as(g.diffuse).expand(3, *g.diffuse.shape)
    assert fan_out is out and torch.equal(fan_out[on], full[on])
    assert bool((fan_out[~on] == -7.0).all())
    # an out the loop cannot write in place: the new tensor returned is written everywhere
    strided = torch.full((3, *g.diffuse.shape[:-1], 2 * g.diffuse.shape[-1]), -7.0, dtype=dtype)
    with backend("native"):
        fresh = separable_sweep(g.diffuse, ks, direction, g, out=strided[..., ::2],
                                keep_inactive=False, **options)  # fmt: skip
    assert torch.equal(fresh, full)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("direction", ["x", "y"])
@pytest.mark.parametrize(("case", "options"), CASE_OPTIONS[:2] + CASE_OPTIONS[4:7])
def test_a_fan_out_writes_the_images_inactive_pixels_into_inactive_into(
    simd, dtype, direction, case, options
):
    """``inactive_into`` gets the image at the inactive pixels and keeps its own (a sentinel
    here) at the active ones, ``torch.where(active, into, image)`` bitwise, on both loops,
    contiguous or a strided view, with ``keep_inactive`` either way; the fan-out itself is
    unchanged. Without a mask every pixel is active: nothing is written. The fused method's
    new image is made so (its y sweep then writes the active pixels)."""
    case = dict(case)
    taps, reach = case.pop("taps", 7), case.pop("reach", 4.0)
    g = scene(b=2, dtype=dtype, **case)
    ks = kernels(3, taps, reach)
    use_mask = options.get("use_mask", True)
    active = (g.mask > 0) if use_mask else torch.ones_like(g.mask, dtype=torch.bool)
    want = torch.where(active, torch.full_like(g.diffuse, -7.0), g.diffuse)
    for name in ("native", "torch"):
        with backend(name):
            full = separable_sweep(g.diffuse, ks, direction, g, **options)
            into = torch.full_like(g.diffuse, -7.0)
            got = separable_sweep(g.diffuse, ks, direction, g, inactive_into=into, **options)
            assert torch.equal(into, want) and torch.equal(got, full), name
            out = torch.full((3, *g.diffuse.shape), -7.0, dtype=dtype)
            wide = torch.full((*g.diffuse.shape[:-1], 2 * g.diffuse.shape[-1]), -7.0, dtype=dtype)
            got = separable_sweep(g.diffuse, ks, direction, g, out=out, keep_inactive=False,
                                  inactive_into=wide[..., ::2], **options)  # fmt: skip
            assert torch.equal(wide[..., ::2], want) and bool((wide[..., 1::2] == -7.0).all())
            on = active.expand_as(g.diffuse).expand(3, *g.diffuse.shape)
            assert torch.equal(got[on], full[on]), name


@needs_native
@pytest.mark.parametrize("direction", ["x", "y"])
def test_inactive_into_of_a_stencil_with_no_active_pixel_is_the_whole_image(simd, direction):
    """No active pixel: the native loop has nothing to compute and still copies every pixel
    into ``inactive_into``, with ``keep_inactive`` either way (every set's result the image,
    or left as it was)."""
    g = scene(b=2)
    g = g.replace(mask=torch.zeros_like(g.mask))
    for keep in (True, False):
        into = torch.full_like(g.diffuse, -7.0)
        out = torch.full((3, *g.diffuse.shape), -7.0, dtype=g.dtype)
        with backend("native"):
            got = separable_sweep(g.diffuse, kernels(3), direction, g, out=out,
                                  keep_inactive=keep, inactive_into=into)  # fmt: skip
        assert torch.equal(into, g.diffuse)
        assert torch.equal(got, torch.stack([g.diffuse] * 3) if keep else torch.full_like(out, -7))


def test_inactive_options_are_refused_where_they_do_not_apply():
    g = scene()
    ks = kernels(2)
    images, coef = torch.stack([g.diffuse] * 2), torch.ones(2, 3, dtype=torch.float64)
    with pytest.raises(ValueError, match="inactive_from is for a fan-in"):
        separable_sweep(g.diffuse, ks, "x", g, inactive_from=g.diffuse)
    with pytest.raises(ValueError, match="inactive_from needs out"):
        separable_sweep(images, ks, "y", g, coefficients=coef, inactive_from=g.diffuse)
    with pytest.raises(ValueError, match="inactive_from must have the images' shape"):
        separable_sweep(images, ks, "y", g, coefficients=coef, out=g.diffuse.clone(),
                        inactive_from=g.diffuse[..., :3])  # fmt: skip
    with pytest.raises(ValueError, match="keep_inactive=False is for a fan-out"):
        separable_sweep(g.diffuse, ks, "x", g, keep_inactive=False)
    with pytest.raises(ValueError, match="keep_inactive=False is for a fan-out"):
        separable_sweep(images, ks, "y", g, coefficients=coef, out=g.diffuse.clone(),
                        keep_inactive=False)  # fmt: skip
    with pytest.raises(ValueError, match="inactive_into is for a fan-out"):
        separable_sweep(images, ks, "y", g, coefficients=coef, inactive_into=g.diffuse.clone())
    with pytest.raises(ValueError, match="inactive_into must be a tensor of the image's shape"):
        separable_sweep(g.diffuse, ks, "x", g, inactive_into=g.diffuse[..., :3].clone())
    with pytest.raises(ValueError, match="inactive_into must be a tensor of the image's shape"):
        separable_sweep(g.diffuse, ks, "x", g, inactive_into=g.diffuse.float())
    with pytest.raises(ValueError, match="inactive_into"):  # the image itself: read meanwhile
        separable_sweep(g.diffuse, ks, "x", g, inactive_into=g.diffuse)


def test_sweep_is_differentiable_on_the_torch_loop():
    """Under autograd the sweep runs the torch loop: its gradient is the numerical one."""
    g = scene(h=5, w=6)
    ks, coef = kernels(2, taps=5), torch.tensor([[0.3, 0.5, 0.7], [0.7, 0.5, 0.3]])

    def f(image):
        gi = g.replace(diffuse=image)
        xs = separable_sweep(image, ks, "x", gi, follow_surface="lerp", surface_scale=2.0)
        return separable_sweep(xs, ks, "y", gi, coefficients=coef.double(),
                               follow_surface="lerp", surface_scale=2.0)  # fmt: skip

    image = g.diffuse.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(f, (image,))


# ------------------------------------------------------------------------------ the kernel
def test_the_method_is_differentiable_into_a_new_image():
    """Under autograd the method runs the torch loop, its new image's inactive pixels written
    by ``inactive_into``'s ``where`` (an in-place copy autograd records): its gradient is the
    numerical one, at masked pixels and at the others (in place it refuses a tensor that
    requires grad, tested with the methods)."""
    g = scene(h=6, w=7)
    op = FusedSumOfGaussiansSSS(SKIN, 5)
    image = g.diffuse.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: op(g.replace(diffuse=x)), (image,))


def test_shared_taps_are_the_preintegrated_offsets_and_each_gaussians_cell_masses():
    """Offsets and cells: the pre-integrated kernel's (equal taps); Gaussian s's weight at tap
    t: its mass over the cell, by erf here; and Σ_s c_s (mass of s over a cell) is the
    pre-integrated kernel's own weight there (000 eq. 5: a_p = Σ_s w_s g_s / Σ w)."""
    ks, coef = shared_gaussian_taps(SKIN, 7)
    pre = preintegrated(SKIN, 7)
    centres, edges = profile_cells(SKIN, 7)
    assert torch.equal(centres, pre.offsets)
    order = torch.argsort(SKIN.variances)
    assert len(ks) == 6
    for k, v in zip(ks, SKIN.variances[order], strict=True):
        assert torch.equal(k.offsets, pre.offsets)
        root2sig = math.sqrt(2 * float(v))
        want = [
            0.5 * (math.erf(b / root2sig) - math.erf(a / root2sig))
            for a, b in zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True)
        ]
        for ch in range(3):
            assert k.weights[:, ch].tolist() == pytest.approx(want, abs=1e-12)
        assert k.weights.sum(0).tolist() == pytest.approx([1.0] * 3, abs=1e-12)
    w = SKIN.weights[order].double()
    torch.testing.assert_close(coef, w / w.sum(0), rtol=1e-15, atol=0)
    mixed = sum(c[None, :] * k.weights for k, c in zip(ks, coef, strict=True))
    torch.testing.assert_close(mixed, pre.weights, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------ the method
def dense_oracle(op: FusedSumOfGaussiansSSS, g: GBuffer) -> torch.Tensor:
    """An independent slow implementation on a flat plane without follow-surface: the 1D
    operator of set s along an axis of n pixels as a dense matrix (tap t of pixel i lands at
    ``clamp(i + o_t · s, 0, n − 1)`` and splits its weight between the two pixels around it
    by linear interpolation), the result ``Σ_s c_s B_s X A_sᵀ`` per channel in float64."""
    _, _, h, w = g.diffuse.shape
    z = float(g.depth[0, 0, 0, 0])
    scale = h / (2.0 * math.tan(g.fov_y / 2.0)) / z  # pixels per mm (pinhole)

    def matrix(k: Kernel1D, n: int, ch: int) -> torch.Tensor:
        m = torch.zeros(n, n, dtype=torch.float64)
        for i in range(n):
            for o, wt in zip(k.offsets.tolist(), k.weights[:, ch].tolist(), strict=True):
                p = min(max(i + o * scale, 0.0), n - 1.0)
                i0 = math.floor(p)
                f = p - i0
                m[i, i0] += wt * (1 - f)
                m[i, min(i0 + 1, n - 1)] += wt * f
        return m

    out = torch.zeros(3, h, w, dtype=torch.float64)
    for k, c in zip(op.kernels, op.coefficients, strict=True):
        for ch in range(3):
            x = g.diffuse[0, ch].double()
            out[ch] += c[ch] * (matrix(k, h, ch) @ x @ matrix(k, w, ch).T)
    return out[None]


@pytest.mark.parametrize("name", ["native", "torch"])
def test_method_is_the_dense_rank_s_convolution_on_a_flat_plane(name):
    if name == "native" and native.library() is None:
        pytest.skip("no C compiler")
    g = GBuffer(
        torch.rand(1, 3, 17, 23, dtype=torch.float64, generator=torch.Generator()),
        torch.full((1, 1, 17, 23), 300.0, dtype=torch.float64),
        0.5,
    )
    op = FusedSumOfGaussiansSSS(SKIN, 7, follow_surface=None)
    with backend(name):
        got = op(g)
    torch.testing.assert_close(got, dense_oracle(op, g), rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_constant_image_stays_constant(dtype):
    """Every set sums to 1 and the coefficients to 1 per channel: across depth steps, mask
    holes and borders a constant image is unchanged (to rounding)."""
    g = scene(h=30, w=40, dtype=dtype)
    g = g.replace(diffuse=torch.full_like(g.diffuse, 0.37))
    for fs in (None, "lerp"):
        got = FusedSumOfGaussiansSSS(SKIN, 7, follow_surface=fs)(g)
        atol = 1e-6 if dtype == torch.float32 else 1e-14
        torch.testing.assert_close(got, g.diffuse, rtol=0, atol=atol)


def test_inplace_width_and_backends_agree():
    """``inplace=True`` writes the copying call's result into the diffuse; a width of ones
    changes nothing, zero width is the identity; native and torch agree bitwise (lerp)."""
    g = scene(h=30, w=40)
    op = FusedSumOfGaussiansSSS(SKIN, 7)
    with backend("torch"):
        spec = op(g)
    ref = op(g)
    assert torch.equal(ref, spec) or native.library() is None
    work = g.replace(diffuse=g.diffuse.clone())
    assert op(work, inplace=True) is work.diffuse and torch.equal(work.diffuse, ref)
    ones = torch.ones_like(g.depth)
    assert torch.equal(op(g, width=ones), ref)
    torch.testing.assert_close(op(g, width=0 * ones), g.diffuse, rtol=0, atol=1e-12)
    with torch.inference_mode():  # the kept workspace is written from inference mode too
        assert torch.equal(op(g), ref)


# ------------------------------------------------------------------------------ refusals
def test_bad_arguments_are_refused_naming_them():
    g = scene()
    ks = kernels(2)
    with pytest.raises(ValueError, match=r"kernels\[1\]\.offsets"):
        separable_sweep(g.diffuse, [ks[0], Kernel1D(ks[1].offsets * 2, ks[1].weights)], "x", g)
    with pytest.raises(TypeError, match="kernels"):
        separable_sweep(g.diffuse, [], "x", g)
    with pytest.raises(ValueError, match="kernels must hold at most"):
        separable_sweep(g.diffuse, [ks[0]] * (MAX_SETS + 1), "x", g)
    with pytest.raises(ValueError, match="coefficients must have shape"):
        separable_sweep(torch.stack([g.diffuse] * 2), ks, "y", g, coefficients=torch.ones(3, 3))
    with pytest.raises(ValueError, match="images must have shape"):
        separable_sweep(torch.stack([g.diffuse] * 3), ks, "y", g, coefficients=torch.ones(2, 3))
    with pytest.raises(ValueError, match="out must be a tensor of shape"):
        separable_sweep(g.diffuse, ks, "x", g, out=torch.empty(3, *g.diffuse.shape))
    with pytest.raises(ValueError, match="direction"):
        separable_sweep(g.diffuse, ks, "z", g)
    with pytest.raises(TypeError, match="profile must be a SumOfGaussians"):
        FusedSumOfGaussiansSSS(preintegrated(SKIN, 7))
    with pytest.raises(ValueError, match="sampling"):
        FusedSumOfGaussiansSSS(SKIN, sampling="optimised")
    with pytest.raises(ValueError, match="samples"):
        FusedSumOfGaussiansSSS(SKIN, samples=0)
    with pytest.raises(ValueError, match="sample_weight"):
        FusedSumOfGaussiansSSS(SKIN)(g, guide=g.depth, sample_weight=lambda c, s: c[:, :1])


def test_the_gl_backend_refuses_the_method_by_name():
    """No GL shader: the GL schedule names the class (no context needed to ask)."""
    from sssbench.gl import GLMethodError
    from sssbench.gl._run import schedule

    with pytest.raises(GLMethodError, match="FusedSumOfGaussiansSSS"):
        schedule(FusedSumOfGaussiansSSS(SKIN))

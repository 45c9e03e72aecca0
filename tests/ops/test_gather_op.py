"""The native pass as a torch operator (``torch.ops.sssbench.gather`` / ``gather_``).

Gradients of the native forward are checked by finite differences of the native forward
itself (``gradcheck``) and against autograd through the torch loop; the in-place form must
bump the version counter like a torch in-place op, so that autograd sees it; and a module
calling the operator must compile with ``fullgraph=True``.
"""

import math

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D
from sssbench.ops import Stretch, backend, native, separable_pass

pytestmark = pytest.mark.skipif(native.library() is None, reason="no C compiler")


def scene(h=6, w=7, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(1, 3, h, w, generator=g, dtype=dtype)
    depth = 60 + 20 * torch.rand(1, 1, h, w, generator=g, dtype=dtype)
    # strengths away from 0 (a finite difference must not cross the stencil's edge) and holes
    mask = 0.3 + 0.7 * torch.rand(1, 1, h, w, generator=g, dtype=dtype)
    mask = mask * (torch.rand(1, 1, h, w, generator=g, dtype=dtype) < 0.8)
    return GBuffer(img, depth, 0.7, mask=mask)


def kernel(taps=5, dtype=torch.float64):
    offsets = torch.linspace(-2.5, 2.5, taps, dtype=dtype)
    weights = torch.exp(-0.5 * offsets[:, None] ** 2 / torch.tensor([0.5, 1.5, 3.0], dtype=dtype))
    return Kernel1D(offsets, weights / weights.sum(0))


def run(x, depth, mask, width, k, direction, options):
    g = GBuffer(x, depth, 0.7, mask=mask)
    return separable_pass(x, k, direction, g, width=width, **options)


OPTIONS = [
    {},
    {"follow_surface": "lerp", "surface_scale": 4.0},
    {"follow_surface": "gaussian", "surface_scale": 3.0, "stretch": Stretch(correction=20.0)},
]


@pytest.mark.parametrize("direction", ["x", "y"])
@pytest.mark.parametrize("options", OPTIONS, ids=["plain", "lerp", "gaussian-stretch"])
def test_gradcheck_through_the_native_pass(direction, options):
    """Finite differences of the native forward against its backward (the torch loop's VJP),
    with respect to the image, depth, mask strength and a per-pixel width at once."""
    g = scene()
    holes = (g.mask > 0).to(g.dtype)  # the strength is holes · m, m in [0.3, 1] perturbed
    width = (0.5 + torch.rand(1, 1, 6, 7, dtype=torch.float64)).requires_grad_()
    inputs = (
        g.diffuse.clone().requires_grad_(),
        g.depth.clone().requires_grad_(),
        (0.3 + 0.6 * torch.rand(1, 1, 6, 7, dtype=torch.float64)).requires_grad_(),
        width,
    )
    k = kernel()
    with backend("native"):
        assert torch.autograd.gradcheck(
            lambda x, d, m, wd: run(x, d, holes * m, wd, k, direction, options),
            inputs,
            atol=1e-7,
        )


@pytest.mark.parametrize("options", OPTIONS, ids=["plain", "lerp", "gaussian-stretch"])
def test_native_gradients_equal_the_torch_loop_gradients(options):
    g = scene(h=9, w=11, seed=3)
    k = kernel(7)
    k = Kernel1D(k.offsets.clone().requires_grad_(), k.weights.clone().requires_grad_())
    grads = {}
    for name in ("native", "torch"):
        leaves = [g.diffuse.clone().requires_grad_(), g.depth.clone().requires_grad_()]
        with backend(name):
            out = run(leaves[0], leaves[1], g.mask, 1.5, k, "y", options)
        weights = torch.linspace(0.1, 1.0, out.numel(), dtype=out.dtype).view_as(out)
        grads[name] = torch.autograd.grad((out * weights).sum(), [*leaves, k.offsets, k.weights])
    for a, b in zip(grads["native"], grads["torch"], strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["native", "torch"])
def test_in_place_pass_bumps_the_version_counter(name):
    g = scene()
    work = g.diffuse.clone()
    before = work._version
    with backend(name), torch.no_grad():
        separable_pass(work, kernel(), "x", g, inplace=True)
    assert work._version > before


@pytest.mark.parametrize("name", ["native", "torch"])
def test_autograd_refuses_a_saved_tensor_the_pass_overwrote(name):
    """``s = (a · a).sum()`` saves ``a``; overwriting ``a`` in place afterwards must make
    ``s.backward()`` raise, as for any in-place op, not return the gradient at new values."""
    g = scene()
    a = g.diffuse.clone().requires_grad_()
    s = (a * a).sum()
    with backend(name), torch.no_grad():
        separable_pass(a, kernel(), "x", g, inplace=True)
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        s.backward()


class TwoPasses(torch.nn.Module):
    """A module calling the registered operator twice (x then y), as a compiled method would."""

    def __init__(self, g: GBuffer, k: Kernel1D):
        super().__init__()
        self.g, self.k = g, k

    def forward(self, image):
        f_px = image.shape[2] / (2.0 * math.tan(self.g.fov_y / 2.0))
        inv = torch.full((3,), 0.25, dtype=image.dtype)
        common = (self.g.mask, None, None, self.k.offsets, self.k.weights, inv, f_px, 1.0,
                  0.0, 0.0)  # fmt: skip
        h = torch.ops.sssbench.gather(image, self.g.depth, *common, False, 1)
        return torch.ops.sssbench.gather(h, self.g.depth, *common, True, 1) * 2.0


def test_a_module_with_the_pass_compiles_without_graph_breaks():
    g = scene(h=12, w=13, dtype=torch.float32)
    k = kernel(dtype=torch.float32)
    module = TwoPasses(g, k)
    eager = module(g.diffuse)
    with backend("torch"):  # the same schedule through the public entry
        x = separable_pass(g.diffuse, k, "x", g, follow_surface="lerp", surface_scale=4.0)
        ref = 2.0 * separable_pass(x, k, "y", g, follow_surface="lerp", surface_scale=4.0)
    torch.testing.assert_close(eager, ref, rtol=0, atol=0)
    torch._dynamo.reset()
    compiled = torch.compile(module, fullgraph=True, backend="aot_eager")  # fake kernels too
    torch.testing.assert_close(compiled(g.diffuse), eager, rtol=0, atol=0)
    explain = torch._dynamo.explain(module)(g.diffuse)
    assert explain.graph_break_count == 0 and explain.graph_count == 1


def test_fake_tensor_shape_and_opcheck():
    """torch.library.opcheck: schema, fake kernel and autograd registration are consistent."""
    g = scene()
    k = kernel()
    args = (g.diffuse, g.depth, g.mask, None, None, k.offsets, k.weights,
            torch.full((3,), 0.25, dtype=torch.float64), 40.0, 1.0, 0.0, 0.0, False, 1)  # fmt: skip
    torch.library.opcheck(torch.ops.sssbench.gather.default, args)
    torch.library.opcheck(torch.ops.sssbench.gather_.default, (g.diffuse.clone(), *args[1:]))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_serial_copy_equals_clone(dtype):
    """serial_copy (a copy on the calling thread, before a native pass writes it) equals a
    contiguous clone bitwise for contiguous, expanded, channels-last and inference tensors;
    owns its memory; and stays a clone autograd records where the input requires a gradient."""
    from sssbench.ops._gather_native import serial_copy

    base = torch.rand(2, 3, 17, 23, dtype=dtype, generator=torch.Generator().manual_seed(3))
    with torch.inference_mode():
        inference = base * 2
    for image in (
        base,
        base[:1, :1].expand(2, 3, 17, 23),
        base.contiguous(memory_format=torch.channels_last),
        base[:, :, ::2, 1:],
        inference,
    ):
        out = serial_copy(image)
        assert out.is_contiguous() and out.dtype == dtype and out.shape == image.shape
        assert torch.equal(out, image.clone(memory_format=torch.contiguous_format))
        assert out.untyped_storage().data_ptr() != image.untyped_storage().data_ptr()
    leaf = base.clone().requires_grad_()
    out = serial_copy(leaf)
    out.sum().backward()
    assert torch.equal(leaf.grad, torch.ones_like(base))

"""Property tests (hypothesis): linearity in the diffuse input, shift invariance on flat scenes
away from the borders, symmetry under a 180° rotation of the scene (non-stochastic methods),
determinism under a fixed seed (stochastic rotation).

Pixel-centre convention for the half turn: pixel ``(i, j)`` goes to ``(H−1−i, W−1−j)`` — i.e.
``flip(-2, -1)`` — and diffuse, depth and mask are turned together, so every neighbour at offset
``+d`` becomes a neighbour at ``−d`` with the same depth: a symmetric kernel gives the same
result, turned.
"""

from __future__ import annotations

import math

import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sssbench.gbuffer import GBuffer
from sssbench.ops import PreintegratedSSS, ReferenceSSS, Stretch, separable_pass
from sssbench.profiles import SumOfGaussians

FAST = settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)
SKIN = SumOfGaussians.from_table("skin_jg10")
FOV = 0.5
FOLLOW = st.sampled_from([None, "lerp", "gaussian"])


def _scene(seed: int, size: int, z: float, slope: float, noise: float, masked: bool) -> GBuffer:
    gen = torch.Generator().manual_seed(seed)
    diffuse = torch.rand(1, 3, size, size, generator=gen, dtype=torch.float64)
    rows = torch.arange(size, dtype=torch.float64)[:, None]
    cols = torch.arange(size, dtype=torch.float64)[None, :]
    depth = z * (1 + slope * (rows + 0.5 * cols) / size)
    depth = depth + noise * z * torch.rand(size, size, generator=gen, dtype=torch.float64)
    mask = None
    if masked:
        mask = (torch.rand(1, 1, size, size, generator=gen, dtype=torch.float64) > 0.2).double()
    return GBuffer(diffuse, depth[None, None], FOV, mask=mask)


def _turn(g: GBuffer) -> GBuffer:
    flip = lambda t: None if t is None else t.flip(-2, -1)  # noqa: E731
    return g.replace(diffuse=flip(g.diffuse), depth=flip(g.depth), mask=flip(g.mask))


scenes = st.builds(
    _scene,
    seed=st.integers(0, 10_000),
    size=st.integers(6, 14),
    z=st.sampled_from([80.0, 300.0, 2000.0]),
    slope=st.floats(0.0, 0.5),
    noise=st.floats(0.0, 0.05),
    masked=st.booleans(),
)


@FAST
@given(g=scenes, a=st.floats(0.0, 10.0), b=st.floats(0.0, 10.0), follow=FOLLOW,
       samples=st.integers(1, 9), seed=st.integers(0, 100))  # fmt: skip
def test_linear_in_diffuse(g, a, b, follow, samples, seed):
    method = PreintegratedSSS(SKIN, samples, follow_surface=follow)
    y = torch.rand(g.diffuse.shape, generator=torch.Generator().manual_seed(seed), dtype=g.dtype)
    lhs = method(g.replace(diffuse=a * g.diffuse + b * y))
    rhs = a * method(g) + b * method(g.replace(diffuse=y))
    assert torch.allclose(lhs, rhs, rtol=1e-12, atol=1e-12 * (a + b + 1))


@FAST
@given(g=scenes, follow=FOLLOW, samples=st.integers(1, 9), stretch=st.booleans(),
       sampling=st.sampled_from(["importance", "uniform", "power"]))  # fmt: skip
def test_half_turn_symmetry(g, follow, samples, stretch, sampling):
    method = PreintegratedSSS(SKIN, samples, sampling, follow_surface=follow)
    out = method(g)
    turned = method(_turn(g))
    assert torch.allclose(turned, out.flip(-2, -1), rtol=1e-12, atol=1e-12)
    if stretch:  # JG10 stretch uses |∂z|, symmetric under the turn too
        k = method.kernel
        st_ = Stretch(1.0, 800.0, 0.23)
        one = separable_pass(g.diffuse, k, "y", g, stretch=st_)
        two = separable_pass(_turn(g).diffuse, k, "y", _turn(g), stretch=st_)
        assert torch.allclose(two, one.flip(-2, -1), rtol=1e-12, atol=1e-12)


@settings(max_examples=4, deadline=None, derandomize=True)
@given(g=st.builds(_scene, seed=st.integers(0, 1000), size=st.integers(5, 8),
                   z=st.just(150.0), slope=st.floats(0.0, 0.3), noise=st.just(0.0),
                   masked=st.booleans()))  # fmt: skip
def test_half_turn_symmetry_reference(g):
    ref = ReferenceSSS(SumOfGaussians(torch.tensor([0.05, 0.3]), torch.ones(2, 3) / 2))
    out = ref(g)
    assert torch.allclose(ref(_turn(g)), out.flip(-2, -1), rtol=1e-10, atol=1e-12)


@FAST
@given(seed=st.integers(0, 10_000), dy=st.integers(-3, 3), dx=st.integers(-3, 3),
       follow=FOLLOW, samples=st.integers(1, 7))  # fmt: skip
def test_shift_invariance_on_flat_scene(seed, dy, dx, follow, samples):
    size = 28
    method = PreintegratedSSS(SKIN, samples, follow_surface=follow)
    px_per_mm = size / (2 * 300.0 * math.tan(FOV / 2))
    reach = math.ceil(method.kernel.extent * px_per_mm) + 1  # pixels a pass can fetch from
    margin = 2 * reach + 3  # two passes, plus the shift
    if margin * 2 >= size:
        margin = size // 2 - 1
    gen = torch.Generator().manual_seed(seed)
    big = torch.rand(1, 3, size + 8, size + 8, generator=gen, dtype=torch.float64)
    x = big[..., 4 : 4 + size, 4 : 4 + size]
    x_shift = big[
        ..., 4 - dy : 4 - dy + size, 4 - dx : 4 - dx + size
    ]  # the scene moved by (dy, dx)
    depth = torch.full((1, 1, size, size), 300.0, dtype=torch.float64)
    out = method(GBuffer(x.contiguous(), depth, FOV))
    out_shift = method(GBuffer(x_shift.contiguous(), depth, FOV))
    lo, hi = margin, size - margin
    if hi - lo < 2:
        return
    inner = out[..., lo:hi, lo:hi]
    moved = out_shift[..., lo + dy : hi + dy, lo + dx : hi + dx]
    assert torch.allclose(moved, inner, rtol=1e-12, atol=1e-12)


@FAST
@given(g=scenes, seed=st.integers(0, 2**31 - 1), radius=st.floats(0.05, 1.0))
def test_rotation_deterministic_under_seed(g, seed, radius):
    a = PreintegratedSSS(SKIN, 7, rotation=radius, seed=seed)(g)
    b = PreintegratedSSS(SKIN, 7, rotation=radius, seed=seed)(g)
    assert torch.equal(a, b)
    f32 = g.to(torch.float32)
    assert torch.equal(
        PreintegratedSSS(SKIN, 7, rotation=radius, seed=seed)(f32),
        PreintegratedSSS(SKIN, 7, rotation=radius, seed=seed)(f32),
    )


def test_rotation_seed_matters():
    g = _scene(3, 16, 100.0, 0.2, 0.0, False)
    a = PreintegratedSSS(SKIN, 7, rotation=1.0, seed=1)(g)
    b = PreintegratedSSS(SKIN, 7, rotation=1.0, seed=2)(g)
    assert not torch.equal(a, b)

"""Optimised kernels (sssbench.tune.optimise): constraints, the fit, the cache, the method."""

from __future__ import annotations

import math

import pytest
import torch

from data_synth import make_scene
from sssbench.gbuffer import GBuffer
from sssbench.kernels import Kernel1D, preintegrated
from sssbench.ops import PreintegratedSSS, ReferenceSSS
from sssbench.ops.preintegrated import two_pass
from sssbench.profiles import SumOfGaussians
from sssbench.score.metrics import rel_rms
from sssbench.tune import optimise as opt

PROFILE = SumOfGaussians.from_table("skin_deon6")


@pytest.fixture(autouse=True)
def _one_thread():
    """One intra-op thread: the images are tiny, and on a busy 2-core machine two threads
    make the small ops of a step ~30x slower (OpenMP barriers; measured)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize("taps", [1, 2, 5, 7, 8])
def test_parametrisation_round_trips_and_keeps_constraints(taps):
    init = preintegrated(PROFILE, taps)
    p = opt.SymmetricTaps(init)
    k0 = p.kernel()
    assert torch.allclose(k0.offsets, init.offsets, rtol=0, atol=1e-12)
    assert torch.allclose(k0.weights, init.weights, rtol=0, atol=1e-12)
    gen = torch.Generator().manual_seed(taps)
    with torch.no_grad():
        for q in p.parameters():
            q.add_(3.0 * torch.randn(q.shape, generator=gen, dtype=q.dtype))
    k = p.kernel()
    assert bool((k.weights >= 0).all())
    assert torch.allclose(k.weights.sum(0), torch.ones(3, dtype=torch.float64), atol=1e-12)
    assert torch.equal(k.offsets, -k.offsets.flip(0))  # symmetric, exactly
    assert torch.equal(k.weights, k.weights.flip(0))
    assert bool((k.offsets[1:] > k.offsets[:-1]).all())  # sorted, distinct
    if taps % 2:
        assert float(k.offsets[taps // 2].detach()) == 0.0


def test_parametrisation_refuses_asymmetric_or_unnormalised_init():
    off = torch.tensor([-1.0, 0.0, 2.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="symmetric"):
        opt.SymmetricTaps(Kernel1D(off, torch.full((3, 3), 1 / 3, dtype=torch.float64)))
    off = torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="sum to 1"):
        opt.SymmetricTaps(Kernel1D(off, torch.full((3, 3), 0.5, dtype=torch.float64)))


def _noise_plane(n: int, pixel_mm: float, seed: int = 0) -> GBuffer:
    """A fronto-parallel plane whose pixels are ``pixel_mm`` wide, white-noise irradiance."""
    fov = math.radians(25.0)
    z = pixel_mm * n / (2 * math.tan(fov / 2))
    gen = torch.Generator().manual_seed(seed)
    diffuse = torch.rand((1, 3, n, n), generator=gen, dtype=torch.float64)
    return GBuffer(diffuse, torch.full((1, 1, n, n), z, dtype=torch.float64), fov)


def test_fit_recovers_a_reachable_target():
    """Closed form: the target is the two passes of a known symmetric kernel K*, each tap in
    its own pixel cell (taps at 1.5 and 3.5 px), so on a white-noise plane K* is the unique
    kernel with zero loss; fitting from a perturbed start recovers its offsets and weights."""
    px = 0.5
    g = _noise_plane(24, px)
    w = torch.tensor(
        [[0.10, 0.20, 0.40, 0.20, 0.10], [0.05, 0.15, 0.60, 0.15, 0.05],
         [0.02, 0.08, 0.80, 0.08, 0.02]], dtype=torch.float64,
    ).T  # fmt: skip
    target_k = Kernel1D(torch.tensor([-3.5, -1.5, 0.0, 1.5, 3.5], dtype=torch.float64) * px, w)
    method = PreintegratedSSS(PROFILE, 5, follow_surface=None)
    with torch.no_grad():
        target = two_pass(g.diffuse, target_k, g, name="target")
    start = Kernel1D(
        torch.tensor([-3.2, -1.2, 0.0, 1.2, 3.2], dtype=torch.float64) * px,
        torch.full((5, 3), 0.2, dtype=torch.float64),
    )
    fit = opt.fit_taps(method, [(g, target)], start, steps=200, lr=0.05)
    assert fit.losses[-1] < 1e-3 * fit.losses[0]
    assert torch.allclose(fit.kernel.offsets, target_k.offsets, atol=0.01 * px, rtol=0)
    assert torch.allclose(fit.kernel.weights, w, atol=2e-3, rtol=0)
    assert method.kernel is not fit.kernel  # the method's own kernel is restored


def test_fit_never_raises_training_error_above_the_importance_start():
    g = make_scene("step_edge", (24, 24), pixel_mm=0.5, dtype=torch.float64)
    ref = ReferenceSSS(PROFILE)(g)
    method = PreintegratedSSS(PROFILE, 5)
    start_error = rel_rms(method(g), ref, g.mask)  # metrics' own implementation
    fit = opt.fit_taps(method, [(g, ref)], method.kernel, steps=6, lr=0.05)
    assert fit.losses[0] == pytest.approx(start_error, rel=1e-9)
    method.kernel = fit.kernel
    assert rel_rms(method(g), ref, g.mask) <= start_error * (1 + 1e-12)


def test_cache_key_follows_the_profile_and_every_input():
    scenes = (opt.TrainingScene("step_edge", (16, 16)),)
    args = ("preintegrated", 7, 0.3, scenes, {"follow_surface": "lerp"}, 10, 0.05)
    base = opt.cache_key(PROFILE, *args)
    assert opt.cache_key(SumOfGaussians.from_table("skin_deon6"), *args) == base
    assert opt.cache_key(SumOfGaussians.from_table("skin_jg10"), *args) != base
    changed = SumOfGaussians.from_table("skin_deon6")
    changed.variances = changed.variances * 1.01
    assert opt.cache_key(changed, *args) != base
    for i, other in [(1, 9), (2, 1.0), (3, (opt.TrainingScene("step_edge", (16, 16), 1),))]:
        assert opt.cache_key(PROFILE, *args[:i], other, *args[i + 1 :]) != base


def test_optimise_caches_on_disk(tmp_path, monkeypatch):
    monkeypatch.setenv("SSSBENCH_CACHE_DIR", str(tmp_path))
    scenes = (opt.TrainingScene("step_edge", (16, 16)),)
    a = opt.optimise(PROFILE, taps=3, pixel_mm=0.5, training=scenes, steps=2)
    assert not a.cached and a.loss <= a.init_loss
    assert a.loss <= min(a.rule_losses.values())  # never worse than the best rule (training)
    assert set(a.rule_losses) == {"importance", "uniform", "power"}
    assert list((tmp_path / "kernels").glob("optimised_*.json"))
    b = opt.optimise(PROFILE, taps=3, pixel_mm=0.5, training=scenes, steps=2)
    assert b.cached and torch.equal(b.kernel.offsets, a.kernel.offsets)
    assert torch.equal(b.kernel.weights, a.kernel.weights)
    c = opt.optimise(PROFILE, taps=3, pixel_mm=0.5, training=scenes, steps=3)
    assert not c.cached


def test_method_uses_the_kernel_fitted_at_the_runs_footprint(tmp_path, monkeypatch):
    monkeypatch.setenv("SSSBENCH_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(opt, "DEFAULT_TRAINING", (opt.TrainingScene("step_edge", (16, 16)),))
    monkeypatch.setattr(opt, "DEFAULT_STEPS", 2)
    g = make_scene("step_edge", (20, 20), pixel_mm=0.32)
    m = PreintegratedSSS(PROFILE, samples=3, sampling="optimised")
    assert m.kernel is None
    with torch.inference_mode():  # as the runner calls it: the first call fits all the same
        out = m(g)
    fitted = opt.optimise(PROFILE, taps=3, pixel_mm=0.3)  # the method's options are defaults
    assert fitted.cached  # the method stored the kernel fitted at the nearest grid point, 0.3
    assert torch.equal(m.kernel.offsets, fitted.kernel.offsets)
    assert torch.equal(
        out,
        two_pass(
            g.diffuse,
            fitted.kernel,
            g,
            name="x",
            follow_surface="lerp",
            surface_scale=m.surface_scale,
            check_finite=False,
        ),
    )


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="pixel_mm"):
        PreintegratedSSS(PROFILE, 7, "importance", pixel_mm=0.3)
    with pytest.raises(ValueError, match="sampling"):
        PreintegratedSSS(PROFILE, 7, "learned")
    with pytest.raises(ValueError, match="samples"):
        PreintegratedSSS(PROFILE, opt.MAX_OPTIMISED_TAPS + 2, "optimised")
    with pytest.raises(ValueError, match="taps"):
        opt.optimise(PROFILE, taps=opt.MAX_OPTIMISED_TAPS + 1)
    with pytest.raises(ValueError, match="method"):
        opt.optimise(PROFILE, method="artist")
    with pytest.raises(TypeError, match="profile"):
        opt.optimise("skin")
    assert opt.nearest_footprint(0.32) == 0.3 and opt.nearest_footprint(1.2) == 1.0

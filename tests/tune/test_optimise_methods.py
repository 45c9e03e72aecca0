"""Optimised kernels of the sum of Gaussians (per-Gaussian tap sets) and of the 2012 kernel
(strength, falloff, width): the parametrisations, the shared fit, the cache, the methods."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from data_synth import make_scene
from sssbench.kernels import Kernel1D, jimenez2012
from sssbench.ops import Jimenez2012SSS, ReferenceSSS, SumOfGaussiansSSS
from sssbench.profiles import SumOfGaussians
from sssbench.run.registry import build_method
from sssbench.score.metrics import rel_rms
from sssbench.tune import optimise as opt
from tests.tune.test_optimise import _noise_plane, _one_thread  # noqa: F401 (autouse)

PROFILE = SumOfGaussians.from_table("skin_deon6")
SHADER = {"strength": (0.48, 0.41, 0.28), "falloff": (1.0, 0.37, 0.3)}  # 002's shader defaults


@pytest.fixture
def kernel_cache(tmp_path, monkeypatch):
    """Fitted kernels in a fresh directory; references and the native gather stay in the
    shared cache (content-keyed), so a fresh cache does not rebuild them."""
    monkeypatch.setattr(opt, "kernel_cache_dir", lambda: tmp_path / "kernels")
    return tmp_path / "kernels"


def _kernel(offsets_px, weights, px) -> Kernel1D:
    w = torch.tensor(weights, dtype=torch.float64).T
    return Kernel1D(torch.tensor(offsets_px, dtype=torch.float64) * px, w)


# ------------------------------------------------------------------- sum of Gaussians
def test_per_gaussian_taps_start_at_the_schedule_and_stay_normalised():
    m = SumOfGaussiansSSS(PROFILE, 5, unblurred_first=True)
    p = opt.PerGaussianTaps(m.schedule)
    steps = p.value()["steps"]
    assert steps[0].kernel is None  # the unblurred first Gaussian has no pass, and keeps none
    for s, ref in zip(steps, m.schedule, strict=True):
        assert s.variance == ref.variance and torch.equal(s.blend, ref.blend)
        if ref.kernel is not None:
            assert torch.allclose(s.kernel.offsets, ref.kernel.offsets, atol=1e-12, rtol=0)
            assert torch.allclose(s.kernel.weights, ref.kernel.weights, atol=1e-12, rtol=0)
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for q in p.parameters():
            q.add_(2.0 * torch.randn(q.shape, generator=gen, dtype=q.dtype))
    fitted = p.fitted()
    assert fitted.kernels[0] is None and len(fitted.kernels) == len(m.schedule)
    for k in fitted.kernels[1:]:
        assert torch.allclose(k.weights.sum(0), torch.ones(3, dtype=torch.float64), atol=1e-12)
        assert bool((k.weights >= 0).all()) and torch.equal(k.offsets, -k.offsets.flip(0))
    for k in fitted.kernels[1:]:  # grey: one weight per tap for every channel
        assert torch.equal(k.weights, k.weights[:, :1].expand(-1, 3))
    other = SumOfGaussiansSSS(PROFILE, 5)  # no unblurred first Gaussian: another schedule
    with pytest.raises(ValueError, match="Gaussian steps"):
        opt.PerGaussianTaps.install(other, fitted)


def test_per_gaussian_fit_recovers_a_reachable_tap_set():
    """Closed form: a two-Gaussian profile whose first Gaussian is the unblurred image (003
    §7.3.3), so the result is ``w' · K*K* E + (1 − w') E`` with the blend ``w'`` of the
    second Gaussian (0.3 / 0.6 / 0.8). With the known tap set K* (each tap in its own pixel
    cell) on a white-noise plane, K* is the unique zero-loss kernel; the fit recovers it from
    a perturbed start, and the pass-free first step stays without taps. The tap sets are
    grey (one weight per tap for R, G, B), as each of 003's Gaussian blurs."""
    px = 0.5
    g = _noise_plane(24, px)
    two = SumOfGaussians(
        torch.tensor([0.01, 1.2], dtype=torch.float64),
        torch.tensor([[0.7, 0.4, 0.2], [0.3, 0.6, 0.8]], dtype=torch.float64),
    )
    m = SumOfGaussiansSSS(two, 5, lod=False, unblurred_first=True, follow_surface=None)
    truth = _kernel([-3.5, -1.5, 0, 1.5, 3.5], [[0.1, 0.2, 0.4, 0.2, 0.1]] * 3, px)  # grey
    m.steps = [replace(s, kernel=None if s.kernel is None else truth) for s in m.schedule]
    with torch.no_grad():
        target = m(g)
    start = _kernel([-3.2, -1.2, 0, 1.2, 3.2], [[0.2] * 5] * 3, px)
    steps = [replace(s, kernel=None if s.kernel is None else start) for s in m.schedule]
    fit = opt.fit_taps(m, [(g, target)], opt.PerGaussianTaps(steps), steps=200, lr=0.05)
    assert fit.losses[-1] < 1e-3 * fit.losses[0]
    first, k = fit.fitted.kernels
    assert first is None
    assert torch.allclose(k.offsets, truth.offsets, atol=0.01 * px, rtol=0)
    assert torch.allclose(k.weights, truth.weights, atol=2e-3, rtol=0)


# ------------------------------------------------------------------- the 2012 kernel
def test_jimenez_parameters_start_at_the_published_kernel():
    m = Jimenez2012SSS(*SHADER.values(), 3.0, 9)
    p = opt.Jimenez2012Parameters(m)
    k = p.value()["kernel"]
    assert torch.allclose(k.offsets, m.kernel.offsets, atol=1e-12, rtol=0)
    assert torch.allclose(k.weights, m.kernel.weights, atol=1e-12, rtol=0)
    f = p.fitted()
    assert f.params["width"] == pytest.approx(3.0, rel=1e-12)
    assert f.params["strength"] == pytest.approx(SHADER["strength"], rel=1e-9)
    assert f.params["falloff"] == pytest.approx(SHADER["falloff"], rel=1e-9)


def test_jimenez_fit_recovers_known_strength_falloff_and_width():
    """The target is the 2012 method itself with known (t*, f*, w*) on a white-noise plane;
    fitting from the shader's defaults at another width recovers them, and installing the fit
    gives the published method with those parameters (built independently)."""
    px = 0.25
    g = _noise_plane(32, px)
    t_true, f_true, w_true = (0.7, 0.5, 0.35), (0.6, 0.3, 0.2), 2.0
    target_m = Jimenez2012SSS(t_true, f_true, w_true, 9, follow_surface=False)
    with torch.no_grad():
        target = target_m(g)
    m = Jimenez2012SSS(*SHADER.values(), 2.6, 9, follow_surface=False)
    fit = opt.fit_taps(m, [(g, target)], opt.Jimenez2012Parameters(m), steps=150, lr=0.1)
    assert fit.losses[-1] < 1e-2 * fit.losses[0]
    got = fit.fitted.params
    assert got["width"] == pytest.approx(w_true, rel=0.01)
    assert got["strength"] == pytest.approx(t_true, abs=0.01)
    assert got["falloff"] == pytest.approx(f_true, rel=0.03)
    opt.Jimenez2012Parameters.install(m, fit.fitted)
    again = Jimenez2012SSS(got["strength"], got["falloff"], got["width"], 9, follow_surface=False)
    assert torch.allclose(m(g), again(g), atol=1e-12, rtol=0)


# ------------------------------------------------------------------- optimise: both methods
SCENES = (opt.TrainingScene("step_edge", (20, 20)),)


@pytest.mark.parametrize(
    ("method", "options", "cls", "args"),
    [
        ("sum_of_gaussians", {}, SumOfGaussiansSSS, lambda n: (PROFILE, n)),
        ("jimenez2012", {**SHADER, "width": 2.0}, Jimenez2012SSS,
         lambda n: (*SHADER.values(), 2.0, n)),
    ],
)  # fmt: skip
def test_fit_never_has_more_training_error_than_the_published_start(
    kernel_cache, monkeypatch, method, options, cls, args
):
    monkeypatch.setattr(opt, "DEFAULT_TRAINING", SCENES)
    monkeypatch.setattr(opt, "DEFAULT_STEPS", 3)
    r = opt.optimise(PROFILE, method, 5, 0.5, options=options)
    g = SCENES[0].build(0.5)
    ref = ReferenceSSS(PROFILE)(g)
    published = rel_rms(cls(*args(5))(g), ref, g.mask)  # metrics' own rel RMS
    fitted = cls(*args(5), sampling="optimised", pixel_mm=0.5)  # the cached fit
    assert rel_rms(fitted(g), ref, g.mask) <= published * (1 + 1e-5)
    assert r.loss <= min(r.rule_losses.values())
    again = opt.optimise(PROFILE, method, 5, 0.5, options=options)
    assert again.cached and again.fitted.params == r.fitted.params
    for a, b in zip(again.fitted.kernels, r.fitted.kernels, strict=True):
        assert (a is None and b is None) or torch.equal(a.weights, b.weights)


def test_cache_key_follows_the_new_methods_options():
    def key(method, **options):
        options = opt.method_options(method, options)
        return opt.cache_key(PROFILE, method, 7, 0.3, SCENES, options, 10, 0.1)

    base = key("jimenez2012", **SHADER, width=3.0)
    assert key("jimenez2012", **SHADER, width=3.0) == base
    assert key("jimenez2012", **SHADER, width=2.0) != base
    assert key("jimenez2012", strength=0.5, falloff=SHADER["falloff"], width=3.0) != base
    sog = key("sum_of_gaussians")
    assert key("sum_of_gaussians", lod=True) == sog  # the default, made explicit
    from sssbench.ops import jg10_stretch

    assert key("sum_of_gaussians", stretch=jg10_stretch(128)) != sog
    assert key("sum_of_gaussians", stretch=jg10_stretch(256)) != key(
        "sum_of_gaussians", stretch=jg10_stretch(128)
    )
    assert key("preintegrated") != sog


def test_methods_fit_at_the_runs_footprint_and_the_registry_builds_them(kernel_cache, monkeypatch):
    monkeypatch.setattr(opt, "DEFAULT_TRAINING", SCENES)
    monkeypatch.setattr(opt, "DEFAULT_STEPS", 2)
    g = make_scene("step_edge", (20, 20), pixel_mm=0.32)
    params = {"preset": "shader_default", "width": 3.0}
    jim = build_method("jimenez2012", None, samples=5, sampling="optimised", params=params)
    sog = build_method("sum_of_gaussians", PROFILE, samples=3, sampling="optimised")
    assert jim.kernel is None and sog.steps is None  # nothing fitted before the first call
    with torch.inference_mode():
        out = jim(g)
        sog(g)
    fit = opt.optimise(PROFILE, "jimenez2012", 5, 0.3, options={**SHADER, "width": 3.0})
    assert fit.cached  # the method stored the fit at the nearest grid point, 0.3 mm/px
    t, f, w = (fit.params[k] for k in ("strength", "falloff", "width"))
    assert jim.width == w and torch.equal(jim.kernel.weights, jimenez2012(t, f, 5).weights)
    same = Jimenez2012SSS(t, f, w, 5, surface_scale=3.0)  # the given width's surface scale
    assert torch.allclose(out, same(g), atol=1e-5, rtol=0)
    fit = opt.optimise(PROFILE, "sum_of_gaussians", 3, 0.3)
    assert fit.cached
    assert [s.kernel is None for s in sog.steps] == [k is None for k in fit.fitted.kernels]
    assert all(torch.equal(s.kernel.offsets, k.offsets) for s, k in
               zip(sog.steps, fit.fitted.kernels, strict=True) if k is not None)  # fmt: skip


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="sampling"):
        Jimenez2012SSS(*SHADER.values(), 3.0, sampling="importance")
    with pytest.raises(ValueError, match="pixel_mm"):
        Jimenez2012SSS(*SHADER.values(), 3.0, pixel_mm=0.3)
    with pytest.raises(ValueError, match="pixel_mm"):
        SumOfGaussiansSSS(PROFILE, 7, "uniform", pixel_mm=0.3)
    with pytest.raises(ValueError, match="samples"):
        SumOfGaussiansSSS(PROFILE, opt.MAX_OPTIMISED_TAPS + 2, "optimised")
    with pytest.raises(ValueError, match="width"):
        opt.optimise(PROFILE, "jimenez2012", options=SHADER)
    with pytest.raises(ValueError, match="halo"):
        opt.optimise(PROFILE, "sum_of_gaussians", options={"halo": "lab"})
    with pytest.raises(ValueError, match="sampling"):
        opt.optimise(PROFILE, "sum_of_gaussians", options={"sampling": "uniform"})
    with pytest.raises(TypeError, match="Jimenez2012SSS"):
        opt.Jimenez2012Parameters(SumOfGaussiansSSS(PROFILE))

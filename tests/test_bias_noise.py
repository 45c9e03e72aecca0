"""The bias / noise split of stochastic methods' errors (sssbench.run.runner.bias_noise), through
a run and into the report's summary table, on a synthetic method whose bias and noise are
known by construction: the exact reference + a constant offset + seeded Gaussian noise."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
from specs import small_spec
from torch import nn

from sssbench.ops import ReferenceSSS
from sssbench.run import registry, runner
from sssbench.run.spec import DEFAULT_SEEDS, RunSpec

#: offset and noise σ of the synthetic method (the scene's irradiance is O(0.1–1))
OFFSET, SIGMA = 0.02, 0.03


class NoisySSS(nn.Module):
    """The exact reference + ``OFFSET`` + ``SIGMA`` · N(0, 1) drawn from ``seed``."""

    needs = ("mask",)

    def __init__(self, profile, seed: int = 0) -> None:
        super().__init__()
        self.profile, self.seed = profile, seed

    def forward(self, gbuffer):
        ref = ReferenceSSS(self.profile)(gbuffer)
        gen = torch.Generator().manual_seed(self.seed)
        noise = torch.randn(ref.shape, generator=gen, dtype=torch.float64).to(ref)
        return ref + OFFSET + SIGMA * noise


@pytest.fixture
def noisy_method(monkeypatch):
    # registered as docs/extending.md shows, marked stochastic
    NoisySSS.__module__ = __name__
    entry = registry.MethodEntry(f"{__name__}:NoisySSS", samples_arg=None, deterministic=False)
    monkeypatch.setitem(registry.METHODS, "noisy", entry)
    return "noisy"


def _spec(tmp_path, method: str, **kw) -> RunSpec:
    return small_spec(tmp_path, method=method, **kw)


def test_a_run_splits_known_bias_and_noise(tmp_path, noisy_method):
    seeds = 6
    spec = _spec(tmp_path, noisy_method, seeds=seeds)
    assert runner.execute(spec, tmp_path / "run").status == "ok"
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    # the expected values, relative to the reference's RMS over the mask (as rel_rms)
    from sssbench.run.registry import build_profile, build_scene

    g = build_scene("step_edge", (24, 24), fields=("mask",), dtype="float64")
    ref = ReferenceSSS(build_profile("skin_jg10"))(g)
    mask = (g.mask > 0).double()
    ref_rms = float(((ref**2 * mask).sum() / (mask.sum() * 3)).sqrt())
    assert m["seeds"] == seeds
    # std across seeds: σ; error of the seed mean: the offset (its σ²/K removed). 24×24×3 values
    # (the step_edge mask holds most of them) estimate σ² to ~3%
    assert m["noise_rel_rms"] == pytest.approx(SIGMA / ref_rms, rel=0.08)
    assert m["bias_rel_rms"] == pytest.approx(OFFSET / ref_rms, rel=0.1)
    # each seed's error is √(offset² + σ²); rel_rms is their mean, and the skill follows it
    assert m["rel_rms"] == pytest.approx((OFFSET**2 + SIGMA**2) ** 0.5 / ref_rms, rel=0.06)
    assert m["skill"] == pytest.approx(1 - m["rel_rms"] / m["rel_rms_identity"], rel=1e-9)
    # and the report's summary table carries the split
    from sssbench.report import load_runs, summary_table
    from sssbench.report.tables import MD_COLUMNS

    table = summary_table(load_runs(tmp_path / "s.sqlite")[0])
    row = table[table["method"] == noisy_method].iloc[0]
    assert row["bias_rel_rms"] == pytest.approx(m["bias_rel_rms"])
    assert row["noise_rel_rms"] == pytest.approx(m["noise_rel_rms"])
    assert {"bias_rel_rms", "noise_rel_rms"} <= set(MD_COLUMNS)


def test_bias_noise_recovers_a_pure_bias_and_pure_noise():
    # closed forms on synthetic images: zero noise -> bias exactly the offset's rel RMS;
    # zero-mean noise -> bias ≈ 0 (the σ²/K correction), noise ≈ σ / RMS(ref)
    gen = torch.Generator().manual_seed(3)
    ref = 1 + torch.rand(1, 3, 64, 64, generator=gen, dtype=torch.float64)
    rms = float(ref.pow(2).mean().sqrt())
    same = runner.bias_noise([ref + 0.1] * 3, ref)
    assert same["noise_rel_rms"] == 0.0
    assert same["bias_rel_rms"] == pytest.approx(0.1 / rms, rel=1e-12)
    assert same["rel_rms"] == pytest.approx(0.1 / rms, rel=1e-12)
    noisy = [ref + 0.05 * torch.randn(ref.shape, generator=gen, dtype=ref.dtype) for _ in range(4)]
    split = runner.bias_noise(noisy, ref)
    assert split["noise_rel_rms"] == pytest.approx(0.05 / rms, rel=0.03)
    # without the correction the seed mean's error would be σ/√K / rms = 0.5 × noise
    assert split["bias_rel_rms"] < 0.15 * split["noise_rel_rms"]
    with pytest.raises(ValueError, match="images"):
        runner.bias_noise([ref], ref)


def test_which_methods_are_split(tmp_path):
    profile = registry.build_profile("skin_jg10")
    disk = registry.build_method("disk", profile, samples=8)
    rotated = registry.build_method("preintegrated", profile, samples=9, params={"rotation": 0.1})
    plain = registry.build_method("preintegrated", profile, samples=9)
    assert runner.is_stochastic("disk", disk)
    assert runner.is_stochastic("preintegrated", rotated)
    assert not runner.is_stochastic("preintegrated", plain)
    # the seed count is in the point only when it is not the default (old hashes unchanged)
    spec = _spec(tmp_path, "disk")
    assert "seeds" not in spec.point()
    assert dataclasses.replace(spec, seeds=DEFAULT_SEEDS + 1).point()["seeds"] == 5
    with pytest.raises(ValueError, match="seeds"):
        runner.measure(dataclasses.replace(spec, seeds=0, samples=8), tmp_path / "run")

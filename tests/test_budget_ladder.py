"""The error budget's converged method (run.budget_step.budget_limit) runs its tap ladder in
float32 (LADDER_DTYPE): it must stop where the float64 ladder stops and give the float64
ladder's image to far below the ladder's own tolerance (score.budget.CONVERGED_TOL)."""

from __future__ import annotations

import pytest
import torch
from specs import small_spec

from sssbench.run import registry
from sssbench.run.budget_step import BUDGET_MAX, BUDGET_START, LADDER_DTYPE, budget_limit
from sssbench.score.budget import CONVERGED_TOL, converged


@pytest.mark.parametrize(
    "scene, method, sampling",
    [("sphere", "preintegrated", "importance"), ("light_dot", "sum_of_gaussians", None)],
)
def test_float32_ladder_matches_the_float64_ladder(tmp_path, scene, method, sampling):
    spec = small_spec(
        tmp_path,
        scene=scene,
        method=method,
        sampling=sampling,
        samples=7,
        resolution=(48, 48),
        budget=True,
        profile="skin_deon6",
        dtype="float32",
    )
    profile = registry.build_profile(spec.profile)
    g = registry.build_scene(scene, (48, 48), dtype="float32")
    ref_rms = float(g.diffuse.double().pow(2).mean().sqrt())  # any fixed scale
    image, n, change = budget_limit(spec, profile, g, g.diffuse)
    assert LADDER_DTYPE == torch.float32 and image.dtype == torch.float64

    # the oracle: the same ladder, every pass in float64
    def build(samples: int):
        return registry.method_from_spec(spec, profile, samples=samples)

    want, n64, change64 = converged(
        build, BUDGET_START, g.to(torch.float64), max_samples=BUDGET_MAX, scale=ref_rms
    )
    assert n == n64
    rel = float((image - want).pow(2).mean().sqrt()) / float(want.pow(2).mean().sqrt())
    # float32 rounding of a few hundred taps, far below the ladder's stopping change
    assert 0 < rel < 1e-2 * CONVERGED_TOL
    assert abs(change - change64) < 1e-2 * CONVERGED_TOL

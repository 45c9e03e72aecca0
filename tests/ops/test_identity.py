"""IdentitySSS: the do-nothing baseline runs in the pipeline, changes nothing, records no pass."""

import inspect
from pathlib import Path

import pytest
import torch
import yaml

from data_synth import make_scene
from sssbench.ops import CurvatureModulation, IdentitySSS, PreintegratedSSS
from sssbench.ops.pipeline import Pipeline
from sssbench.profiles import SumOfGaussians

PROFILE = SumOfGaussians.from_table("skin_jg10")
CONF = Path(__file__).resolve().parents[2] / "sssbench" / "conf" / "method"


def test_pipeline_runs_identity_with_zero_passes():
    g = make_scene("head_cheek", (16, 16), fields=["mask", "normal"], dtype=torch.float64)
    res = Pipeline(IdentitySSS(), add_specular=False).run(g)
    assert res.records == []  # zero passes: the baseline costs nothing
    assert torch.equal(res.image, g.diffuse)
    # a real method on the same G-buffer does record passes (the check above can fail)
    assert len(Pipeline(PreintegratedSSS(PROFILE), add_specular=False).run(g).records) == 2


def test_identity_accepts_every_pipeline_option():
    g = make_scene("head_cheek", (16, 16), fields=["mask", "normal"], dtype=torch.float64)
    pipe = Pipeline(
        IdentitySSS(PROFILE),
        curvature=CurvatureModulation(),
        halo="bilateral",
        add_specular=False,
    )
    res = pipe.run(g)
    assert torch.equal(res.image, g.diffuse)
    assert all(not r.name.startswith("identity") for r in res.records)
    out = IdentitySSS()(g, inplace=True)
    assert out is g.diffuse


def test_identity_builds_like_a_profile_method():
    # the app builds methods whose first argument is `profile` as cls(profile, **params)
    first = list(inspect.signature(IdentitySSS.__init__).parameters)[1]
    assert first == "profile"
    conf = yaml.safe_load((CONF / "identity.yaml").read_text())
    assert conf["name"] == "identity" and conf["samples"] is None
    assert isinstance(IdentitySSS(PROFILE, **(conf["params"] or {})), IdentitySSS)


def test_identity_rejects_bad_input():
    with pytest.raises(TypeError, match="profile"):
        IdentitySSS("skin_jg10")
    with pytest.raises(TypeError, match="gbuffer"):
        IdentitySSS()(torch.zeros(1, 3, 4, 4))

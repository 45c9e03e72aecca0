"""Pipeline: composition, plan (DESIGN §5), stencil, records."""

import pytest
import torch

from data_synth import make_scene
from sssbench.ops import CurvatureModulation, PreintegratedSSS, ReferenceSSS, Translucency
from sssbench.ops.pipeline import Pipeline
from sssbench.profiles import SumOfGaussians

PROFILE = SumOfGaussians.from_table("skin_deon6")


def _method():
    return PreintegratedSSS(PROFILE, 7)


def _full(**kw):
    return Pipeline(
        _method(),
        translucency=Translucency(PROFILE, 0.9, 8.0),
        texturing="post",
        **kw,
    )


def _plan(pipe, g):
    return {e.stage: e for e in pipe.plan(g)}


def test_plan_leaves_translucency_out_of_step_edge():
    g = make_scene("step_edge", (16, 16), dtype=torch.float64)
    plan = _plan(_full(), g)
    assert not plan["translucency"].runs
    assert plan["translucency"].reason == "no thickness in the G-buffer"
    res = _full().run(g)
    assert ("translucency", "no thickness in the G-buffer") in res.skipped
    assert not any(r.name == "translucency" for r in res.records)


def test_no_back_light_and_zero_mask():
    g = make_scene("backlit_ear", (16, 16), dtype=torch.float64, light_dir=(0.2, 0.3, 0.93))
    plan = _plan(_full(), g)
    assert not plan["translucency"].runs and "no back light" in plan["translucency"].reason
    g0 = g.replace(mask=torch.zeros_like(g.depth))
    res = _full().run(g0)
    reasons = {e.stage: e.reason for e in res.plan if not e.runs}
    for stage in ("translucency", "texturing", "sss", "specular"):
        assert reasons[stage] == "mask is zero everywhere (stencil)"
    assert reasons["curvature"] == reasons["halo"] == "disabled"
    assert res.records == []
    torch.testing.assert_close(res.image, g0.diffuse)


def test_computes_nothing_outside_the_mask():
    g = make_scene("backlit_ear", (32, 32), dtype=torch.float64)
    n_mask = int((g.mask > 0).sum())
    assert 0 < n_mask < 32 * 32
    res = _full().run(g)
    ran = [e.stage for e in res.plan if e.runs]
    assert ran == ["translucency", "texturing", "sss", "specular"]
    assert {r.name for r in res.records} >= {"translucency", "preintegrated.x", "specular"}
    assert all(r.pixels == n_mask for r in res.records)
    outside = (g.mask == 0).expand_as(res.image)
    torch.testing.assert_close(res.image[outside], g.diffuse[outside])


def test_skips_specular_when_absent():
    g = make_scene("sphere", (16, 16), dtype=torch.float64, fields=["mask", "albedo"])
    res = Pipeline(_method()).run(g)
    assert ("specular", "no specular in the G-buffer") in res.skipped
    assert all(r.name != "specular" for r in res.records)
    assert Pipeline(_method(), add_specular=False).plan(g)[-1].reason == "disabled"


def test_backlit_ear_runs_translucency():
    g = make_scene("backlit_ear", (32, 32), dtype=torch.float64)
    pipe = _full()
    assert set(pipe.needs) >= {"thickness", "normal", "albedo", "mask", "specular"}
    res = pipe.run(g)
    assert _plan(pipe, g)["translucency"].runs
    assert sum(r.name == "translucency" for r in res.records) == 1
    without = Pipeline(_method(), texturing="post").run(g)
    inside = (g.mask > 0).expand_as(res.image)
    gain = (res.image - without.image)[inside]
    assert float(gain.min()) >= -1e-12 and float(gain.max()) > 0.01


def test_composition_order():
    # pre texturing: blur(albedo · (E + T)) + specular; sqrt: √a · blur(√a (E + T)) + spec
    g = make_scene("backlit_ear", (24, 24), dtype=torch.float64)
    tr = Translucency(PROFILE, 0.9, 8.0, apply_albedo=False)
    m = _method()
    e = g.diffuse + tr(g)
    inside = g.mask > 0
    for mode in ("pre", "sqrt"):
        a = g.albedo if mode == "pre" else g.albedo.sqrt()
        after = 1.0 if mode == "pre" else a
        expect = after * m(g.replace(diffuse=torch.where(inside, a * e, e))) + g.specular
        expect = torch.where(inside, expect, g.diffuse)
        got = Pipeline(m, translucency=tr, texturing=mode).run(g).image
        torch.testing.assert_close(got, expect)


def test_texturing_skipped_without_albedo_and_curvature_without_normals():
    g = make_scene("sphere", (16, 16), dtype=torch.float64, fields=["mask"])
    pipe = Pipeline(_method(), texturing="sqrt", curvature=CurvatureModulation(), halo="bilateral")
    plan = _plan(pipe, g)
    assert plan["texturing"].reason == "no albedo in the G-buffer"
    assert plan["curvature"].reason == "no normals in the G-buffer"
    assert plan["halo"].reason == "no normals in the G-buffer"
    assert set(pipe.needs) >= {"albedo", "normal", "mask"}


def test_curvature_and_halo_reach_the_method():
    g = make_scene("sphere", (24, 24), dtype=torch.float64)
    res = Pipeline(_method(), curvature=CurvatureModulation("reduce"), halo="bilateral").run(g)
    names = [r.name for r in res.records]
    assert names[:2] == ["curvature", "halo.bilateral"] and "preintegrated.y" in names
    plain = Pipeline(_method()).run(g).image
    assert float((res.image - plain).abs().max()) > 1e-4
    with pytest.raises(TypeError, match="width"):
        Pipeline(ReferenceSSS(PROFILE), curvature=CurvatureModulation())


def test_a_caller_timing_a_pipeline_sees_its_passes():
    """A pipeline keeps its own records for its result; a caller's ``record_passes`` around it
    must see the same passes (it used to see none, which experiments read as 0 ms), and the
    operator's own passes run alone must be the pipeline's SSS passes (conservation: nothing
    counted twice, nothing lost)."""
    from sssbench.ops import record_passes

    g = make_scene("backlit_ear", (16, 16), dtype=torch.float64)
    with record_passes() as outer:
        res = _full().run(g)
    assert [r.name for r in outer] == [r.name for r in res.records]
    assert len(outer) == len(res.records) > 0
    with record_passes() as outer, record_passes() as inner:
        _method()(g)
    assert (
        [r.name for r in outer] == [r.name for r in inner] == ["preintegrated.x", "preintegrated.y"]
    )

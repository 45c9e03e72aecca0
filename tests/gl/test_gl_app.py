"""``backend=gl`` in the app: the run's passes are timed on the GL device, the renderer is
recorded beside the times and shown in the report, the image is the torch image; a method
without a GL shader fails naming it (never timed on the CPU instead)."""

from __future__ import annotations

import json

import pytest

from sssbench import gl
from sssbench.app import compose_spec
from sssbench.io import read_image_exr
from sssbench.report import load_runs, summary_table
from sssbench.report.tables import device_lines, format_console
from sssbench.run import runner
from sssbench.score.metrics import rel_rms

OK, WHY = gl.available()
pytestmark = pytest.mark.skipif(not OK, reason=f"no headless GL: {WHY}")

COMMON = ["scene=face_close", "resolution=[32,32]", "repeats=2", "warmup=1", "budget=false"]


def _run(tmp_path, backend, method="preintegrated", *extra):
    spec = compose_spec(
        f"method={method}",
        f"backend={backend}",
        *COMMON,
        *extra,
        f"reference_cache={tmp_path / 'refs'}",
        store=tmp_path / "s.sqlite",
    )
    out = runner.execute(spec, tmp_path / f"{method}-{backend}")
    return out, tmp_path / f"{method}-{backend}"


@pytest.mark.parametrize("method", ["preintegrated", "jimenez2012", "sum_of_gaussians"])
def test_gl_run_records_device_times_and_renderer(tmp_path, method):
    gl_out, gl_dir = _run(tmp_path, "gl", method)
    cpu_out, cpu_dir = _run(tmp_path, "torch", method)
    assert gl_out.status == "ok", gl_out.message
    assert cpu_out.status == "ok", cpu_out.message
    m = json.loads((gl_dir / "metrics.json").read_text())
    # the renderer as the driver names it, beside the GL times
    assert m["renderer"] == gl.renderer_info()["renderer"]
    assert m["gl_version"] == gl.renderer_info()["version"]
    assert m["time_source"] == "GL_TIME_ELAPSED"
    assert m["backend"] == "gl"
    assert ("llvmpipe" in m["renderer"]) == bool(m["timing_note"])
    # the method's passes, each timed by the device; the run's time is their sum
    c = json.loads((cpu_dir / "metrics.json").read_text())
    gl_names = [p["name"] for p in m["pass_times"]]
    assert gl_names and all(p["ms_median"] > 0 for p in m["pass_times"])
    assert m["time_ms"] == pytest.approx(sum(p["ms_median"] for p in m["pass_times"]))
    # the CPU run's blur passes are among them (the GL schedule may add blend passes)
    cpu_blurs = [p["name"] for p in c["pass_times"] if p["name"].endswith((".x", ".y"))]
    assert cpu_blurs and set(cpu_blurs) <= set(gl_names)
    # the scored image is the torch image (the GL passes with SeparableSSS.h semantics)
    a = read_image_exr(gl_dir / "result.exr")
    b = read_image_exr(cpu_dir / "result.exr")
    assert rel_rms(a, b) <= 1e-5
    # the report names the renderer beside the times
    table = summary_table(load_runs(tmp_path / "s.sqlite")[0])
    lines = device_lines(table)
    assert len(lines) == 1 and m["renderer"] in lines[0]
    assert m["renderer"] in format_console(table)


def test_a_method_without_a_gl_shader_fails_naming_it(tmp_path):
    out, _ = _run(tmp_path, "gl", "preintegrated", "halo=on")
    assert out.status == "failed"
    assert "halo" in out.message.lower()


@pytest.mark.parametrize("estimator", ["sssbench", "hdrp"])
def test_gl_disk_run_records_device_times(tmp_path, estimator):
    """``sssbench method=disk backend=gl``: the disk's draw timed by GL_TIME_ELAPSED, the
    precision of its sample geometry recorded, its image the torch disk's (whole image,
    tests/gl/test_gl_disk.py)."""
    est = f"method.params.estimator={estimator}"
    gl_out, gl_dir = _run(tmp_path, "gl", "disk", est)
    cpu_out, cpu_dir = _run(tmp_path, "torch", "disk", est)
    assert gl_out.status == "ok", gl_out.message
    assert cpu_out.status == "ok", cpu_out.message
    m = json.loads((gl_dir / "metrics.json").read_text())
    assert m["time_source"] == "GL_TIME_ELAPSED"
    assert m["renderer"] == gl.renderer_info()["renderer"]
    assert m["gl_disk_geometry"] == gl.disk_geometry() == "float64"
    (rec,) = m["pass_times"]
    assert rec["name"] == "disk" and rec["samples"] == 32 and rec["ms_median"] > 0
    assert m["time_ms"] == pytest.approx(rec["ms_median"])
    c = json.loads((cpu_dir / "metrics.json").read_text())
    assert "disk" in {p["name"] for p in c["pass_times"]}  # (the CPU run also times specular)
    a = read_image_exr(gl_dir / "result.exr")
    b = read_image_exr(cpu_dir / "result.exr")
    assert rel_rms(a, b) <= 1e-5

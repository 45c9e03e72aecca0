"""Issue 28, the first hour (and issue 29's classes 9 and 17): every README example does what
it says, bad values are refused before the first run, files any tool can open, the reference
reported at its cost, plots whose legend explains every mark, no noise.

In-process where possible; the subprocess checks use tiny resolutions and put every output,
the store and the caches under ``tmp_path``.
"""

from __future__ import annotations

import base64
import json
import math
import re
import sqlite3
import struct
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch

from sssbench import _console, _json, app, report
from sssbench.run import inputs as runner_inputs
from sssbench.run import runner
from sssbench.store.tracking import PassStats, RunRecord, RunStore, config_hash
from tests.test_app import _env, _sssbench

REPO = Path(__file__).resolve().parents[1]
TINY = ("resolution=[24,24]", "repeats=1", "warmup=0", "previews=false", "budget=false")


def _strict_loads(text: str):
    """``json.loads`` that refuses ``NaN`` / ``Infinity`` as JavaScript's ``JSON.parse`` does."""

    def refuse(constant: str):
        raise ValueError(f"not strict JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def _spec(tmp_path: Path, *overrides: str):
    return app.compose_spec(
        *TINY, *overrides, f"reference_cache={tmp_path / 'cache'}", store=tmp_path / "s.sqlite"
    )


# ----------------------------------------------------------------------------- 1. examples
def _readme_translucency_command() -> list[str]:
    lines = [
        ln for ln in (REPO / "README.md").read_text().splitlines() if "translucency=off,on" in ln
    ]
    assert lines, "the README has a translucency example"
    return lines[0].split("#")[0].split()


def test_readme_translucency_example_runs_the_stage_and_changes_the_numbers(tmp_path):
    cmd = _readme_translucency_command()
    scene = next(a for a in cmd if a.startswith("scene="))
    rel = {}
    for value in ("off", "on"):
        spec = _spec(tmp_path, scene, "method=sum_of_gaussians", f"translucency={value}")
        payload, _ = runner.measure(spec, tmp_path / value)
        plan = {e["stage"]: e for e in payload["plan"]}
        assert plan["translucency"]["runs"] == (value == "on"), plan["translucency"]
        rel[value] = payload["rel_rms"]
    assert not math.isclose(rel["off"], rel["on"], rel_tol=1e-3), rel


def test_requested_stage_that_cannot_run_fails_naming_why(tmp_path):
    spec = _spec(tmp_path, "scene=step_edge", "translucency=on")
    out = runner.execute(spec, tmp_path / "run")
    assert out.status == "failed"
    assert "translucency" in out.message and "thickness" in out.message


#: a back-lit slab 5 mm thick: skin_jg10's transmittance there is ~2e-6 (004 eq. 3.10: the
#: widest Gaussian, v = 2.0 mm², weight 0.46 in red: 0.46 exp(-25 / 2.0) = 1.8e-6), below the
#: automatic plan's 1e-3 but not zero
THIN_ENOUGH = ("scene=backlit_slab", "++scene.params.thickness=5.0", "translucency=on")


def test_requested_stage_is_never_planned_away(tmp_path):
    # judged negligible by the automatic plan (T ~ 2e-6 < 1e-3), the stage asked for still
    # runs (its cost is measured) instead of being silently left out, and it is announced
    spec = _spec(tmp_path, *THIN_ENOUGH)
    (note,) = runner_inputs.check_stages(spec)
    assert "translucency" in note and "backlit_slab" in note and "too thick" in note
    payload, _ = runner.measure(spec, tmp_path / "run")
    assert {e["stage"]: e["runs"] for e in payload["plan"]}["translucency"] is True


def _stage_images(tmp_path, *overrides: str):
    """The run's pipeline output with the stage and without it, in float64."""
    images = []
    for stages in (overrides, [o for o in overrides if not o.startswith("translucency=")]):
        spec = _spec(tmp_path, *stages, "dtype=float64")
        built = runner_inputs.build(spec) if spec.stages["translucency"] is None else None
        if built is None:  # asked for: run the stage whatever the app says of it
            from sssbench.run import registry

            profile = registry.build_profile(spec.profile, spec.profile_kind)
            pipe = runner_inputs.stage_pipeline(
                spec, registry.method_from_spec(spec, profile), profile
            )
            g = runner_inputs.scene_gbuffer(spec, pipe.needs)
        else:
            pipe, g = built.pipeline, built.gbuffer
        images.append(pipe.run(g).image)
    return images


def test_a_stage_that_would_add_nothing_is_refused_and_adds_nothing(tmp_path):
    # issue 28: face_portrait's thinnest back-lit ear is ~120 mm: T = 0 in float64, so
    # translucency=on would store a row claiming a stage that changed no bit of the image.
    # Refused before the run; the oracle: run anyway, the image equals the one without it
    spec = _spec(tmp_path, "scene=face_portrait", "translucency=on")
    with pytest.raises(ValueError, match=r"translucency=on cannot change the image on scene face"):
        runner_inputs.check_stages(spec)
    on, off = _stage_images(tmp_path, "scene=face_portrait", "translucency=on")
    assert torch.equal(on, off)
    # the thin slab's negligible stage is not refused because it does change the image
    on, off = _stage_images(tmp_path, *THIN_ENOUGH)
    assert not torch.equal(on, off)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        # cannot run: no thickness, only in the grid's second scene (a point neither the first
        # job nor a one-axis change of it reaches: the whole grid is checked)
        (
            ["-m", "scene=backlit_ear,step_edge", "translucency=off,on"],
            ["translucency", "step_edge", "thickness"],
        ),
        # would add exactly nothing (T = 0)
        (
            ["-m", "scene=backlit_ear,face_portrait", "translucency=on"],
            ["translucency", "face", "T = 0"],
        ),
        # the method does not take the stage's input
        (["-m", "method=preintegrated,disk", "curvature=on"], ["curvature", "DiskSSS"]),
        # a preset's own grid (the benchmark's step_edge)
        (["-m", "+experiment=benchmark", "translucency=on"], ["translucency", "step_edge"]),
    ],
)
def test_requested_stage_that_cannot_run_is_refused_for_the_whole_grid(args, words):
    # refused before the first run: by the value check when the stage cannot be built with the
    # method (issue 28: every value of every job), else by the stage check on the scene
    problem = app.check_values([*args, *TINY]) or app.check_stages([*args, *TINY])[0]
    assert problem is not None and "\n" not in problem
    assert all(w in problem for w in words), problem


def test_no_stage_no_scene_is_built(monkeypatch):
    # the stage check costs nothing when no stage is switched on
    monkeypatch.setattr(runner_inputs, "build", lambda spec: pytest.fail("built a scene"))
    assert app.check_stages(["-m", "scene=step_edge,face", "method=preintegrated,disk"]) == (
        None,
        [],
    )


def test_requested_stage_refused_before_the_first_run(tmp_path):
    # one line, exit 2, nothing run or stored (it used to run the sweep, store the point
    # failed and exit 1)
    proc = _sssbench(
        tmp_path, *TINY, "scene=backlit_ear,step_edge", "translucency=on", multirun=True
    )
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "translucency=on cannot run on scene step_edge" in lines[0], lines
    assert not (tmp_path / "store.sqlite").exists()
    assert not list((tmp_path / "sweep").glob("*/point.json"))
    # a negligible stage runs, announced by one note before the first run
    proc = _sssbench(tmp_path, *TINY, *THIN_ENOUGH)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "sssbench: note: translucency=on on scene backlit_slab" in proc.stderr
    (row,) = RunStore(tmp_path / "store.sqlite").runs()
    assert row["status"] == "ok" and "translucency" in row["config"]["stages"]


def _rows(store: RunStore, stages_of: dict[str, dict | None]) -> None:
    for method, t in (("preintegrated", 1.0), ("sum_of_gaussians", 2.0)):
        for name, stages in stages_of.items():
            cfg = {"scene": "backlit_ear", "method": method, "profile": "p", "sampling": "uniform",
                   "samples": 7, "stages": stages, "resolution": [24, 24]}  # fmt: skip
            store.record(
                RunRecord(
                    config=cfg,
                    status="ok",
                    metrics={"rel_rms": 0.1 * t + (0.01 if name else 0.0), "flip": 0.01},
                    passes=[PassStats("x", 7, 64, t, t, t, 1)],
                    time_ms=t,
                )
            )


def test_console_table_shows_the_stages_when_a_sweep_varies_them(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _rows(store, {"": {}, "t": {"translucency": {"form": "deon"}}})
    text = report.format_console(report.summary_table(report.load_runs(store.path)[0]))
    header = text.splitlines()[0].split()
    assert "stages" in header
    assert "translucency" in text


def test_explicit_resolution_with_a_file_scene_is_honoured_or_refused(tmp_path):
    import data_synth
    from sssbench.io import write_gbuffer

    write_gbuffer(tmp_path / "f.npz", data_synth.make_scene("sphere", (20, 24)))
    path = f"scene.path={tmp_path / 'f.npz'}"
    assert app.compose_spec("scene=file", path).resolution == (20, 24)  # the default: the file's
    assert app.compose_spec("scene=file", path, "resolution=[20,24]").resolution == (20, 24)
    with pytest.raises(ValueError, match=r"resolution=\[8, 8\].*20x24"):
        app.compose_spec("scene=file", path, "resolution=[8,8]")


# ----------------------------------------------------------------------------- 2. values
@pytest.mark.parametrize(
    ("args", "key"),
    [
        (["resolution=[0,0]"], "resolution"),
        (["scene=file"], "scene.path"),
        (["scene=file", "scene.path=missing.exr"], "scene.path"),
        (["samples=-3"], "samples"),
        (["-m", "samples=3,-3"], "samples"),
        (["threads=0"], "threads"),
        (["store=/no/such/folder/s.sqlite"], "store"),
        (["seed=4294967296"], "seed"),  # 2^32: its bit 32 would be dropped (issue 29.1)
        (["seed=-1"], "seed"),
    ],
)
def test_every_value_is_checked_before_the_first_run(args, key):
    problem = app.check_values(args)
    assert problem is not None and key in problem and "\n" not in problem


def test_good_values_pass_the_check():
    assert app.check_values(["-m", "method=preintegrated,identity", "samples=3,5"]) is None
    assert app.check_values(["+experiment=benchmark", "hydra/launcher=joblib"]) is None


def test_bad_value_is_one_line_exit_2_and_no_row(tmp_path):
    proc = _sssbench(tmp_path, "samples=-3", "scene=sphere")
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "samples" in lines[0], proc.stderr
    assert not (tmp_path / "store.sqlite").exists() and not (tmp_path / "run").exists()


def test_report_prints_stored_configurations_as_key_value_text(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    # a row as stores written before this fix hold them: the scene's config group as a dict
    bad = {"scene": {"name": "file", "path": None}, "method": {"name": "disk", "params": {}}}
    store.record(RunRecord(config=bad, status="failed", error="ValueError: x"))
    table = report.summary_table(report.load_runs(store.path)[0])
    text = report.format_console(table) + report.summary_markdown(table, "s")
    assert "{'" not in text and "name=file" in text
    assert report.config_text({"a": {"b": 1}, "c": [1, 2]}) == "a.b=1, c=[1,2]"


# ----------------------------------------------------------------------------- 3. strict JSON
def test_strict_json_helper_round_trips_non_finite_numbers():
    obj = {"a": math.nan, "b": [1.0, math.inf], "c": {"d": -math.inf}, "e": 2}
    text = _json.dumps(obj)
    parsed = _strict_loads(text)
    assert parsed["a"] is None and parsed["a_nonfinite"] == "nan"
    assert parsed["c"] == {"d": None, "d_nonfinite": "-inf"}
    back = _json.loads(text)
    assert math.isnan(back["a"]) and back["c"]["d"] == -math.inf and back["e"] == 2


def test_every_file_a_run_writes_is_strict_json(tmp_path):
    # the sphere is curved: the error budget's err_recon is measured there too
    # (docs/error_budget.md); non-finite numbers round-trip in the helper's test above
    spec = app.compose_spec(
        "scene=sphere", "resolution=[24,24]", "repeats=1", "warmup=0", "previews=false",
        f"reference_cache={tmp_path / 'cache'}", store=tmp_path / "s.sqlite",
    )  # fmt: skip
    assert spec.budget
    out = runner.execute(spec, tmp_path / "run")
    assert out.status == "ok", out.message
    metrics = _strict_loads((tmp_path / "run" / "metrics.json").read_text())
    _strict_loads((tmp_path / "run" / "point.json").read_text())
    assert metrics["err_recon"] > 0 and "err_recon_nonfinite" not in metrics
    with sqlite3.connect(tmp_path / "s.sqlite") as conn:
        for row in conn.execute("SELECT config_json, metrics_json, info_json FROM runs"):
            for text in row:
                _strict_loads(text)
    (stored,) = RunStore(tmp_path / "s.sqlite").runs()
    assert stored["metrics"]["err_recon"] == metrics["err_recon"]  # read back as written


def test_no_plain_json_dump_left_in_the_writers():
    writers = [p for p in (REPO / "sssbench").rglob("*.py") if p.name != "_json.py"]
    for path in writers:
        for line in path.read_text().splitlines():
            if re.search(r"(?<!_)json\.dump\(|write_text\(json\.dumps", line):
                pytest.fail(f"{path.relative_to(REPO)} writes JSON without sssbench._json: {line}")


# ----------------------------------------------------------------------------- 4. reference time
def test_the_reference_is_reported_at_its_cost(tmp_path):
    # a flat scene: the reference's FFT path (the README's sweep on light_dot, step_edge) and a
    # curved one (its multipole path)
    for scene in ("step_edge", "sphere"):
        spec = _spec(tmp_path, f"scene={scene}", "method=reference")
        payload, stats = runner.measure(spec, tmp_path / scene)
        names = [p.name for p in stats]
        assert names.count("reference") == 1 and stats[0].ms_median > 0, names
        assert payload["passes"] >= 1 and payload["time_ms"] >= stats[0].ms_median > 0


# ----------------------------------------------------------------------------- 5. legend
def _plot_table() -> pd.DataFrame:
    rows = [
        ("identity", None, None, 1.0, 0.5),
        ("reference", None, None, 0.0, 40.0),
        ("preintegrated", "importance", 7, 0.1, 1.0),
        ("sum_of_gaussians", "uniform", 7, 0.05, 3.0),
        ("artist", "uniform", 7, 2.0, 2.0),  # worse than doing nothing
        ("low_rank", None, 7, 0.08, 5.0),
    ]
    table = pd.DataFrame(
        [
            {
                "scene": "s",
                "scale": "1 mm/px",
                "resolution": "8x8",
                "profile": "p",
                "stages": "–",
                "method": m,
                "sampling": sm,
                "samples": n,
                "status": "ok",
                "rel_rms": e,
                "time_ms": t,
                "skill": 1 - e,
                "visible": True,
                "note": "",
                "pareto": m in ("preintegrated", "sum_of_gaussians"),
                "best": False,
                "worse_than_nothing": m == "artist",
                "run_dir": None,
            }  # fmt: skip
            for m, sm, n, e, t in rows
        ]
    )
    return table


def test_every_mark_of_the_error_plot_has_a_legend_entry():
    from matplotlib.collections import PathCollection
    from matplotlib.lines import Line2D

    from sssbench.report import plots

    fig = plots.error_vs_time_figure(_plot_table())
    (legend,) = fig.legends
    entries = {t.get_text() for t in legend.get_texts()}
    ax = fig.axes[0]
    marks = [c for c in ax.collections if isinstance(c, PathCollection)]
    marks += [ln for ln in ax.lines if isinstance(ln, Line2D)]
    assert marks
    for mark in marks:
        gid = mark.get_gid() or ""
        assert gid.startswith("legend:"), f"a mark without a legend entry: {mark}"
        for needed in gid[len("legend:") :].split("|"):
            assert needed in entries, (needed, entries)
    # every style has its own entry: the Pareto ring, the reference star, the baseline line,
    # the worse-than-nothing cross — and a ring never means "worse than doing nothing"
    for label in (plots.PARETO_LABEL, plots.REFERENCE_LABEL, plots.WORSE_LABEL):
        assert label in entries
    handles = {h.get_label(): h for h in legend.legend_handles}
    assert handles[plots.PARETO_LABEL].get_markerfacecolor() == "none"
    assert handles[plots.WORSE_LABEL].get_marker() == "x"
    assert handles[plots.REFERENCE_LABEL].get_marker() == "*"
    import matplotlib.pyplot as plt

    plt.close(fig)


# ----------------------------------------------------------------------------- 6. noise
def test_the_baseline_is_one_point_per_scene():
    a, b = (app.compose_spec("method=identity", f"samples={n}") for n in (7, 13))
    assert config_hash(a.point()) == config_hash(b.point())


def test_progress_bars_only_on_a_terminal(capsys):
    bar = _console.bar(True, total=3, desc="x")
    bar.update(3)
    bar.close()
    assert bar.disable  # pytest's stderr is not a terminal
    assert capsys.readouterr().err == ""


def test_third_party_log_lines_stay_out_of_the_console(tmp_path):
    # a fresh matplotlib config dir: matplotlib logs "building the font cache" on first use
    store = RunStore(tmp_path / "s.sqlite")
    _rows(store, {"": {}})
    env = _env() | {"MPLCONFIGDIR": str(tmp_path / "mpl")}
    # matplotlib logs its font-cache message only when the build takes over 5 s: the plot is
    # wrapped to log that very line through matplotlib's logger, as a slow first use does
    script = (
        "import logging, sys\n"
        "from sssbench.report import files, main\n"
        "plot = files.plot_error_vs_time\n"
        "def slow_first_use(*a, **k):\n"
        "    logging.getLogger('matplotlib.font_manager').warning(\n"
        "        'Matplotlib is building the font cache; this may take a moment.')\n"
        "    return plot(*a, **k)\n"
        "files.plot_error_vs_time = slow_first_use\n"
        "sys.exit(main())\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "s.sqlite")],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "matplotlib" not in (proc.stdout + proc.stderr).lower()
    assert "report: reading" in proc.stdout and proc.stderr == ""  # says what it does


def _png_size(uri: str) -> tuple[int, int]:
    data = base64.b64decode(uri.split(",", 1)[1])
    return struct.unpack(">II", data[16:24])


def test_html_page_embeds_thumbnails_and_links_full_resolution_files(tmp_path):
    import torch

    from sssbench.io import write_image_exr
    from sssbench.report.html import THUMB_PX, write_html

    rows = []
    gen = torch.Generator().manual_seed(0)
    for i, method in enumerate(("preintegrated", "sum_of_gaussians", "identity")):
        run = tmp_path / f"run{i}"
        run.mkdir()
        ref = torch.rand(1, 3, 512, 512, generator=gen)
        write_image_exr(run / "reference.exr", ref, allow_rounding=True)
        write_image_exr(run / "result.exr", ref * 0.9, allow_rounding=True)
        (run / "point.json").write_text(_json.dumps({"config": {"method": method, "x": math.nan}}))
        rows.append(
            {
                "scene": "s",
                "scale": "1 mm/px",
                "pixel_mm": 1.0,
                "resolution": "512x512",
                "profile": "p",
                "stages": "–",
                "method": method,
                "sampling": "uniform",
                "samples": 7,
                "status": "ok",
                "rel_rms": 0.1,
                "time_ms": 1.0,
                "skill": 0.5,
                "flip": 0.01,
                "visible": True,
                "note": "",
                "pareto": False,
                "best": False,
                "worse_than_nothing": False,
                "run_dir": str(run),
            }  # fmt: skip
        )
    table = pd.DataFrame(rows)
    for col in ("err_model", "err_taps", "err_screen", "bias_rel_rms", "noise_rel_rms"):
        table[col] = None
    lines: list[str] = []
    page = write_html(table, tmp_path / "out", "src", [], progress=lines.append)
    text = page.read_text()
    uris = re.findall(r"src='(data:image/png;base64,[^']*)'", text)
    sizes = [_png_size(u) for u in uris]
    assert sizes and all(max(s) <= max(THUMB_PX, 400) for s in sizes), sizes
    assert len(re.findall(r"data:image/png", text)) == len(uris)  # the reference embedded once
    full = sorted((tmp_path / "out" / "report_files").glob("*.png"))
    assert len(full) == 1 + 2 * 3
    assert all(f"report_files/{p.name}" in text for p in full)
    assert page.stat().st_size < 2_000_000
    assert lines and lines[0].startswith("report.html: 1/1")
    assert "x=nan" in text  # the stored configuration as key=value


def test_the_report_step_says_what_it_does(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _rows(store, {"": {}})
    lines: list[str] = []
    report.write_report(store.path, tmp_path / "out", progress=lines.append)
    assert [ln.split(":")[0] for ln in lines[:2]] == ["report", "report"] and len(lines) >= 3


# ----------------------------------------------------------------------------- 7. warm-up
def test_a_multirun_warms_its_caches_in_parallel(tmp_path, monkeypatch):
    from omegaconf import OmegaConf

    from sssbench.run import warm

    basic = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"
    cfg = OmegaConf.create(
        {
            "warm_workers": 2,
            "store": str(tmp_path / "s.sqlite"),
            "hydra": {
                "launcher": {"_target_": basic},
                "sweeper": {"params": {"scene": "step_edge,light_dot"}},
                "overrides": {
                    "task": [
                        "method=preintegrated,identity",
                        "resolution=[128,128]",
                        "hydra.job.chdir=false",
                    ]  # fmt: skip
                },
            },
        }
    )
    jobs = app.sweep_jobs(cfg)
    assert len(jobs) == 4 and all("resolution=[128,128]" in j for j in jobs)
    seen = []
    monkeypatch.setattr(warm, "warm", lambda specs, workers, progress: seen.append(specs) or 0.0)
    app._warm_sweep(cfg)
    assert len(seen) == 1 and len(seen[0]) == 4
    assert {s.scene for s in seen[0]} == {"step_edge", "light_dot"}
    # tiny images are not worth a process start
    cfg.hydra.overrides.task[1] = "resolution=[24,24]"
    app._warm_sweep(cfg)
    assert len(seen) == 1


@pytest.mark.skipif(
    __import__("shutil").which("node") is None, reason="needs node to run the page's script"
)
def test_the_pages_flip_shows_the_groups_reference_and_back():
    # the reference is embedded once per group (an id); a result flips to it and back
    from sssbench.report.html import _JS

    harness = (
        _JS.replace("window.addEventListener", "(function(){})")
        + """
var attrs={src:'RESULT','data-ref':'ref0'}, caption={textContent:'result'};
var im={getAttribute:function(k){return k in attrs?attrs[k]:null;},
        setAttribute:function(k,v){attrs[k]=v;}, removeAttribute:function(k){delete attrs[k];},
        parentNode:{querySelector:function(){return caption;}}};
var document={getElementById:function(i){return i==='ref0'?{src:'REFERENCE'}:null;}};
flip(im); var a=attrs.src+'/'+caption.textContent;
flip(im); var b=attrs.src+'/'+caption.textContent;
console.log(a+' '+b);
"""
    )
    proc = subprocess.run(["node", "-e", harness], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "REFERENCE/reference RESULT/result", proc.stderr


def test_the_native_library_build_is_announced(tmp_path, monkeypatch, caplog):
    # the first run from an empty cache compiles the native gather (about 14 s of CPU with gcc 12):
    # one line says so, instead of a silent pause (issue 28, point 6: nothing silent for long)
    import logging

    from sssbench.ops import native

    monkeypatch.setenv("SSSBENCH_CACHE_DIR", str(tmp_path))
    calls = []

    def compile_nothing(cmd, **kwargs):
        calls.append(cmd)
        Path(cmd[cmd.index("-o") + 1]).write_bytes(b"")

    monkeypatch.setattr(native.subprocess, "run", compile_nothing)
    with caplog.at_level(logging.INFO, logger="sssbench"):
        path = native._build("cc")
    # each of the library's units compiled on its own, then one link
    assert len(calls) == len(native._GATHER_UNITS) + 1 and path.parent == tmp_path / "native"
    assert [c.count("-c") for c in calls] == [1] * len(native._GATHER_UNITS) + [0]
    (line,) = [r.getMessage() for r in caplog.records if "native" in r.getMessage()]
    assert line.startswith("building the native gather library with cc")
    with caplog.at_level(logging.INFO, logger="sssbench"):
        caplog.clear()
        assert native._build("cc") == path  # cached: built once, announced once
    assert not caplog.records and len(calls) == len(native._GATHER_UNITS) + 1

"""Issue 28, the last part: every value the app takes is checked before the first run — one
line naming the key, exit 2, no row stored — for **every job** of a ``-m`` grid, by the run's own
constructors (no second copy of the rules: :func:`sssbench.run.inputs.check_spec`,
:func:`data_synth.check_scene`); a run that fails for a reason only the run can find is stored
``failed`` and the report prints it as readable text.
"""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import data_synth
from data_synth import render, scenes
from sssbench import app
from sssbench.run import registry
from sssbench.store.tracking import RunStore
from tests.test_app import _env
from tests.test_docs import DRY, _command_blocks

REPO = Path(__file__).resolve().parents[1]
TINY = ("scene=sphere", "resolution=[16,16]", "repeats=1", "warmup=0", "previews=false")


def _app(tmp_path: Path, *args: str, multirun: bool = False) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "sssbench", *(["-m"] if multirun else []), *args,
           "hydra.run.dir=" + str(tmp_path / "run"), "hydra.sweep.dir=" + str(tmp_path / "sweep"),
           "store=" + str(tmp_path / "store.sqlite"),
           "reference_cache=" + str(tmp_path / "cache")]  # fmt: skip
    return subprocess.run(cmd, cwd=tmp_path, env=_env(), capture_output=True, text=True,
                          timeout=300)  # fmt: skip


def _refused(proc: subprocess.CompletedProcess, tmp_path: Path, *words: str) -> None:
    """Exit 2, exactly one stderr line holding ``words``, nothing run or stored."""
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("sssbench: "), proc.stderr
    assert all(w in lines[0] for w in words), lines[0]
    assert not (tmp_path / "store.sqlite").exists()
    assert not (tmp_path / "run").exists() and not (tmp_path / "sweep").exists()


# ----------------------------------------------------------------------------- one run
@pytest.mark.parametrize(
    ("args", "words"),
    [
        # the scene builder's own check (pixel_mm of skin per pixel must be > 0)
        (["method=preintegrated", "++scene.params.pixel_mm=-1"], ["scene.params", "pixel_mm"]),
        (["scene=file"], ["scene.path"]),
        (["resolution=[0,0]"], ["resolution"]),
        # the exact reference's tolerance lies in (0, 1) (ReferenceSSS)
        (["++reference_params.tol=-1"], ["reference_params", "tol"]),
        (["++reference_params.tol=0"], ["reference_params", "tol"]),
    ],
)
def test_bad_value_is_refused_before_the_first_run(tmp_path, args, words):
    _refused(_app(tmp_path, *TINY, *args), tmp_path, *words)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["++profile.params.sigma=1"], ["profile.params", "sigma"]),
        (["profile=burley_skin1", "++profile.params.fit=exact"], ["profile.params", "fit"]),
        (["method=preintegrated", "++method.params.rank=2"], ["method.params", "rank"]),
        (["method=low_rank", "++method.params.rank=0"], ["method", "rank"]),
        (["store_journal=fast"], ["store_journal"]),
        (["timeout_s=-1"], ["timeout_s"]),
        (["warm_workers=-1"], ["warm_workers"]),
        (["scene=step_edge", "++scene.params.edge=99"], ["scene.params", "edge"]),
        (["scene=face", "++scene.params.yaw=120"], ["scene.params", "yaw"]),
        (["scene=sphere", "++scene.params.colour=1"], ["scene.params", "colour"]),
        (["translucency=on", "++translucency.params.scale=1"], ["translucency", "scale"]),
        (
            ["reference=mc", "scene=step_edge", "++reference_params.mc_batches=1"],
            ["reference_params", "batches"],
        ),  # fmt: skip
    ],
)
def test_every_other_value_is_refused_in_one_line(args, words, capsys, monkeypatch, tmp_path):
    # the app's entry point in this process (it exits before Hydra starts): exit 2, one line
    # (samples, seeds, seed, dtype, threads, backend, repeats: test_first_hour.py, test_app.py)
    monkeypatch.chdir(tmp_path)
    tiny = [a for a in TINY if not (a.startswith("scene=") and any("scene=" in b for b in args))]
    monkeypatch.setattr(sys, "argv", ["sssbench", *tiny, *args])
    with pytest.raises(SystemExit) as exit_:
        app.main()
    assert exit_.value.code == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and all(w in lines[0] for w in words), lines
    assert not list(tmp_path.iterdir())  # no store, no run folder


def test_a_zero_timeout_keeps_its_meaning_no_limit():
    # timeout_s=0 meant "no limit" before the pre-check existed (sssbench.run.settings.time_limit
    # skips a limit <= 0): the check keeps that meaning for 0 and refuses only negatives
    assert app.check_values([*TINY, "timeout_s=0"]) is None
    assert app.check_values([*TINY, "timeout_s=null"]) is None
    assert "timeout_s" in (app.check_values([*TINY, "timeout_s=-0.5"]) or "")


# ----------------------------------------------------------------------------- a -m grid
def test_bad_combination_in_a_grid_whose_first_values_are_fine(tmp_path):
    # edge=40 fits a 64-pixel-wide step edge, edge=0 any width; only the combination of the
    # second values of both axes (32 px wide, edge 40) is out of [0, W]: found by checking every
    # job of the product, not each value with the other keys at their first
    args = ["scene=step_edge", "resolution=[64,64],[32,32]", "++scene.params.edge=0,40"]
    assert app.check_values(["-m", *args[:2], "++scene.params.edge=0"]) is None
    assert app.check_values(["-m", args[0], "resolution=[64,64]", args[2]]) is None
    proc = _app(tmp_path, *TINY[2:], *args, multirun=True)
    _refused(proc, tmp_path, "scene.params", "edge", "[0, 32]")


def test_method_option_valid_for_one_method_of_the_grid_only(tmp_path):
    # rank is an option of the low-rank method (the grid's first), not of the pre-integrated one
    proc = _app(
        tmp_path, *TINY, "method=low_rank,preintegrated", "++method.params.rank=2", multirun=True
    )
    _refused(proc, tmp_path, "method.params", "preintegrated", "rank")


def test_paper_benchmark_grid_is_read_whole_and_builds_no_image(monkeypatch):
    # every job of the preset's grid (conf/experiment/paper_benchmark.yaml: 6 scenes x 3 scales
    # x the 8 methods other than the reference (artist, disk, identity, jimenez2012, low_rank,
    # preintegrated, sum_of_gaussians, sum_of_gaussians_fused) x 2 tap counts), no scene built
    def no_image(*args, **kwargs):
        raise AssertionError("the value check built an image")

    monkeypatch.setattr(registry, "build_scene", no_image)
    # the image steps behind the builders' first image (tracing, a G-buffer, a texture)
    for module, name in ((render, "_primary"), (render, "gbuffer"), (scenes, "texture")):
        monkeypatch.setattr(module, name, no_image)
    for scene in ("sphere", "step_edge", "pores"):  # the patches do stop a build
        with pytest.raises(AssertionError, match="built an image"):
            data_synth.make_scene(scene, (8, 8))
    argv = ["-m", "+experiment=paper_benchmark"]
    problem, specs = app._grid_specs(argv)
    assert problem is None and len(specs) == 6 * 3 * 8 * 2
    assert {(s.scene, s.scene_params["pixel_mm"]) for s in specs} == {
        (scene, px)
        for scene in ("step_edge", "light_dot", "pores", "sphere", "head_cheek", "face")
        for px in (0.1, 0.3, 1.0)
    }
    assert app.check_values(argv) is None
    # a bad value inside the preset's grid is found (the check read the command line's values
    # only): pores' pore_depth must stay below z / 2, and z shrinks with the scale (512 px at
    # 0.1 mm/px: z = 115 mm; 60 mm fits 0.3 and 1.0 mm/px but not 0.1)
    problem = app.check_values([*argv, "scene=pores", "++scene.params.pore_depth=60"])
    assert problem is not None and "pore_depth must be < z / 2" in problem and "0.1" in problem


@pytest.mark.parametrize(
    "groups",
    [
        ("+experiment=paper_benchmark", "scene=face", "method=disk"),
        ("scene=face_portrait", "method=low_rank", "translucency=on", "profile=burley_skin1"),
        ("scene=backlit_ear", "halo=lab", "curvature=on", "texturing=sqrt", "sampling=power"),
        ("+experiment=benchmark", "method=artist"),
    ],
)
def test_assembled_config_equals_hydras_composition_of_the_combination(groups):
    from omegaconf import OmegaConf

    fast = OmegaConf.to_container(app._assembled(groups), resolve=False)
    whole = OmegaConf.to_container(app._compose_groups(groups), resolve=False)
    assert fast == whole


# ----------------------------------------------------------------------------- same rules
@pytest.mark.parametrize(
    ("scene", "params"),
    [
        ("step_edge", {"pixel_mm": -1.0}),
        ("step_edge", {"edge": 17}),
        ("light_dot", {"radius": 0.0}),
        ("sphere", {"distance": 10.0}),
        ("head", {"distance": "near"}),
        ("crowd", {"n_heads": 3, "spread": 100.0}),
        ("pores", {"pore_depth": 30.0}),
        ("halo", {"tilt": 90.0}),
        ("backlit_ear", {"thickness": 5.0, "distance": 4.0}),
        ("backlit_slab", {"window": -1.0}),
        ("face", {"pixel_mm": "huge"}),
        ("head_mid", {"aim": "ear"}),
    ],
)
def test_scene_check_and_scene_build_refuse_alike(scene, params):
    with pytest.raises((ValueError, TypeError)) as built:
        data_synth.make_scene(scene, (16, 16), **params)
    with pytest.raises(type(built.value)) as checked:
        data_synth.check_scene(scene, (16, 16), **params)
    assert str(checked.value) == str(built.value)


@pytest.mark.parametrize("scene", sorted(data_synth.SCENES))
def test_every_scene_check_stops_before_its_first_image(scene):
    # 8192² is the largest side a scene takes: a build there would take gigabytes
    assert data_synth.check_scene(scene, (8192, 8192)) is True


def test_a_value_only_the_render_finds_is_left_to_the_run():
    # the halo turned by 80 degrees leaves pixels empty: the check accepts it, the build refuses
    assert data_synth.check_scene("halo", (16, 16), tilt=80.0) is True
    with pytest.raises(ValueError, match="empty"):
        data_synth.make_scene("halo", (16, 16), tilt=80.0)


# ----------------------------------------------------------------------------- docs commands
def _documented_sssbench_commands() -> list[tuple[str, list[str]]]:
    out = []
    for where, commands in _command_blocks():
        for command in commands:
            args = shlex.split(command)
            if args[0] == "sssbench":
                out.append((where, args[1:]))
    return out


@pytest.mark.parametrize("command", _documented_sssbench_commands(), ids=lambda c: c[0])
def test_every_documented_command_passes_the_check(command, tmp_path, monkeypatch):
    where, args = command
    monkeypatch.chdir(tmp_path)
    (tmp_path / "shared" / "project").mkdir(parents=True)
    args = [a.replace("/shared/project", str(tmp_path / "shared" / "project")) for a in args]
    if any("my_frame.exr" in a for a in args):
        from sssbench.io import write_gbuffer

        write_gbuffer(tmp_path / "my_frame.exr", data_synth.make_scene("head_closeup", (16, 16)))
    assert app.check_overrides(args) is None, (where, args)
    assert app.check_values(args) is None, (where, args)
    assert any(a.startswith(DRY) for a in args) or app.check_stages(args)[0] is None


# ----------------------------------------------------------------------------- the report
def test_run_failure_is_stored_and_reported_as_key_value_text(tmp_path):
    # an error only the run can find (injected into its timing step) is stored failed, exit 1;
    # sssbench-report on that store prints the configurations as readable text, no dicts
    inject = (
        "import sys; import sssbench.run.runner as r\n"
        "def boom(*a, **k): raise RuntimeError('injected failure inside the run')\n"
        "r.time_runs = boom\n"
        "from sssbench.app import main; sys.argv[0] = 'sssbench'; main()\n"
    )
    store = tmp_path / "store.sqlite"
    proc = subprocess.run(
        [sys.executable, "-c", inject, "-m", *TINY, "method=preintegrated,disk",
         "++scene.params.ambient=0.05", f"store={store}", f"hydra.sweep.dir={tmp_path / 'sweep'}",
         f"reference_cache={tmp_path / 'cache'}"],  # fmt: skip
        cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    rows = RunStore(store).runs()
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert all("injected failure" in r["error"] for r in rows)
    out = subprocess.run(
        [sys.executable, "-c", "import sys; from sssbench.report import main; sys.exit(main())",
         str(store)],  # fmt: skip
        cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    written = [(tmp_path / "report" / n).read_text() for n in ("summary.md", "summary.csv")]
    for text in (out.stdout, *written):
        assert "{'" not in text and '{"' not in text, text
    failed = written[0].split("## Failed or timed-out runs", 1)[1]
    for method in ("preintegrated", "disk"):
        assert f"| sphere | {method} | skin_jg10 |" in failed
    assert failed.count("RuntimeError: injected failure inside the run") == 2

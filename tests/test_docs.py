"""The docs' worked examples run (docs/extending.md), and the docs link only inside the repo."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [
    REPO / "README.md",
    REPO / "experiments" / "README.md",
    *sorted((REPO / "docs").glob("*.md")),
]


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


def test_extending_examples_run():
    from sssbench.run import registry

    saved = (dict(registry.METHODS), dict(registry.PROFILE_KINDS), dict(registry.STAGES))
    module = types.ModuleType("sssbench_docs_example")
    sys.modules[module.__name__] = module
    try:
        blocks = _python_blocks(REPO / "docs" / "extending.md")
        assert len(blocks) >= 4
        for block in blocks:
            exec(compile(block, "docs/extending.md", "exec"), module.__dict__)
    finally:
        sys.modules.pop(module.__name__, None)
        registry.METHODS.clear()
        registry.METHODS.update(saved[0])
        registry.PROFILE_KINDS.clear()
        registry.PROFILE_KINDS.update(saved[1])
        registry.STAGES.clear()
        registry.STAGES.update(saved[2])


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_docs_link_only_inside_the_repo(path):
    text = path.read_text()
    assert "../shared" not in text and "/work/shared" not in text
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        assert (path.parent / target).exists(), f"{path.name} links to missing {target}"


# ----------------------------------------------------------------------------- commands
# Every `sssbench ...` command of a fenced shell block in README.md and docs/*.md is executed by
# test_documented_commands_run, block by block, each block in a fresh folder with an empty cache
# ($SSSBENCH_CACHE_DIR and $MPLCONFIGDIR inside the folder). What the test adds, and why:
# - to every `sssbench` run: TINY_RUN below (16² pixels, one timed repeat, no error budget,
#   no previews), so the whole set runs in minutes; the commands are otherwise as written;
# - the heavy ones (DRY: the paper benchmark, the Optuna searches, the cluster and joblib
#   launchers) are composed, not run: every job of the grid is read into the RunSpec the app
#   would run (sssbench.app.compose_spec, the same checks as before a first run);
# - `multirun/<date>/<time>` (or a dated example path) in a report command is the newest sweep
#   directory of the block's folder; `my_frame.exr` is written (a 16² head_close G-buffer)
#   before the command that reads it, as docs/io.md tells a user to make one; the cluster
#   example's shared folder (`/shared/project`) is a folder made inside the block's folder.
TINY_RUN = ["resolution=[16,16]", "repeats=1", "warmup=0", "budget=false", "previews=false"]
DRY = ("+experiment=paper_benchmark", "+experiment=optuna", "hydra/launcher=")
_COMMAND = re.compile(r"^(?:.*&&\s*)?((?:sssbench|sssbench-report|sssbench-export-kernel)\b.*)$")


def _command_blocks() -> list[tuple[str, list[str]]]:
    """``(where, commands)`` per fenced shell block holding sssbench commands (continuation
    lines joined, comments and a leading ``pip install ... &&`` removed)."""
    out = []
    for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        blocks = re.findall(r"```(?:bash|sh|shell|console)\n(.*?)```", path.read_text(), re.S)
        for k, block in enumerate(blocks):
            text = re.sub(r"\\\n\s*", " ", block)
            commands = []
            for line in text.splitlines():
                m = _COMMAND.match(line.split(" #")[0].strip())
                if m:
                    commands.append(m.group(1).strip())
            if commands:
                out.append((f"{path.name}#{k}", commands))
    return out


def test_every_documented_command_is_found():
    found = [c for _, cs in _command_blocks() for c in cs]
    assert any("translucency=off,on" in c for c in found)
    assert any(c.startswith("sssbench-report") for c in found)
    assert any("+experiment=paper_benchmark" in c for c in found)


def _dry(args: list[str]) -> None:
    from sssbench import app

    assert app.check_overrides(args) is None, args
    assert app.check_values(args) is None, args
    presets = [a.split("=", 1)[1] for a in args if a.startswith("+experiment=")]
    values = [a for a in args if "=" in a and not a.startswith(("-", "+experiment", "hydra"))]
    for preset in presets:
        if "n_trials" in app.preset_hydra(preset).sweeper:  # a search: its base point
            app.compose_spec(f"+experiment={preset}", *values, store="x.sqlite")
            continue
        jobs = app.preset_grid(preset)
        for job in jobs:
            app.compose_spec(*job, *values, store="x.sqlite")


@pytest.mark.parametrize("block", _command_blocks(), ids=lambda b: b[0])
def test_documented_commands_run(block, tmp_path):
    import os
    import shlex
    import subprocess

    where, commands = block
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    env |= {"SSSBENCH_CACHE_DIR": str(tmp_path / "cache"), "MPLCONFIGDIR": str(tmp_path / "mpl")}
    for command in commands:
        shared = tmp_path / "shared" / "project"
        shared.mkdir(parents=True, exist_ok=True)
        args = shlex.split(command.replace("/shared/project", str(shared)))
        program, args = args[0], args[1:]
        if program == "sssbench" and any(a.startswith(DRY) for a in args):
            _dry(args)
            continue
        if "my_frame.exr" in command:
            import data_synth
            from sssbench.io import write_gbuffer

            write_gbuffer(
                tmp_path / "my_frame.exr", data_synth.make_scene("head_closeup", (16, 16))
            )
        if program == "sssbench-report":
            sweeps = sorted((tmp_path / "multirun").glob("*/*"), key=lambda p: p.stat().st_mtime)
            args = [str(sweeps[-1]) if a.startswith("multirun/") else a for a in args]
            cmd = [sys.executable, "-c", "import sys; from sssbench.report import main; "
                   "sys.exit(main())", *args]  # fmt: skip
        elif program == "sssbench":
            cmd = [sys.executable, "-m", "sssbench", *args, *TINY_RUN]
        else:
            pytest.fail(f"{where}: no rule to run {command!r}")
        proc = subprocess.run(
            cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900
        )
        assert proc.returncode == 0, (
            f"{where}: {command}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
        )


def test_readme_timings_are_the_measurement_scripts_latest_output():
    """The README's timings are copied from ``experiments/readme_timings.json``, written by the
    script the README names (``python -m experiments.readme_timings --write``)."""
    from sssbench import _json

    text = " ".join((REPO / "README.md").read_text().split())  # line breaks as spaces
    assert "experiments/readme_timings.py" in text
    record = _json.loads((REPO / "experiments" / "readme_timings.json").read_text())
    bench, machine = record["benchmark"], record["machine"]
    assert bench["exit_code"] == 0
    for figure in (
        f"{bench['wall_s']:.0f} s wall",
        f"{bench['cpu_s']:.0f} s CPU",
        f"load average {bench['load_before'][0]:.1f}",
        f"{machine['cores']} cores",
    ):
        assert figure in text, figure
    if "paper" in record:
        assert record["paper"]["exit_code"] == 0
        assert f"{record['paper']['wall_s'] / 60:.0f} min wall" in text
    else:  # no paper-benchmark time the script did not measure
        assert "paper benchmark's time from cold has not been measured" in text
        assert not re.search(r"paper benchmark[^.]*\d+ min", text), "an unmeasured paper time"
    # the block is exactly what the script writes from the JSON (no hand edits)
    from experiments import readme_timings

    readme = (REPO / "README.md").read_text()
    assert readme_timings.readme_block(record) in readme

"""The house (docs/architecture.md §1): the import-linter contract in pyproject.toml holds on
the code, fails on a deliberately added back-import, and equals the diagram in the docs; the
module table names every module."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"

lint_imports = shutil.which("lint-imports")
pytestmark = pytest.mark.skipif(lint_imports is None, reason="import-linter not installed")


def _run(tree: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command;"
         "sys.exit(lint_imports_command())"],
        cwd=tree, capture_output=True, text=True, env={"PYTHONPATH": str(tree), "PATH": ""},
    )  # fmt: skip


def _copy(tmp_path: Path) -> Path:
    tree = tmp_path / "tree"
    for name in ("sssbench", "data_synth"):
        shutil.copytree(ROOT / name, tree / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    return tree


def test_the_code_keeps_the_contract(tmp_path):
    out = _run(_copy(tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr
    assert "0 broken" in out.stdout


@pytest.mark.parametrize(
    ("module", "back_import"),
    [
        ("sssbench/ops/identity.py", "from sssbench.run import registry"),  # ops -> runner
        ("sssbench/kernels/sources.py", "from sssbench.tune import optimise"),  # the old circle
        ("sssbench/score/verdict.py", "from sssbench.report import tables"),  # score -> report
        ("data_synth/scenes.py", "from data_synth import mc_scenes"),  # scenes <-> mc models
    ],
)
def test_a_back_import_breaks_the_contract(tmp_path, module, back_import):
    tree = _copy(tmp_path)
    path = tree / module
    path.write_text(path.read_text() + f"\n{back_import}  # noqa\n")
    out = _run(tree)
    assert out.returncode != 0
    assert "BROKEN" in out.stdout
    assert "." + Path(module).stem in out.stdout  # the offending module is named


def _contract_layers() -> list[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (layers,) = [c["layers"] for c in config["contracts"] if c["type"] == "layers"]
    return layers


def test_the_contract_equals_the_diagram():
    """The fenced ``layers`` block of docs/architecture.md lists the contract's layers, top
    first, one per line (``|`` between independent siblings)."""
    text = DOC.read_text()
    block = re.search(r"```text layers\n(.*?)```", text, re.S)
    assert block, "docs/architecture.md has no ```text layers block"
    drawn = [re.split(r"\s{2,}", line.strip())[0] for line in block.group(1).splitlines()]
    assert [d for d in drawn if d] == _contract_layers()


def test_the_module_table_names_every_module():
    text = DOC.read_text()
    missing = []
    for package in ("sssbench", "data_synth"):
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if f"`{rel}`" not in text:
                missing.append(rel)
    assert not missing, f"docs/architecture.md's module table misses {missing}"


def test_no_module_over_600_lines_without_a_reason():
    """A module over ~600 lines says at its top why it is one module (docs/architecture.md)."""
    long = []
    for package in ("sssbench", "data_synth"):
        for path in sorted((ROOT / package).rglob("*.py")):
            lines = path.read_text().splitlines()
            if len(lines) > 600 and not any("One module because" in s for s in lines[:40]):
                long.append(f"{path.relative_to(ROOT)} ({len(lines)} lines)")
    assert not long, f"modules over 600 lines without a reason at the top: {long}"

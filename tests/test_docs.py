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

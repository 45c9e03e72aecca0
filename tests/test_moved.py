"""Old import paths of moved modules stay aliases of the new ones (docs/architecture.md §1)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from sssbench._moved import MOVED


@pytest.mark.parametrize(("old", "new"), sorted(MOVED.items()))
def test_old_path_is_the_new_module_with_a_warning(old, new):
    """In a fresh interpreter (nothing imported yet): the old name imports the very module at
    the new place and warns once, naming the new path."""
    code = (
        "import importlib, warnings\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        f"new = importlib.import_module({new!r})\n"
        "assert old is new, (old, new)\n"
        "msgs = [str(x.message) for x in w if issubclass(x.category, FutureWarning)]\n"
        f"assert any({new!r} in m for m in msgs), msgs\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_every_new_path_exists():
    for new in MOVED.values():
        assert importlib.util.find_spec(new) is not None, new


def test_an_unknown_old_name_still_fails():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("sssbench.no_such_module")

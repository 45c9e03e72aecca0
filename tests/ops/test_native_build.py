"""How the native library is built: its units compiled side by side, then linked
(``sssbench/ops/native/__init__.py: _compile_and_link``). That the library built this way
computes what the torch loop does is every other native test's business."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest

from sssbench.ops import native


def test_units_compile_side_by_side_up_to_the_cores_then_link(monkeypatch, tmp_path):
    """Three units on two cores: two compilers at once, never three; the link comes after
    every compile and takes every object."""
    lock = threading.Lock()
    running = {"now": 0, "most": 0}
    calls: list[list[str]] = []

    def fake_run(cmd, **kwargs):
        with lock:
            calls.append(cmd)
            running["now"] += 1
            running["most"] = max(running["most"], running["now"])
        time.sleep(0.2)  # long enough for the second compiler to start meanwhile
        Path(cmd[cmd.index("-o") + 1]).write_bytes(b"")
        with lock:
            running["now"] -= 1

    monkeypatch.setattr(native.subprocess, "run", fake_run)
    monkeypatch.setattr(native, "_cores", lambda: 2)
    out = tmp_path / "lib.so"
    native._compile_and_link("cc", native._GATHER_UNITS, str(out), tmp_path)
    assert running["most"] == 2
    *compiles, link = calls
    assert len(compiles) == 3 and all("-c" in c for c in compiles)
    objects = sorted(c[c.index("-o") + 1] for c in compiles)
    assert "-c" not in link and "-shared" in link and link[link.index("-o") + 1] == str(out)
    assert sorted(a for a in link if a.endswith(".o")) == objects
    # gather.c's two halves and the disk's loop, each once
    parts = sorted(tuple(a for a in c if a.startswith("-DSSS_PART")) for c in compiles)
    assert parts == [(), ("-DSSS_PART=1",), ("-DSSS_PART=2",)]
    assert out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["lib.so"]


def test_a_failing_unit_stops_the_units_not_yet_started(monkeypatch, tmp_path):
    """One core, the first of three units fails: its error is raised and the two units
    queued behind it never run, nor does the link."""
    calls: list[list[str]] = []

    def fake_run(cmd, **kwargs):
        calls.append(cmd)
        if len(calls) == 1:
            raise subprocess.CalledProcessError(1, cmd, stderr="gather.c: error")
        Path(cmd[cmd.index("-o") + 1]).write_bytes(b"")

    monkeypatch.setattr(native.subprocess, "run", fake_run)
    monkeypatch.setattr(native, "_cores", lambda: 1)
    with pytest.raises(subprocess.CalledProcessError) as caught:
        native._compile_and_link("cc", native._GATHER_UNITS, str(tmp_path / "lib.so"), tmp_path)
    assert caught.value.stderr == "gather.c: error"
    assert len(calls) == 1 and list(tmp_path.iterdir()) == []


def test_a_unit_that_does_not_compile_raises_the_compilers_message(tmp_path):
    """A unit with an error: the compiler's ``CalledProcessError`` with its stderr (what the
    fallback warning shows), no library written, no object left behind."""
    cc = native._compiler()
    if cc is None or shutil.which(cc) is None:
        pytest.skip("no C compiler")
    good = tmp_path / "good.c"
    good.write_text("int sss_good(void) { return 1; }\n")
    bad = tmp_path / "bad.c"
    bad.write_text("int sss_bad(void) { return undeclared_name; }\n")
    build = tmp_path / "build"
    build.mkdir()
    out = build / "lib.so"
    with pytest.raises(subprocess.CalledProcessError) as caught:
        native._compile_and_link(cc, ((str(good),), (str(bad),)), str(out), build)
    assert "undeclared_name" in caught.value.stderr
    assert list(build.iterdir()) == []

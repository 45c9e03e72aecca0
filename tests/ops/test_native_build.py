"""How the native libraries are built: their units compiled side by side, then linked
(``sssbench/ops/native/__init__.py: _compile_and_link``), the float64 loops a library of their
own built on first use and bound to the loaded gather library (``library64``). That the
libraries built this way compute what the torch loop does is every other native test's
business."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest
import torch

from sssbench.ops import native

#: every unit: the gather library's three and the float64 library's two
ALL_UNITS = (*native._GATHER_UNITS, *native._GATHER64_UNITS)


def unit_flags(cmd: list[str]) -> tuple[str, ...]:
    """The ``-DSSS_`` flags of a compile command: which part of gather.c it builds."""
    return tuple(a for a in cmd if a.startswith("-DSSS_"))


#: gather.c's four units (two parts, each split along its AVX-512 loops) and the disk's
GATHER_PARTS = sorted(
    [(), *((f"-DSSS_PART={p}", f"-DSSS_AVX512_UNIT={u}") for p in (1, 2) for u in (0, 1))]
)


def test_units_compile_side_by_side_up_to_the_cores_then_link(monkeypatch, tmp_path):
    """Five units on two cores: two compilers at once, never three; the link comes after
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
    native._compile_and_link("cc", ALL_UNITS, str(out), tmp_path)
    assert running["most"] == 2
    *compiles, link = calls
    assert len(compiles) == 5 and all("-c" in c for c in compiles)
    objects = sorted(c[c.index("-o") + 1] for c in compiles)
    assert "-c" not in link and "-shared" in link and link[link.index("-o") + 1] == str(out)
    assert sorted(a for a in link if a.endswith(".o")) == objects
    # gather.c's four units and the disk's loop, each once
    assert sorted(unit_flags(c) for c in compiles) == GATHER_PARTS
    assert out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["lib.so"]


def test_a_failing_unit_stops_the_units_not_yet_started(monkeypatch, tmp_path):
    """One core, the first of five units fails: its error is raised and the four units
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
        native._compile_and_link("cc", ALL_UNITS, str(tmp_path / "lib.so"), tmp_path)
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


def test_the_gather_library_holds_float32_and_the_float64_library_float64():
    """Each part of gather.c in two units, all but the AVX-512 loops first (the longer
    compile, started first), the disk's loop last (the second compiler takes it once the
    AVX-512 loops are done)."""
    assert native._GATHER_UNITS == (
        ("gather.c", "-DSSS_PART=1", "-DSSS_AVX512_UNIT=0"),
        ("gather.c", "-DSSS_PART=1", "-DSSS_AVX512_UNIT=1"),
        ("disk.c",),
    )
    assert native._GATHER64_UNITS == (
        ("gather.c", "-DSSS_PART=2", "-DSSS_AVX512_UNIT=0"),
        ("gather.c", "-DSSS_PART=2", "-DSSS_AVX512_UNIT=1"),
    )


NATIVE = pytest.mark.skipif(native.library() is None, reason="no C compiler")


@NATIVE
def test_the_avx512_loops_are_linked_in_and_not_exported():
    """Each part's AVX-512 loops are a unit of their own (``SSS_AVX512_UNIT``): the pass's
    entry calls their ``run_f32_avx512`` / ``run_f64_avx512`` (a pass at that level gives the
    scalar loop's bits: tests/ops/test_gather_backends.py), a hidden symbol of its library —
    absent from the dynamic symbol table, so no other loaded library's symbol of that name can
    stand in for it — while the entries are exported."""
    for lib, suffix in ((native.library(), "f32"), (native.library64(), "f64")):
        assert hasattr(lib, f"sss_gather_{suffix}")
        for isa in ("avx512", "avx2"):
            assert not hasattr(lib, f"run_{suffix}_{isa}")


@NATIVE
def test_the_float64_loops_bind_to_the_loaded_gather_library():
    """The float64 library's undefined symbols (the SIMD level, the OpenMP hand-over: gather.c's
    shared state) resolve to the gather library already loaded — one copy of it is mapped —
    so that set_simd and set_pool reach the float64 loops too."""
    import ctypes

    lib, lib64 = native.library(), native.library64()
    assert lib64 is not None and native.library_for(torch.float64) is lib64
    assert native.library_for(torch.float32) is lib and native.library_for(torch.int32) is None
    for name in ("sss_get_simd", "sss_set_omp", "sss_omp_parallel", "sss_omp_pid"):
        here = ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
        assert ctypes.cast(getattr(lib64, name), ctypes.c_void_p).value == here, name
    mapped = {
        Path(line.split()[-1]).name
        for line in Path("/proc/self/maps").read_text().splitlines()
        if "sssgather" in line
    }
    path = Path(str(native._STATE["path"]))
    assert sum(1 for m in mapped if m.startswith("sssgather-")) == 1 and path.name in mapped
    with pytest.raises(AttributeError):
        lib.sss_gather_f64  # noqa: B018 - not in the gather library


@NATIVE
def test_a_float32_run_builds_no_float64_library(tmp_path):
    """A process that runs only float32 passes loads the gather library and never builds the
    float64 one (the README's main job is float32)."""
    folder = tmp_path / "native"
    folder.mkdir(mode=0o700)
    built = Path(str(native._STATE["path"]))
    shutil.copy(built, folder / built.name)  # the same sources: found by name, not rebuilt
    code = (
        "import torch\n"
        "from sssbench.ops import gather, native\n"
        "from sssbench.gbuffer import GBuffer\n"
        "from sssbench.kernels import Kernel1D\n"
        "g = GBuffer(torch.rand(1, 3, 16, 16), torch.full((1, 1, 16, 16), 500.0), 0.4)\n"
        "k = Kernel1D(torch.linspace(-2, 2, 5), torch.full((5, 3), 0.2))\n"
        "with gather.backend('native'):\n"
        "    gather.separable_pass(g.diffuse, k, 'x', g)\n"
        "print(gather._backend_for(g.diffuse, None, None), native._STATE64['tried'])\n"
    )
    env = dict(__import__("os").environ, SSSBENCH_CACHE_DIR=str(tmp_path))
    res = subprocess.run(
        [__import__("sys").executable, "-c", code], capture_output=True, text=True, env=env
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["native", "False"]
    assert sorted(p.name for p in folder.iterdir()) == [built.name]


@NATIVE
def test_without_the_float64_library_float64_passes_run_the_torch_loop(monkeypatch):
    """A float64 library that cannot be built: one warning, float64 passes on the torch loop
    (the same image), float32 passes still native."""
    import warnings

    from sssbench.gbuffer import GBuffer
    from sssbench.kernels import Kernel1D
    from sssbench.ops import gather

    build = native._build

    def no_float64(cc, fresh=False, **spec):
        if spec.get("needs") is not None:
            raise subprocess.CalledProcessError(1, ["cc"], stderr="gather.c: no float64 today")
        return build(cc, fresh=fresh, **spec)

    monkeypatch.setattr(native, "_STATE64", {"lib": None, "tried": False})
    monkeypatch.setattr(native, "_build", no_float64)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert native.library64() is None and native.library64() is None
    assert len(caught) == 1 and "no float64 today" in str(caught[0].message)
    g = GBuffer(torch.rand(1, 3, 16, 16, dtype=torch.float64),
                torch.full((1, 1, 16, 16), 500.0, dtype=torch.float64), 0.4)  # fmt: skip
    k = Kernel1D(torch.linspace(-2, 2, 5, dtype=torch.float64),
               torch.full((5, 3), 0.2, dtype=torch.float64))  # fmt: skip
    assert gather._backend_for(g.diffuse, None, None) == "torch"
    assert gather._backend_for(g.diffuse.float(), None, None) == "native"
    from sssbench.run.settings import backend_used  # what a run's record says it used

    assert backend_used("native", "float64") == "torch"
    assert backend_used("native", "float32") == "native"
    assert backend_used("torch", "float32") == "torch"
    with gather.backend("native"):
        fell_back = gather.separable_pass(g.diffuse, k, "x", g)
    with gather.backend("torch"):
        assert torch.equal(fell_back, gather.separable_pass(g.diffuse, k, "x", g))


def test_both_dtypes_build_side_by_side_when_float64_is_wanted(monkeypatch, tmp_path):
    """``_build_both`` on an empty cache: the five units compiled together (2 cores: two at
    once), the gather library linked from its three objects, the float64 one from its two
    and the gather library's file (its DT_NEEDED: the gather library's SONAME), both under
    the names library() and library64() look for; cached, nothing runs again."""
    monkeypatch.setenv("SSSBENCH_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(native, "_cores", lambda: 2)
    calls: list[list[str]] = []

    def compile_nothing(cmd, **kwargs):
        calls.append(cmd)
        Path(cmd[cmd.index("-o") + 1]).write_bytes(b"")

    monkeypatch.setattr(native.subprocess, "run", compile_nothing)
    path = native._build_both("cc")
    name = native._library_name("cc", native._SOURCES, native._GATHER_UNITS, "sssgather")
    name64 = native._library_name(
        "cc", native._SOURCES, native._GATHER64_UNITS, "sssgather64", name
    )
    assert path == tmp_path / "native" / name
    assert sorted(p.name for p in path.parent.iterdir()) == sorted([name, name64])
    compiles, (link, link64) = calls[:5], calls[5:]
    assert sorted(unit_flags(c) for c in compiles) == GATHER_PARTS and len(calls) == 7
    objects = {unit_flags(c): c[c.index("-o") + 1] for c in compiles}
    part = {p: [o for f, o in objects.items() if f"-DSSS_PART={p}" in f] for p in (1, 2)}
    assert sorted(a for a in link if a.endswith(".o")) == sorted([objects[()], *part[1]])
    assert sorted(a for a in link64 if a.endswith(".o")) == sorted(part[2])
    gather_file = link[link.index("-o") + 1]
    assert gather_file in link64 and f"-Wl,-soname,{name}" in link
    assert f"-Wl,-soname,{name64}" in link64 and f"-Wl,-rpath,{path.parent}" in link64
    assert native._build_both("cc") == path and len(calls) == 7  # cached
    # what library64() would build is the same file: found, not built
    assert native._build("cc", units=native._GATHER64_UNITS, prefix="sssgather64",
                         needs=path) == path.parent / name64  # fmt: skip
    assert len(calls) == 7


def test_runs_that_run_float64_passes():
    from sssbench.app import compose_spec
    from sssbench.run.budget_step import runs_float64

    spec = compose_spec("method=artist", "scene=step_edge")
    assert spec.budget and runs_float64(spec)  # its budget runs the method in float64
    assert not runs_float64(compose_spec("method=artist", "scene=step_edge", "budget=false"))
    assert runs_float64(
        compose_spec("method=artist", "scene=step_edge", "budget=false", "dtype=float64")
    )
    assert not runs_float64(compose_spec("method=identity", "scene=step_edge"))  # no budget

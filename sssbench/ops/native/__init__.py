"""The native tap loop of the gather primitive: C source built on first use, called via ctypes.

``gather.c`` (float32 and float64, threads via pthreads; it works line by line, a row for an x
pass and a strip of columns for a y pass, and interleaves (r, g, b, depth) of the window the
line's taps can reach into a small buffer, so that each tap is one 4-lane load from cache and
4-lane arithmetic, and a pass reads only around the active pixels) is compiled with the system C
compiler (``$CC``, else ``cc``/``gcc``) into a per-user cache
(``$SSSBENCH_CACHE_DIR/native``, default ``~/.cache/sssbench/native``), keyed by the hash of
the source and the compiler, written atomically so that parallel sweep workers may race. No
Python package beyond the declared ones is needed; on a machine without a C compiler
:func:`library` returns ``None`` once with a warning and the gather runs its torch loop.
``disk.c`` (with ``disk_body.h`` and the vectorised ``disk_simd.h``), the disk's sample loop
(:mod:`sssbench.ops._disk_native`), is another translation unit of the same library, at the
same SIMD level. The library's units (``gather.c``'s shared state and float32 loops, in two
units split along the AVX-512 loops, and ``disk.c``: :data:`_GATHER_UNITS`) are compiled side
by side, one compiler per core this process may use, and linked. ``gather.c``'s float64 loops
are a second library (:func:`library64`, :data:`_GATHER64_UNITS`, split likewise), built the
first time a float64 pass runs and linked against the first, whose shared state (the SIMD
level, the OpenMP hand-over) it uses: a float32 run never waits for them (about 12 of the 28 s
of CPU with gcc 12). :func:`library_for` gives the library of an image's dtype.
``quad.c`` (with ``quad_simd.h``), the Gauss–Legendre cell sums of the exact reference's near
field (:mod:`sssbench.ops._reference_quad`), is a library of its own (:func:`quad_library`):
it builds in about a second, so a reference never waits for the tap loop's long build.
The torch loop (:mod:`sssbench.ops._gather_torch`) is the specification: the native loop
performs the same float operations in the same order and is tested bitwise equal to it (but
for ``exp``); :mod:`sssbench.ops._gather_native` registers it as a torch operator.

The tap loop exists at three instruction-set levels (:data:`SIMD_LEVELS`): the scalar loop
and, in ``gather_simd.h``, vectorised loops for AVX2 and AVX-512F that hold many neighbouring
pixels of a row per vector. They are compiled into the same library through ``target``
attributes (no ``-march``: the library runs on any x86-64) and a pass uses the widest level the
CPU supports, or the one :func:`set_simd` / :class:`simd` / ``$SSSBENCH_SIMD`` asks for.

A pass's threads (``torch.get_num_threads()`` of them) are, by default, torch's own OpenMP team
(:func:`set_pool`, ``native/pool.h``): after a torch operation that team's workers spin for
milliseconds on the cores a second pool of threads would need. ``$SSSBENCH_POOL=own`` (or
``set_pool("own")``) runs them on the library's own pthread pool instead; the results are the
same bits either way (tested).
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import warnings
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

__all__ = [
    "library",
    "quad_library",
    "cache_dir",
    "FALLBACK_NOTE",
    "SIMD_LEVELS",
    "simd",
    "set_simd",
    "simd_level",
    "simd_levels",
    "POOLS",
    "set_pool",
    "pool",
]

_HERE = Path(__file__).resolve().parent
_SOURCES = (
    "gather.c",
    "gather_body.h",
    "gather_simd.h",
    "pool.h",
    "disk.c",
    "disk_body.h",
    "disk_simd.h",
    "exp2_32.h",
)
#: the gather library's units (a source and its ``-D`` flags), compiled side by side in this
#: order: ``gather.c``'s ``SSS_PART`` 1 (the shared state, the float32 loops) but its AVX-512
#: loops (8 s with gcc 12), those loops (``SSS_AVX512_UNIT``, 6 s), then the disk's (2 s):
#: about 8 s of wall time on 2 cores (13 s with the float32 part one unit, until 2026-12-06)
_GATHER_UNITS: tuple[tuple[str, ...], ...] = (
    ("gather.c", "-DSSS_PART=1", "-DSSS_AVX512_UNIT=0"),
    ("gather.c", "-DSSS_PART=1", "-DSSS_AVX512_UNIT=1"),
    ("disk.c",),
)
#: the float64 loops' library (:func:`library64`): ``gather.c``'s ``SSS_PART`` 2, split
#: likewise (7.5 and 5 s), linked against the gather library for its shared state
_GATHER64_UNITS: tuple[tuple[str, ...], ...] = (
    ("gather.c", "-DSSS_PART=2", "-DSSS_AVX512_UNIT=0"),
    ("gather.c", "-DSSS_PART=2", "-DSSS_AVX512_UNIT=1"),
)
#: the reference quadrature's library (:func:`quad_library`): its sources, its one unit
_QUAD_SOURCES = ("quad.c", "quad_simd.h", "exp2_32.h")
_QUAD_UNITS: tuple[tuple[str, ...], ...] = (("quad.c",),)
#: each unit's compile flags (the link adds ``-shared`` and the libraries)
_FLAGS = ["-O3", "-fPIC", "-ffp-contract=off", "-fno-math-errno", "-Wno-psabi"]
_STATE: dict[str, object] = {"lib": None, "tried": False}
_STATE64: dict[str, object] = {"lib": None, "tried": False}
_QUAD_STATE: dict[str, object] = {"lib": None, "tried": False}
_BUILD_TIMEOUT_S = 1800
log = logging.getLogger("sssbench")


def cache_dir() -> Path:
    """Where built libraries are kept (``$SSSBENCH_CACHE_DIR/native`` or ``~/.cache``)."""
    root = os.environ.get("SSSBENCH_CACHE_DIR")
    base = Path(root) if root else Path.home() / ".cache" / "sssbench"
    return base / "native"


def _compiler() -> str | None:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return name
    return None


def _cores() -> int:
    """The cores this process may run on (its affinity, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _compile_and_link(
    cc: str,
    units: tuple[tuple[str, ...], ...],
    out: str,
    folder: Path,
    link: tuple[str, ...] = (),
) -> None:
    """Compile each of ``units`` (a source and its ``-D`` flags) to an object in a temporary
    folder inside ``folder``, at most :func:`_cores` compilers at a time (a unit starts when a
    compiler ends), and link the objects into the shared library ``out`` (``link``: further
    arguments of the link, before the system libraries). After a compiler fails no further
    unit starts; once those running have ended, the failure's ``CalledProcessError`` is raised
    (its ``stderr`` is what the fallback warning shows)."""
    with tempfile.TemporaryDirectory(dir=folder) as objects:
        _link(cc, _compile(cc, units, objects), out, link)


_RUN = {"check": True, "capture_output": True, "text": True, "timeout": _BUILD_TIMEOUT_S}


def _compile(cc: str, units: tuple[tuple[str, ...], ...], objects: str) -> list[str]:
    """The objects of ``units`` compiled into the folder ``objects`` as
    :func:`_compile_and_link` compiles them (side by side, stopping at a failure)."""
    paths = [str(Path(objects) / f"unit{i}.o") for i in range(len(units))]
    waiting = [
        [cc, *_FLAGS, *flags, "-c", "-o", path, str(_HERE / source)]
        for (source, *flags), path in zip(units, paths, strict=True)
    ]
    slots = max(1, min(len(waiting), _cores()))
    failure: BaseException | None = None
    with ThreadPoolExecutor(slots) as compilers:
        running: set[Future] = set()
        while running or (waiting and failure is None):
            while waiting and failure is None and len(running) < slots:
                running.add(compilers.submit(subprocess.run, waiting.pop(0), **_RUN))
            ended, running = wait(running, return_when=FIRST_COMPLETED)
            failure = failure or next((e.exception() for e in ended if e.exception()), None)
    if failure is not None:
        raise failure
    return paths


def _link(cc: str, paths: list[str], out: str, link: tuple[str, ...]) -> None:
    subprocess.run([cc, "-shared", "-o", out, *paths, *link, "-lm", "-lpthread"], **_RUN)


def _library_name(
    cc: str,
    sources: tuple[str, ...],
    units: tuple[tuple[str, ...], ...],
    prefix: str,
    needs: str | None = None,
) -> str:
    """The file name of the library of ``units`` built from ``sources`` with ``cc``: a digest
    of the sources, the compiler and flags, the units and the name of the library it needs."""
    digest = hashlib.sha256()
    for name in sources:
        digest.update((_HERE / name).read_bytes())
    digest.update(" ".join([cc, *_FLAGS]).encode())
    digest.update(repr(units).encode())  # how the sources are split into units
    if needs is not None:
        digest.update(needs.encode())  # the library it binds to, by name
    return f"{prefix}-{digest.hexdigest()[:16]}.so"


def _place(name: str, fresh: bool = False) -> tuple[Path, bool]:
    """``(folder, found)``: the folder the library ``name`` is kept in (the cache, or the
    temp dir where the cache is not writable) and whether it is there (never with ``fresh``)."""
    fallback = Path(tempfile.gettempdir()) / f"sssbench-native-{os.getuid()}"
    for folder in (cache_dir(), fallback):  # an unwritable home: the temp dir
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
            if folder.stat().st_uid != os.getuid():
                continue  # never load a library from a folder somebody else owns
            if (folder / name).exists() and not fresh:
                return folder, True
            if os.access(folder, os.W_OK):
                return folder, False
        except OSError:
            continue
    raise OSError(f"cannot write the native library to {cache_dir()} or {fallback}")


def _build_both(cc: str) -> Path:
    """The gather library, built together with the float64 one when neither is there: every
    unit of the two compiled side by side (2 cores: 15-17 s of wall time, as one library took
    before the split, against about 13 s for the gather library and 12 s for the float64 one
    after it), then each linked (the float64 library against the gather library's file, which
    its ``DT_NEEDED`` names by the gather library's ``SONAME``). Otherwise, or if building both
    fails, :func:`_build` of the gather library alone (:func:`library64` builds the other)."""
    name = _library_name(cc, _SOURCES, _GATHER_UNITS, "sssgather")
    name64 = _library_name(cc, _SOURCES, _GATHER64_UNITS, "sssgather64", name)
    try:
        folder, found = _place(name)
        if found or (folder / name64).exists():
            return _build(cc)
        log.info(
            "building the native gather and float64 gather libraries with %s into %s (once "
            "per source version: about 26 s of CPU with gcc 12, %d compilers side by side)",
            cc,
            folder,
            max(1, min(3, _cores())),
        )
        fd, tmp = tempfile.mkstemp(suffix=".so", dir=folder)
        os.close(fd)
        fd, tmp64 = tempfile.mkstemp(suffix=".so", dir=folder)
        os.close(fd)
        try:
            with tempfile.TemporaryDirectory(dir=folder) as objects:
                paths = _compile(cc, _GATHER_UNITS + _GATHER64_UNITS, objects)
                n = len(_GATHER_UNITS)
                _link(cc, paths[:n], tmp, (f"-Wl,-soname,{name}",))
                _link(cc, paths[n:], tmp64, (tmp, f"-Wl,-rpath,{folder}", f"-Wl,-soname,{name64}"))
            os.replace(tmp, folder / name)  # atomic, the one needed first
            os.replace(tmp64, folder / name64)
        finally:
            for t in (tmp, tmp64):
                if os.path.exists(t):
                    os.unlink(t)
        return folder / name
    except Exception:  # built alone, as library() alone would: its own errors
        return _build(cc)


def _build(
    cc: str,
    fresh: bool = False,
    sources: tuple[str, ...] = _SOURCES,
    units: tuple[tuple[str, ...], ...] = _GATHER_UNITS,
    prefix: str = "sssgather",
    needs: Path | None = None,
) -> Path:
    """The library of ``units`` (each a source and its ``-D`` flags; ``sources``: every file
    it is built from) for the current sources and ``cc``: the cached one, or a new build
    (``fresh``: build anew even when one is cached, replacing it atomically). ``needs``: a
    library this one is linked against (its file name is part of this one's, its folder the
    run-time search path), whose symbols this one's undefined ones bind to when it loads."""
    name = _library_name(cc, sources, units, prefix, None if needs is None else needs.name)
    link: tuple[str, ...] = ()
    if needs is not None:
        link = (f"-L{needs.parent}", f"-l:{needs.name}", f"-Wl,-rpath,{needs.parent}")
    folder, found = _place(name, fresh)
    if found:
        return folder / name
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=folder)
    target = folder / name
    os.close(fd)
    try:
        compilers = max(1, min(len(units), _cores()))
        what, cost = _ABOUT[prefix]
        side = f"{compilers} compilers side by side" if compilers > 1 else "one compiler"
        log.info(  # the first run's longest silence otherwise (issue 28: nothing silent for long)
            "building the native %s library with %s into %s (once per source version: %s)",
            what,
            cc,
            folder,
            cost if len(units) == 1 else f"{cost}, {side}",
        )
        # once per source version and user (cached), on a 2-core AMD EPYC with gcc 12: the
        # gather library (the scalar, AVX2 and AVX-512 float32 loops, disk.c) about 14 s of CPU,
        # 13-14 s of wall time with two compilers; the float64 library about 12 s (the two were
        # one library of 28 s until 2026-12-06, 83 s before each loop specialisation became its
        # own function); the timeout leaves room for a slow, loaded machine
        # the name a library needing this one records (its DT_NEEDED): the loader then finds
        # the copy already loaded, not a second one with a state of its own
        soname = (f"-Wl,-soname,{name}",)
        _compile_and_link(cc, units, tmp, folder, (*link, *soname))
        os.replace(tmp, target)  # atomic: a racing worker sees a whole library or none
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


#: what the build's log line says of each library: its name and its cost
_ABOUT = {
    "sssgather": ("gather", "about 14 s of CPU with gcc 12"),
    "sssgather64": ("float64 gather", "about 12 s of CPU with gcc 12"),
    "sssquad": ("reference quadrature", "about a second"),
}


def _declare_loops(lib: ctypes.CDLL, suffix: str) -> None:
    """The argument types of the gather library's loops for one dtype (``"f32"``, ``"f64"``)."""
    p, i64, i32, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_double
    fn = getattr(lib, f"sss_gather_{suffix}")
    fn.restype = ctypes.c_int64  # active pixels, -1: out of memory
    fn.argtypes = [p] * 10 + [f64] * 4 + [i64] * 4 + [i32] * 4 + [p, p, i64, i64, i32, p, p, p]
    fn = getattr(lib, f"sss_blend_{suffix}")
    fn.restype = ctypes.c_int64  # active pixels
    fn.argtypes = [p] * 4 + [i64] * 3 + [i32]
    fn = getattr(lib, f"sss_spans_{suffix}")
    fn.restype = ctypes.c_int64  # runs of active pixels
    fn.argtypes = [p, i64, i64, p, i64]


def _declare64(lib: ctypes.CDLL) -> None:
    _declare_loops(lib, "f64")


def _declare(lib: ctypes.CDLL) -> None:
    p, i32 = ctypes.c_void_p, ctypes.c_int
    _declare_loops(lib, "f32")
    for fn in (lib.sss_simd_best, lib.sss_get_simd):
        fn.restype, fn.argtypes = i32, []
    lib.sss_set_simd.restype, lib.sss_set_simd.argtypes = i32, [i32]
    lib.sss_set_omp.restype, lib.sss_set_omp.argtypes = i32, [p] * 4
    for fn in (lib.sss_disk_f32, lib.sss_disk_f64, lib.sss_disk_hdrp_f32, lib.sss_disk_hdrp_f64):
        fn.restype, fn.argtypes = None, [p]  # a disk_args * (sssbench.ops._disk_native)


def _declare_quad(lib: ctypes.CDLL) -> None:
    p, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    lib.quad_cell_sums.restype, lib.quad_cell_sums.argtypes = i32, [p]  # a quad_args *
    lib.quad_exp_array.restype, lib.quad_exp_array.argtypes = None, [p, p, i64]
    lib.quad_exp_small_array.restype, lib.quad_exp_small_array.argtypes = None, [p, p, i64]
    lib.quad_exp_small_bound.restype, lib.quad_exp_small_bound.argtypes = ctypes.c_double, []
    for fn in (lib.quad_best_level, lib.quad_get_level):
        fn.restype, fn.argtypes = i32, []
    lib.quad_set_level.restype, lib.quad_set_level.argtypes = i32, [i32]
    lib.quad_set_split.restype, lib.quad_set_split.argtypes = i32, [i32]
    lib.quad_offset_fields.restype = None
    lib.quad_offset_fields.argtypes = [p, i64, i64, p, i64, p, i64, p]


def _load(path: Path, declare=_declare) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    declare(lib)  # AttributeError: a symbol is missing
    return lib


def _load_or_rebuild(
    cc: str, declare=_declare, build: Callable[[], Path] | None = None, **spec: Any
) -> tuple[ctypes.CDLL, Path]:
    """``(library, its file)``: the library of ``spec`` (:func:`_build`'s keywords; ``build``:
    another way to get its file the first time) loaded and its symbols declared; a corrupt or
    stale cached file (it does not load, or lacks a symbol) is built anew once."""
    try:
        path = build() if build is not None else _build(cc, **spec)
        return _load(path, declare), path
    except (OSError, AttributeError):
        path = _build(cc, fresh=True, **spec)
        return _load(path, declare), path


def _warn_unavailable(what: str, exc: BaseException, instead: str) -> None:
    """The ONE warning of a library that cannot be had: ``what`` failed (the compiler's
    message, or the error's), and what runs ``instead``."""
    detail = getattr(exc, "stderr", None) or f"{type(exc).__name__}: {exc}"
    warnings.warn(
        f"sssbench: native {what} unavailable ({str(detail).strip()[:300]}); {instead}",
        UserWarning,
        stacklevel=4,  # the caller of library() / library64() / quad_library()
    )


def quad_library() -> ctypes.CDLL | None:
    """The reference quadrature's native library (``quad.c``), building it on first use (about
    a second); ``None`` if it cannot be had, with ONE warning per process, and the reference
    computes the same sums with torch (equal to rounding, slower)."""
    if not _QUAD_STATE["tried"]:
        _QUAD_STATE["tried"] = True
        spec = {"sources": _QUAD_SOURCES, "units": _QUAD_UNITS, "prefix": "sssquad"}
        try:
            cc = _compiler()
            if cc is None:
                raise OSError("no C compiler found ($CC, cc, gcc, clang)")
            _QUAD_STATE["lib"] = _load_or_rebuild(cc, _declare_quad, **spec)[0]
        except Exception as exc:  # any failure: the torch sums
            _warn_unavailable(
                "reference quadrature",
                exc,
                "the reference uses its torch sums instead (equal to rounding, slower)",
            )
    return _QUAD_STATE["lib"]  # type: ignore[return-value]


#: what the fallback gives (the warning says it; tests/reliability/test_gather_safety.py
#: checks it): see ``BACKEND_AGREEMENT`` in sssbench/ops/gather.py
FALLBACK_NOTE = (
    "using the torch loop instead (slower; results bitwise equal to the native loop's "
    "except follow_surface='gaussian', where exp differs by a few ulp)"
)


def library() -> ctypes.CDLL | None:
    """The loaded native library, building it on first use; ``None`` if it cannot be had.

    Any failure (no compiler, a failed build, a cached file that does not load or lacks a
    symbol: ``OSError``, ``AttributeError``, ...) is reported by ONE warning per process and
    the gather runs its torch loop; a cached library that fails to load is rebuilt once first.
    """
    if not _STATE["tried"]:
        _STATE["tried"] = True
        try:
            cc = _compiler()
            if cc is None:
                raise OSError("no C compiler found ($CC, cc, gcc, clang)")
            both = (lambda: _build_both(cc)) if _STATE.get("want64") else None
            lib, path = _load_or_rebuild(cc, build=both)
            _STATE["lib"], _STATE["path"], _STATE["cc"] = lib, path, cc
            want = os.environ.get("SSSBENCH_SIMD", "").strip().lower()
            if want:
                set_simd(want)
            set_pool(os.environ.get("SSSBENCH_POOL", "").strip().lower() or "openmp")
        except Exception as exc:  # any failure: the torch loop
            _warn_unavailable("gather", exc, FALLBACK_NOTE)
    return _STATE["lib"]  # type: ignore[return-value]


def want_float64() -> None:
    """Say that this process will run float64 passes (a run with an error budget, whose
    method runs once in float64, or a float64 run): if :func:`library` has not loaded the
    gather library yet and neither library is built, it then builds both side by side
    (:func:`_build_both`) instead of the float64 one alone after it. Only the build's order
    changes: the libraries are the same."""
    _STATE["want64"] = True


def library64() -> ctypes.CDLL | None:
    """The float64 loops' library (``gather.c``'s ``SSS_PART`` 2: ``sss_gather_f64``,
    ``sss_blend_f64``, ``sss_spans_f64``), building it the first time it is asked for (about
    12 s of CPU with gcc 12; a float32 run never asks). It is linked against :func:`library`'s
    file and binds to that loaded copy, so the SIMD level (:func:`set_simd`) and the pool
    (:func:`set_pool`) set there are the float64 loops' too. ``None`` if either cannot be had,
    with ONE warning per process (none more when :func:`library` has warned already): the
    float64 passes run the torch loop."""
    if not _STATE64["tried"]:
        _STATE64["tried"] = True
        if library() is None:
            return None  # library() has warned
        spec = {"units": _GATHER64_UNITS, "prefix": "sssgather64", "needs": _STATE["path"]}
        try:
            _STATE64["lib"] = _load_or_rebuild(str(_STATE["cc"]), _declare64, **spec)[0]
        except Exception as exc:  # any failure: the torch loop for float64
            _warn_unavailable("float64 gather", exc, FALLBACK_NOTE)
    return _STATE64["lib"]  # type: ignore[return-value]


def library_for(dtype: object) -> ctypes.CDLL | None:
    """The library holding the gather loops of ``dtype`` (a torch dtype): :func:`library` for
    ``torch.float32``, :func:`library64` for ``torch.float64``, ``None`` for any other dtype or
    when that library cannot be had (then the passes run the torch loop)."""
    import torch

    if dtype == torch.float32:
        return library()
    if dtype == torch.float64:
        return library64()
    return None


#: the tap loop's instruction-set levels, narrowest first: ``"scalar"`` (one pixel at a time,
#: its colour and depth in one 4-lane vector: any CPU), ``"avx2"`` (AVX2 with FMA, used by the
#: float32 exp only: 8 float32 / 4 float64 pixels per vector) and ``"avx512"`` (AVX-512F:
#: 16 / 8); see ``native/gather_simd.h``
SIMD_LEVELS = ("scalar", "avx2", "avx512")


def simd_levels() -> tuple[str, ...]:
    """The levels this CPU supports, narrowest first (``()`` without the library)."""
    lib = library()
    return () if lib is None else SIMD_LEVELS[: lib.sss_simd_best() + 1]


def simd_level() -> str | None:
    """The level the native loop uses now (``None`` without the library)."""
    lib = library()
    return None if lib is None else SIMD_LEVELS[lib.sss_get_simd()]


def set_simd(level: str | None) -> str | None:
    """Make the native loop use ``level`` (one of :data:`SIMD_LEVELS`; ``None`` or ``"best"``:
    the widest the CPU supports), capped at the widest the CPU supports; returns the level set
    (``None`` without the library). Process-wide: every thread's passes use it. The environment
    variable ``SSSBENCH_SIMD`` sets it when the library loads. All levels give bitwise the same
    results (tested in ``tests/ops/test_gather_backends.py``); the choice is for tests and
    timings."""
    lib = library()
    if lib is None:
        return None
    if level in (None, "best", "auto"):
        code = -1
    elif level in SIMD_LEVELS:
        code = SIMD_LEVELS.index(level)
    else:
        raise ValueError(f"unknown SIMD level {level!r}: one of {SIMD_LEVELS} or 'best'")
    return SIMD_LEVELS[lib.sss_set_simd(code)]


class simd:  # noqa: N801 - used as a context manager, like torch.no_grad
    """``with native.simd("avx2"): ...`` runs the block's passes at that level (capped at the
    CPU's) and restores the previous level on exit; ``as`` gives the level in use."""

    def __init__(self, level: str | None) -> None:
        self.level = level
        self.previous: str | None = None

    def __enter__(self) -> str | None:
        self.previous = simd_level()
        return set_simd(self.level)

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            set_simd(self.previous)


#: where a pass runs its threads: ``"openmp"``, torch's own OpenMP team (the default, where
#: torch's parallel backend is OpenMP and its runtime is found), or ``"own"``, the library's
#: pthread pool
POOLS = ("openmp", "own")


def _openmp_entry_points() -> tuple[int, int, int, int] | None:
    """The addresses of ``GOMP_parallel``, ``omp_get_thread_num``, ``omp_get_num_threads`` and
    ``omp_in_parallel`` of the OpenMP runtime torch runs its operations on: the one mapped into
    this process from torch's ``lib`` folder (Linux: ``/proc/self/maps``), or the only one
    mapped; ``None`` when torch's parallel backend is not OpenMP or the runtime is not found
    unambiguously. ``dlopen`` of a loaded library's path returns that same library (not a
    second copy with threads of its own)."""
    try:
        import torch

        if "parallel backend: OpenMP" not in torch.__config__.parallel_info():
            return None
        paths = set()
        for line in Path("/proc/self/maps").read_text().splitlines():
            fields = line.split(maxsplit=5)
            if len(fields) == 6 and ("libgomp" in fields[5] or "libiomp5" in fields[5]):
                paths.add(fields[5])
        torch_lib = Path(torch.__file__).resolve().parent / "lib"
        found = [p for p in paths if Path(p).parent == torch_lib] or sorted(paths)
        if len(found) != 1:
            return None
        runtime = ctypes.CDLL(found[0])
        names = ("GOMP_parallel", "omp_get_thread_num", "omp_get_num_threads", "omp_in_parallel")
        return tuple(ctypes.cast(getattr(runtime, n), ctypes.c_void_p).value for n in names)
    except Exception:  # no /proc, no such symbol...: the own pool
        return None


def set_pool(kind: str) -> str | None:
    """Run the native passes' threads on ``kind`` (one of :data:`POOLS`); returns the pool in
    use: ``"own"`` where torch's OpenMP runtime is not available (``None`` without the
    library). Process-wide; a process forked from this one uses its own pool. Why torch's team
    by default: after a torch operation its OpenMP workers spin for milliseconds waiting for
    more work (libgomp's ``GOMP_SPINCOUNT``), on the very cores the pass's own second thread
    needs; the pass run by that team takes them instead (measured in ``docs/numerics.md``).
    The same bits either way: which thread computes a line never changes it."""
    if kind not in POOLS:
        raise ValueError(f"unknown pool {kind!r}: one of {POOLS}")
    lib = library()
    if lib is None:
        return None
    points = _openmp_entry_points() if kind == "openmp" else None
    on = lib.sss_set_omp(*(points or (None,) * 4))
    _STATE["pool"] = "openmp" if on else "own"
    _STATE["pool_pid"] = os.getpid()  # the C side's check: torch's team serves this process only
    return _STATE["pool"]  # type: ignore[return-value]


def pool() -> str | None:
    """The pool the native passes run on now (:func:`set_pool`; ``None`` without the
    library): ``"own"`` in a process forked after the pool was set, whose passes run on their
    own pool whatever the parent set (``pool_run`` in ``native/pool.h`` checks the pid)."""
    if library() is None:
        return None
    if _STATE.get("pool_pid") != os.getpid():
        return "own"
    return _STATE.get("pool", "own")  # type: ignore[return-value]

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
same SIMD level. The library's units (``gather.c``'s float32 and float64 halves, ``disk.c``:
:data:`_GATHER_UNITS`) are compiled side by side, one compiler per core this process may use,
and linked: on 2 cores the build takes 15-17 s of wall time instead of 26 s (its CPU time,
about 28 s with gcc 12, is the same).
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
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from pathlib import Path

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
#: the gather library's translation units, each a source and its ``-D`` flags: ``gather.c``
#: compiled twice (``SSS_PART`` 1: the shared state and the float32 loops, 2: the float64
#: loops; their compile times are about equal, 12 s each with gcc 12), then the disk's loop;
#: the longest first, so that on 2 cores the short one follows whichever ends first
_GATHER_UNITS: tuple[tuple[str, ...], ...] = (
    ("gather.c", "-DSSS_PART=1"),
    ("gather.c", "-DSSS_PART=2"),
    ("disk.c",),
)
#: the reference quadrature's library (:func:`quad_library`): its sources, its one unit
_QUAD_SOURCES = ("quad.c", "quad_simd.h", "exp2_32.h")
_QUAD_UNITS: tuple[tuple[str, ...], ...] = (("quad.c",),)
#: each unit's compile flags (the link adds ``-shared`` and the libraries)
_FLAGS = ["-O3", "-fPIC", "-ffp-contract=off", "-fno-math-errno", "-Wno-psabi"]
_STATE: dict[str, object] = {"lib": None, "tried": False}
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


def _compile_and_link(cc: str, units: tuple[tuple[str, ...], ...], out: str, folder: Path) -> None:
    """Compile each of ``units`` (a source and its ``-D`` flags) to an object in a temporary
    folder inside ``folder``, at most :func:`_cores` compilers at a time (a unit starts when a
    compiler ends), and link the objects into the shared library ``out``. After a compiler
    fails no further unit starts; once those running have ended, the failure's
    ``CalledProcessError`` is raised (its ``stderr`` is what the fallback warning shows)."""
    run = {"check": True, "capture_output": True, "text": True, "timeout": _BUILD_TIMEOUT_S}
    with tempfile.TemporaryDirectory(dir=folder) as objects:
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
                    running.add(compilers.submit(subprocess.run, waiting.pop(0), **run))
                ended, running = wait(running, return_when=FIRST_COMPLETED)
                failure = failure or next((e.exception() for e in ended if e.exception()), None)
        if failure is not None:
            raise failure
        subprocess.run([cc, "-shared", "-o", out, *paths, "-lm", "-lpthread"], **run)


def _build(
    cc: str,
    fresh: bool = False,
    sources: tuple[str, ...] = _SOURCES,
    units: tuple[tuple[str, ...], ...] = _GATHER_UNITS,
    prefix: str = "sssgather",
) -> Path:
    """The library of ``units`` (each a source and its ``-D`` flags; ``sources``: every file
    it is built from) for the current sources and ``cc``: the cached one, or a new build
    (``fresh``: build anew even when one is cached, replacing it atomically)."""
    digest = hashlib.sha256()
    for name in sources:
        digest.update((_HERE / name).read_bytes())
    digest.update(" ".join([cc, *_FLAGS]).encode())
    digest.update(repr(units).encode())  # how the sources are split into units
    name = f"{prefix}-{digest.hexdigest()[:16]}.so"
    fallback = Path(tempfile.gettempdir()) / f"sssbench-native-{os.getuid()}"
    for folder in (cache_dir(), fallback):  # an unwritable home: the temp dir
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
            if folder.stat().st_uid != os.getuid():
                continue  # never load a library from a folder somebody else owns
            if (folder / name).exists() and not fresh:
                return folder / name
            fd, tmp = tempfile.mkstemp(suffix=".so", dir=folder)
            break
        except OSError:
            continue
    else:
        raise OSError(f"cannot write the native library to {cache_dir()} or {fallback}")
    target = folder / name
    os.close(fd)
    try:
        compilers = max(1, min(len(units), _cores()))
        log.info(  # the first run's longest silence otherwise (issue 28: nothing silent for long)
            "building the native %s library with %s into %s (once per source version: %s)",
            "reference quadrature" if prefix == "sssquad" else "gather",
            cc,
            folder,
            "about a second"
            if prefix == "sssquad"
            else "about 28 s of CPU with gcc 12, "
            + (f"{compilers} compilers side by side" if compilers > 1 else "one compiler"),
        )
        # once per source version and user (cached): 28 s of CPU with gcc 12 on a 2-core AMD
        # EPYC, 15-17 s of wall time with two compilers (83 s before each loop specialisation
        # became its own function, 18 s before issue 30's multi-set sweep; the scalar loop and
        # the AVX2 and AVX-512 loops, float32 and float64, disk.c included); the timeout leaves
        # room for a slow, loaded machine
        _compile_and_link(cc, units, tmp, folder)
        os.replace(tmp, target)  # atomic: a racing worker sees a whole library or none
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


def _declare(lib: ctypes.CDLL) -> None:
    p, i64, i32, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_double
    for fn in (lib.sss_gather_f32, lib.sss_gather_f64):
        fn.restype = ctypes.c_int64  # active pixels, -1: out of memory
        fn.argtypes = [p] * 10 + [f64] * 4 + [i64] * 4 + [i32] * 4 + [p] * 2 + [i64] * 2 + [i32, p]
    for fn in (lib.sss_blend_f32, lib.sss_blend_f64):
        fn.restype = ctypes.c_int64  # active pixels
        fn.argtypes = [p] * 4 + [i64] * 3 + [i32]
    for fn in (lib.sss_spans_f32, lib.sss_spans_f64):
        fn.restype = ctypes.c_int64  # runs of active pixels
        fn.argtypes = [p, i64, i64, p, i64]
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
            try:
                lib = _load(_build(cc, **spec), _declare_quad)
            except (OSError, AttributeError):  # a corrupt or stale cached file: build anew
                lib = _load(_build(cc, fresh=True, **spec), _declare_quad)
            _QUAD_STATE["lib"] = lib
        except Exception as exc:  # any failure: the torch sums
            detail = getattr(exc, "stderr", None) or f"{type(exc).__name__}: {exc}"
            warnings.warn(
                f"sssbench: native reference quadrature unavailable ({str(detail).strip()[:300]});"
                " the reference uses its torch sums instead (equal to rounding, slower)",
                UserWarning,
                stacklevel=3,
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
            try:
                lib = _load(_build(cc))
            except (OSError, AttributeError):  # a corrupt or stale cached file: build anew
                lib = _load(_build(cc, fresh=True))
            _STATE["lib"] = lib
            want = os.environ.get("SSSBENCH_SIMD", "").strip().lower()
            if want:
                set_simd(want)
            set_pool(os.environ.get("SSSBENCH_POOL", "").strip().lower() or "openmp")
        except Exception as exc:  # any failure: the torch loop
            detail = getattr(exc, "stderr", None) or f"{type(exc).__name__}: {exc}"
            warnings.warn(
                f"sssbench: native gather unavailable ({str(detail).strip()[:300]}); "
                + FALLBACK_NOTE,
                UserWarning,
                stacklevel=3,
            )
    return _STATE["lib"]  # type: ignore[return-value]


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

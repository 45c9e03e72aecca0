"""Content digests that key caches (the reference cache, fitted kernels, Monte Carlo images,
the functional operators' module cache): of a profile's content and of all of the code.

Kept at the bottom of the house so that operators and Monte Carlo may key their caches
without reaching up into the run store (docs/architecture.md).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
from pathlib import Path
from typing import Any

import torch

__all__ = ["code_digest", "far_exp", "numeric_libraries", "numpy_exp_vectorised", "profile_digest"]


def _package_root(name: str) -> Path:
    """The folder of package ``name``, found without importing it (its files are read here,
    never run)."""
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise ImportError(f"package {name!r} not found")
    return Path(spec.origin).parent


@functools.cache
def numpy_exp_vectorised() -> bool:
    """Whether NumPy's float64 ``exp`` runs its own vectorised loop on this CPU (what
    :func:`sssbench.ops._reference_far.exp_in_place` then takes): NumPy dispatches that loop to
    AVX-512 only (its ``X86_V4`` target, the ``AVX512_SKX`` feature group); on a CPU without it
    NumPy's loop calls the C library's scalar ``exp`` per element. Read once per process from
    NumPy's CPU-feature table; ``False`` where the table cannot be read (``torch.exp_`` then)."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # NumPy 1.x
        try:
            from numpy.core import _multiarray_umath as umath  # type: ignore[no-redef]
        except ImportError:
            return False
    features = getattr(umath, "__cpu_features__", None)
    return bool(isinstance(features, dict) and features.get("AVX512_SKX"))


def far_exp() -> str:
    """Which ``exp`` :func:`sssbench.ops._reference_far.exp_in_place` takes for the
    reference's float64 tensors on this machine: ``"numpy"`` or ``"torch"``
    (:func:`numpy_exp_vectorised`; part of :func:`numeric_libraries`, so cached images name
    it)."""
    return "numpy" if numpy_exp_vectorised() else "torch"


def numeric_libraries() -> str:
    """The numeric libraries whose rounding cached images carry, as one line: the versions
    of torch and NumPy, the BLAS NumPy loaded (its library, version and the kernels it
    picked for this CPU; ``threadpoolctl``), read at each call, and which library's ``exp``
    the reference's far field takes on this CPU (:func:`far_exp`)."""
    import numpy
    from threadpoolctl import threadpool_info

    blas = sorted(
        f"{i.get('internal_api')} {i.get('version')} {i.get('architecture')}"
        for i in threadpool_info()
        if i.get("user_api") == "blas"
    )
    return f"torch {torch.__version__} numpy {numpy.__version__} blas {blas} exp {far_exp()}"


@functools.cache
def code_digest() -> str:
    """A digest of every source file of :mod:`sssbench` and :mod:`data_synth`: the Python
    files and the native tap loop's C sources (``*.c``, ``*.h``: the budget's converged
    limits are cached images the native loop computes), read once per process, and of the
    versions of torch and NumPy and of the BLAS NumPy loaded, whose kernels' rounding the
    cached images carry (the reference's far field takes NumPy's BLAS's products, its FFTs
    torch's, its ``exp`` NumPy's or torch's by the CPU: :func:`far_exp`). Cached images
    depend on the scene builders, the profiles, the reference, the methods and the pipeline;
    keying on all of the code is conservative (any change recomputes) and can never serve an
    image made by other code or by other numeric libraries."""
    h = hashlib.sha256(f"{numeric_libraries()}\n".encode())
    for package in ("sssbench", "data_synth"):
        root = _package_root(package)
        files = [p for suffix in ("*.py", "*.c", "*.h") for p in root.rglob(suffix)]
        for path in sorted(files):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def profile_digest(profile: Any) -> str:
    """A digest of a profile's content: its class and every tensor / number it holds."""
    h = hashlib.sha256(type(profile).__qualname__.encode())

    def add(name: str, value: Any) -> None:
        if isinstance(value, torch.Tensor):
            t = value.detach().cpu().contiguous().to(torch.float64)
            h.update(f"{name}:{tuple(t.shape)}".encode())
            h.update(t.numpy().tobytes())
        elif isinstance(value, (int, float, str, bool, type(None))):
            h.update(f"{name}={value!r}".encode())
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                add(f"{name}[{i}]", v)

    for name, value in sorted(vars(profile).items()):
        add(name, value)
    return h.hexdigest()[:24]

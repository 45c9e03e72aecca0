"""The cache keys' code digest (sssbench._digest.code_digest) covers every source a cached
image depends on: the Python files and the native tap loop's C sources (the budget's
converged limits are computed by the native loop) and the numeric libraries' versions, and
nothing else."""

from __future__ import annotations

import numpy
import torch

from sssbench import _digest


def test_code_digest_changes_with_python_and_c_sources_only(tmp_path, monkeypatch):
    for package in ("sssbench", "data_synth"):
        (tmp_path / package / "ops" / "native").mkdir(parents=True)
        (tmp_path / package / "__init__.py").write_text("x = 1\n")
    native = tmp_path / "sssbench" / "ops" / "native"
    (native / "gather.c").write_text("int f(void) { return 1; }\n")
    (native / "gather_body.h").write_text("#define K 1\n")
    (native / "notes.txt").write_text("not a source\n")
    monkeypatch.setattr(_digest, "_package_root", lambda name: tmp_path / name)
    digest = _digest.code_digest.__wrapped__  # uncached: the files are re-read
    base = digest()
    (native / "notes.txt").write_text("still not a source\n")
    assert digest() == base
    for path, text in [
        (native / "gather_body.h", "#define K 2\n"),
        (native / "gather.c", "int f(void) { return 2; }\n"),
        (tmp_path / "data_synth" / "__init__.py", "x = 2\n"),
    ]:
        before = digest()
        path.write_text(text)
        assert digest() != before


def test_code_digest_changes_with_the_numeric_libraries_versions(monkeypatch):
    """A reference cached under another torch or NumPy (other exp / FFT rounding) is not
    served: their versions are part of the key."""
    digest = _digest.code_digest.__wrapped__
    base = digest()
    monkeypatch.setattr(torch, "__version__", torch.__version__ + ".other")
    moved_torch = digest()
    monkeypatch.undo()
    monkeypatch.setattr(numpy, "__version__", numpy.__version__ + ".other")
    moved_numpy = digest()
    monkeypatch.undo()
    assert moved_torch != base and moved_numpy != base and moved_torch != moved_numpy
    assert digest() == base


def test_code_digest_changes_with_the_blas_numpy_loaded(monkeypatch):
    """The reference's far-field products run in NumPy's BLAS: a reference cached under
    another BLAS, or the same one with other kernels (another CPU), is not served — neither
    by the run cache (code_digest) nor by the reference images' cache
    (reference_code_digest)."""
    import threadpoolctl

    digest = _digest.code_digest.__wrapped__
    base = digest()
    real = threadpoolctl.threadpool_info

    def other(field: str, value: str):
        def info():
            return [{**i, field: value} if i.get("user_api") == "blas" else i for i in real()] or [
                {"user_api": "blas", field: value}
            ]

        return info

    from sssbench.ops.reference import reference_code_digest

    ref_base = reference_code_digest()
    moved, ref_moved = [], []
    for field, value in (("internal_api", "mkl"), ("version", "0.0.1"), ("architecture", "Zen")):
        monkeypatch.setattr(threadpoolctl, "threadpool_info", other(field, value))
        moved.append(digest())
        ref_moved.append(reference_code_digest())  # the reference images' own key too
        monkeypatch.undo()
    assert len(set(moved)) == 3 and base not in moved
    assert len(set(ref_moved)) == 3 and ref_base not in ref_moved
    assert digest() == base and reference_code_digest() == ref_base

"""Without a GL context the GL backend says what to install in one line and never falls back
to torch (runs everywhere: the context is simulated missing)."""

from __future__ import annotations

import sys

import pytest
import torch

import sssbench
from sssbench import gl
from sssbench.gl import _context


@pytest.fixture
def no_context(monkeypatch):
    """The module's context state emptied for the test, restored afterwards."""
    monkeypatch.setattr(_context, "_CONTEXT", None)
    monkeypatch.setattr(_context, "_FAILURE", None)
    yield


def _one_line_naming_packages(message: str) -> None:
    assert "\n" not in message
    for package in ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "sssbench[gl]"):
        assert package in message


def test_no_moderngl(no_context, monkeypatch):
    monkeypatch.setitem(sys.modules, "moderngl", None)  # import moderngl -> ImportError
    ok, why = gl.available()
    assert not ok and "moderngl" in why
    _one_line_naming_packages(why)
    with pytest.raises(gl.GLUnavailable) as err:
        gl.get_context()
    _one_line_naming_packages(str(err.value))


def test_no_egl_library(no_context, monkeypatch):
    pytest.importorskip("moderngl")
    monkeypatch.setenv("GLCONTEXT_LINUX_LIBEGL", "/nonexistent/libEGL.so.1")
    ok, why = gl.available()
    assert not ok and "EGL" in why
    _one_line_naming_packages(why)


def test_backend_gl_refuses_at_entry_without_falling_back(no_context, monkeypatch):
    monkeypatch.setitem(sys.modules, "moderngl", None)
    with pytest.raises(gl.GLUnavailable, match="libegl1"):
        with sssbench.backend("gl"):
            pass  # pragma: no cover - never entered
    assert sssbench.get_backend() == "native"  # restored
    g = sssbench.GBuffer(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 100.0), 0.5)
    from sssbench.run import registry

    m = registry.build_method("preintegrated", registry.build_profile("skin_deon6"), samples=3)
    with pytest.raises(gl.GLUnavailable):
        gl.run_method(m, g)

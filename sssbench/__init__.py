"""sssbench: screen-space subsurface scattering methods side by side against an exact reference.

The package's public face: :class:`GBuffer`, the gather :func:`backend`, :mod:`sssbench.io`
and the version. The layers, bottom to top (docs/architecture.md, checked by import-linter):
``gbuffer -> profiles -> kernels -> ops | mc -> score -> tune -> store -> run -> report -> app``.
"""

from sssbench import _moved, io  # users' G-buffers

# the GL backend's pass registers itself with the gather (sssbench.gl; moderngl loads lazily)
from sssbench import gl as _gl  # noqa: F401
from sssbench._version import __version__
from sssbench.gbuffer import GBuffer, pixel_size_mm, view_positions
from sssbench.ops.gather import backend, get_backend

# the fitted kernels ('optimised') reach the operators as data: importing the fitting code
# registers it as a kernel source (sssbench.kernels.sources)
from sssbench.tune import optimise as _optimise  # noqa: F401

# old import paths (sssbench.runner, sssbench.report's html_report, ...) stay aliases
_moved.install()

__all__ = [
    "GBuffer",
    "pixel_size_mm",
    "view_positions",
    "backend",
    "get_backend",
    "io",
    "__version__",
]

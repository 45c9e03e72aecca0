"""sssbench: screen-space subsurface scattering methods side by side against an exact reference.

Layers (DESIGN §1): ``profiles -> kernels -> ops -> pipeline -> app -> tracking -> report``.
"""

from sssbench.gbuffer import GBuffer, pixel_size_mm, view_positions
from sssbench.ops.gather import backend, get_backend

__version__ = "0.1.0"

__all__ = ["GBuffer", "pixel_size_mm", "view_positions", "backend", "get_backend", "__version__"]

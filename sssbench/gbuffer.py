"""The G-buffer: what a screen-space SSS pass reads (DESIGN §3).

Camera convention (DESIGN §2): pinhole, vertical field of view ``fov_y`` in radians, **linear**
depth in millimetres along the view axis. A pixel at depth ``z`` covers
``2 z tan(fov_y / 2) / H`` mm; :func:`pixel_size_mm` and :func:`view_positions` are the only
places that turn depth into world units.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from contextlib import AbstractContextManager
from dataclasses import dataclass, fields, replace

import torch

from sssbench._checks import check_range, check_scalar, check_tensor
from sssbench._memo import Sealing, memoised, sealed

__all__ = ["GBuffer", "pixel_size_mm", "view_positions"]

#: fields that hold images, with their channel counts
_IMAGE_FIELDS = {
    "diffuse": 3,
    "depth": 1,
    "albedo": 3,
    "specular": 3,
    "normal": 3,
    "mask": 1,
    "thickness": 1,
}


@dataclass(frozen=True)
class GBuffer:
    """Screen-space inputs of an SSS pipeline.

    Args:
        diffuse: diffuse irradiance (linear, >= 0), ``(B, 3, H, W)``.
        depth: linear view depth in mm, > 0, ``(B, 1, H, W)``.
        fov_y: vertical field of view in radians, in (0, pi).
        albedo: surface colour in [0, 1], ``(B, 3, H, W)``, optional.
        specular: specular radiance to add after scattering (>= 0), ``(B, 3, H, W)``, optional.
        normal: unit view-space normals (camera looks down -z), ``(B, 3, H, W)``, optional.
        mask: SSS strength / stencil in [0, 1], ``(B, 1, H, W)``, optional (``None`` = all 1).
        thickness: distance through the object toward the light in mm (>= 0),
            ``(B, 1, H, W)``, optional.
        light_dir: unit view-space direction *toward* the light, ``(B, 3)``, optional; used by
            translucency (back light) and by scenes.
        profile_id: per-pixel index of the material's diffusion profile, ``(B, 1, H, W)``
            integer (any torch integer dtype, >= 0; not cast by :meth:`to`), optional; used by
            methods that take a list of profiles (:class:`~sssbench.ops.DiskSSS`).

    Fields a scene does not provide stay ``None``; operators declare which ones they need.

    Example:
        >>> g = GBuffer(torch.ones(1, 3, 4, 4), torch.full((1, 1, 4, 4), 500.0), 0.5)
        >>> g.shape
        (1, 4, 4)
    """

    diffuse: torch.Tensor
    depth: torch.Tensor
    fov_y: float
    albedo: torch.Tensor | None = None
    specular: torch.Tensor | None = None
    normal: torch.Tensor | None = None
    mask: torch.Tensor | None = None
    thickness: torch.Tensor | None = None
    light_dir: torch.Tensor | None = None
    profile_id: torch.Tensor | None = None

    def __post_init__(self) -> None:
        fov = check_scalar(
            "fov_y", self.fov_y, 0.0, math.pi, low_inclusive=False, high_inclusive=False
        )
        object.__setattr__(self, "fov_y", fov)
        diffuse = check_tensor("diffuse", self.diffuse, ndim=4, channels=3)
        check_range("diffuse", diffuse, 0.0)
        b, _, h, w = diffuse.shape
        if h < 1 or w < 1 or b < 1:
            raise ValueError(
                f"diffuse must have non-empty B, H, W, got shape {tuple(diffuse.shape)}"
            )
        for name in _IMAGE_FIELDS:
            if name != "diffuse":
                self._validate_field(name)
        self._validate_field("light_dir")
        self._validate_field("profile_id")

    def _validate_field(self, name: str) -> None:
        """Check one field other than ``diffuse`` / ``fov_y`` against ``diffuse`` (valid)."""
        value = getattr(self, name)
        if value is None:
            return
        b, _, h, w = self.diffuse.shape
        if name == "profile_id":
            if not isinstance(value, torch.Tensor):
                raise TypeError(f"profile_id must be a torch.Tensor, got {type(value).__name__}")
            if value.dtype.is_floating_point or value.dtype.is_complex or value.dtype == torch.bool:
                raise TypeError(f"profile_id must have an integer dtype, got {value.dtype}")
            if value.shape != (b, 1, *self.diffuse.shape[2:]):
                raise ValueError(
                    f"profile_id must have shape ({b}, 1, {h}, {w}) to match diffuse, "
                    f"got {tuple(value.shape)}"
                )
            if value.numel() and int(value.min()) < 0:
                raise ValueError(f"profile_id must be >= 0, got min {int(value.min())}")
            return
        if name == "light_dir":
            check_tensor("light_dir", value, ndim=2)
            if value.shape != (b, 3):
                raise ValueError(f"light_dir must have shape ({b}, 3), got {tuple(value.shape)}")
            return
        channels = _IMAGE_FIELDS[name]
        check_tensor(name, value, ndim=4, channels=channels)
        if value.shape[0] != b or value.shape[2:] != self.diffuse.shape[2:]:
            raise ValueError(
                f"{name} must have shape ({b}, {channels}, {h}, {w}) to match diffuse, "
                f"got {tuple(value.shape)}"
            )
        if value.dtype != self.diffuse.dtype:
            raise TypeError(
                f"{name} has dtype {value.dtype} but diffuse has {self.diffuse.dtype}; "
                "all G-buffer tensors must share one dtype"
            )
        if name == "depth":
            check_range("depth", value, 0.0, low_inclusive=False)
            # the passes step 1 / pixel size pixels per mm: it must be finite in the dtype, i.e.
            # the nearest pixel's footprint a normal float (float32, fov_y = 1e-40: 0 · inf)
            nearest = 2.0 * float(value.detach().min()) * math.tan(self.fov_y / 2.0) / h
            tiny = torch.finfo(value.dtype).tiny
            if not nearest >= tiny:
                raise ValueError(
                    f"fov_y and depth must give a pixel footprint 2 z tan(fov_y/2) / H >= "
                    f"{tiny:g} mm (the smallest normal {value.dtype}) at the nearest depth, got "
                    f"{nearest:g} mm (fov_y={self.fov_y:g}, min depth={float(value.min()):g}); "
                    "use a larger fov_y or float64"
                )
        elif name in ("mask", "albedo"):
            check_range(name, value, 0.0, 1.0)
        elif name in ("specular", "thickness"):
            check_range(name, value, 0.0)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(B, H, W)``."""
        b, _, h, w = self.diffuse.shape
        return b, h, w

    @property
    def dtype(self) -> torch.dtype:
        return self.diffuse.dtype

    @property
    def device(self) -> torch.device:
        return self.diffuse.device

    def mask_or_ones(self) -> torch.Tensor:
        """The SSS mask, or ones ``(B, 1, H, W)`` when the scene gives none."""
        if self.mask is not None:
            return self.mask
        return torch.ones_like(self.depth)

    def tensors(self) -> dict[str, torch.Tensor]:
        """The tensor fields that are set, by name."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        return {k: v for k, v in out.items() if isinstance(v, torch.Tensor)}

    def sealed(
        self, pristine: GBuffer | None = None, *, writable: Iterable[str] = ()
    ) -> AbstractContextManager[Sealing]:
        """A block in which this G-buffer's tensors are sealed (:func:`sssbench._memo.sealed`):
        read-only by contract, so the stencils, LOD masks and field checks memoised on them
        are trusted in O(1) per call instead of a bitwise compare proportional to the image.
        A write is an error (:class:`~sssbench._memo.SealBroken`): at the next memo lookup
        if torch counted it, else at the next verification point — ``seal.verify()`` or the
        block's end, which always verifies — never a stale value passed on silently.

        Args:
            pristine: a separate copy of this G-buffer (same bits) that nothing writes:
                verified against by ``memcmp``; without it, by SHA-256 digests taken now.
            writable: names of fields left unsealed because the block writes them, e.g.
                ``("diffuse",)`` for a renderer's ``op(g, inplace=True)``, which overwrites
                the lit diffuse under the stencil while the stencil and depth stay sealed.

        Raises:
            ValueError: ``writable`` names something that is not a field of a G-buffer.

        Example:
            >>> g = GBuffer(torch.ones(1, 3, 4, 4), torch.full((1, 1, 4, 4), 500.0), 0.5)
            >>> with g.sealed() as seal:
            ...     seal.verify()
        """
        names = (writable,) if isinstance(writable, str) else tuple(writable)
        known = {f.name for f in fields(self)}
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(
                f"writable must name G-buffer fields (one of {sorted(known)}), got {unknown}"
            )
        kept = {k: v for k, v in self.tensors().items() if k not in names}
        twins = None if pristine is None else pristine.tensors()
        return sealed(kept, twins)

    def to(self, dtype: torch.dtype) -> GBuffer:
        """A copy with every floating-point tensor field cast to ``dtype`` (``profile_id``
        keeps its integer dtype); this G-buffer itself when every such field has ``dtype``
        already (the copy would hold the same tensors: ``Tensor.to`` of a tensor's own dtype
        returns it, and a G-buffer's fields are never reassigned), so a cast that changes
        nothing does not validate its fields again."""
        changes = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, torch.Tensor) and f.name != "profile_id" and value.dtype != dtype:
                changes[f.name] = value.to(dtype)
        return replace(self, **changes) if changes else self

    def replace(self, **changes: object) -> GBuffer:
        """A copy with some fields replaced; the replaced fields are validated.

        Fields that are not replaced were validated when this G-buffer was built and are not
        scanned again (a method that swaps in a per-step stencil would otherwise re-read every
        image of a 1080p G-buffer per step), nor is a replacing tensor already checked against
        the same diffuse shape, dtype and ``fov_y`` (memoised on its identity and version,
        :func:`~sssbench._memo.memoised`). Replacing ``diffuse`` or ``fov_y`` validates all.
        """
        if not changes.keys() <= {f.name for f in fields(self)}:
            unknown = sorted(changes.keys() - {f.name for f in fields(self)})
            raise TypeError(f"GBuffer has no field(s) {unknown}")
        if changes.keys() & {"diffuse", "fov_y"}:
            return replace(self, **changes)
        new = object.__new__(GBuffer)
        for f in fields(self):
            object.__setattr__(new, f.name, changes.get(f.name, getattr(self, f.name)))
        for name in changes:
            # a field checked against the same diffuse shape, dtype and fov_y before (e.g. a
            # per-step stencil swapped in on every call) is not scanned again
            tag = ("valid_field", name, tuple(self.diffuse.shape), self.dtype, self.fov_y)
            value = changes[name]
            if isinstance(value, torch.Tensor):
                memoised((value,), tag, lambda name=name: new._validate_field(name) or True)
            else:
                new._validate_field(name)
        return new


def pixel_size_mm(depth: torch.Tensor, fov_y: float, height: int) -> torch.Tensor:
    """World size of one pixel at linear depth ``depth``: ``2 z tan(fov_y/2) / H`` (DESIGN §2).

    Args:
        depth: linear depth in mm, any shape.
        fov_y: vertical field of view in radians.
        height: image height H in pixels.

    Returns:
        mm per pixel, same shape as ``depth``.
    """
    return depth * (2.0 * math.tan(fov_y / 2.0) / height)


def view_positions(depth: torch.Tensor, fov_y: float) -> torch.Tensor:
    """View-space positions (mm) of pixel centres for a pinhole camera.

    Pixel ``(i, j)`` (row, column) has its centre at normalised device coordinates
    ``u = (j + 0.5 - W/2) / (H/2)``, ``v = (H/2 - i - 0.5) / (H/2)`` (square pixels), so
    ``x = u z tan(fov_y/2)``, ``y = v z tan(fov_y/2)`` and the position is ``(x, y, z)`` with
    ``z`` the (positive) linear depth.

    Args:
        depth: ``(B, 1, H, W)`` linear depth in mm.
        fov_y: vertical field of view in radians.

    Returns:
        ``(B, 3, H, W)`` positions in mm.
    """
    _, _, h, w = depth.shape
    t = math.tan(fov_y / 2.0)
    cols = (torch.arange(w, dtype=depth.dtype, device=depth.device) + 0.5 - w / 2) / (h / 2)
    rows = (h / 2 - torch.arange(h, dtype=depth.dtype, device=depth.device) - 0.5) / (h / 2)
    x = cols.view(1, 1, 1, w) * depth * t
    y = rows.view(1, 1, h, 1) * depth * t
    return torch.cat([x, y, depth], dim=1)

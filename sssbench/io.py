"""Users' own G-buffers and result images on disk: OpenEXR and ``.npz`` (docs/io.md).

A G-buffer file holds the fields of a :class:`~sssbench.gbuffer.GBuffer` under fixed names:

============  =========================================  ======================================
field         OpenEXR channels (FLOAT or HALF)           ``.npz`` array
============  =========================================  ======================================
diffuse       ``diffuse.R`` ``diffuse.G`` ``diffuse.B``  ``diffuse`` ``(B, 3, H, W)``
depth         ``depth.Z`` (linear view depth, mm)        ``depth`` ``(B, 1, H, W)``
normal        ``normal.X`` ``normal.Y`` ``normal.Z``     ``normal`` ``(B, 3, H, W)``
albedo        ``albedo.R`` ``albedo.G`` ``albedo.B``     ``albedo`` ``(B, 3, H, W)``
specular      ``specular.R`` ``specular.G`` ``specular.B`` ``specular`` ``(B, 3, H, W)``
mask          ``mask.A`` (or ``mask.Y``)                 ``mask`` ``(B, 1, H, W)``
thickness     ``thickness.Y`` (mm)                       ``thickness`` ``(B, 1, H, W)``
light_dir     header attribute ``light_dir`` (v3f/v3d)   ``light_dir`` ``(B, 3)``
============  =========================================  ======================================

plus ``fov_y`` (radians, in (0, pi)), ``units`` (must be ``"mm"``) and ``sssbench_version`` as
OpenEXR header attributes or 0-d ``.npz`` arrays. ``diffuse``, ``depth``, ``fov_y`` and
``units`` are required; the rest is optional.

Precision (a choice): OpenEXR has no float64 channels. :func:`write_gbuffer` writes float32
G-buffers as FLOAT channels, bit-exact (lossless ZIP compression), and **refuses** a float64
G-buffer for ``.exr`` unless ``allow_rounding=True`` (then every value is rounded to the
nearest float32) — a silent halving of the precision would be a silent wrong answer for a
float64 study. ``fov_y`` is written as a ``double`` attribute, so it round-trips exactly in
both dtypes. ``.npz`` keeps float32 and float64 as they are. An EXR holds one image (B = 1);
batches go to ``.npz``.

Every problem with a file is one ``ValueError`` line naming the file and what is wrong
(missing channel with the ones present, units, non-finite or non-positive depth, mismatched
sizes, not an EXR, ``fov_y`` missing or out of range).

Example:
    >>> import tempfile, os, torch
    >>> g = GBuffer(torch.ones(1, 3, 4, 4), torch.full((1, 1, 4, 4), 500.0), 0.5)
    >>> path = write_gbuffer(os.path.join(tempfile.mkdtemp(), "g.exr"), g)
    >>> torch.equal(read_gbuffer(path).depth, g.depth)
    True
"""

from __future__ import annotations

import hashlib
import math
import os
import threading
from collections.abc import Iterable
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sssbench._checks import check_tensor
from sssbench.gbuffer import GBuffer

__all__ = [
    "EXR_CHANNELS",
    "OPTIONAL_FIELDS",
    "read_gbuffer",
    "write_gbuffer",
    "read_image_exr",
    "write_image_exr",
    "load_scene_file",
    "scene_file_digest",
]

#: G-buffer image field -> its OpenEXR channel names, in tensor channel order
EXR_CHANNELS: dict[str, tuple[str, ...]] = {
    "diffuse": ("diffuse.R", "diffuse.G", "diffuse.B"),
    "depth": ("depth.Z",),
    "normal": ("normal.X", "normal.Y", "normal.Z"),
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "specular": ("specular.R", "specular.G", "specular.B"),
    "mask": ("mask.A",),
    "thickness": ("thickness.Y",),
}
#: channels also accepted when reading, in place of the written name
_EXR_ALIASES = {"mask.A": ("mask.Y",)}
#: the fields a file may leave out (the same names as ``data_synth.OPTIONAL_FIELDS``)
OPTIONAL_FIELDS = ("albedo", "specular", "normal", "mask", "thickness")
_IMAGE_CHANNELS = ("R", "G", "B")
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_UNITS = "mm"
_SUFFIXES = (".exr", ".npz")


def _version() -> str:
    from sssbench._version import __version__

    return __version__


def _openexr() -> Any:
    try:
        import OpenEXR
    except ImportError as exc:  # pragma: no cover - openexr is a dependency
        raise ImportError(
            'reading and writing .exr files needs the openexr package: pip install "openexr>=3.3"'
        ) from exc
    return OpenEXR


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(
            f"{path}: unknown G-buffer file type {path.suffix!r}; expected one of {_SUFFIXES}"
        )
    return suffix


def _atomic_target(path: Path) -> Path:
    """A temporary name beside ``path`` (same suffix) to write to before ``os.replace``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(f".{path.stem}.{os.getpid()}.{threading.get_ident()}.tmp{path.suffix}")


# ----------------------------------------------------------------------------- OpenEXR core
def _read_exr(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Header and channels (name -> pixel array as stored) of a single-part EXR."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != _EXR_MAGIC:
        raise ValueError(
            f"{path}: not an OpenEXR file (starts with {magic!r}, expected {_EXR_MAGIC!r})"
        )
    exr = _openexr()
    try:
        file = exr.File(str(path), separate_channels=True)
    except Exception as exc:
        raise ValueError(f"{path}: unreadable OpenEXR file ({type(exc).__name__}: {exc})") from exc
    if len(file.parts) != 1:
        raise ValueError(
            f"{path}: has {len(file.parts)} parts; sssbench reads single-part EXR files "
            "(one image; write batches as .npz)"
        )
    header = dict(file.header())
    channels = {name: np.asarray(c.pixels) for name, c in file.channels().items()}
    return header, channels


def _float_channels(path: Path, channels: dict[str, np.ndarray], names: list[str]) -> np.ndarray:
    """The named channels as one float32 ``(C, H, W)`` array (HALF widened exactly); only the
    channels sssbench reads must be FLOAT/HALF and of one size (other AOVs are ignored)."""
    for name in names:
        if channels[name].dtype not in (np.float32, np.float16):
            raise ValueError(
                f"{path}: channel {name} has pixel type {channels[name].dtype}; "
                "expected FLOAT or HALF"
            )
    shapes = {name: channels[name].shape for name in names}
    if len(set(shapes.values())) > 1:
        sizes = ", ".join(f"{n} {s[1]}x{s[0]}" for n, s in shapes.items())
        raise ValueError(
            f"{path}: channels have mismatched sizes (W x H: {sizes}); "
            "subsampled channels are not supported"
        )
    return np.stack([channels[name] for name in names]).astype(np.float32)


def _write_exr(path: Path, header: dict[str, Any], channels: dict[str, np.ndarray]) -> Path:
    """Write float32 ``(H, W)`` channels losslessly (ZIP) and atomically; return the path."""
    exr = _openexr()
    header = {"compression": exr.ZIP_COMPRESSION, "type": exr.scanlineimage, **header}
    tmp = _atomic_target(path)
    try:
        exr.File(header, {n: np.ascontiguousarray(c) for n, c in channels.items()}).write(str(tmp))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _float32_array(path: Path, name: str, tensor: torch.Tensor, allow_rounding: bool) -> np.ndarray:
    """``tensor`` as a float32 numpy array; a float64 one only with ``allow_rounding``."""
    if tensor.dtype == torch.float64 and not allow_rounding:
        raise ValueError(
            f"{path}: {name} is float64 but OpenEXR stores at most float32; pass "
            "allow_rounding=True to round to float32, or write a .npz file (keeps float64)"
        )
    return tensor.detach().to("cpu", torch.float32).numpy()


# ----------------------------------------------------------------------------- header values
def _header_text(path: Path, value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.ndim == 0:
        return str(value.item())
    return str(value)


def _check_units(path: Path, units: Any) -> None:
    if units is None:
        raise ValueError(
            f"{path}: no 'units' attribute; sssbench needs depth and thickness in mm "
            "(add units='mm' after converting)"
        )
    text = _header_text(path, units)
    if text != _UNITS:
        raise ValueError(
            f"{path}: units is {text!r}, expected 'mm' (convert depth and thickness to "
            "millimetres and set units='mm')"
        )


def _fov_y(path: Path, value: Any) -> float:
    """``fov_y`` from a header (float, 1-element double array) or a 0-d ``.npz`` array."""
    if value is None:
        raise ValueError(f"{path}: no 'fov_y' attribute (vertical field of view, radians)")
    array = np.asarray(value)
    if array.size != 1 or array.dtype.kind not in "fi":
        raise ValueError(f"{path}: fov_y must be one real number (radians), got {value!r}")
    fov = float(array.reshape(()).item())
    if not (0.0 < fov < math.pi):
        raise ValueError(f"{path}: fov_y must lie in (0, pi) radians, got {fov!r}")
    return fov


def _check_depth(path: Path, name: str, depth: np.ndarray) -> None:
    """Linear view depth must be finite and > 0 everywhere (one line naming the first bad
    pixel); renderers often write inf for the background: give it a finite far depth and
    mask 0 there."""
    bad = ~np.isfinite(depth) | ~(depth > 0)
    if not bad.any():
        return
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    n_nan = int(np.isnan(depth).sum())
    n_inf = int(np.isinf(depth).sum())
    n_neg = int(bad.sum()) - n_nan - n_inf
    where = f"row {first[-2]}, column {first[-1]}" + (
        f" of image {first[0]}" if depth.ndim == 4 and depth.shape[0] > 1 else ""
    )
    raise ValueError(
        f"{path}: {name} must be finite and > 0 mm (linear view depth) but has {n_nan} NaN, "
        f"{n_inf} inf and {n_neg} values <= 0 (first at {where}: {float(depth[first]):g})"
    )


def _gbuffer(path: Path, **values: Any) -> GBuffer:
    """Build the G-buffer; its validation errors become one line naming the file."""
    try:
        return GBuffer(**values)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _tensor(array: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array)).to(dtype)


def _dtype(dtype: torch.dtype | None, default: torch.dtype) -> torch.dtype:
    if dtype is None:
        return default
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32, torch.float64 or None, got {dtype}")
    return dtype


# ----------------------------------------------------------------------------- G-buffers: EXR
def _missing_channels(path: Path, field: str, missing: list[str], present: list[str]) -> str:
    also = [a for n in missing for a in _EXR_ALIASES.get(n, ())]
    alt = f" (or {', '.join(also)})" if also else ""
    return (
        f"{path}: missing channel(s) {', '.join(missing)}{alt} for {field}; "
        f"channels present: {', '.join(sorted(present)) or 'none'}"
    )


def _read_gbuffer_exr(path: Path, dtype: torch.dtype | None) -> GBuffer:
    header, channels = _read_exr(path)
    _check_units(path, header.get("units"))
    fov = _fov_y(path, header.get("fov_y"))

    def resolve(name: str) -> str | None:
        """The file's channel for one of ours (the written name first, then its aliases)."""
        return next((c for c in (name, *_EXR_ALIASES.get(name, ())) if c in channels), None)

    layout: dict[str, list[str]] = {}  # field -> the file's channel names, in tensor order
    for field, names in EXR_CHANNELS.items():
        found = [resolve(n) for n in names]
        if field in OPTIONAL_FIELDS and all(c is None for c in found):
            continue
        missing = [n for n, c in zip(names, found, strict=True) if c is None]
        if missing:
            raise ValueError(_missing_channels(path, field, missing, list(channels)))
        layout[field] = [c for c in found if c is not None]
    used = [c for names in layout.values() for c in names]
    stacked = _float_channels(path, channels, used)[None]  # (1, all used channels, H, W)
    out_dtype = _dtype(dtype, torch.float32)
    values: dict[str, Any] = {"fov_y": fov}
    start = 0
    for field, names in layout.items():
        array = stacked[:, start : start + len(names)]
        start += len(names)
        if field == "depth":
            _check_depth(path, "depth.Z", array)
        values[field] = _tensor(array, out_dtype)
    if "light_dir" in header:
        light = np.asarray(header["light_dir"], dtype=np.float64).reshape(1, -1)
        values["light_dir"] = _tensor(light, out_dtype)
    return _gbuffer(path, **values)


def _write_gbuffer_exr(path: Path, gbuffer: GBuffer, allow_rounding: bool) -> Path:
    b = gbuffer.shape[0]
    if b != 1:
        raise ValueError(
            f"{path}: an OpenEXR G-buffer holds one image but the G-buffer has B={b}; "
            "write a .npz file or one .exr per image"
        )
    channels: dict[str, np.ndarray] = {}
    for field, names in EXR_CHANNELS.items():
        value = getattr(gbuffer, field)
        if value is not None:
            array = _float32_array(path, field, value, allow_rounding)[0]
            channels.update(zip(names, array, strict=True))
    header: dict[str, Any] = {
        # a 1-element float64 array is written as a 'double' attribute: fov_y is exact
        "fov_y": np.array([gbuffer.fov_y], dtype=np.float64),
        "units": _UNITS,
        "sssbench_version": _version(),
    }
    if gbuffer.light_dir is not None:
        # a v3d attribute: exact for float32 (and float64) light directions
        header["light_dir"] = gbuffer.light_dir[0].detach().to("cpu", torch.float64).numpy()
    return _write_exr(path, header, channels)


# ----------------------------------------------------------------------------- G-buffers: npz
_NPZ_FIELDS = tuple(f.name for f in dataclass_fields(GBuffer) if f.name != "fov_y")


def _read_gbuffer_npz(path: Path, dtype: torch.dtype | None) -> GBuffer:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as exc:
        raise ValueError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from exc
    present = ", ".join(sorted(arrays)) or "none"
    for required in ("diffuse", "depth"):
        if required not in arrays:
            raise ValueError(f"{path}: missing array {required!r}; arrays present: {present}")
    _check_units(path, arrays.get("units"))
    fov = _fov_y(path, arrays.get("fov_y"))
    stored = {k: arrays[k] for k in _NPZ_FIELDS if k in arrays}
    kinds = {k: a.dtype for k, a in stored.items() if a.dtype not in (np.float32, np.float64)}
    if kinds:
        raise ValueError(
            f"{path}: arrays must be float32 or float64, got "
            + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items()))
        )
    _check_depth(path, "depth", stored["depth"])
    default = torch.float64 if stored["diffuse"].dtype == np.float64 else torch.float32
    out_dtype = _dtype(dtype, default)
    values = {k: _tensor(a, out_dtype) for k, a in stored.items()}
    return _gbuffer(path, fov_y=fov, **values)


def _write_gbuffer_npz(path: Path, gbuffer: GBuffer) -> Path:
    arrays: dict[str, np.ndarray] = {
        "fov_y": np.array(gbuffer.fov_y, dtype=np.float64),
        "units": np.array(_UNITS),
        "sssbench_version": np.array(_version()),
    }
    for name in _NPZ_FIELDS:
        value = getattr(gbuffer, name)
        if value is not None:
            arrays[name] = value.detach().cpu().numpy()
    tmp = _atomic_target(path)
    try:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


# ----------------------------------------------------------------------------- public API
def read_gbuffer(path: str | os.PathLike[str], *, dtype: torch.dtype | None = None) -> GBuffer:
    """Read a G-buffer from an OpenEXR (``.exr``) or NumPy (``.npz``) file.

    Args:
        path: the file; its suffix picks the format (names and layout: module docstring).
        dtype: ``torch.float32`` / ``torch.float64`` to cast every field to, or ``None`` for
            the stored precision (float32 for EXR — HALF channels are widened exactly — and
            the dtype of ``diffuse`` for ``.npz``).

    Returns:
        A validated :class:`~sssbench.gbuffer.GBuffer` (B = 1 for EXR).

    Raises:
        FileNotFoundError: no such file.
        ValueError: one line naming the file and the problem.
    """
    path = Path(path)
    if _suffix(path) == ".exr":
        return _read_gbuffer_exr(path, dtype)
    return _read_gbuffer_npz(path, dtype)


def write_gbuffer(
    path: str | os.PathLike[str], gbuffer: GBuffer, *, allow_rounding: bool = False
) -> Path:
    """Write a G-buffer to ``.exr`` or ``.npz`` (atomically; parent directories are created).

    ``write_gbuffer`` then :func:`read_gbuffer` gives back every field bit for bit for a
    float32 G-buffer in both formats and for a float64 one in ``.npz``.

    Args:
        path: target file, ``.exr`` or ``.npz``.
        gbuffer: the G-buffer; ``.exr`` needs B = 1.
        allow_rounding: let a float64 G-buffer be written to ``.exr`` rounded to float32
            (refused otherwise; ``.npz`` keeps float64).

    Returns:
        The path written.
    """
    path = Path(path)
    if not isinstance(gbuffer, GBuffer):
        raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
    if _suffix(path) == ".exr":
        return _write_gbuffer_exr(path, gbuffer, allow_rounding)
    return _write_gbuffer_npz(path, gbuffer)


def write_image_exr(
    path: str | os.PathLike[str], image: torch.Tensor, *, allow_rounding: bool = False
) -> Path:
    """Write a linear RGB image ``(1, 3, H, W)`` as FLOAT channels ``R``, ``G``, ``B``.

    Values are written as they are (no tone mapping, no clamping; NaN and inf kept) so a run's
    ``result.exr`` / ``reference.exr`` can be compared in any HDR viewer. float32 round-trips
    bit-exact through :func:`read_image_exr`; a float64 image needs ``allow_rounding=True``.

    Returns:
        The path written (atomically; parent directories are created).
    """
    path = Path(path)
    check_tensor("image", image, ndim=4, channels=3, finite=False)
    if image.shape[0] != 1:
        raise ValueError(f"image must have shape (1, 3, H, W), got {tuple(image.shape)}")
    rgb = _float32_array(path, "image", image, allow_rounding)[0]
    channels = dict(zip(_IMAGE_CHANNELS, rgb, strict=True))
    return _write_exr(path, {"sssbench_version": _version()}, channels)


def read_image_exr(
    path: str | os.PathLike[str], *, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Read the ``R``, ``G``, ``B`` channels of an EXR as a ``(1, 3, H, W)`` tensor."""
    path = Path(path)
    _, channels = _read_exr(path)
    missing = [c for c in _IMAGE_CHANNELS if c not in channels]
    if missing:
        raise ValueError(_missing_channels(path, "the image", missing, list(channels)))
    rgb = _float_channels(path, channels, list(_IMAGE_CHANNELS))[None]
    return _tensor(rgb, _dtype(dtype, torch.float32))


def load_scene_file(
    path: str | os.PathLike[str],
    *,
    fields: Iterable[str] | None = None,
    dtype: torch.dtype = torch.float32,
) -> GBuffer:
    """The G-buffer of ``scene=file scene.path=...``: like ``data_synth.make_scene`` for a
    user's file.

    Args:
        path: an ``.exr`` or ``.npz`` G-buffer file.
        fields: the optional fields the run needs (``Pipeline.needs``), a subset of
            :data:`OPTIONAL_FIELDS` and ``light_dir``. Each must be in the file — a missing one
            is an error naming it, never a silent default (a missing ``mask`` would scatter the
            whole frame): write ``mask.A`` = 1 to scatter everywhere. Optional image fields
            not requested are dropped, as ``make_scene`` does (``light_dir`` is kept); ``None``
            keeps every field of the file.
        dtype: the run's dtype.

    Returns:
        A validated :class:`~sssbench.gbuffer.GBuffer`.
    """
    path = Path(path)
    requestable = (*OPTIONAL_FIELDS, "light_dir")
    wanted = None
    if fields is not None:
        if isinstance(fields, str):
            raise TypeError(f"fields must be a collection of field names, got {fields!r}")
        wanted = list(fields)
        unknown = sorted(set(wanted) - set(requestable))
        if unknown:
            raise ValueError(f"fields must be a subset of {list(requestable)}, got {unknown}")
    gbuffer = read_gbuffer(path, dtype=dtype)
    if wanted is None:
        return gbuffer
    have = [f for f in requestable if getattr(gbuffer, f) is not None]
    missing = [f for f in requestable if f in wanted and f not in have]
    if missing:
        if path.suffix.lower() == ".exr":
            names = [n for f in missing for n in EXR_CHANNELS.get(f, (f"attribute {f}",))]
            hint = "; add " + ", ".join(names)
        else:
            hint = "; add array(s) " + ", ".join(missing)
        raise ValueError(
            f"{path}: the run needs field(s) {', '.join(missing)} that the file does not have "
            f"(it has diffuse, depth{''.join(', ' + f for f in have)}){hint}"
        )
    drop = {f: None for f in have if f in OPTIONAL_FIELDS and f not in wanted}
    return gbuffer.replace(**drop) if drop else gbuffer


def scene_file_digest(path: str | os.PathLike[str]) -> str:
    """SHA-256 (hex, 16 chars) of a scene file's bytes.

    Put it in the run's point (e.g. ``scene_params["sha256"]``): the store's config hash and
    the reference cache key then change when the file's content changes, so no result or
    cached reference of an older file is reused.
    """
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()[:16]

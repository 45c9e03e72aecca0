"""Users' own G-buffers and result images on disk: OpenEXR and ``.npz`` (docs/io.md).

One module because it is one surface: both formats share the field table, the checks of what a
file holds and the one-line diagnosis of a bad or damaged file (the EXR header read here before
the binding sees the file).

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

``profile_id`` (integer material index per pixel) is the ``.npz`` array ``profile_id`` (its
integer dtype kept) and the OpenEXR UINT channel ``profile_id.I`` (read back as int64; values
above 2³² − 1 are refused on writing, naming the field). Every field of a G-buffer therefore
round-trips through both formats (``tests/test_io.py``).

Every problem with a file is one ``ValueError`` line naming the file and what is wrong
(missing channel with the ones present, units, non-finite or non-positive depth, mismatched
sizes, not an EXR, ``fov_y`` missing or out of range). A path that is a directory is an
``IsADirectoryError`` saying so. A **damaged** EXR is one line too, said before anything large
is allocated: its header is parsed here first, so a header cut short is "truncated", a data
window whose decoded channels would exceed :data:`MAX_EXR_BYTES` is "too large", and a file the
OpenEXR library cannot read (missing pixel data: "has 0 parts") is "damaged or truncated";
the library's own warnings are swallowed at the file-descriptor level (nothing else reaches
stderr).

Example:
    >>> import tempfile, os, torch
    >>> g = GBuffer(torch.ones(1, 3, 4, 4), torch.full((1, 1, 4, 4), 500.0), 0.5)
    >>> path = write_gbuffer(os.path.join(tempfile.mkdtemp(), "g.exr"), g)
    >>> torch.equal(read_gbuffer(path).depth, g.depth)
    True
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import struct
import sys
import tempfile
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
    "MAX_EXR_BYTES",
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
#: the integer field's OpenEXR channel (UINT: 32 bits)
_PROFILE_ID_CHANNEL = "profile_id.I"
#: largest decoded size of an EXR's channels read (float32 per sample): 4 GiB, a 16384² image
#: with four channels; a header claiming more is refused before the library allocates it
MAX_EXR_BYTES = 1 << 32
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


def _check_file(path: Path) -> None:
    """An existing regular file, else one line: "is a directory" or "no such file"."""
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, expected a {path.suffix} file")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")


def _check_write_target(path: Path) -> None:
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, expected a {path.suffix} file to write")


# ----------------------------------------------------------------------------- OpenEXR core
class _Truncated(Exception):
    """The header ends before its end marker."""


def _exr_headers(data: bytes) -> list[dict[str, Any]]:
    """The parts' headers of an EXR, parsed here (no pixel is read or allocated): per part
    ``data_window`` ``(xmin, ymin, xmax, ymax)`` and ``channels`` ``[(name, pixel type,
    x sampling, y sampling)]``. Raises ``_Truncated`` when the bytes end inside a header."""
    pos = 8
    flags = struct.unpack_from("<I", data, 4)[0] if len(data) >= 8 else 0
    if len(data) < 8:
        raise _Truncated
    multipart = bool(flags & 0x1000)

    def cstring() -> bytes:
        nonlocal pos
        end = data.find(b"\0", pos)
        if end < 0:
            raise _Truncated
        text, pos = data[pos:end], end + 1
        return text

    parts: list[dict[str, Any]] = []
    while True:
        header: dict[str, Any] = {}
        attributes = 0
        while True:
            name = cstring()
            if not name:
                break
            attributes += 1
            kind = cstring()
            if pos + 4 > len(data):
                raise _Truncated
            size = struct.unpack_from("<i", data, pos)[0]
            pos += 4
            if size < 0 or pos + size > len(data):
                raise _Truncated
            value = data[pos : pos + size]
            pos += size
            if name == b"dataWindow" and kind == b"box2i" and size == 16:
                header["data_window"] = struct.unpack("<4i", value)
            elif name == b"channels" and kind == b"chlist":
                header["channels"] = _chlist(value)
        if not attributes and parts:  # the empty header ending a multi-part list
            break
        parts.append(header)
        if not multipart:
            break
    return parts


def _chlist(value: bytes) -> list[tuple[str, int, int, int]]:
    out, pos = [], 0
    while pos < len(value) and value[pos] != 0:
        end = value.find(b"\0", pos)
        if end < 0 or end + 17 > len(value):
            break
        pixel_type, _, xs, ys = struct.unpack_from("<iiii", value, end + 1)
        out.append((value[pos:end].decode("utf-8", "replace"), pixel_type, xs, ys))
        pos = end + 17
    return out


def _check_exr_header(path: Path) -> None:
    """Refuse a damaged EXR from its header alone, before the library allocates anything:
    a header cut short (truncated), a data window that is empty, inverted or whose decoded
    channels exceed :data:`MAX_EXR_BYTES` (too large)."""
    size = path.stat().st_size
    chunk = 1 << 16  # a header is a few kB; read more only if it is longer
    while True:
        with open(path, "rb") as f:
            data = f.read(chunk)
        try:
            parts = _exr_headers(data)
            break
        except _Truncated:
            if len(data) >= size:
                raise ValueError(
                    f"{path}: damaged OpenEXR file: truncated (the header ends early, at "
                    f"{size} bytes)"
                ) from None
            chunk *= 16
    for header in parts:
        window = header.get("data_window")
        if window is None or "channels" not in header:
            raise ValueError(
                f"{path}: damaged OpenEXR file: no dataWindow or channels in its header"
            )
        xmin, ymin, xmax, ymax = window
        w, h = xmax - xmin + 1, ymax - ymin + 1
        if w < 1 or h < 1:
            raise ValueError(f"{path}: damaged OpenEXR file: empty data window {window}")
        samples = sum(
            -(-w // max(xs, 1)) * -(-h // max(ys, 1)) for *_, xs, ys in header["channels"]
        )
        decoded = 4 * samples
        if decoded > MAX_EXR_BYTES:
            raise ValueError(
                f"{path}: OpenEXR file too large (or a damaged header): it claims a {w}x{h} "
                f"data window with {len(header['channels'])} channel(s), "
                f"{decoded / 2**30:.3g} GiB decoded, over the {MAX_EXR_BYTES / 2**30:g} GiB "
                "sssbench reads"
            )


_STDERR_LOCK = threading.Lock()


def _flush_all() -> None:
    """Flush Python's and C's standard streams (``fflush(NULL)``)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def _quiet_stderr() -> Any:
    """Send file descriptors 1 and 2, and Python's ``sys.stdout`` / ``sys.stderr``, to a
    temporary file while the OpenEXR library runs (it prints its own errors at the C level and
    "Warning: …" lines through Python's stdout); yields a function returning what it wrote."""
    import io as _io

    text = _io.StringIO()
    _flush_all()  # what was written before goes where it was meant to
    with (
        _STDERR_LOCK,
        tempfile.TemporaryFile() as tmp,
        contextlib.redirect_stdout(text),
        contextlib.redirect_stderr(text),
    ):
        saved = {}
        for fd in (1, 2):
            with contextlib.suppress(OSError):  # a closed descriptor: nothing to redirect
                saved[fd] = os.dup(fd)
                os.dup2(tmp.fileno(), fd)

        def captured() -> str:
            _flush_all()
            tmp.seek(0)
            return tmp.read().decode("utf-8", "replace") + text.getvalue()

        try:
            yield captured
        finally:
            _flush_all()  # C stdio buffers the library's lines when stdout is not a terminal
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)


def _read_exr(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Header and channels (name -> pixel array as stored) of a single-part EXR."""
    _check_file(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != _EXR_MAGIC:
        raise ValueError(
            f"{path}: not an OpenEXR file (starts with {magic!r}, expected {_EXR_MAGIC!r})"
        )
    _check_exr_header(path)
    exr = _openexr()
    with _quiet_stderr() as captured:
        try:
            file = exr.File(str(path), separate_channels=True)
            parts = len(file.parts)
            if parts == 1:
                header = dict(file.header())
                channels = {name: np.asarray(c.pixels) for name, c in file.channels().items()}
        except Exception as exc:
            detail = f"{type(exc).__name__}: {exc}".replace("\n", " ")
            raise ValueError(f"{path}: damaged or truncated OpenEXR file ({detail})") from exc
        said = (captured().strip().splitlines() or [""])[0].replace(f"{path}: ", "").strip()
    if parts == 0:  # the library's answer to missing pixel data
        hint = f": {said[:160]}" if said else ""
        raise ValueError(
            f"{path}: damaged or truncated OpenEXR file (the OpenEXR library read no part{hint})"
        )
    if parts != 1:
        raise ValueError(
            f"{path}: has {parts} parts; sssbench reads single-part EXR files "
            "(one image; write batches as .npz)"
        )
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
    if _PROFILE_ID_CHANNEL in channels:
        ids = channels[_PROFILE_ID_CHANNEL]
        if ids.dtype != np.uint32:
            raise ValueError(
                f"{path}: channel {_PROFILE_ID_CHANNEL} has pixel type {ids.dtype}; expected "
                "UINT (integer material indices)"
            )
        if ids.shape != stacked.shape[-2:]:
            raise ValueError(
                f"{path}: channel {_PROFILE_ID_CHANNEL} is {ids.shape[1]}x{ids.shape[0]} but "
                f"the image is {stacked.shape[-1]}x{stacked.shape[-2]} (W x H)"
            )
        values["profile_id"] = torch.from_numpy(ids.astype(np.int64))[None, None]
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
    if gbuffer.profile_id is not None:
        ids = gbuffer.profile_id.detach().cpu()
        if int(ids.max()) > 2**32 - 1:
            raise ValueError(
                f"{path}: profile_id has values up to {int(ids.max())} but the OpenEXR channel "
                f"{_PROFILE_ID_CHANNEL} is UINT (at most 2^32 - 1); write a .npz file"
            )
        channels[_PROFILE_ID_CHANNEL] = ids[0, 0].numpy().astype(np.uint32)
    unwritten = [
        f.name
        for f in dataclass_fields(GBuffer)
        if f.name not in (*EXR_CHANNELS, "fov_y", "light_dir", "profile_id")
        and getattr(gbuffer, f.name) is not None
    ]
    if unwritten:  # a field added to GBuffer without an EXR layout: refuse, never drop
        raise ValueError(f"{path}: the OpenEXR layout has no place for field(s) {unwritten}")
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
#: fields stored with their integer dtype (not cast to the G-buffer's float dtype)
_INT_FIELDS = ("profile_id",)


def _read_gbuffer_npz(path: Path, dtype: torch.dtype | None) -> GBuffer:
    _check_file(path)
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
    stored = {k: arrays[k] for k in _NPZ_FIELDS if k in arrays and k not in _INT_FIELDS}
    ints = {k: arrays[k] for k in _INT_FIELDS if k in arrays}
    for k, a in ints.items():
        if a.dtype.kind not in "iu":
            raise ValueError(f"{path}: array {k} must have an integer dtype, got {a.dtype}")
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
    for k, a in ints.items():  # the stored integer dtype (uint32 and wider as int64)
        keep = a.dtype in (np.int8, np.uint8, np.int16, np.int32, np.int64)
        values[k] = torch.from_numpy(np.ascontiguousarray(a if keep else a.astype(np.int64)))
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
        IsADirectoryError: the path is a directory.
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
    suffix = _suffix(path)
    _check_write_target(path)
    if suffix == ".exr":
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
    _check_write_target(path)
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
    _check_file(Path(path))
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()[:16]

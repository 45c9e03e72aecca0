"""G-buffer and image files (sssbench.io): bit-exact round trips, files written by another
tool under the documented channel names, and one clear line for each kind of bad file."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.io import (
    load_scene_file,
    read_gbuffer,
    read_image_exr,
    scene_file_digest,
    write_gbuffer,
    write_image_exr,
)

TENSOR_FIELDS = ("diffuse", "depth", "albedo", "specular", "normal", "mask", "thickness")
H, W = 6, 5


def full_gbuffer(dtype: torch.dtype = torch.float32, batch: int = 1, seed: int = 0) -> GBuffer:
    """Every field set, with full-mantissa random values, a subnormal, zeros and -0.0."""
    gen = torch.Generator().manual_seed(seed)

    def rand(c: int, scale: float = 1.0) -> torch.Tensor:
        return torch.rand(batch, c, H, W, generator=gen, dtype=dtype) * scale

    specular = rand(3)
    specular[0, 0, 0, 0] = torch.finfo(torch.float32).tiny / 8  # a float32 subnormal
    normal = torch.nn.functional.normalize(rand(3) - 0.5, dim=1)
    normal[0, 0, 1, 1] = -0.0
    light = torch.nn.functional.normalize(torch.rand(batch, 3, generator=gen, dtype=dtype), dim=1)
    return GBuffer(
        diffuse=rand(3, 4.0),
        depth=300.0 + rand(1, 500.0),
        fov_y=0.4363323129985824,  # 25 degrees: not a float32 number
        albedo=rand(3),
        specular=specular,
        normal=normal,
        mask=(rand(1) > 0.3).to(dtype) * rand(1),
        thickness=rand(1, 20.0),
        light_dir=light,
    )


def assert_same(a: GBuffer, b: GBuffer) -> None:
    assert a.fov_y == b.fov_y
    for name in (*TENSOR_FIELDS, "light_dir"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype, name
            # bit for bit: equal values and the same sign of zero
            assert torch.equal(x, y), name
            assert torch.equal(torch.signbit(x), torch.signbit(y)), name


def write_raw_exr(path: Path, channels: dict[str, np.ndarray], **header: object) -> Path:
    """An EXR written by the OpenEXR binding directly (as a user's own tool would)."""
    OpenEXR.File(dict(header), dict(channels)).write(str(path))  # the binding edits its dict
    return path


def plane_channels(depth: float = 500.0, dtype: str = "f") -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    out = {f"diffuse.{c}": rng.random((H, W)).astype(dtype) for c in "RGB"}
    out["depth.Z"] = np.full((H, W), depth, dtype=dtype)
    return out


def subsampled_exr(path: Path) -> Path:
    """An uncompressed scanline EXR built byte by byte (the binding cannot write subsampled
    channels): ``diffuse.R/G/B`` 4x4 and ``depth.Z`` sampled every 2nd pixel (2x2)."""
    h = w = 4

    def attr(name: str, typ: str, payload: bytes) -> bytes:
        return f"{name}\0{typ}\0".encode() + struct.pack("<i", len(payload)) + payload

    chans = [("depth.Z", 2), ("diffuse.B", 1), ("diffuse.G", 1), ("diffuse.R", 1)]  # sorted
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, s, s) for n, s in chans)
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = b"".join(
        [
            attr("channels", "chlist", chlist + b"\0"),
            attr("compression", "compression", b"\0"),
            attr("dataWindow", "box2i", box),
            attr("displayWindow", "box2i", box),
            attr("fov_y", "float", struct.pack("<f", 0.5)),
            attr("lineOrder", "lineOrder", b"\0"),
            attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
            attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0)),
            attr("screenWindowWidth", "float", struct.pack("<f", 1.0)),
            attr("units", "string", b"mm"),
        ]
    )
    first = 8 + len(header) + 1 + 8 * h  # magic+version, header, its end byte, offset table
    chunks: list[bytes] = []
    offsets = []
    for y in range(h):
        data = b"".join(np.full(w // s, 500.0, "<f4").tobytes() for _, s in chans if y % s == 0)
        offsets.append(first + sum(len(c) for c in chunks))
        chunks.append(struct.pack("<ii", y, len(data)) + data)
    body = struct.pack(f"<{h}Q", *offsets) + b"".join(chunks)
    path.write_bytes(b"\x76\x2f\x31\x01" + struct.pack("<i", 2) + header + b"\0" + body)
    return path


def one_line_error(match: str, fn, *args, **kwargs) -> str:
    with pytest.raises(ValueError, match=match) as info:
        fn(*args, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".exr", ".npz"])
def test_float32_round_trip_is_bit_exact(tmp_path, suffix):
    g = full_gbuffer()
    path = write_gbuffer(tmp_path / f"g{suffix}", g)
    assert path == tmp_path / f"g{suffix}" and path.is_file()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left behind
    assert_same(read_gbuffer(path), g)


def test_npz_keeps_float64_and_batches_bit_exact(tmp_path):
    g = full_gbuffer(torch.float64, batch=2)
    assert_same(read_gbuffer(write_gbuffer(tmp_path / "g.npz", g)), g)


def test_only_the_fields_present_are_written_and_read(tmp_path):
    g = GBuffer(torch.rand(1, 3, H, W), torch.full((1, 1, H, W), 700.0), 0.3)
    for suffix in (".exr", ".npz"):
        assert_same(read_gbuffer(write_gbuffer(tmp_path / f"g{suffix}", g)), g)
    names = set(OpenEXR.File(str(tmp_path / "g.exr"), separate_channels=True).channels())
    assert names == {"diffuse.R", "diffuse.G", "diffuse.B", "depth.Z"}


def test_exr_header_and_channels_follow_the_documented_names(tmp_path):
    g = full_gbuffer()
    path = write_gbuffer(tmp_path / "g.exr", g)
    f = OpenEXR.File(str(path), separate_channels=True)
    header, channels = f.header(), f.channels()
    assert header["units"] == "mm"
    assert float(np.asarray(header["fov_y"]).item()) == g.fov_y
    assert header["sssbench_version"]
    for name, (field, c) in {
        "diffuse.G": ("diffuse", 1),
        "depth.Z": ("depth", 0),
        "normal.Z": ("normal", 2),
        "albedo.B": ("albedo", 2),
        "specular.R": ("specular", 0),
        "mask.A": ("mask", 0),
        "thickness.Y": ("thickness", 0),
    }.items():
        assert channels[name].pixels.dtype == np.float32
        np.testing.assert_array_equal(channels[name].pixels, getattr(g, field)[0, c].numpy())


def test_float64_to_exr_is_refused_unless_rounding_is_allowed(tmp_path):
    g = full_gbuffer(torch.float64)
    one_line_error("allow_rounding=True", write_gbuffer, tmp_path / "g.exr", g)
    assert not (tmp_path / "g.exr").exists()
    back = read_gbuffer(write_gbuffer(tmp_path / "g.exr", g, allow_rounding=True))
    assert back.dtype == torch.float32 and back.fov_y == g.fov_y  # fov_y is a double
    for name in TENSOR_FIELDS:
        # round to nearest float32, computed by numpy
        expected = getattr(g, name).numpy().astype(np.float32)
        np.testing.assert_array_equal(getattr(back, name).numpy(), expected)


def test_read_dtype_casts(tmp_path):
    g = full_gbuffer()
    back = read_gbuffer(write_gbuffer(tmp_path / "g.exr", g), dtype=torch.float64)
    assert_same(back, g.to(torch.float64))  # float32 -> float64 is exact


def test_users_file_with_half_channels_mask_y_and_float_fov(tmp_path):
    """Written by another tool: HALF pixels, ``mask.Y`` for the mask, a float fov_y attribute
    and extra channels (an integer object-ID AOV) that sssbench ignores."""
    chans = plane_channels(dtype="e")
    chans["mask.Y"] = np.linspace(0, 1, H * W, dtype=np.float16).reshape(H, W)
    chans["objectId"] = np.arange(H * W, dtype=np.uint32).reshape(H, W)
    path = write_raw_exr(tmp_path / "user.exr", chans, fov_y=0.5, units="mm")
    g = read_gbuffer(path)
    assert g.dtype == torch.float32 and g.fov_y == 0.5  # 0.5 is a float32 number
    np.testing.assert_array_equal(g.depth[0, 0].numpy(), 500.0)
    for i, c in enumerate("RGB"):  # HALF -> FLOAT widening is exact
        np.testing.assert_array_equal(g.diffuse[0, i].numpy(), chans[f"diffuse.{c}"].astype("f"))
    np.testing.assert_array_equal(g.mask[0, 0].numpy(), chans["mask.Y"].astype("f"))
    assert g.normal is None and g.light_dir is None


def test_image_round_trip_and_channels(tmp_path):
    image = torch.rand(1, 3, H, W) * 100
    image[0, 1, 2, 3] = math.inf  # written as it is: no clamping
    path = write_image_exr(tmp_path / "result.exr", image)
    back = read_image_exr(path)
    assert back.dtype == torch.float32 and torch.equal(back, image)
    chans = OpenEXR.File(str(path), separate_channels=True).channels()
    np.testing.assert_array_equal(chans["G"].pixels, image[0, 1].numpy())
    assert read_image_exr(path, dtype=torch.float64).dtype == torch.float64


def test_image_float64_needs_allow_rounding(tmp_path):
    image = torch.rand(1, 3, H, W, dtype=torch.float64)
    one_line_error("allow_rounding", write_image_exr, tmp_path / "r.exr", image)
    back = read_image_exr(write_image_exr(tmp_path / "r.exr", image, allow_rounding=True))
    np.testing.assert_array_equal(back.numpy(), image.numpy().astype(np.float32))
    with pytest.raises(ValueError, match=r"\(1, 3, H, W\)"):
        write_image_exr(tmp_path / "r2.exr", torch.rand(2, 3, H, W))
    path = write_raw_exr(tmp_path / "y.exr", {"Y": np.ones((H, W), "f")})
    msg = one_line_error("missing channel", read_image_exr, path)
    assert "R, G, B" in msg and "present: Y" in msg


# ----------------------------------------------------------------------------- bad files
def test_missing_channel_is_named_with_the_ones_present(tmp_path):
    chans = plane_channels()
    del chans["diffuse.G"]
    path = write_raw_exr(tmp_path / "g.exr", chans, fov_y=0.5, units="mm")
    msg = one_line_error("missing channel", read_gbuffer, path)
    assert str(path) in msg and "diffuse.G" in msg
    assert "channels present: depth.Z, diffuse.B, diffuse.R" in msg
    # an optional field with only some of its channels is an error too
    chans = plane_channels() | {"normal.X": np.zeros((H, W), "f")}
    path = write_raw_exr(tmp_path / "n.exr", chans, fov_y=0.5, units="mm")
    msg = one_line_error("missing channel", read_gbuffer, path)
    assert "normal.Y, normal.Z for normal" in msg


@pytest.mark.parametrize(
    "header, match",
    [
        ({"fov_y": 0.5, "units": "cm"}, "units is 'cm', expected 'mm'"),
        ({"fov_y": 0.5}, "no 'units' attribute"),
        ({"units": "mm"}, "no 'fov_y' attribute"),
        ({"fov_y": 0.0, "units": "mm"}, r"fov_y must lie in \(0, pi\)"),
        ({"fov_y": 3.5, "units": "mm"}, r"fov_y must lie in \(0, pi\)"),
        ({"fov_y": -0.5, "units": "mm"}, r"fov_y must lie in \(0, pi\)"),
        ({"fov_y": "wide", "units": "mm"}, "fov_y must be one real number"),
    ],
)
def test_bad_header(tmp_path, header, match):
    path = write_raw_exr(tmp_path / "g.exr", plane_channels(), **header)
    assert str(path) in one_line_error(match, read_gbuffer, path)


@pytest.mark.parametrize(
    "value, counts",
    [(math.nan, "1 NaN, 0 inf and 0 values <= 0"), (math.inf, "0 NaN, 1 inf and 0 values"),
     (-2.0, "0 NaN, 0 inf and 1 values <= 0"), (0.0, "0 NaN, 0 inf and 1 values <= 0")],
)  # fmt: skip
@pytest.mark.parametrize("suffix", [".exr", ".npz"])
def test_bad_depth_names_the_first_pixel(tmp_path, value, counts, suffix):
    g = GBuffer(torch.rand(1, 3, H, W), torch.full((1, 1, H, W), 500.0), 0.5)
    good = write_gbuffer(tmp_path / f"good{suffix}", g)
    depth = g.depth.clone()
    depth[0, 0, 4, 2] = value
    path = tmp_path / f"g{suffix}"
    if suffix == ".exr":
        write_raw_exr(
            path, plane_channels() | {"depth.Z": depth[0, 0].numpy()}, fov_y=0.5, units="mm"
        )
    else:
        arrays = dict(np.load(good))
        np.savez(path, **(arrays | {"depth": depth.numpy()}))
    msg = one_line_error("must be finite and > 0 mm", read_gbuffer, path)
    assert str(path) in msg and counts in msg and "row 4, column 2" in msg


def test_not_an_exr(tmp_path):
    path = tmp_path / "g.exr"
    path.write_text("P3\n1 1\n255\n0 0 0\n")
    assert str(path) in one_line_error("not an OpenEXR file", read_gbuffer, path)
    truncated = write_gbuffer(tmp_path / "t.exr", full_gbuffer())
    truncated.write_bytes(truncated.read_bytes()[:200])  # right magic, broken file
    one_line_error("damaged OpenEXR file", read_gbuffer, truncated)
    (tmp_path / "g.npz").write_text("not a zip")
    one_line_error("not a readable .npz", read_gbuffer, tmp_path / "g.npz")
    one_line_error("unknown G-buffer file type '.png'", read_gbuffer, tmp_path / "g.png")
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_gbuffer(tmp_path / "missing.exr")


def test_mismatched_sizes(tmp_path):
    path = subsampled_exr(tmp_path / "sub.exr")
    assert OpenEXR.File(str(path), separate_channels=True).channels()["depth.Z"].xSampling == 2
    msg = one_line_error("mismatched sizes", read_gbuffer, path)
    assert str(path) in msg and "diffuse.R 4x4" in msg and "depth.Z 2x2" in msg
    g = GBuffer(torch.rand(1, 3, H, W), torch.full((1, 1, H, W), 500.0), 0.5)
    arrays = dict(np.load(write_gbuffer(tmp_path / "good.npz", g)))
    np.savez(tmp_path / "g.npz", **(arrays | {"mask": np.ones((1, 1, H, W + 1), "f")}))
    msg = one_line_error("must have shape", read_gbuffer, tmp_path / "g.npz")
    assert str(tmp_path / "g.npz") in msg and f"(1, 1, {H}, {W + 1})" in msg


def test_npz_missing_array_units_and_dtype(tmp_path):
    g = GBuffer(torch.rand(1, 3, H, W), torch.full((1, 1, H, W), 500.0), 0.5)
    arrays = dict(np.load(write_gbuffer(tmp_path / "good.npz", g)))
    np.savez(tmp_path / "a.npz", **{k: v for k, v in arrays.items() if k != "depth"})
    msg = one_line_error("missing array 'depth'", read_gbuffer, tmp_path / "a.npz")
    assert "arrays present: diffuse, fov_y, sssbench_version, units" in msg
    np.savez(tmp_path / "u.npz", **(arrays | {"units": np.array("m")}))
    one_line_error("units is 'm', expected 'mm'", read_gbuffer, tmp_path / "u.npz")
    np.savez(tmp_path / "i.npz", **(arrays | {"diffuse": np.ones((1, 3, H, W), np.int32)}))
    one_line_error("float32 or float64, got diffuse int32", read_gbuffer, tmp_path / "i.npz")


def test_out_of_range_field_names_the_file(tmp_path):
    chans = plane_channels() | {"albedo." + c: np.full((H, W), 1.5, "f") for c in "RGB"}
    path = write_raw_exr(tmp_path / "g.exr", chans, fov_y=0.5, units="mm")
    msg = one_line_error(r"albedo must lie in \[0, 1\]", read_gbuffer, path)
    assert msg.startswith(str(path))


def test_exr_holds_one_image(tmp_path):
    msg = one_line_error("B=2", write_gbuffer, tmp_path / "g.exr", full_gbuffer(batch=2))
    assert ".npz" in msg


# ----------------------------------------------------------------------------- scene files
def test_load_scene_file_fields(tmp_path):
    g = full_gbuffer()
    path = write_gbuffer(tmp_path / "g.exr", g)
    got = load_scene_file(path, fields=("mask", "normal"), dtype=torch.float64)
    assert got.dtype == torch.float64 and got.albedo is None and got.thickness is None
    assert torch.equal(got.mask, g.mask.double()) and torch.equal(got.normal, g.normal.double())
    assert torch.equal(got.light_dir, g.light_dir.double())
    assert_same(load_scene_file(path), g)  # fields=None keeps all

    bare = g.replace(mask=None, thickness=None, light_dir=None)
    wanted = ["mask", "normal", "thickness", "light_dir"]
    msg = one_line_error(
        "needs field", load_scene_file, write_gbuffer(tmp_path / "bare.exr", bare), fields=wanted
    )
    assert "mask, thickness, light_dir that the file does not have" in msg
    assert "(it has diffuse, depth, albedo, specular, normal)" in msg
    assert "add mask.A, thickness.Y, attribute light_dir" in msg
    msg = one_line_error(
        "needs field", load_scene_file, write_gbuffer(tmp_path / "bare.npz", bare), fields=wanted
    )
    assert "add array(s) mask, thickness, light_dir" in msg
    with pytest.raises(ValueError, match="subset of"):
        load_scene_file(path, fields=["diffuse"])
    with pytest.raises(TypeError, match="collection"):
        load_scene_file(path, fields="mask")


def test_scene_file_digest_follows_content(tmp_path):
    g = full_gbuffer()
    a = write_gbuffer(tmp_path / "a.exr", g)
    b = write_gbuffer(tmp_path / "b.exr", g)
    depth = g.depth.clone()
    depth[0, 0, 0, 0] = torch.nextafter(depth[0, 0, 0, 0], torch.tensor(math.inf))  # one ulp
    c = write_gbuffer(tmp_path / "c.exr", g.replace(depth=depth))
    assert scene_file_digest(a) == scene_file_digest(b) != scene_file_digest(c)


@pytest.mark.parametrize("suffix", [".exr", ".npz"])
def test_read_back_scene_gives_the_same_sss(tmp_path, suffix):
    """A scene written and read back scatters to exactly the same image."""
    import data_synth
    from sssbench.ops import PreintegratedSSS
    from sssbench.ops.pipeline import Pipeline
    from sssbench.profiles import SumOfGaussians

    g = data_synth.make_scene("head", (48, 40), fields=data_synth.OPTIONAL_FIELDS)
    back = read_gbuffer(write_gbuffer(tmp_path / f"head{suffix}", g))
    assert_same(back, g)
    pipeline = Pipeline(PreintegratedSSS(SumOfGaussians.from_table("skin_jg10")))
    with torch.inference_mode():
        ours, theirs = pipeline.run(back).image, pipeline.run(g).image
    assert torch.equal(ours, theirs)
    assert not torch.equal(ours, g.diffuse)  # it did scatter

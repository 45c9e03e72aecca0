"""Issue 29 (no silent wrong answer, round three): the surfaces added since issue 15 under
hostile input, one section per failure class (``docs/reliability.md``). Each test failed on the
code before its fix."""

from __future__ import annotations

import logging
import math
import sqlite3
import struct
from dataclasses import fields as dataclass_fields

import numpy as np
import pytest
import torch

import data_synth
import sssbench
import sssbench._checks as checks
import sssbench.io as sio
import sssbench.ops._overlap as overlap
from sssbench import GBuffer
from sssbench.ops import PreintegratedSSS, SumOfGaussiansSSS
from sssbench.ops.gather import Stretch
from sssbench.ops.rotation import random_rotation
from sssbench.profiles import BurleyNormalized, SumOfGaussians


def flat(h: int = 6, w: int = 5, dtype: torch.dtype = torch.float32) -> GBuffer:
    gen = torch.Generator().manual_seed(3)
    return GBuffer(
        torch.rand(1, 3, h, w, generator=gen).to(dtype),
        torch.full((1, 1, h, w), 300.0, dtype=dtype),
        0.5,
    )


# ----------------------------------------------------------------------------- 1. seeds
WIDE = [2**32, 2**32 + 5, 2**40, 2**63 - 1, 2**64]


@pytest.mark.parametrize("seed", WIDE)
def test_check_seed_refuses_what_the_generator_cannot_honour(seed):
    with pytest.raises(ValueError, match=r"^seed must be an integer seed in \[0, 4294967295\]"):
        checks.check_seed("seed", seed)


def test_check_seed_keeps_every_bit_it_accepts():
    assert checks.check_seed("seed", checks.MAX_SEED) == checks.MAX_SEED
    a = torch.rand(4, generator=torch.Generator().manual_seed(checks.MAX_SEED))
    b = torch.rand(4, generator=torch.Generator().manual_seed(checks.MAX_SEED - 2**31))
    assert not torch.equal(a, b)  # bit 31 is honoured


def test_derived_seeds_stay_in_range_and_apart():
    seeds = {checks.derive_seed(checks.MAX_SEED, "batch", b) for b in range(1000)}
    assert len(seeds) == 1000 and max(seeds) <= checks.MAX_SEED


@pytest.mark.parametrize(
    "call",
    [
        lambda s: random_rotation(flat(), 0.1, s),
        lambda s: PreintegratedSSS(BurleyNormalized([1.0] * 3, [0.8] * 3), 5, seed=s),
        lambda s: data_synth.make_scene("face", (8, 8), s),
        lambda s: __import__("sssbench.mc.walk", fromlist=["walk"]).walk(0.5, photons=8, seed=s),
        lambda s: __import__("sssbench.tune.optimise", fromlist=["x"]).TrainingScene(
            "face", seed=s
        ),
    ],
    ids=["rotation", "method", "scene", "walk", "training_scene"],
)
def test_every_api_refuses_a_seed_wider_than_32_bits(call):
    # before: 5 and 2**32 + 5 gave the same angles / scene / photons without a word
    with pytest.raises(ValueError, match="seed must be an integer seed in"):
        call(2**32 + 5)


# ----------------------------------------------------------------------------- 5. names
def test_scene_mc_names_the_seed_the_user_gave():
    from sssbench.mc.scene import scene_mc

    g = data_synth.make_scene("step_edge", (8, 8), fields=[])
    with pytest.raises(ValueError, match=r"seed .* got -1$"):  # not "-7919"
        scene_mc("step_edge", g, {}, photons=60, batches=2, seed=-1, cache=False)


@pytest.mark.parametrize("mfp", [1e30, 1e-30])
def test_burley_mean_free_path_is_named_not_the_derived_d(mfp):
    with pytest.raises(ValueError, match="^mfp_mm"):
        BurleyNormalized.from_albedo_mfp(0.5, mfp)


def test_burley_mfp_whose_d_leaves_the_range_names_mfp_mm():
    # ℓ inside the length range, d = ℓ / s(A) below it: the message still names mfp_mm
    with pytest.raises(ValueError, match="^mfp_mm must give d"):
        BurleyNormalized.from_albedo_mfp(0.9, 1.5e-6)


def test_burley_albedo_mfp_names_fit_not_kind():
    from sssbench.profiles.burley import burley_albedo_mfp

    with pytest.raises(ValueError, match="^fit must be"):
        burley_albedo_mfp("x", 0.5, 1.0, "nope")


# ----------------------------------------------------------------------------- 6. damaged files
def _exr(tmp_path) -> bytes:
    g = flat()
    return sio.write_gbuffer(tmp_path / "ok.exr", g).read_bytes()


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.6, 0.9, 0.99])
def test_a_truncated_exr_is_one_line_and_nothing_on_stdout_or_stderr(tmp_path, capfd, fraction):
    data = _exr(tmp_path)
    cut = tmp_path / "cut.exr"
    cut.write_bytes(data[: max(8, int(len(data) * fraction))])
    capfd.readouterr()
    with pytest.raises(ValueError) as info:
        sio.read_gbuffer(cut)
    msg = str(info.value)
    assert "\n" not in msg and "truncated" in msg and "damaged" in msg, msg
    assert "0 parts" not in msg
    out, err = capfd.readouterr()
    assert (out, err) == ("", "")  # the binding's own warnings are swallowed


def test_a_header_claiming_65536_squared_is_too_large_before_any_allocation(
    tmp_path, capfd, monkeypatch
):
    data = _exr(tmp_path)
    tag = b"dataWindow\0box2i\0"
    at = data.index(tag) + len(tag) + 4
    big = tmp_path / "big.exr"
    big.write_bytes(data[:at] + struct.pack("<4i", 0, 0, 65535, 65535) + data[at + 16 :])

    def no_binding():
        raise AssertionError("the OpenEXR library was asked to read a 16 GiB image")

    monkeypatch.setattr(sio, "_openexr", no_binding)
    capfd.readouterr()
    with pytest.raises(ValueError, match=r"too large.*65536x65536") as info:
        sio.read_gbuffer(big)
    assert "\n" not in str(info.value)
    assert capfd.readouterr() == ("", "")


def test_an_intact_exr_still_reads_without_output(tmp_path, capfd):
    _exr(tmp_path)
    capfd.readouterr()
    assert sio.read_gbuffer(tmp_path / "ok.exr").shape == (1, 6, 5)
    assert capfd.readouterr() == ("", "")


# ----------------------------------------------------------------------------- 7. directories
@pytest.mark.parametrize("suffix", [".exr", ".npz"])
def test_a_directory_is_a_directory_not_a_missing_file(tmp_path, suffix):
    d = tmp_path / f"scene{suffix}"
    d.mkdir()
    for call in (
        lambda: sio.read_gbuffer(d),
        lambda: sio.load_scene_file(d),
        lambda: sio.write_gbuffer(d, flat()),
        lambda: sio.scene_file_digest(d),
    ):
        with pytest.raises(IsADirectoryError, match="is a directory"):
            call()
    with pytest.raises(IsADirectoryError, match="is a directory"):
        sio.read_image_exr(tmp_path / "scene.exr") if suffix == ".exr" else sio.read_gbuffer(d)


# ----------------------------------------------------------------------------- 8. fields
def every_field(dtype: torch.dtype = torch.float32) -> GBuffer:
    gen = torch.Generator().manual_seed(1)
    h, w = 6, 5

    def rand(c: int, scale: float = 1.0) -> torch.Tensor:
        return (torch.rand(1, c, h, w, generator=gen, dtype=torch.float64) * scale).to(dtype)

    g = GBuffer(
        diffuse=rand(3, 4.0),
        depth=300.0 + rand(1, 50.0),
        fov_y=0.4363323129985824,
        albedo=rand(3),
        specular=rand(3),
        normal=torch.nn.functional.normalize(rand(3) + 0.1, dim=1),
        mask=rand(1),
        thickness=rand(1, 20.0),
        light_dir=torch.nn.functional.normalize(torch.rand(1, 3, generator=gen), dim=1).to(dtype),
        profile_id=torch.randint(0, 7, (1, 1, h, w), generator=gen),
    )
    unset = [f.name for f in dataclass_fields(GBuffer) if getattr(g, f.name) is None]
    assert not unset, f"the test must set every GBuffer field, missing {unset}"
    return g


@pytest.mark.parametrize("suffix", [".exr", ".npz"])
def test_every_gbuffer_field_survives_both_formats(tmp_path, suffix):
    g = every_field()
    back = sio.read_gbuffer(sio.write_gbuffer(tmp_path / f"g{suffix}", g))
    for f in dataclass_fields(GBuffer):
        a, b = getattr(g, f.name), getattr(back, f.name)
        assert b is not None, f"{f.name} lost through {suffix}"
        if isinstance(a, torch.Tensor):
            assert torch.equal(a.to(b.dtype), b), f.name
        else:
            assert a == b, f.name


def test_profile_id_keeps_its_integer_dtype_in_npz(tmp_path):
    g = every_field().replace(profile_id=torch.zeros(1, 1, 6, 5, dtype=torch.int16))
    back = sio.read_gbuffer(sio.write_gbuffer(tmp_path / "g.npz", g))
    assert back.profile_id.dtype == torch.int16


def test_profile_id_beyond_uint32_is_refused_for_exr_naming_it(tmp_path):
    ids = torch.full((1, 1, 6, 5), 2**33, dtype=torch.int64)
    with pytest.raises(ValueError, match="profile_id"):
        sio.write_gbuffer(tmp_path / "g.exr", every_field().replace(profile_id=ids))
    assert not (tmp_path / "g.exr").exists()


# ----------------------------------------------------------------------------- 10. degenerate MC
def test_whole_scene_mc_without_scattering_is_a_clear_error_not_nan():
    from sssbench.mc.scene import scene_mc

    g = data_synth.make_scene("step_edge", (8, 8), fields=[])
    with pytest.raises(ValueError, match="sigma_s_prime = 0"):
        scene_mc("step_edge", g, {}, ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0), photons=60,
                 batches=2, cache=False)  # fmt: skip
    with pytest.raises(ValueError, match="channel.*G"):
        scene_mc("step_edge", g, {}, ((1.0, 0.0, 1.0), (1.0, 1.0, 1.0), 1.0), photons=60,
                 batches=2, cache=False)  # fmt: skip


# ----------------------------------------------------------------------------- 11. the fit
def test_rel_rms_loss_has_a_finite_gradient_at_an_exact_match():
    from sssbench.tune.optimise import rel_rms_loss

    x = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    rel_rms_loss(x, x.detach(), None).backward()
    assert bool(torch.isfinite(x.grad).all())


def test_a_training_term_reaching_zero_keeps_the_fit_finite():
    from sssbench.kernels.parametrise import SymmetricTaps
    from sssbench.tune.optimise import fit_taps

    profile = SumOfGaussians.from_table("skin_jg10")
    g = data_synth.make_scene("step_edge", (12, 12), pixel_mm=0.5, dtype=torch.float64)
    method = PreintegratedSSS(profile, 5, follow_surface=None)
    start = SymmetricTaps(method.kernel)
    saved = method.kernel
    with torch.no_grad(), sssbench.backend("torch"):  # the fit's own kernel and backend
        method.kernel = start.value()["kernel"]
        exact = method(g)  # the start matches this problem bit for bit: its term is 0
    method.kernel = saved
    other = exact * 1.1
    fit = fit_taps(method, [(g, exact), (g, other)], start, steps=3, lr=0.05)
    assert fit.losses[0] > 0
    assert all(math.isfinite(v) for v in fit.losses), fit.losses
    assert bool(torch.isfinite(fit.kernel.offsets).all())
    assert bool(torch.isfinite(fit.kernel.weights).all())


def test_a_non_finite_training_loss_fails_clearly():
    from sssbench.tune.optimise import fit_taps

    g = data_synth.make_scene("step_edge", (8, 8), pixel_mm=0.5, dtype=torch.float64)
    method = PreintegratedSSS(SumOfGaussians.from_table("skin_jg10"), 3, follow_surface=None)
    dark = torch.zeros_like(g.diffuse)  # Σ m R² = 0: the relative error is 0/0
    with pytest.raises(ValueError, match="training loss is (nan|inf)|not finite"):
        fit_taps(method, [(g, dark)], method.kernel, steps=2, lr=0.05)


# ----------------------------------------------------------------------------- 12. consoles
@pytest.mark.parametrize("where", ["a_directory", "under_a_file"])
def test_exporter_unwritable_out_is_one_line_exit_2(tmp_path, capsys, where):
    from sssbench.export import main

    (tmp_path / "file").write_text("x")
    out = tmp_path if where == "a_directory" else tmp_path / "file" / "k.glsl"
    assert main(["method=preintegrated", "samples=5", "--format", "glsl", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sssbench-export-kernel: --out"), lines
    assert "Traceback" not in captured.err


def test_report_unwritable_out_is_one_line_exit_2(tmp_path, capsys):
    from sssbench import report
    from sssbench.store.tracking import RunRecord, RunStore

    store = RunStore(tmp_path / "s.sqlite")
    store.record(RunRecord(config={"scene": "s", "method": "m"}, status="failed", error="x"))
    (tmp_path / "file").write_text("x")
    assert report.main([str(store.path), "--out", str(tmp_path / "file" / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sssbench-report: "), err


# ----------------------------------------------------------------------------- 13. readers
def old_store(path) -> None:
    """A store as written before the ``runs_one_ok`` index (tracking.py's migration): the
    same tables without that index, two ``ok`` rows of one point, a rollback journal."""
    from sssbench.store.tracking import _SCHEMA

    schema = ";".join(s for s in _SCHEMA.split(";") if "runs_one_ok" not in s)
    with sqlite3.connect(path) as conn:
        conn.execute("PRAGMA journal_mode = delete")
        conn.executescript(schema)
        for i, status in enumerate(["ok", "ok", "failed"]):
            conn.execute(
                "INSERT INTO runs (config_hash, config_json, scene, method, status, "
                "started_at, finished_at, rel_rms) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                ("h1", '{"scene": "s", "method": "m"}', "s", "m", status,
                 f"2024-01-0{i + 1}", f"2024-01-0{i + 1}", 0.1 * (i + 1)),
            )  # fmt: skip
    conn.close()


def test_report_on_an_old_store_leaves_it_byte_identical(tmp_path, capsys):
    from sssbench import report

    path = tmp_path / "old.sqlite"
    old_store(path)
    before = path.read_bytes()
    files_before = sorted(p.name for p in tmp_path.iterdir())
    assert report.main([str(path), "--out", str(tmp_path / "out")]) == 0
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "out") == files_before


def test_writing_migrates_an_old_store_after_a_backup_and_says_so(tmp_path, caplog):
    from sssbench.store.tracking import RunStore

    path = tmp_path / "old.sqlite"
    old_store(path)
    before = path.read_bytes()
    with caplog.at_level(logging.WARNING, logger="sssbench.store.tracking"):
        store = RunStore(path)
    backups = list(tmp_path.glob("old.sqlite.pre-migration-*.bak"))
    assert len(backups) == 1
    assert "migrating" in caplog.text and str(backups[0]) in caplog.text
    with sqlite3.connect(backups[0]) as conn:  # the backup holds the rows the migration drops
        assert conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0] == 3
    conn.close()
    assert len(store) == 2 and path.read_bytes() != before


def test_a_read_only_store_refuses_to_record(tmp_path):
    from sssbench.store.tracking import RunRecord, RunStore

    path = tmp_path / "old.sqlite"
    old_store(path)
    store = RunStore(path, readonly=True)
    assert [r["rel_rms"] for r in store.runs(latest=True)] == [0.30000000000000004]
    with pytest.raises(ValueError, match="read-only"):
        store.record(RunRecord(config={"a": 1}, status="failed", error="x"))


def test_report_reads_a_wal_store_without_writing(tmp_path, capsys):
    from sssbench import report
    from sssbench.store.tracking import RunRecord, RunStore

    store = RunStore(tmp_path / "s.sqlite")
    store.record(RunRecord(config={"scene": "s", "method": "m"}, status="ok", metrics={}))
    before = store.path.read_bytes()
    files = sorted(p.name for p in tmp_path.iterdir())
    assert report.main([str(store.path), "--out", str(tmp_path / "out")]) == 0
    assert store.path.read_bytes() == before
    # no -wal / -shm left beside it (a plain mode=ro connection to WAL creates both)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "out") == files


# ----------------------------------------------------------------------------- 14. constructors
def test_a_bad_stretch_is_refused_even_when_lod_culls_every_pass():
    profile = SumOfGaussians.from_table("skin_jg10")

    def build_and_run():  # before: LOD culled every pass, so nothing looked at ssslevel
        op = SumOfGaussiansSSS(profile, stretch=Stretch(ssslevel=-1.0), lod_threshold=1e6)
        return op(flat())

    with pytest.raises(ValueError, match="ssslevel"):
        build_and_run()


def test_jg10_stretch_refuses_a_zero_ssslevel_by_its_name():
    from sssbench.ops import jg10_stretch

    with pytest.raises(ValueError, match="^ssslevel"):
        jg10_stretch(100, ssslevel=0.0)


# ----------------------------------------------------------------------------- 15. overlap
def test_in_place_on_a_window_view_is_accepted_and_equals_the_copy():
    big = torch.rand(1, 3, 20, 24, dtype=torch.float64)
    depth = torch.full((1, 1, 12, 15), 300.0, dtype=torch.float64)
    op = PreintegratedSSS(SumOfGaussians.from_table("skin_jg10"), 5, follow_surface=None)
    window = big[:, :, 4:16, 5:20]
    expected = op(GBuffer(window.clone(), depth, 0.5))
    outside = big.clone()
    out = op(GBuffer(window, depth, 0.5), inplace=True)
    assert out.data_ptr() == window.data_ptr()
    torch.testing.assert_close(big[:, :, 4:16, 5:20], expected, rtol=0, atol=1e-12)
    mask = torch.ones_like(big, dtype=torch.bool)
    mask[:, :, 4:16, 5:20] = False
    assert torch.equal(big[mask], outside[mask])  # nothing outside the window written


def test_interleaved_disjoint_views_do_not_share_memory():
    x = torch.zeros(2, 3, 8, 8)
    assert not overlap.shares_memory(x[..., ::2], x[..., 1::2])
    assert overlap.shares_memory(x[..., ::2], x[..., 2::4])
    assert not overlap.has_internal_overlap(x[:, :, 1:5, 2:7])
    assert overlap.has_internal_overlap(x[:, :1].expand(2, 3, 8, 8))


def _addresses(t: torch.Tensor) -> set[int]:
    """Brute force: every byte address an element of ``t`` covers."""
    item = t.element_size()
    idx = np.indices(t.shape).reshape(t.ndim, -1).T if t.numel() else np.zeros((0, t.ndim), int)
    out: set[int] = set()
    for i in idx:
        a = t.data_ptr() + item * int(sum(int(k) * s for k, s in zip(i, t.stride(), strict=True)))
        out.update(range(a, a + item))
    return out


def _random_view(rng: np.random.Generator, base: torch.Tensor) -> torch.Tensor:
    """A strided view (torch has no negative strides) with stride-0, interleaved and
    overlapping dimensions, at a random offset of ``base``."""
    ndim = int(rng.integers(1, 4))
    sizes = [int(rng.integers(1, 5)) for _ in range(ndim)]
    strides = [int(rng.integers(0, 7)) for _ in range(ndim)]
    span = sum((n - 1) * s for n, s in zip(sizes, strides, strict=True)) + 1
    offset = int(rng.integers(0, base.numel() - span + 1))
    return base.as_strided(sizes, strides, offset)


def test_exact_overlap_equals_a_brute_force_oracle_on_random_views():
    rng = np.random.default_rng(29)
    base = torch.zeros(200, dtype=torch.float32)
    for _ in range(400):
        a, b = _random_view(rng, base), _random_view(rng, base)
        sa, sb = _addresses(a), _addresses(b)
        assert overlap.shares_memory(a, b) == bool(sa & sb), (
            a.shape,
            a.stride(),
            b.shape,
            b.stride(),
        )
        distinct = len(sa) == a.numel() * a.element_size()
        assert overlap.has_internal_overlap(a) == (not distinct), (a.shape, a.stride())
    # different element sizes over one storage: bytes, not elements
    raw = torch.zeros(64, dtype=torch.float64)
    as32 = raw.view(torch.float32)
    assert overlap.shares_memory(raw[1:2], as32[3:4]) and not overlap.shares_memory(
        raw[1:2], as32[4:6]
    )


def test_overlap_oracle_helpers_are_sane():
    x = torch.zeros(10)
    assert _addresses(x[2:4]) == set(range(x.data_ptr() + 8, x.data_ptr() + 16))


@pytest.mark.parametrize("kw", [dict(lod=float("nan")), dict(lod="no"), dict(unblurred_first=0.0)])
def test_sum_of_gaussians_flags_are_checked_on_construction(kw):
    # a NaN or "no" read as True: the same class (a constructor leaving a value unchecked)
    with pytest.raises(TypeError, match=next(iter(kw))):
        SumOfGaussiansSSS(SumOfGaussians.from_table("skin_jg10"), **kw)


def test_a_stochastic_run_at_the_largest_seed_keeps_its_further_seeds_valid(tmp_path, monkeypatch):
    """The bias / noise split evaluates seeds s + 1 … s + K − 1: at s = 2³² − 1 they wrap within
    the generators' range (before: 2³², which the generator folds onto seed 0)."""
    from specs import small_spec

    from sssbench.run import registry, stochastic

    seen = []

    class Image:
        image = torch.zeros(1)

    class Pipeline:
        def run(self, gbuffer):
            return Image()

    def method_from_spec(spec, profile, seed, params):
        seen.append(checks.check_seed("seed", seed))
        return object()

    monkeypatch.setattr(stochastic, "is_stochastic", lambda *a: True)
    monkeypatch.setattr(registry, "method_from_spec", method_from_spec)
    monkeypatch.setattr(registry, "build_pipeline", lambda *a, **k: Pipeline())
    monkeypatch.setattr(stochastic, "bias_noise", lambda *a: {})
    spec = small_spec(tmp_path, seed=checks.MAX_SEED, seeds=3)
    stochastic.seed_split(spec, object(), None, None, torch.zeros(1), torch.zeros(1), None)
    assert seen == [0, 1]

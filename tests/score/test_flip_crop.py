"""FLIP evaluated only over the mask's bounding box (``metrics.flip_map_over``): bit for bit
the whole image's map on every pixel it keeps, NaN elsewhere, and never read there.

The expected values come from outside the code under test (the crop and the memo): the torch
FLIP map (``flip_ldr.flip_ldr_map``) of the whole images, called here directly (no memo, no
crop), itself checked against NVIDIA's ``flip_evaluator.evaluate`` within 1e-5 here and in
``tests/score/test_flip_ldr.py``."""

from __future__ import annotations

import math

import flip_evaluator
import numpy as np
import pytest
import torch

from sssbench.score import metrics, verdict
from sssbench.score.flip_ldr import flip_ldr_map
from sssbench.score.metrics import flip_map_over, flip_support
from tests.specs import small_spec

H, W = 80, 104


def _flip_whole(res: torch.Tensor, ref: torch.Tensor, ppd: float = 67.0) -> np.ndarray:
    """FLIP of the whole tone-mapped images, ``(B, H, W)``, as ``metrics.flip_map`` documents
    it, without any memo or crop."""
    maps = []
    for i in range(ref.shape[0]):
        a, b = (
            np.ascontiguousarray(
                metrics.tonemap(x[i : i + 1].clamp(min=0.0).double())[0].permute(1, 2, 0).numpy(),
                dtype=np.float32,
            )
            for x in (ref, res)
        )
        fmap, _, _ = flip_evaluator.evaluate(
            a, b, "LDR", inputsRGB=True, applyMagma=False, computeMeanError=False,
            parameters={"ppd": ppd},
        )  # fmt: skip
        ours = flip_ldr_map(
            torch.from_numpy(a).permute(2, 0, 1), torch.from_numpy(b).permute(2, 0, 1), ppd
        )
        assert np.abs(ours - np.asarray(fmap, dtype=np.float32)[..., 0]).max() <= 1e-5
        maps.append(ours)
    return np.stack(maps)


def _images(kind: str, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """``(result, reference)`` ``(1, 3, H, W)``: random noise, or edges, stripes and a dot
    (structured) with a noisy, blurred-looking result."""
    gen = torch.Generator().manual_seed(seed)
    if kind == "random":
        ref = torch.rand(1, 3, H, W, generator=gen, dtype=torch.float64) * 2.0
        res = torch.rand(1, 3, H, W, generator=gen, dtype=torch.float64) * 2.0
        return res, ref
    yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    ref = torch.stack(
        [
            (xx > W // 2).double() * 1.5 + 0.1,
            ((xx + yy) % 13 < 6).double() * 0.7,
            torch.exp(-((xx - 30.0) ** 2 + (yy - 20.0) ** 2) / 20.0) * 3.0,
        ]
    )[None]
    res = (ref * 0.9 + 0.05 * torch.randn(ref.shape, generator=gen, dtype=torch.float64)).abs()
    return res, ref


def _mask(*boxes: tuple[int, int, int, int], soft: bool = False) -> torch.Tensor:
    """A ``(1, 1, H, W)`` mask, 1 (or 0.3..1 if ``soft``) on the boxes ``(y0, y1, x0, x1)``."""
    m = torch.zeros(1, 1, H, W, dtype=torch.float64)
    for y0, y1, x0, x1 in boxes:
        m[..., y0:y1, x0:x1] = 1.0
    if soft:
        m = m * torch.linspace(0.3, 1.0, W, dtype=torch.float64)
    return m


MASKS = {
    "inner_blob": _mask((30, 45, 40, 60)),
    "one_pixel": _mask((50, 51, 70, 71)),
    "touches_top_left": _mask((0, 12, 0, 20)),
    "touches_bottom_right": _mask((60, H, 85, W)),
    "two_blobs": _mask((5, 15, 10, 22), (60, 72, 80, 96)),
    "near_border_not_on_it": _mask((3, 10, 4, 9)),
    "soft": _mask((25, 50, 30, 70), soft=True),
    "everything": torch.ones(1, 1, H, W, dtype=torch.float64),
}


def test_flip_support_is_the_filters_radius_and_enough():
    """10 px (the CSF filter's radius) at 67 ppd, + 1 guard; grows with ppd."""
    assert flip_support(67.0) == 11
    assert flip_support(134.0) == 20  # CSF: ceil(3 * 0.04502 * 134) = ceil(18.1) = 19, + 1
    assert flip_support(10.0) < flip_support(67.0) < flip_support(200.0)
    with pytest.raises(ValueError, match="ppd"):
        flip_support(0.0)


@pytest.mark.parametrize("kind", ["random", "structured"])
@pytest.mark.parametrize("name", sorted(MASKS))
def test_crop_map_is_the_whole_map_bit_for_bit_on_the_mask(kind, name):
    res, ref = _images(kind, seed=len(name))
    mask = MASKS[name]
    whole = _flip_whole(res, ref)
    over = flip_map_over(res, ref, mask)
    assert over.shape == whole.shape and over.dtype == np.float32
    on = mask[:, 0].numpy() > 0
    assert not np.isnan(over[on]).any()
    assert np.array_equal(over[on], whole[on])  # bit for bit where the mask reads it
    kept = ~np.isnan(over)
    assert np.array_equal(over[kept], whole[kept])  # and on every pixel it keeps
    if name not in ("everything", "two_blobs"):  # boxes (+ 11 px) that leave pixels out
        assert np.isnan(over).any()  # a pixel not computed is not shown as a value


def test_margin_is_needed_a_pixel_less_changes_bits():
    """FLIP's own reach: the map of a crop equals the whole map at ``flip_support - 1`` px
    (10) inside its cut edges and not at one pixel less (random images, FLIP called
    directly): the margin is neither guessed nor loose by more than the guard pixel."""
    res, ref = _images("random", seed=3)
    whole = _flip_whole(res, ref)[0]
    reach = flip_support(67.0) - 1
    y0, y1, x0, x1 = 30, 50, 40, 64
    for margin, equal in ((reach, True), (reach - 1, False)):
        crop = (slice(y0 - margin, y1 + margin), slice(x0 - margin, x1 + margin))
        part = _flip_whole(res[..., crop[0], crop[1]], ref[..., crop[0], crop[1]])[0]
        inner = part[margin:-margin, margin:-margin]
        assert np.array_equal(inner, whole[y0:y1, x0:x1]) is equal


def test_empty_mask_image_is_all_nan_and_batches_are_per_image():
    res, ref = _images("random", seed=5)
    res2, ref2 = torch.cat([res, res.flip(-1)]), torch.cat([ref, ref.flip(-1)])
    mask = torch.cat([MASKS["inner_blob"], torch.zeros(1, 1, H, W, dtype=torch.float64)])
    over = flip_map_over(res2, ref2, mask)
    assert np.isnan(over[1]).all()
    on = mask[0, 0].numpy() > 0
    assert np.array_equal(over[0][on], _flip_whole(res, ref)[0][on])


def test_no_mask_is_the_whole_map():
    res, ref = _images("structured")
    assert np.array_equal(flip_map_over(res, ref, None), _flip_whole(res, ref))


def test_consumers_read_only_the_mask_and_give_the_whole_maps_numbers():
    """flip, compute_all and visibility_stats give the same numbers, bit for bit, from the
    crop's map (with its NaN) as from the whole map; a map computed over a smaller mask is
    refused where the mask reads a NaN, naming fmap."""
    res, ref = _images("structured", seed=7)
    mask = MASKS["two_blobs"]
    whole = _flip_whole(res, ref)
    over = flip_map_over(res, ref, mask)
    assert metrics.flip(res, ref, mask, fmap=over) == metrics.flip(res, ref, mask, fmap=whole)
    assert metrics.compute_all(res, ref, mask, fmap=over) == metrics.compute_all(
        res, ref, mask, fmap=whole
    )
    assert metrics.compute_all(res, ref, mask) == metrics.compute_all(res, ref, mask, fmap=whole)
    a = verdict.visibility_stats(ref, res, mask, fmap=over)
    b = verdict.visibility_stats(ref, res, mask, fmap=whole)
    assert a == b and all(math.isfinite(v) for v in a)
    assert verdict.visibility_stats(ref, res, mask) == b  # its own crop when given no map
    small = flip_map_over(res, ref, MASKS["one_pixel"])
    with pytest.raises(ValueError, match="fmap"):
        metrics.flip(res, ref, mask, fmap=small)
    with pytest.raises(ValueError, match="fmap"):
        verdict.visibility_stats(ref, res, mask, fmap=small)
    with pytest.raises(ValueError, match="fmap"):
        verdict.visibility_stats(ref, res, None, fmap=small)


def test_bad_mask_names_the_argument():
    res, ref = _images("random")
    with pytest.raises(ValueError, match="mask"):
        flip_map_over(res, ref, torch.ones(1, 1, H, W + 1, dtype=torch.float64))
    with pytest.raises(ValueError, match="mask"):
        flip_map_over(res, ref, torch.full((1, 1, H, W), 2.0, dtype=torch.float64))


def test_runner_scores_as_with_the_whole_map(tmp_path, monkeypatch):
    """A small run on a scene whose mask covers part of the image (a sphere, 4 mm per pixel)
    stores the same metrics when the runner computes FLIP over the mask's box as when it
    computes the whole map (the previous code)."""
    from sssbench.run import runmemo, runner

    def run(sub: str) -> dict:
        spec = small_spec(
            tmp_path / sub,
            scene="sphere",
            scene_params={"pixel_mm": 4.0},
            method="preintegrated",
            samples=7,
            resolution=(64, 64),
            dtype="float32",
        )
        out = runner.execute(spec, tmp_path / sub / "run")
        assert out.status == "ok", out.message
        return {k: v for k, v in out.metrics.items() if not k.endswith("_ms")}

    calls = []
    real = metrics.flip_map_over

    def spy(r, f, m, **kw):
        out = real(r, f, m, **kw)
        calls.append(bool(np.isnan(out).any()))
        return out

    runmemo.clear()  # the scene's baseline (its visibility) computed anew in each run
    monkeypatch.setattr(runner, "flip_map_over", spy)
    new = run("crop")
    assert calls == [True]  # the run's map was a crop (NaN outside the mask's box)
    # the previous code: the whole map for the run and for its baseline's visibility
    whole = lambda r, f, m, **kw: metrics.flip_map(r, f, **kw)  # noqa: E731
    monkeypatch.setattr(runner, "flip_map_over", whole)
    monkeypatch.setattr(metrics, "flip_map_over", whole)
    runmemo.clear()
    before = run("whole")
    assert new == before

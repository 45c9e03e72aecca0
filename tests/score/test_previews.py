"""The preview strip (sssbench/score/previews.py): its panels are the native PNGs' own pixels,
each repeated as an integer block, inside a black frame; the colour bar sits beside the error
panel; the native PNGs are the images' tonemapped values and the error map's colours."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.image  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from matplotlib import colormaps  # noqa: E402

from sssbench.score.metrics import tonemap  # noqa: E402
from sssbench.score.previews import MIN_HEIGHT_PX, preview_strip, strip_layout  # noqa: E402


def _magma(rel: torch.Tensor, top: float) -> np.ndarray:
    """The 8-bit colours matplotlib's 256-entry magma gives ``rel`` on [0, top], as floats."""
    idx = np.clip((rel / top).numpy() * 256, 0, 255).astype(int)
    return colormaps["magma"].resampled(256)(idx)[..., :3]


def _pair(h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(h * 1000 + w)
    reference = torch.rand(1, 3, h, w, generator=gen, dtype=torch.float64) * 2.0
    result = reference + 0.1 * torch.rand(1, 3, h, w, generator=gen, dtype=torch.float64)
    return result, reference


@pytest.mark.parametrize("h, w", [(24, 24), (16, 40), (300, 200), (1, 700)])
def test_the_strip_holds_each_native_image_pixel_for_pixel(tmp_path, h, w):
    result, reference = _pair(h, w)
    files = preview_strip(tmp_path, result, reference, title="sphere · identity")
    assert files == ["result.png", "reference.png", "error.png", "preview.png"]
    strip = matplotlib.image.imread(tmp_path / "preview.png")  # (H, W, 4) floats k / 255
    lay = strip_layout(h, w)
    k = lay["scale"]
    assert strip.shape[:2] == lay["size"]
    # the smallest integer scale reaching MIN_HEIGHT_PX, unless the panel would pass 2048 px
    assert k == max(1, min(-(-MIN_HEIGHT_PX // h), 2048 // w))
    for (r, c), name in zip(lay["panels"], ("result", "reference", "error"), strict=True):
        native = matplotlib.image.imread(tmp_path / f"{name}.png")
        assert native.shape[:2] == (h, w)
        panel = strip[r : r + h * k, c : c + w * k]
        np.testing.assert_array_equal(panel, native.repeat(k, 0).repeat(k, 1))
        frame = np.concatenate(
            [strip[r - 1, c - 1 : c + w * k + 1], strip[r + h * k, c - 1 : c + w * k + 1]]
        )
        np.testing.assert_array_equal(frame[:, :3], 0.0)
    # the native result is the tonemapped image, truncated to 8 bits as matplotlib's imsave does
    want = tonemap(result.clamp(min=0))[0].permute(1, 2, 0).clamp(0, 1).numpy()
    got = matplotlib.image.imread(tmp_path / "result.png")[..., :3]
    np.testing.assert_array_equal(np.round(got * 255), np.floor(want * 255))
    # the error map's colours: magma over [0, the run's maximum] of |result - ref| / ref peak
    rel = (result - reference).abs().mean(1)[0] / reference.max()
    err = matplotlib.image.imread(tmp_path / "error.png")[..., :3]
    np.testing.assert_allclose(err, _magma(rel, float(rel.max())), atol=1 / 255)
    # the colour bar: the magma ramp inside its box, brightest at the top (a flat image's
    # strip, 2 px high, has no room for one to test)
    br, bc, bh, bw = lay["bar"]
    if bh >= 8:
        mid = strip[br + 2 : br + bh - 2, bc + bw // 2, :3]
        assert mid[0].sum() > mid[-1].sum()


def test_a_given_error_scale_sets_the_colours(tmp_path):
    result, reference = _pair(24, 24)
    preview_strip(tmp_path, result, reference, error_scale=10.0)  # far above every error
    err = matplotlib.image.imread(tmp_path / "error.png")[..., :3]
    rel = (result - reference).abs().mean(1)[0] / reference.max()
    np.testing.assert_allclose(err, _magma(rel, 10.0), atol=1 / 255)


def test_a_canvas_one_pixel_short_still_gives_the_layout(tmp_path, monkeypatch):
    """Agg sizes its canvas from figsize · dpi, a float product (0.29 · 100 = 28.999...) that
    some matplotlib versions truncate: a canvas one pixel short on both sides must still give
    the layout's strip with every panel in place (here simulated by cropping the buffer)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    full = FigureCanvasAgg.buffer_rgba
    monkeypatch.setattr(
        FigureCanvasAgg, "buffer_rgba", lambda self: np.asarray(full(self))[:-1, :-1]
    )
    result, reference = _pair(24, 24)
    preview_strip(tmp_path, result, reference)
    strip = matplotlib.image.imread(tmp_path / "preview.png")
    lay = strip_layout(24, 24)
    assert strip.shape[:2] == lay["size"]
    k = lay["scale"]
    (r, c) = lay["panels"][2]
    native = matplotlib.image.imread(tmp_path / "error.png")
    np.testing.assert_array_equal(
        strip[r : r + 24 * k, c : c + 24 * k], native.repeat(k, 0).repeat(k, 1)
    )

"""ReferenceSSS on several Python threads equals the serial evaluation, whatever torch's own
thread count (the accuracy on threads: tests/ops/test_reference_close.py), and the exact
sub-patch moments of large cells equal the closed-form moments of
the whole cell."""

import numpy as np
import pytest
import torch
from oracles import flat

from data_synth import make_scene
from sssbench.ops import _reference_far as far
from sssbench.ops import reference as reference
from sssbench.ops.reference import reference_sss
from sssbench.profiles import SumOfGaussians

#: skin_deon6's two narrowest Gaussians: σ 0.08 mm (cell by cell at 0.07 mm per pixel) and
#: 0.22 mm (moments; the steep cells of the nose's side split into sub-patches)
_SKIN = SumOfGaussians.from_table("skin_deon6")
PROFILE = SumOfGaussians(_SKIN.variances[:2], _SKIN.weights[:2])


def scene():
    """The side of the nose turned 60° away at 0.07 mm per pixel (slopes up to ~3)."""
    return make_scene("face", (24, 32), dtype=torch.float64, pixel_mm=0.07, aim="face", yaw=60.0)


@pytest.fixture
def torch_threads():
    """Set torch's intra-op thread count inside a test, restored after."""
    prev = torch.get_num_threads()
    yield torch.set_num_threads
    torch.set_num_threads(prev)


def _rel_max(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max())


@pytest.mark.parametrize(
    ("method", "reconstruction"),
    [("multipole", "box"), ("multipole", "bilinear"), ("gather", "box")],
)
def test_threads_give_the_serial_result(monkeypatch, torch_threads, method, reconstruction):
    # small chunks of centres, so the cell gather has many chunks to share out; the moment
    # path has tiles of 16 pixels, the pyramid bands of 2–4 rows: several of each
    monkeypatch.setattr(reference, "_CENTRES", 97)
    g = scene()
    torch_threads(1)
    serial = reference_sss(g, PROFILE, method=method, reconstruction=reconstruction, threads=1)
    torch_threads(2)
    got = reference_sss(g, PROFILE, method=method, reconstruction=reconstruction, threads=3)
    assert _rel_max(got, serial) <= 1e-12
    assert torch.get_num_threads() == 2  # restored after the threaded evaluation


def test_threads_must_be_a_positive_int():
    g = flat(torch.full((1, 3, 4, 4), 0.5, dtype=torch.float64))
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="threads"):
            reference_sss(g, PROFILE, threads=bad)


def _shift(pos: torch.Tensor, mom: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """Moments ``(S, C, 10)`` about ``pos`` ``(S, 3)`` summed about ``centre`` ``(3,)``
    (parallel-axis theorem, written out independently of the pyramid's merge)."""
    d = (pos - centre)[:, None, :]  # (S, 1, 3)
    m, dip, qd = mom[..., 0], mom[..., 1:4], mom[..., 4:]
    out = [m.sum(0)]
    out += list((dip + m[..., None] * d).sum(0).unbind(-1))
    for j, (k, l) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
        dk, dl = d[..., k], d[..., l]
        t = qd[..., j] + dip[..., k] * dl + dip[..., l] * dk + m * dk * dl
        out.append(t.sum(0))
    return torch.stack(out, -1)  # (C, 10)


@pytest.mark.parametrize("reconstruction", ["box", "bilinear"])
@pytest.mark.parametrize("panels", [1, 3])
def test_sub_patch_moments_add_up_to_the_cell_moments(reconstruction, panels):
    # a steep tilted cell (slopes 3 and −1.5) with a different value at each neighbour: the
    # 2-point Gauss–Legendre moments of its (2·panels)² sub-patches, shifted to the cell's
    # centre, equal the closed-form moments of the whole cell (products of 1D integrals)
    gen = torch.Generator().manual_seed(5)
    f = torch.zeros(6, 3, 3, dtype=torch.float64)
    f[0], f[1], f[2] = 1.3, -0.7, 40.0
    f[3], f[4], f[5] = 0.45, 3.0, -1.5
    q = torch.rand(2, 3, 3, generator=gen, dtype=torch.float64)
    one = torch.tensor([0])
    pos, mom = far.cell_patches(f, q, one, one, panels, reconstruction)
    assert pos.shape[0] == 4 * panels**2
    got = _shift(pos, mom, f[:3, 1, 1])
    want = far.cells_at(f, q, one, one, reconstruction)[0]
    scale = want.abs().amax(1, keepdim=True)
    np.testing.assert_allclose((got / scale).numpy(), (want / scale).numpy(), atol=1e-13)
    # the sub-patches tile the cell: their centres average to the cell's centre
    assert torch.allclose(pos.mean(0), f[:3, 1, 1], atol=1e-13)


def test_map_threads_keeps_the_order_and_one_torch_thread_per_item(torch_threads):
    torch_threads(2)
    assert list(far.map_threads(lambda i: i * i, range(50), 3)) == [i * i for i in range(50)]
    # every item runs with one intra-op thread: the same kernels whatever the worker count
    assert set(far.map_threads(lambda _: torch.get_num_threads(), range(8), 2)) == {1}

    def boom(i: int) -> int:
        if i == 7:
            raise RuntimeError("item 7")
        return i

    with pytest.raises(RuntimeError, match="item 7"):
        list(far.map_threads(boom, range(20), 2))
    assert torch.get_num_threads() == 2  # restored, also after an error


@pytest.mark.parametrize("method", ["multipole", "gather"])
def test_threads_under_inference_mode(monkeypatch, method):
    """Autograd's modes are thread-local: a threaded reference called under
    ``torch.inference_mode()`` (as the runner calls it) must run its workers under it too
    (tensors made in inference mode can only be written to there); the result is the
    serial one outside inference mode."""
    monkeypatch.setattr(reference, "_CENTRES", 97)
    g = scene()
    serial = reference_sss(g, PROFILE, method=method, threads=1)
    with torch.inference_mode():
        got = reference_sss(g, PROFILE, method=method, threads=2)
    assert _rel_max(got, serial) <= 1e-12

"""The disk's seams for backends above the operators (the GL disk): its per-pixel random numbers
and pixel areas as planes, and the disk pass's registration."""

from __future__ import annotations

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.ops import DiskSSS
from sssbench.ops.disk import hash_uniform
from sssbench.ops.pass_backends import register_pass_backend
from sssbench.profiles import BurleyNormalized

P = BurleyNormalized([1.0, 0.5, 0.25], [0.8, 0.6, 0.4])


def _gbuffer() -> GBuffer:
    mask = torch.ones(2, 1, 5, 7)
    mask[:, :, 0, :3] = 0
    return GBuffer(torch.rand(2, 3, 5, 7), torch.full((2, 1, 5, 7), 200.0), 0.5, mask=mask)


def test_noise_is_the_documented_hash_of_the_pixel_in_its_image():
    g = _gbuffer()
    m = DiskSSS(P, seed=2**40 + 3)
    phase, shift = m.noise(g, 2)
    pixel = torch.arange(35).reshape(5, 7)
    on = g.mask[0, 0] > 0
    for b in range(2):  # the same noise in every image of the batch (keyed in-image)
        want_phase = hash_uniform(pixel, m.seed, 2, 0)  # stream 0: rotation 2s, shift 2s + 1
        want_shift = hash_uniform(pixel, m.seed, 2, 1)
        assert torch.equal(phase[b, 0][on], want_phase[on])
        assert torch.equal(shift[b, 0][on], want_shift[on])
        assert not phase[b, 0][~on].any() and not shift[b, 0][~on].any()
    _, fixed = DiskSSS(P, jitter_radius=False).noise(g, 0)
    assert not fixed.any()


def test_noise_refuses_bad_arguments_naming_them():
    m = DiskSSS(P)
    with pytest.raises(ValueError, match="frame"):
        m.noise(_gbuffer(), -1)
    with pytest.raises(TypeError, match="stream"):
        m.noise(_gbuffer(), 0, 0.5)
    with pytest.raises(TypeError, match="gbuffer"):
        m.noise(torch.zeros(1), 0)


def test_pixel_areas_of_a_fronto_parallel_plane_are_the_pixel_footprint():
    g = _gbuffer()
    foot = 2 * 200.0 * torch.tan(torch.tensor(0.25, dtype=torch.float64)) / 5  # mm per pixel
    area = DiskSSS(P).pixel_areas(g)
    assert area.shape == (2, 1, 5, 7)
    torch.testing.assert_close(area.double(), torch.full_like(area, float(foot**2)).double())


def test_a_disk_pass_must_be_callable():
    with pytest.raises(TypeError, match="disk_pass"):
        register_pass_backend("gl", lambda: None, lambda *a, **k: None, disk_pass=3)

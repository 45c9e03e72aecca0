"""Issue 29's classes on the disk (and the same classes where other operators have them):
seeds wider than 32 bits (1), noise keyed on the batch position (2), float32 in the bilinear
fetch (3), profiles that are not densities (4), unbounded work from one argument (16).
Each test failed on the code before its fix (docs/reliability.md)."""

from __future__ import annotations

import math
import time

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.ops import DiskSSS, record_passes
from sssbench.ops import disk as disk_module
from sssbench.ops.reference import reference_sss
from sssbench.profiles import BurleyNormalized, SumOfGaussians

DT = torch.float64
MAX_DISK_SAMPLES = getattr(disk_module, "MAX_DISK_SAMPLES", 1 << 16)
MAX_DISK_FRAMES = getattr(disk_module, "MAX_DISK_FRAMES", 1 << 12)
BURLEY = BurleyNormalized([1.0, 0.5, 0.25], [0.8, 0.6, 0.4])


def image(h: int = 12, w: int = 12, z: float = 300.0, seed: int = 0, fov: float = 0.4, b=1):
    gen = torch.Generator().manual_seed(seed)
    e = torch.rand(b, 3, h, w, generator=gen, dtype=DT)
    depth = z * (1 + 0.05 * torch.rand(b, 1, h, w, generator=gen, dtype=DT))
    return GBuffer(e, depth, fov)


# ----------------------------------------------------------------------------- class 1: seeds
@pytest.mark.parametrize("rotation", ["hash", "ign", "blue_noise"])
@pytest.mark.parametrize("seed", [5, 2**50, 2**62 + 12345])
def test_seeds_differing_above_bit_32_give_different_images(rotation, seed):
    g = image()
    p = SumOfGaussians.from_table("skin_deon6")
    a = DiskSSS(p, 8, rotation=rotation, seed=seed)(g)
    for other in (seed + 2**33, seed ^ 1):  # a high bit, and the lowest bit
        b = DiskSSS(p, 8, rotation=rotation, seed=other)(g)
        assert not torch.equal(a, b), (seed, other)


def test_seed_range_is_documented_and_refused_beyond_it():
    DiskSSS(BURLEY, seed=2**63 - 1)
    for bad in (2**63, -1):
        with pytest.raises(ValueError, match=r"^seed must be an integer in \[0, "):
            DiskSSS(BURLEY, seed=bad)


# ----------------------------------------------------------------------------- class 2: batches
@pytest.mark.parametrize("estimator", ["sssbench", "hdrp"])
@pytest.mark.parametrize("rotation", ["hash", "ign", "blue_noise"])
def test_an_image_in_a_batch_equals_the_same_image_alone(estimator, rotation):
    batch = image(b=3, seed=4)
    options = {} if estimator == "sssbench" else {"estimator": estimator}
    op = DiskSSS(BURLEY, 8, rotation=rotation, seed=9, **options)
    together = op(batch)
    for i in range(3):
        alone = op(GBuffer(batch.diffuse[i : i + 1], batch.depth[i : i + 1], batch.fov_y))
        # equal to rounding (torch's vectorised elementwise functions may round the tail
        # lanes of a longer tensor apart); before the fix they differed by O(1)
        assert torch.allclose(together[i : i + 1], alone, rtol=1e-12, atol=0), i


# ----------------------------------------------------------------------------- class 3: float32
@pytest.mark.parametrize("fetch", ["bilinear", "point"])
@pytest.mark.parametrize("z, fov", [(300.0, 1e-3), (5e3, 0.01), (40.0, 2.5)])
def test_float32_bilinear_fetch_within_the_float32_bound(fetch, z, fov):
    # a narrow field of view far away: pixels of 0.01 mm at 300 mm depth, so a depth
    # interpolated as an absolute value (ulp(300) = 3e-5 mm) moved each distance by 0.3 %
    h = 16
    pix = 2 * z * math.tan(fov / 2) / h
    p = BurleyNormalized([2 * pix, pix, 0.5 * pix], 0.8)
    g32 = image(h, h, z=z, fov=fov).to(torch.float32)
    g32 = g32.replace(depth=torch.full_like(g32.depth, z))  # a plane: exact in float32
    op = DiskSSS(p, 16, fetch=fetch, seed=3)
    with record_passes() as recs:
        out32 = op(g32)
    out64 = op(g32.to(DT))
    tol = sum(max(1e-5, r.samples * 2.0**-24) for r in recs)  # docs/reliability.md, per pass
    err = float((out32.double() - out64).abs().max()) / float(g32.diffuse.max())
    assert err <= tol, (err, tol)


def test_float32_fetch_on_a_sloped_surface_within_the_bound():
    h, z, fov = 16, 300.0, 1e-3
    pix = 2 * z * math.tan(fov / 2) / h
    rows = torch.arange(h, dtype=DT).view(1, 1, h, 1)
    depth = (z + 0.3 * pix * rows).expand(1, 1, h, h).contiguous()
    g = image(h, h, z=z, fov=fov).replace(depth=depth).to(torch.float32)
    op = DiskSSS(BurleyNormalized(pix, 0.8), 16, fetch="bilinear")
    err = float((op(g).double() - op(g.to(DT))).abs().max()) / float(g.diffuse.max())
    assert err <= 1e-5, err


# ----------------------------------------------------------------------------- class 4: densities
def negative_lobe() -> SumOfGaussians:
    # a narrow positive Gaussian minus a wide one: total 0.7 > 0, but R < 0 in the tail
    v = torch.tensor([0.2, 3.0], dtype=DT)
    w = torch.tensor([[1.0] * 3, [-0.3] * 3], dtype=DT)
    return SumOfGaussians(v, w)


def test_profile_with_a_negative_lobe_is_refused_naming_the_argument():
    p = negative_lobe()
    assert bool((p.total() > 0).all())
    with pytest.raises(ValueError, match=r"^profile is negative in its sampled .* density"):
        DiskSSS(p)
    with pytest.raises(ValueError, match=r"^profile\[1\] is negative"):
        DiskSSS([BURLEY, p])


def test_profiles_whose_sampled_channel_is_a_density_are_accepted():
    from sssbench.profiles.empirical import empirical_dipole_fit

    # (skin1's fit dips to −1e-6 in green, which is not sampled: a signed integrand is fine)
    for p in (BURLEY, SumOfGaussians.from_table("skin_deon6"), empirical_dipole_fit("skin1")):
        DiskSSS(p)


# ----------------------------------------------------------------------------- class 16: bounds
@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(samples=10**15), "samples"),
        (dict(samples=MAX_DISK_SAMPLES + 1), "samples"),
        (dict(frames=10**12), "frames"),
        (dict(frames=MAX_DISK_FRAMES + 1), "frames"),
        (dict(adaptive=(4, 10**15)), "adaptive[1]"),
    ],
)
def test_disk_sizes_are_bounded_on_entry(kwargs, name):
    t = time.perf_counter()
    with pytest.raises(ValueError) as info:
        DiskSSS(BURLEY, **kwargs)
    assert str(info.value).startswith(name) and "\n" not in str(info.value)
    assert time.perf_counter() - t < 1.0


@pytest.mark.parametrize("radius, exc", [(10**9, ValueError), (2**40, ValueError), (-1, ValueError),
                                         (2.5, TypeError), (True, TypeError)])  # fmt: skip
def test_reference_window_is_bounded_before_any_allocation(radius, exc):
    g = image(8, 8)
    t = time.perf_counter()
    with pytest.raises(exc) as info:
        reference_sss(g, BURLEY, radius_px=radius, method="gather")
    assert str(info.value).startswith("radius_px") and "\n" not in str(info.value)
    assert time.perf_counter() - t < 5.0


def test_reference_window_up_to_the_image_size_still_runs():
    g = image(6, 6)
    out = reference_sss(g, BURLEY, radius_px=6, method="gather")
    assert bool(torch.isfinite(out).all())


def test_a_weight_float32_flushes_to_zero_does_not_flip_the_pixel():
    """Found by the long fuzz profile: one sample landing 20 mm away in depth has a weight
    float32 flushes to 0 and float64 keeps at ~1e-100; the normalised estimate must not hand
    the pixel to that sample in one dtype and keep it in the other (a total weight at or
    below the estimator's "no weight" keeps the pixel's own irradiance in both)."""
    from sssbench.profiles import SumOfGaussians

    diffuse = torch.tensor(
        [[[[5.8451e-08, 2.1374e-07, 3.5087e-07]], [[1.4817e-07, 4.0009e-07, 2.5815e-07]],
          [[3.2155e-07, 9.9325e-07, 4.2326e-07]]]]
    )  # fmt: skip
    g = GBuffer(diffuse=diffuse, depth=torch.tensor([[[[40.0, 40.0, 60.0]]]]), fov_y=0.001)
    op = DiskSSS(SumOfGaussians.from_table("skin_deon6"), samples=1, seed=0, fetch="point")
    out32, out64 = op(g), op(g.to(torch.float64))
    assert float((out32.double() - out64).abs().max() / out64.abs().max()) <= 1e-5


def test_an_adaptive_target_whose_square_overflows_is_refused_by_name():
    """Found by the long fuzz profile: ``adaptive_target=1e200`` overflowed (``target**2``)
    inside the pass with a bare OverflowError; the constructor refuses it naming the option."""
    with pytest.raises(ValueError, match="adaptive_target"):
        DiskSSS(BURLEY, adaptive=(4, 16), adaptive_target=1e200)


def test_float32_geometry_at_a_kilometre_matches_float64():
    """Found by the long fuzz profile: at 1 km depth a bilinear sample's sub-pixel fraction and
    interpolated depth difference, rounded to float32 before R(d), put the weight 6e-5 off
    float64; the geometry is float64 in every dtype (docs/reliability.md, class 3)."""
    from sssbench.profiles import SumOfGaussians

    diffuse = torch.tensor(
        [[[[9.2075e-07, 6.4502e-07]], [[7.9115e-07, 1.7861e-07]], [[3.5111e-07, 5.8134e-07]]]]
    )
    g = GBuffer(diffuse=diffuse, depth=torch.tensor([[[[1e6, 1016666.6875]]]]), fov_y=0.001)
    op = DiskSSS(
        SumOfGaussians.from_table("skin_deon6"),
        samples=1, seed=0, pattern="r2", normalise=False, fetch="bilinear",
    )  # fmt: skip
    out32, out64 = op(g), op(g.to(torch.float64))
    assert float((out32.double() - out64).abs().max() / out64.abs().max()) <= 1e-5

"""Importance-sampled 2D disk SSS: the engines' method (Unity HDRP, Unreal Engine 5's
screen-space Burley pass, Blender EEVEE).

One module because the estimators share one loop (positions, fetch, weights, normalisation)
and differ in a few formulas each cites; HDRP's rules sit beside the ones they replace.

Golubev 2018 ("Efficient screen-space subsurface scattering using Burley's normalized
diffusion in real-time", SIGGRAPH Advances in Real-Time Rendering) replaces the papers'
separable passes by one gather over N samples on a disk in the screen plane: radii drawn from
the profile's radial CDF, angles on a golden-angle spiral rotated per pixel, each sample
weighted by the profile over the sampling density, and the sum divided by the sum of the
weights. :class:`DiskSSS` has two estimators of that family on a G-buffer:

- ``estimator="sssbench"`` (default, described first below): the weight ``R(d) / pdf_area``
  with ``d`` the 3D distance between the two surface points — an importance-sampled estimate
  of the surface integral the exact reference computes — with radial jitter, a choice of
  patterns, fetches, adaptive counts and a surface-area element;
- ``estimator="hdrp"``: Unity HDRP's pass exactly (last section below), whose weight is
  ``EvalBurley(r3D) · rcpPdf(r2D)``: the profile in polar measure at the 3D distance over the
  polar density at the disk radius, i.e. ours times ``r3D / r2D`` — across a depth step HDRP
  weighs the far side's samples up by that factor.

Per pixel ``p`` (centre view position ``x_p``, :func:`~sssbench.gbuffer.view_positions`) and
frame ``f``, sample ``i`` of ``N``:

- ``u_i`` (radial quantile) and ``θ_i`` (angle): ``pattern="fibonacci"`` (Vogel's spiral:
  ``u_i = (i + ½)/N``, ``θ_i = i · golden angle``; HDRP's ``SampleDiskGolden`` turns the other
  way, ``θ_i = 2π frac(i/φ) = −i · golden angle`` mod 2π, which ``estimator="hdrp"`` uses) or
  ``"r2"`` (Roberts' R2 sequence,
  ``(u_i, v_i) = frac(½ + i (1/g, 1/g²))``, g the plastic number, ``θ_i = 2π v_i``);
- ``θ_i += 2π φ(p, f)`` with ``φ`` from ``rotation`` (``"hash"``: a seeded integer hash of
  pixel, seed and frame, white noise; ``"ign"``: interleaved gradient noise, Jimenez 2014,
  the per-pixel rotation of UE's and Call of Duty's screen-space samplers; ``"blue_noise"``:
  a tiled 64² void-and-cluster mask, Ulichney 1993, animated over frames by the golden
  ratio, :func:`blue_noise_phase`; ``"none"``);
- with ``jitter_radius=True`` (default) also ``u_i ← frac(u_i + ψ(p, f))`` (a
  Cranley–Patterson shift, ψ another hash): each ``u_i`` is then uniform and the
  ``normalise=False`` estimator is exactly unbiased; HDRP keeps ``u_i`` fixed (its frames
  then converge to the midpoint rule in ``u``, not to the integral). Our choice, stated here.
- ``r_i, 1/pdf_i``: the radial sampler of the widest channel (:mod:`._disk_radial`: closed
  form for Burley, tabulated inverse CDF otherwise); the offset ``r_i (cos θ_i, sin θ_i)``
  mm is turned into pixels at the centre's depth (:func:`~sssbench.gbuffer.pixel_size_mm`)
  — the disk lies in the screen-parallel plane through the centre, as in HDRP without its
  tangent-plane option (no area element on tilted surfaces; see ``surface_area``);
- fetch (``fetch="point"``, HDRP: a load at the rounded position) of irradiance ``E_i`` and
  depth ``z_i`` from the pixel containing the sample, or ``fetch="bilinear"`` (the four
  corners, weighted by bilinear weight × stencil, renormalised);
- the sample's surface point: ``x_i = x_p z_i / z_p + Δ pixel_size(z_i)`` (the view ray
  through the sample's continuous, unclamped screen position at the fetched depth), so
  ``d_i = |x_i − x_p|`` equals ``r_i`` on a fronto-parallel plane;
- weight per channel ``w_ic = R_c(d_i) / pdf_i / ‖R_c‖₁``, times, with
  ``surface_area=True``, the area the sample's pixel covers on the surface over the area it
  covers in the disk's plane, ``a_i = (z_i / z_p)² √(1 + s_x² + s_y²)`` (``s``: the depth
  slopes of the sample's pixel, minmod of the one-sided differences clamped at 85°, as the
  exact reference's cells). The engines (default ``False``) leave it out: the disk then
  integrates over the screen-parallel plane, not the surface. On a plane (``a`` constant up
  to perspective) the normalised estimator does not see the difference; on a curved surface
  it weighs the neighbours facing the camera more than the reference, which weighs each by
  its surface area — the disk's bias on curved scenes (measured on ``head_cheek``, see
  experiments/disk.py). What it converges to on a plane tilted 45° (unnormalised, constant
  irradiance, pixel = d/2, Burley): **1.025**, not 1, with the point fetch (measured: 1.0249
  ± 0.0002, 2048 samples per pixel, ``tests/ops/test_disk.py``): a point fetch reads the
  depth and area of the pixel *centre* and places the sample on the view ray at that depth,
  so on a tilted surface the sample's 3D distance is off by up to half a pixel's depth
  change, which shrinks with the pixel against the profile. We keep the estimator as it is
  (the engines' point fetch) and state its limit (the bilinear fetch's limit is not
  measured).
- geometry in differences: the sample's screen offset from its centre pixel, its depth as
  ``z_i − z_p`` (the bilinear fetch interpolates depth differences) and ``x_i − x_p =
  x_p (z_i − z_p)/z_p + Δ pixel_size(z_i)``, never one absolute position minus another:
  float32 keeps the distances to its own rounding (``docs/reliability.md``).

Rules (our choices, documented because the sources leave them to the engine):

- **Image border**: the fetch clamps to the edge (a sampler's clamp mode; the same as the
  separable passes and the exact reference, whose border neighbours keep the border's
  colour and depth at their own, extended, grid position — ``d_i`` uses the unclamped
  position).
- **Stencil**: a sample whose pixel has ``mask == 0`` (bilinear: all four corners) is
  rejected: weight 0 (HDRP tests each sample's SSS marker the same way).
- **Normalisation** (``normalise=True``, HDRP): ``Σ_i w_ic E_ic / Σ_i w_ic`` per channel
  over the accepted samples — rejected samples are renormalised away, and a bright pixel
  cannot push energy above the kernel's mass. If no sample is accepted the pixel keeps its
  irradiance. ``normalise=False``: the plain Monte Carlo estimate ``(1/N) Σ_i w_ic E_ic``
  (rejected samples contribute 0), an unbiased estimate of ``∫ R(|y|) E(p + y) dA / ‖R‖₁``
  over the stencil — on a flat plane exactly what :class:`~sssbench.ops.ReferenceSSS`
  computes (with point fetch the sample reads its pixel's irradiance and is weighted at its
  true position, so its expectation is the reference's per-cell integral).
- **Strength**: as the reference, ``out = lerp(E_p, scattered, mask)`` on ``mask > 0``;
  pixels with ``mask == 0`` are copied through.
- ``frames=K`` averages K frames' estimates (frame f: its own rotation and radial shift), an
  ideal temporal resolve of a static scene.
- ``adaptive=(n_min, n_max)`` (UE5's Burley pass varies the count per pixel from a variance
  estimate; our rule, within one frame): a pilot of ``n_min`` samples gives per channel the
  squared relative standard error ε² of its estimate ``m`` (samples treated as
  independent): for ``normalise=True`` the delta-method variance of the ratio,
  ``Σ w_i² (E_i − m)² / (Σ w_i)²`` over ``m²`` (zero on a constant irradiance whatever the
  weights: the self-normalised estimator is exact there); for ``normalise=False`` that of
  the mean of ``f_i = w_i E_i``, ``(mean f² − (mean f)²) / (n_min (mean f)²)``;
  a pixel needs ``n = n_min ε² / target²`` samples for a relative error ``target``
  (``ε_max`` over channels); its count is the smallest ``n_min · 2^k ≥ n``, at most
  ``n_max``, and it draws ``count − n_min`` more samples (a pattern of that size with its own
  hash stream), pooled with the pilot's.
- **Noise keys**: every per-pixel random number (rotation, radial shift) is a function of
  the pixel's position *in its image*, the seed, the frame and the stream — not of the
  image's place in a batch: an image scattered in a batch equals it scattered alone. The
  seed is any integer in ``[0, 2⁶³ − 1]`` and every bit of it counts: it is folded into the
  32-bit hash keys in exact integer arithmetic (:func:`_seed_key`; ``"ign"``'s frame offset
  likewise, :func:`_ign_frame`), never through a float.
- **Premise**: the radial sampler treats the sampled (widest) channel as a density, so a
  profile negative anywhere in that channel on its radial grid (a fitted negative lobe; its
  tabulated CDF is then not monotone) is refused when the operator is built, naming
  ``profile`` (other channels are integrands and may be signed).
- **Bounds**: ``samples`` and ``adaptive[1]`` at most :data:`MAX_DISK_SAMPLES`, ``frames``
  at most :data:`MAX_DISK_FRAMES`, checked on entry (the pattern and the passes grow with
  them).
- **Per-pixel profiles**: with a list of profiles, pixel ``p`` scatters with
  ``profiles[profile_id[p]]`` (its own radial sampler and weights; ``gbuffer.profile_id``).
  A sample landing on a pixel of another profile is rejected like a stencil miss
  (``cross_profile="reject"``, default: each material integrates only its own surface, as if
  the seam were a silhouette — the choice that keeps each side of a seam equal to its own
  profile's result away from the seam, and the one the engines' per-profile stencils make)
  or weighted with the centre's profile (``"accept"``: light crosses the seam with the
  receiving material's kernel).

``estimator="hdrp"``: Unity HDRP's pass (Unity-Technologies/Graphics,
``com.unity.render-pipelines.high-definition/Runtime/Material/SubsurfaceScattering/
SubsurfaceScattering.compute``, ``EvaluateSss`` / ``EvaluateSample`` /
``ComputeBilateralWeight``, with ``SSS_USE_TANGENT_PLANE 0``, ``SSS_BILATERAL_FILTER 1``;
``DiffusionProfile.hlsl``; ``DiffusionProfileSettings.cs``; core ``Sampling/Fibonacci.hlsl``),
re-implemented here from the published formulas and checked against an independent loop
implementation of them (``tests/ops/test_disk_hdrp.py``):

- profile: HDRP's is Burley's, ``S = 1 / (scatteringDistance · multiplier)`` per channel
  with *no* albedo fit — :class:`~sssbench.profiles.BurleyNormalized` with ``d`` = the
  scattering distance (:meth:`~sssbench.profiles.BurleyNormalized.from_scattering_distance`).
  Radii are drawn for the widest channel with HDRP's closed-form inverse CDF
  (:func:`~sssbench.ops._disk_radial.hdrp_burley_sample`); another profile gets the same
  rules with its tabulated sampler (HDRP has no such profile: our extension);
- filter radius ``R_f``: the 0.997 quantile of the sampled channel (mm);
- per pixel: ``pixels_per_mm = 1 / max(0.1 mm, pixel_size(z_p))`` (HDRP floors the pixel
  footprint at 0.0001 world units, 0.1 mm at its default 1 m per unit), sample count
  ``n = min(⌊π (R_f · pixels_per_mm)² / 4⌋, samples)`` (``SSS_PIXELS_PER_SAMPLE = 4``,
  ``samples`` the budget); ``n = 0``: the pixel keeps its irradiance (no filtering);
- sample ``i < n``: ``u_i = (i + ½)/n`` *fixed* (no radial jitter: frames average only
  over rotations), ``(r_i, rcpPdf_i)`` the radius and the inverse *polar* density, angle
  ``ψ_i = 2π frac(i/φ) + 2π φ(p, f)`` (``SampleDiskGolden``; φ the golden ratio; the
  per-pixel rotation from ``rotation`` — HDRP hashes the pixel and its device depth, we the
  pixel, seed and frame);
- fetch at ``(column, row) + round(r_i · pixels_per_mm · (cos ψ_i, sin ψ_i))`` (round half
  to even; rows downward as in HDRP's pixel coordinates); a sample outside the image is
  rejected (an out-of-bounds load returns 0, which fails HDRP's SSS tag test), as is one
  off the stencil (or on another profile, ``cross_profile``; HDRP without SSS occlusion
  accepts, i.e. ``"accept"``);
- weight per channel ``w_c = EvalBurley_c(r3D) · rcpPdf_i`` with ``r3D = √(r_i² + (z_i −
  z_p)²)`` — the nominal disk radius, not the fetched pixel's position, and the depth
  difference in mm — and ``EvalBurley_c(r) = S_c/(8π) (e^{−S_c r/3} + e^{−S_c r})``
  (the profile in polar measure, ``2π r R_c(r) / (2π ‖R_c‖₁)``);
- result ``Σ w_c E_c / max(Σ w_c, FLT_MIN)`` over the accepted samples (0 if none is).

**Loop**: the samples are gathered in C (:mod:`._disk_native`, ``native/disk.c``: the same
operations in the same order, geometry in float64, noise from this module or hashed in C from
its keys, :func:`hash_key`; vectorised across pixels at AVX2/AVX-512, ``native/disk_simd.h``;
float32 equal, float64 to 5e-14 of the torch loop in every tested combination,
``docs/numerics.md``); the torch loops below
(:meth:`DiskSSS._gather`, :meth:`DiskSSS._gather_hdrp`) are its specification and run instead
under ``gather.backend("torch")``, without the C library, for a profile other than
:class:`~sssbench.profiles.BurleyNormalized` / :class:`~sssbench.profiles.SumOfGaussians`, or
when autograd records the call (the torch loop is differentiable; the C loop has no backward).

Not reproduced (the G-buffer has no such inputs): HDRP's ``subsurfaceMask`` scales the
filter radius (``distScale``), where our ``mask`` is a stencil and strength; its albedo
multiply after the pass (texturing mode) is the pipeline's texturing stage here.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn

from sssbench._checks import check_choice, check_int, check_scalar
from sssbench.gbuffer import GBuffer, pixel_size_mm, view_positions
from sssbench.ops import _disk_native
from sssbench.ops._disk_noise import blue_noise_mask
from sssbench.ops._disk_radial import RadialSampler, radial_sampler
from sssbench.ops._repr import options_repr
from sssbench.ops._stencil import active_pixels, write_active
from sssbench.ops.functional import functional
from sssbench.ops.gather import get_backend
from sssbench.ops.pass_backends import PASS_BACKENDS_ABOVE, _disk_pass_backend
from sssbench.ops.reference import _minmod_slope
from sssbench.ops.timing import timed_pass
from sssbench.profiles.base import Profile
from sssbench.profiles.burley import BurleyNormalized

__all__ = [
    "DiskSSS",
    "disk_sss",
    "DISK_PATTERNS",
    "DISK_ROTATIONS",
    "DISK_FETCHES",
    "DISK_CROSS_PROFILE",
    "DISK_ESTIMATORS",
    "MAX_DISK_SAMPLES",
    "MAX_DISK_FRAMES",
]

DISK_PATTERNS = ("fibonacci", "r2")
DISK_ROTATIONS = ("hash", "ign", "blue_noise", "none")
DISK_FETCHES = ("point", "bilinear")
DISK_CROSS_PROFILE = ("reject", "accept")
#: ``"sssbench"``: the estimator of the module doc; ``"hdrp"``: Unity HDRP's pass exactly
#: (module doc, "estimator='hdrp'")
DISK_ESTIMATORS = ("sssbench", "hdrp")

#: largest ``samples`` (and ``adaptive[1]``) per pixel per frame: the pattern allocates
#: 16 bytes per sample and each sample is a pass over the pixels (HDRP's highest budget is
#: 1000)
MAX_DISK_SAMPLES = 1 << 16
#: largest ``frames`` (each frame is a full estimate)
MAX_DISK_FRAMES = 1 << 12
#: HDRP's golden ratio (``Golden2dSeq``: the i-th angle is ``2π frac(i / φ)``)
GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
#: HDRP: one sample per 4 pixels of the projected filter disk (``SSS_PIXELS_PER_SAMPLE``)
HDRP_PIXELS_PER_SAMPLE = 4
#: HDRP's filter radius: the radius holding 99.7 % of the widest channel's energy
HDRP_FILTER_CDF = 0.997
#: HDRP floors a pixel's footprint at 0.0001 world units (``max(0.0001f, unitsPerPixel)``):
#: 0.1 mm at its default world scale of 1 m per unit
HDRP_MIN_PIXEL_MM = 0.1
#: the sssbench estimator's "no weight": a normalised pixel whose total sample weight (``R/pdf``,
#: of order 1 for a sample inside the profile) is at or below it keeps its own irradiance, in
#: float32 and float64 alike (issue 29 class 3: a sample 20 mm away in depth has a weight that
#: float32 flushes to 0 and float64 keeps at 1e-100; the pixel must not flip on the dtype)
_NO_WEIGHT = 1e-30
#: HDRP's ``max(totalWeight, FLT_MIN)`` (the float32 smallest normal)
_FLT_MIN = 1.1754943508222875e-38

#: golden angle π (3 − √5) (Vogel's spiral; HDRP ``SampleDiskGolden``)
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
#: the plastic number g, g³ = g + 1 (Roberts' R2 sequence)
_PLASTIC = 1.324717957244746
_MASK32 = 0xFFFFFFFF


def _hash32(x: torch.Tensor) -> torch.Tensor:
    """Wellons' ``lowbias32`` integer hash on int64 tensors holding 32-bit values."""
    x = x & _MASK32
    x = x ^ (x >> 16)
    x = (x * 0x7FEB352D) & _MASK32
    x = x ^ (x >> 15)
    x = (x * 0x846CA68B) & _MASK32
    return x ^ (x >> 16)


def _hash32_int(x: int) -> int:
    """:func:`_hash32` on one Python integer (exact: no tensor, no float)."""
    x &= _MASK32
    x ^= x >> 16
    x = (x * 0x7FEB352D) & _MASK32
    x ^= x >> 15
    x = (x * 0x846CA68B) & _MASK32
    return x ^ (x >> 16)


#: the disk's seeds: its hash folds every bit of a 63-bit seed into its keys in exact integer
#: arithmetic (the APIs seeding a ``torch.Generator`` keep 32 bits: ``_checks.MAX_SEED``)
DISK_MAX_SEED = 2**63 - 1


def _seed_key(seed: int) -> int:
    """The 32-bit key of a seed in ``[0, 2⁶³ − 1]``, in exact integer arithmetic: the low 32
    bits hashed as they always were (seeds below 2³² keep their streams), the high bits
    hashed into it when there are any — every bit of the seed changes the key."""
    lo, hi = seed & _MASK32, seed >> 32
    key = _hash32_int(lo * 0x9E3779B1 + 0x632BE5AB)
    if hi:
        key = _hash32_int(key ^ _hash32_int(hi * 0x27D4EB2F + 0x165667B1))
    return key


def hash_uniform(pixel: torch.Tensor, seed: int, frame: int, stream: int) -> torch.Tensor:
    """Uniform ``[0, 1)`` float64 per pixel index (int64: the pixel's index *within its
    image*, so an image's noise does not depend on where it sits in a batch), reproducible
    from ``(seed, frame, stream)``: a chain of :func:`_hash32` keyed in exact integer
    arithmetic (:func:`_seed_key`; distinct streams are independent draws)."""
    return _hash32(pixel ^ hash_key(seed, frame, stream)).double() / 2.0**32


def hash_key(seed: int, frame: int, stream: int) -> int:
    """The 32-bit key :func:`hash_uniform` XORs into the pixel index before hashing (the
    disk's C loop takes it to hash the pixels itself: ``native/disk.c``)."""
    return _hash32_int(_seed_key(seed) ^ ((frame * 0x85EBCA77 + stream * 0xC2B2AE3D) & _MASK32))


def _ign_frame(seed: int, frame: int, stream: int) -> int:
    """The frame index interleaved gradient noise is evaluated at for ``(seed, frame,
    stream)``: ``frame + 31 stream + 7919 seed`` modulo 2³² for seeds below 2³² (so small
    seeds keep their noise), the high 32 bits of the seed hashed in; an exact integer below
    2³³ (float64 keeps every bit of it)."""
    lo, hi = seed & _MASK32, seed >> 32
    offset = (7919 * lo + (_hash32_int(hi * 0x27D4EB2F + 0x165667B1) if hi else 0)) & _MASK32
    return frame + 31 * stream + offset


def interleaved_gradient_noise(row: torch.Tensor, col: torch.Tensor, frame: int) -> torch.Tensor:
    """Jimenez 2014 (SIGGRAPH Advances, "Next generation post processing in Call of Duty:
    Advanced Warfare"): ``frac(52.9829189 frac(0.06711056 x + 0.00583715 y))`` at pixel
    ``(x, y)``, shifted by ``5.588238 f`` pixels per frame (as in UE's temporal samplers)."""
    x = col.double() + 5.588238 * frame
    y = row.double() + 5.588238 * frame
    return torch.frac(52.9829189 * torch.frac(0.06711056 * x + 0.00583715 * y))


#: side of the tiled blue-noise mask (pixels)
BLUE_NOISE_TILE = 64


def blue_noise_phase(
    row: torch.Tensor, col: torch.Tensor, seed: int, frame: int, stream: int
) -> torch.Tensor:
    """``frac((rank + ½)/T² + f (√5 − 1)/2)`` of the tiled void-and-cluster mask
    (:mod:`._disk_noise`) at a per-``(seed, stream)`` toroidal offset: blue noise in space in
    every frame, and the golden-ratio sequence per pixel over frames (the usual way engines
    animate a blue-noise texture)."""
    t = BLUE_NOISE_TILE
    mask = torch.from_numpy(blue_noise_mask(t))
    off = hash_uniform(torch.tensor([0, 1]), seed, 0, 1000 + stream)
    oy, ox = int(off[0] * t), int(off[1] * t)
    rank = mask[(row.long() + oy) % t, (col.long() + ox) % t].double()
    return torch.frac((rank + 0.5) / t**2 + frame * (math.sqrt(5.0) - 1.0) / 2.0)


def pattern_points(pattern: str, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Unrotated radial quantiles ``u`` and angles ``θ`` (radians) of ``n`` samples, float64."""
    i = torch.arange(n, dtype=torch.float64)
    if pattern == "fibonacci":
        return (i + 0.5) / n, i * GOLDEN_ANGLE
    a = torch.frac(0.5 + i / _PLASTIC)
    b = torch.frac(0.5 + i / _PLASTIC**2)
    return a, 2 * math.pi * b


class DiskSSS(nn.Module):
    """Importance-sampled disk SSS (module doc: estimator, rules and choices).

    Args:
        profile: radial diffusion profile (mm), or a list of them indexed per pixel by
            ``gbuffer.profile_id`` (then ``needs`` includes ``profile_id``); every channel's
            total must be > 0 and its widest channel non-negative (a density to sample).
        samples: samples per pixel per frame (N), at most :data:`MAX_DISK_SAMPLES`; with
            ``estimator="hdrp"`` the sample *budget* (HDRP's ``_SssSampleBudget``).
        pattern: ``"fibonacci"`` (golden-angle spiral) or ``"r2"``.
        rotation: per-pixel rotation: ``"hash"``, ``"ign"``, ``"blue_noise"`` or ``"none"``.
        frames: number of frames averaged (1 <= K <= :data:`MAX_DISK_FRAMES`).
        normalise: divide by the sum of weights per channel (HDRP); ``False``: plain MC.
        jitter_radius: per-pixel Cranley–Patterson shift of the radial quantiles; ``None``
            (default): the estimator's own (``True`` for ``"sssbench"``, ``False`` for
            ``"hdrp"``).
        fetch: ``"point"`` (HDRP) or ``"bilinear"``.
        adaptive: ``None`` or ``(n_min, n_max)`` (replaces ``samples``; see module doc).
        adaptive_target: target relative standard error of the adaptive rule, in (0, 1e3].
        cross_profile: with a list of profiles: ``"reject"`` or ``"accept"`` samples on
            another profile's pixels (module doc).
        surface_area: weight each sample by its pixel's surface area (module doc; the
            engines: ``False``).
        seed: seed of the rotation hash, an integer in [0, 2⁶³ − 1], every bit of which
            changes the noise (frame f of seed s differs from frame f of s + 1).
        estimator: ``"sssbench"`` (default: the module doc's estimator, weight ``R(d)/pdf``
            at the 3D distance, radial jitter) or ``"hdrp"`` (Unity HDRP's pass, module doc
            "estimator='hdrp'"; it fixes ``pattern``, ``normalise``, ``fetch``,
            ``jitter_radius``, ``adaptive`` and ``surface_area`` at HDRP's values, and a
            different explicit value is refused).

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)`` in the G-buffer's dtype.

    Example:
        >>> from sssbench.profiles import BurleyNormalized
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 300.0), 0.4)
        >>> out = DiskSSS(BurleyNormalized(1.0, 0.8), samples=8)(g)
        >>> bool(torch.allclose(out, g.diffuse))
        True
    """

    extra_repr = options_repr

    needs: tuple[str, ...] = ("mask",)

    def __init__(
        self,
        profile: Profile | Sequence[Profile],
        samples: int = 32,
        pattern: str = "fibonacci",
        rotation: str = "hash",
        frames: int = 1,
        normalise: bool = True,
        jitter_radius: bool | None = None,
        fetch: str = "point",
        adaptive: Sequence[int] | None = None,
        adaptive_target: float = 0.05,
        cross_profile: str = "reject",
        surface_area: bool = False,
        seed: int = 0,
        estimator: str = "sssbench",
    ) -> None:
        super().__init__()
        self.estimator = check_choice("estimator", estimator, DISK_ESTIMATORS)
        profiles = [profile] if isinstance(profile, Profile) else profile
        if not isinstance(profiles, Sequence) or not profiles:
            raise TypeError(
                f"profile must be a sssbench Profile or a non-empty list of them, got "
                f"{type(profile).__name__}"
            )
        name = "profile" if isinstance(profile, Profile) else "profile[{}]"
        self.kernels = [_Kernel.of(name.format(k), p) for k, p in enumerate(profiles)]
        self.profile = profile
        self.per_pixel = not isinstance(profile, Profile)
        if self.per_pixel:
            self.needs = ("mask", "profile_id")
        self.cross_profile = check_choice("cross_profile", cross_profile, DISK_CROSS_PROFILE)
        self.samples = check_int("samples", samples, 1, MAX_DISK_SAMPLES)
        self.pattern = check_choice("pattern", pattern, DISK_PATTERNS)
        self.rotation = check_choice("rotation", rotation, DISK_ROTATIONS)
        self.frames = check_int("frames", frames, 1, MAX_DISK_FRAMES)
        if jitter_radius is None:
            jitter_radius = self.estimator == "sssbench"
        for key, value in (
            ("normalise", normalise),
            ("jitter_radius", jitter_radius),
            ("surface_area", surface_area),
        ):
            if not isinstance(value, bool):
                raise TypeError(f"{key} must be a bool, got {type(value).__name__}")
        self.normalise = normalise
        self.jitter_radius = jitter_radius
        self.surface_area = surface_area
        self.fetch = check_choice("fetch", fetch, DISK_FETCHES)
        if adaptive is not None:
            if not isinstance(adaptive, Sequence) or len(adaptive) != 2:
                raise ValueError(f"adaptive must be None or (n_min, n_max), got {adaptive!r}")
            lo = check_int("adaptive[0]", adaptive[0], 1, MAX_DISK_SAMPLES)
            hi = check_int("adaptive[1]", adaptive[1], lo, MAX_DISK_SAMPLES)
            adaptive = (lo, hi)
        self.adaptive = adaptive
        # a relative standard error: above 1e3 it means nothing (and its square overflows)
        self.adaptive_target = check_scalar(
            "adaptive_target", adaptive_target, 0.0, 1e3, low_inclusive=False
        )
        self.seed = check_int("seed", seed, 0, DISK_MAX_SEED)  # every bit hashed (_seed_key)
        if self.estimator == "hdrp":
            hdrp = {
                "pattern": (self.pattern, "fibonacci"),
                "normalise": (self.normalise, True),
                "fetch": (self.fetch, "point"),
                "jitter_radius": (self.jitter_radius, False),
                "adaptive": (self.adaptive, None),
                "surface_area": (self.surface_area, False),
            }
            for key, (value, want) in hdrp.items():
                if value != want:
                    raise ValueError(
                        f"{key}={value!r} is not HDRP's: estimator='hdrp' runs with "
                        f"{key}={want!r} (leave it unset, or use estimator='sssbench')"
                    )
        #: per active pixel, the sample count of the last call's last frame (adaptive and
        #: ``estimator="hdrp"``; a diagnostic, overwritten by every call)
        self.last_counts: torch.Tensor | None = None

    def __repr__(self) -> str:
        return (
            f"DiskSSS({self.profile!r}, samples={self.samples}, pattern={self.pattern!r}, "
            f"rotation={self.rotation!r}, frames={self.frames}, normalise={self.normalise}, "
            f"adaptive={self.adaptive}, surface_area={self.surface_area}, "
            f"estimator={self.estimator!r})"
        )

    # ------------------------------------------------------------------ per-pixel noise
    def _phase(self, ctx: _Pixels, sel: torch.Tensor, frame: int, stream: int) -> torch.Tensor:
        """The rotation (turns, float64) of the active pixels ``sel`` in ``frame``: keyed on
        the pixel's position *in its image*, the seed, the frame and the stream."""
        if self.rotation == "hash":
            return hash_uniform(ctx.take(ctx.index, sel) % ctx.hw, self.seed, frame, 2 * stream)
        row, col = ctx.take(ctx.row, sel), ctx.take(ctx.col, sel)
        if self.rotation == "ign":
            return interleaved_gradient_noise(row, col, _ign_frame(self.seed, frame, stream))
        if self.rotation == "blue_noise":
            return blue_noise_phase(row, col, self.seed, frame, stream)
        return torch.zeros(sel.shape, dtype=torch.float64)

    def noise(
        self, gbuffer: GBuffer, frame: int, stream: int = 0
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The per-pixel random numbers of ``frame`` and ``stream`` as :meth:`forward` draws
        them: the rotation (turns) and the radial shift (0 without ``jitter_radius``), each
        ``(B, 1, H, W)`` float64 in ``[0, 1)``, 0 at pixels with ``mask == 0``. For backends
        that take them as a texture (the GL disk, :mod:`sssbench.gl`): GLSL 330 has no 64-bit
        integers for the hash of a 63-bit seed."""
        if not isinstance(gbuffer, GBuffer):
            raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
        frame = check_int("frame", frame, 0, MAX_DISK_FRAMES - 1)
        stream = check_int("stream", stream, 0, MAX_DISK_SAMPLES)
        ctx = _Pixels(gbuffer)
        pix = ctx.index
        phase = self._phase(ctx, ctx.every, frame, stream)
        shift = (
            hash_uniform(pix % ctx.hw, self.seed, frame, 2 * stream + 1)
            if self.jitter_radius
            else torch.zeros_like(phase)
        )
        b, h, w = gbuffer.shape
        planes = []
        for values in (phase, shift):
            full = torch.zeros(b * h * w, dtype=torch.float64).index_copy(0, pix, values.double())
            planes.append(full.reshape(b, 1, h, w))
        return planes[0], planes[1]

    def pixel_areas(self, gbuffer: GBuffer) -> torch.Tensor:
        """Each pixel's surface area (mm²) as ``surface_area=True`` weighs it (module doc):
        ``(B, 1, H, W)`` in the G-buffer's dtype. For backends that take it as a texture."""
        area = _Pixels(gbuffer, surface_area=True).area
        return area.reshape(gbuffer.depth.shape)

    # ------------------------------------------------------------------ one batch of samples
    def _gather(
        self,
        ctx: _Pixels,
        kernel: _Kernel,
        accept: torch.Tensor,
        sel: torch.Tensor,
        n: int,
        frame: int,
        stream: int,
        moments: bool = True,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """``Σ w E``, ``Σ w`` per channel ``(M, 3)`` and the second moments ``(M, 3, 3)``
        ``[Σ (w E)², Σ w² E, Σ w²]`` over ``n`` samples of the pattern with ``kernel`` for the
        active pixels ``sel`` (indices into ``ctx``); ``accept`` (flat, 1 / 0) says which
        pixels a sample may land on. ``moments=False``: the moments are not formed (``None``;
        only the adaptive pilot reads them), the sums are the same bit for bit.

        Geometry in differences (float32 keeps them): the sample's screen offset ``(Δr, Δc)``
        from its centre pixel, its depth as ``Δz = z_i − z_p`` (fetched as differences of
        depths), and ``x_i − x_p = x_p Δz / z_p + Δc · pixel_size(z_p + Δz)`` — never an
        absolute position subtracted from another."""
        pix = ctx.take(ctx.index, sel)
        z_c = ctx.depth[pix]
        # pixels per mm at the centre, float64 whatever the dtype: which pixel a sample lands
        # in must not depend on the dtype (a sample on a pixel boundary would jump)
        step = 1.0 / pixel_size_mm(z_c.double(), ctx.fov_y, ctx.h)
        u0, theta0 = pattern_points(self.pattern, n)
        if _disk_native.usable(ctx, kernel):  # the same loop in C (module _disk_native)
            # the hashes by their keys: the C loop hashes the pixels itself (same integers)
            hashed = self.rotation == "hash"
            turn = None if hashed else 2 * math.pi * self._phase(ctx, sel, frame, stream)
            jitter = self.jitter_radius
            return _disk_native.gather(
                ctx, kernel, accept, pix, turn, None, step, u0, theta0,
                self.fetch == "bilinear",
                turn_key=hash_key(self.seed, frame, 2 * stream) if hashed else None,
                shift_key=hash_key(self.seed, frame, 2 * stream + 1) if jitter else None,
                moments=moments,
            )  # fmt: skip
        phase = self._phase(ctx, sel, frame, stream)
        shift = (
            hash_uniform(pix % ctx.hw, self.seed, frame, 2 * stream + 1)
            if self.jitter_radius
            else 0.0
        )
        dt = ctx.dtype
        m = pix.numel()
        num = torch.zeros(m, 3, dtype=dt)
        den = torch.zeros(m, 3, dtype=dt)
        mom = torch.zeros(m, 3, 3, dtype=dt) if moments else None
        # the sample's geometry in float64 whatever the dtype (issue 29 class 3): a weight is
        # R(d) at a distance formed from a sub-pixel offset and interpolated depths, which the
        # long fuzz profile showed off by 6e-5 in float32 at 1 km depth; only colours stay in dt
        per_mm = pixel_size_mm(torch.ones((), dtype=torch.float64), ctx.fov_y, ctx.h)
        z_c64, pos_c64 = z_c.double(), ctx.pos[pix].double()  # (M,), (M, 3)
        for i in range(n):
            u = torch.frac(u0[i] + shift) if self.jitter_radius else u0[i].expand(m)
            r, inv_pdf = kernel.sampler.sample(u)
            theta = theta0[i] + 2 * math.pi * phase
            dcol64 = r * torch.cos(theta) * step
            drow64 = -r * torch.sin(theta) * step  # screen y is up, rows go down
            rgb, dz, ok, area = ctx.fetch(pix, drow64, dcol64, self.fetch, accept)
            dz = dz.double()
            lateral = (z_c64 + dz) * per_mm
            dx = pos_c64[:, 0] * (dz / z_c64) + dcol64 * lateral
            dy = pos_c64[:, 1] * (dz / z_c64) - drow64 * lateral
            dist = torch.sqrt(dx * dx + dy * dy + dz * dz)
            w = kernel.profile.evaluate(dist) * inv_pdf[:, None] / kernel.total
            if area is not None:  # surface area over the disk plane's pixel area
                w = w * (area.double() / pixel_size_mm(z_c64, ctx.fov_y, ctx.h) ** 2)[:, None]
            w = w.to(dt) * ok[:, None]
            f = w * rgb
            num += f
            den += w
            if mom is not None:
                mom += torch.stack([f * f, w * f, w * w], 2)
        return num, den, mom

    def _estimate(self, num: torch.Tensor, den: torch.Tensor, n: torch.Tensor | int, centre):
        if self.normalise:
            # a total weight at or below _NO_WEIGHT is no weight, in every dtype: the samples
            # lie many profile widths away, where float32 cannot form Σ w E / Σ w (w and w E
            # underflow) and float64 would hand the pixel to a sample of weight 1e-100
            safe = den > _NO_WEIGHT
            return torch.where(safe, num / torch.where(safe, den, 1.0), centre)
        return num / n

    def _relative_error2(
        self, num: torch.Tensor, den: torch.Tensor, mom: torch.Tensor, n: int
    ) -> torch.Tensor:
        """Squared relative standard error of the ``n``-sample estimate per channel (module
        doc, adaptive rule), ``(M, 3)``."""
        ff, wf, ww = mom.unbind(2)
        if self.normalise:  # delta method for the ratio Σ w E / Σ w
            safe = den > _NO_WEIGHT
            m = torch.where(safe, num / torch.where(safe, den, 1.0), 0.0)
            var = (ff - 2 * m * wf + m * m * ww).clamp_min(0) / torch.where(safe, den, 1.0) ** 2
        else:  # the mean of f = w E
            m = num / n
            var = (ff / n - m * m).clamp_min(0) / n
        return torch.where(m > 0, var / (m * m).clamp_min(1e-300), 0.0)

    def _frame(
        self, ctx: _Pixels, kernel: _Kernel, accept: torch.Tensor, sel: torch.Tensor, frame: int
    ) -> torch.Tensor:
        """One frame's scattered irradiance ``(M, 3)`` at the active pixels ``sel``."""
        if self.estimator == "hdrp":
            return self._frame_hdrp(ctx, kernel, accept, sel, frame)
        centre = ctx.take(ctx.centre, sel)
        if self.adaptive is None:
            with timed_pass("disk", self.samples, sel.numel()):
                num, den, _ = self._gather(
                    ctx, kernel, accept, sel, self.samples, frame, 0, moments=False
                )
            return self._estimate(num, den, self.samples, centre)
        lo, hi = self.adaptive
        with timed_pass("disk.pilot", lo, sel.numel()):
            num, den, mom = self._gather(ctx, kernel, accept, sel, lo, frame, 0)
        need = lo * self._relative_error2(num, den, mom, lo).amax(1) / self.adaptive_target**2
        count = torch.full_like(need, float(lo))
        level, k = lo, 1
        while level < hi:
            level = min(lo * 2**k, hi)
            count = torch.where(need > count, float(level), count)
            k += 1
        count_i = count.long()
        for level in sorted(set(count_i.tolist()) - {lo}):
            part = torch.nonzero(count_i == level).squeeze(1)
            with timed_pass(f"disk.adaptive{level}", level - lo, part.numel()):
                n2, d2, _ = self._gather(
                    ctx, kernel, accept, sel[part], level - lo, frame, level, moments=False
                )
            num[part] += n2
            den[part] += d2
        self.last_counts[sel] = count_i
        return self._estimate(num, den, count.to(num.dtype)[:, None], centre)

    # ------------------------------------------------------------------ estimator="hdrp"
    def hdrp_counts(self, gbuffer: GBuffer, kernel: int = 0) -> torch.Tensor:
        """HDRP's per-pixel sample count ``(B, 1, H, W)`` (int64) with profile ``kernel``:
        ``min(⌊π (R_f · pixels per mm)² / 4⌋, samples)`` (module doc)."""
        z = gbuffer.depth.double()
        return _hdrp_counts(self.kernels[kernel], z, gbuffer.fov_y, gbuffer.shape[1], self.samples)

    def _frame_hdrp(
        self, ctx: _Pixels, kernel: _Kernel, accept: torch.Tensor, sel: torch.Tensor, frame: int
    ) -> torch.Tensor:
        """One frame of HDRP's pass at the active pixels ``sel`` (module doc): the pixels
        are grouped by their sample count, each group one recorded pass."""
        out = ctx.take(ctx.centre, sel).clone()  # fewer than one sample: no filtering
        z_c = ctx.depth[ctx.take(ctx.index, sel)].double()
        counts = _hdrp_counts(kernel, z_c, ctx.fov_y, ctx.h, self.samples)
        self.last_counts[sel] = counts
        for n in sorted(set(counts.tolist()) - {0}):
            part = torch.nonzero(counts == n).squeeze(1)
            with timed_pass("disk", n, part.numel()):
                num, den = self._gather_hdrp(ctx, kernel, accept, sel[part], n, frame)
            out[part] = (num / den.clamp_min(_FLT_MIN)).to(out.dtype)
        return out

    def _gather_hdrp(
        self,
        ctx: _Pixels,
        kernel: _Kernel,
        accept: torch.Tensor,
        sel: torch.Tensor,
        n: int,
        frame: int,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``Σ w E`` and ``Σ w`` ``(M, 3)`` over HDRP's ``n`` samples for the pixels ``sel``."""
        pix = ctx.take(ctx.index, sel)
        base = pix - pix % ctx.hw
        row, col = ctx.take(ctx.row, sel).long(), ctx.take(ctx.col, sel).long()
        z_c = ctx.depth[pix]
        ppm = 1.0 / pixel_size_mm(z_c.double(), ctx.fov_y, ctx.h).clamp_min(HDRP_MIN_PIXEL_MM)
        turn = 2 * math.pi * self._phase(ctx, sel, frame, 0)
        i = torch.arange(n, dtype=torch.float64)
        r, rcp_pdf = kernel.sampler.sample_polar((i + 0.5) / n)  # fixed: no radial jitter
        phi = 2 * math.pi * torch.frac(i / GOLDEN_RATIO)
        if _disk_native.usable(ctx, kernel):  # the same loop in C (module _disk_native)
            return _disk_native.gather_hdrp(ctx, kernel, accept, pix, turn, ppm, r, rcp_pdf, phi)
        dt = ctx.dtype
        m = pix.numel()
        num = torch.zeros(m, 3, dtype=dt)
        den = torch.zeros(m, 3, dtype=dt)
        for k in range(n):
            psi = phi[k] + turn
            rs = row + torch.round(ppm * r[k] * torch.sin(psi)).long()
            cs = col + torch.round(ppm * r[k] * torch.cos(psi)).long()
            inside = (rs >= 0) & (rs < ctx.h) & (cs >= 0) & (cs < ctx.w)
            j = base + rs.clamp(0, ctx.h - 1) * ctx.w + cs.clamp(0, ctx.w - 1)
            dz = (ctx.depth[j] - z_c).double()
            r3 = torch.sqrt(r[k] * r[k] + dz * dz)
            w = kernel.polar(r3) * rcp_pdf[k]
            w = w.to(dt) * (inside.to(dt) * accept[j])[:, None]
            num += w * ctx.rgb[j]
            den += w
        return num, den

    def _groups(self, g: GBuffer, ctx: _Pixels):
        """``(kernel, accept, sel)`` per profile: its kernel, the pixels its samples may land
        on (flat 1 / 0) and its active pixels (indices into ``ctx``)."""
        if not self.per_pixel:
            return [(self.kernels[0], ctx.on, ctx.every)]
        if g.profile_id is None:
            raise ValueError("DiskSSS with a list of profiles needs gbuffer.profile_id")
        ids = g.profile_id.reshape(-1)
        if int(ids.max()) >= len(self.kernels):
            raise ValueError(
                f"profile_id must index the {len(self.kernels)} profiles, got max {int(ids.max())}"
            )
        centre_ids = ids[ctx.index]
        groups = []
        for k, kernel in enumerate(self.kernels):
            sel = torch.nonzero(centre_ids == k).squeeze(1)
            if sel.numel():
                same = ctx.on * (ids == k).to(ctx.on.dtype)
                groups.append((kernel, same if self.cross_profile == "reject" else ctx.on, sel))
        return groups

    def forward(self, gbuffer: GBuffer, *, inplace: bool = False) -> torch.Tensor:
        """Scattered diffuse ``(B, 3, H, W)`` (``inplace``: written into ``gbuffer.diffuse``)."""
        if not isinstance(gbuffer, GBuffer):
            raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
        if get_backend() in PASS_BACKENDS_ABOVE:  # e.g. the GL fragment shader (sssbench.gl)
            out = _disk_pass_backend(get_backend())(self, gbuffer)
            return gbuffer.diffuse.copy_(out) if inplace else out
        ctx = _Pixels(gbuffer, surface_area=self.surface_area)
        m = ctx.index.numel()
        counted = self.adaptive is not None or self.estimator == "hdrp"
        self.last_counts = torch.zeros(m, dtype=torch.long) if counted else None
        groups = self._groups(gbuffer, ctx)
        if self.frames == 1 and len(groups) == 1 and groups[0][2] is ctx.every:
            # one frame of every active pixel: the sum below is 0 + x and its mean x / 1,
            # x itself but for a zero's sign, which the lerp below does not keep
            scattered = self._frame(ctx, *groups[0], 0)
        else:
            acc = torch.zeros(m, 3, dtype=gbuffer.dtype)
            for kernel, accept, sel in groups:
                for frame in range(self.frames):
                    acc[sel] += self._frame(ctx, kernel, accept, sel, frame)
            scattered = acc / self.frames
        centre = ctx.centre
        strength = ctx.mask[ctx.index][:, None]
        value = centre + strength * (scattered - centre)
        out = write_active(gbuffer.diffuse, ctx.index, value.to(ctx.rgb.dtype))
        if inplace:
            return gbuffer.diffuse.copy_(out)
        return out


def _hdrp_counts(
    kernel: _Kernel, depth: torch.Tensor, fov_y: float, height: int, budget: int
) -> torch.Tensor:
    """HDRP's sample count at linear depths ``depth`` (mm, float64): the filter disk's area
    in pixels over :data:`HDRP_PIXELS_PER_SAMPLE`, truncated, capped at ``budget``."""
    ppm = 1.0 / pixel_size_mm(depth, fov_y, height).clamp_min(HDRP_MIN_PIXEL_MM)
    area = math.pi * (kernel.filter_radius * ppm) ** 2
    return torch.floor(area / HDRP_PIXELS_PER_SAMPLE).clamp_max(budget).long()


@dataclass(frozen=True)
class _Kernel:
    """One profile as the estimator uses it: the profile, its radial sampler and totals."""

    profile: Profile
    sampler: RadialSampler
    total: torch.Tensor

    @classmethod
    def of(cls, name: str, profile: Profile) -> _Kernel:
        if not isinstance(profile, Profile):
            raise TypeError(f"{name} must be a sssbench Profile, got {type(profile).__name__}")
        total = profile.total()
        if bool((total <= 0).any()):
            raise ValueError(f"{name} total must be > 0 in every channel, got {total.tolist()}")
        try:
            sampler = radial_sampler(profile)
        except ValueError as exc:  # not a density (module doc, "Premise")
            raise ValueError(f"{name} {exc}") from None
        return cls(profile, sampler, total)

    @property
    def filter_radius(self) -> float:
        """HDRP's filter radius (mm): the :data:`HDRP_FILTER_CDF` quantile of the sampled
        channel."""
        return self.sampler.quantile_radius(HDRP_FILTER_CDF)

    def polar(self, r: torch.Tensor) -> torch.Tensor:
        """``2π r R_c(r) / ‖R_c‖₁ / 2π`` per channel ``(M, 3)``, float64: the profile in
        polar measure, normalised — HDRP's ``EvalBurleyDiffusionProfile`` (``S/(8π)
        (e^{−Sr/3} + e^{−Sr})``, ``S = 1/d``) for Burley, in that closed form."""
        if type(self.profile) is BurleyNormalized:
            d = self.profile.d.double()
            rr = r.double()[:, None]
            return (torch.exp(-rr / (3 * d)) + torch.exp(-rr / d)) / (8 * math.pi * d)
        return r.double()[:, None] * self.profile.evaluate(r.double()) / self.total


class _Pixels:
    """Channels-last flat views of one G-buffer and its active pixels (for :class:`DiskSSS`)."""

    def __init__(self, g: GBuffer, surface_area: bool = False) -> None:
        b, h, w = g.shape
        self.h, self.w, self.hw, self.fov_y, self.dtype = h, w, h * w, g.fov_y, g.dtype
        mask = g.mask_or_ones()
        self.rgb = g.diffuse.permute(0, 2, 3, 1).reshape(b * h * w, 3)
        self.mask = mask.reshape(-1)
        self.on = (self.mask > 0).to(g.dtype)
        self.pos = view_positions(g.depth, g.fov_y).permute(0, 2, 3, 1).reshape(b * h * w, 3)
        self.depth = self.pos[:, 2]
        #: per pixel, its surface area (mm²): lateral footprint² × √(1 + s_x² + s_y²)
        self.area: torch.Tensor | None = None
        if surface_area:
            view = self.pos.reshape(b, h, w, 3).permute(0, 3, 1, 2)
            sx = _minmod_slope(g.depth, view[:, :1], 3)
            sy = _minmod_slope(g.depth, view[:, 1:2], 2)
            foot = pixel_size_mm(g.depth, g.fov_y, h)
            self.area = (foot**2 * torch.sqrt(1 + sx * sx + sy * sy)).reshape(-1)
        index = active_pixels(g.mask, b * h * w)
        self.index = torch.arange(b * h * w) if index is None else index
        #: the selection of every active pixel, in order (:meth:`take` answers it without
        #: an index pass; on the 512² close-up each such pass over 244 405 pixels took
        #: 1.5 ms, and with the rows it then gathers 4–6 ms, measured)
        self.every = torch.arange(self.index.numel())

    def take(self, t: torch.Tensor, sel: torch.Tensor) -> torch.Tensor:
        """``t[sel]`` for ``t`` indexed like :attr:`index` (one entry per active pixel):
        ``t`` itself when ``sel`` is :attr:`every` (the same values; callers only read it)."""
        return t if sel is self.every else t[sel]

    @functools.cached_property
    def row(self) -> torch.Tensor:
        """Each active pixel's row in its image ``(M,)``, in the image dtype."""
        return (self.index % self.hw // self.w).to(self.dtype)

    @functools.cached_property
    def col(self) -> torch.Tensor:
        """Each active pixel's column ``(M,)``, in the image dtype."""
        return (self.index % self.hw % self.w).to(self.dtype)

    @functools.cached_property
    def centre(self) -> torch.Tensor:
        """Each active pixel's own irradiance ``(M, 3)`` (read, never written)."""
        return self.rgb[self.index]

    def fetch(
        self,
        pix: torch.Tensor,
        drow: torch.Tensor,
        dcol: torch.Tensor,
        mode: str,
        accept: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Irradiance ``(M, 3)``, depth *difference* to the centre ``(M,)``, acceptance (1 /
        0, from the flat ``accept``) and surface area (``(M,)`` mm², ``None`` unless built
        with ``surface_area``) at the offset ``(drow, dcol)`` pixels from the centre pixels
        ``pix`` (flat indices), clamped to the edge of their image. The offset's integer and
        fractional parts are taken from the offset itself (not from the rounded absolute
        position) and depths are interpolated as differences to the centre's."""
        base = pix - pix % self.hw  # the image's first flat index
        rem = pix % self.hw
        row, col = rem // self.w, rem % self.w
        z_c = self.depth[pix]
        if mode == "point":
            ri = (row + torch.floor(drow + 0.5).long()).clamp(0, self.h - 1)
            ci = (col + torch.floor(dcol + 0.5).long()).clamp(0, self.w - 1)
            j = base + ri * self.w + ci
            area = None if self.area is None else self.area[j]
            return self.rgb[j], self.depth[j] - z_c, accept[j], area
        fr0, fc0 = torch.floor(drow), torch.floor(dcol)
        fr, fc = (drow - fr0).double(), (dcol - fc0).double()  # the offset's fraction, float64
        r0, c0 = row + fr0.long(), col + fc0.long()
        rows = (r0.clamp(0, self.h - 1), (r0 + 1).clamp(0, self.h - 1))
        cols = (c0.clamp(0, self.w - 1), (c0 + 1).clamp(0, self.w - 1))
        corners = [
            (rows[0], cols[0], (1 - fr) * (1 - fc)),
            (rows[0], cols[1], (1 - fr) * fc),
            (rows[1], cols[0], fr * (1 - fc)),
            (rows[1], cols[1], fr * fc),
        ]
        rgb = torch.zeros(drow.shape[0], 3, dtype=self.dtype)
        dz = torch.zeros_like(fr)
        total = torch.zeros_like(fr)
        area = None if self.area is None else torch.zeros_like(fr)
        nearest = None
        for ri, ci, wt in corners:
            j = base + ri * self.w + ci
            nearest = j if nearest is None else nearest
            wt = wt * accept[j].double()
            rgb += (wt[:, None] * self.rgb[j].double()).to(self.dtype)
            dz += wt * (self.depth[j] - z_c).double()  # a difference of two depths, then float64
            if area is not None:
                area += wt * self.area[j].double()
            total += wt
        ok = (total > 0).to(self.dtype)
        safe = torch.where(total > 0, total, 1.0)
        # all corners off the stencil: the sample is rejected; its depth is the first corner's
        dz = torch.where(total > 0, dz / safe, (self.depth[nearest] - z_c).double())
        area = None if area is None else area / safe
        return (rgb / safe[:, None].to(self.dtype)), dz, ok, area


#: the functional twin: every argument of :class:`DiskSSS`, kernels reused
disk_sss = functional(DiskSSS, "disk_sss")

"""Whole-scene Monte Carlo ground truth: the diffuse exitance of an analytic scene, per pixel.

For a scene with an analytic model (:func:`data_synth.mc_scenes.mc_model`: a plane, a thin
slab, a sphere) photons enter the surface where the scene's irradiance is, are walked through
the medium (:func:`sssbench.mc.transport.transport`) and the light leaving the
camera-visible surface is binned into the scene's pixels through the scene's own camera
(:func:`sssbench.gbuffer.view_positions`: pixel ``(i, j)`` covers
``x/z ∈ [(j − W/2), (j + 1 − W/2)]·2 tan(fov_y/2)/H`` and likewise ``y`` downward).

Quantity. The physical exitance ``M`` (per unit of the scene's irradiance, W mm⁻² for W mm⁻²)
includes the Fresnel loss at entry and the material's total diffuse reflectance; the
screen-space pipeline blurs the irradiance with a profile normalised to 1 (texturing off). The
two are compared through the material's diffuse albedo at normal incidence,
``ρ = (1 − F(0)) R_d`` (``R_d``: the MC total diffuse reflectance of the half-space,
:func:`sssbench.mc.transport.transport` from a point under normal incidence, with many
more photons than a pixel gets): the image is
``M / ρ``, which is exactly ``E`` on a uniformly, normally lit plane, as the blurred irradiance
is. What remains is the light transport the profile model leaves out or gets wrong: the
radial shape of the real point-spread function, the angle of incidence (Fresnel and the
refracted depth on a sphere), curvature, and light through thin parts.

Estimators:

* flat scenes (plane, slab): translation invariance makes the exitance a 2D convolution
  ``M = Σ_j E_j K_{k−j}`` of the per-pixel irradiance (constant over each pixel, extended
  beyond the frame by the border pixels) with the pixel-to-pixel transfer kernel
  ``K_m`` = the fraction of the light entering a pixel that leaves the camera face through
  the pixel ``m`` pixels away. ``K`` is estimated by one walk (entry uniform over a pixel,
  exits binned by pixel offset up to ``P = max(H, W)`` pixels; light leaving further away is
  reported as ``far``) and the convolution is exact (FFT, float64). Every photon serves
  every pixel, so the noise is spatially correlated.
* the sphere: entry points sampled over the whole ball in proportion to its irradiance
  (directional: uniform over the ball's disc seen from the light, which is ∝ ``n·l`` on the
  surface; ambient: uniform over the sphere with cosine-distributed incoming directions),
  refracted with weight ``1 − F``; a photon leaving a point that faces the camera is binned
  into the pixel it projects to, divided by the area of the sphere seen through that pixel
  (8 × 8 sub-rays per pixel).

Noise: the photons are split into ``batches`` independent walks (their own seeds); every
statistic (per-pixel standard error, the noise-corrected error of
:func:`noise_corrected_rel_rms`, its standard error by the jackknife over batches) is
computed from the batch images, so it holds for correlated noise too. Results are cached on
disk (``$SSSBENCH_CACHE_DIR/mc``) keyed by the model, the medium, photons, batches, seed and
the digest of all source of ``sssbench`` and ``data_synth`` (never stale).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass

import torch

from sssbench._checks import check_int, derive_seed
from sssbench.mc.boundary import normal_specular
from sssbench.mc.cache import cached_entry
from sssbench.mc.options import PROFILE_MATERIALS, check_options, medium_for
from sssbench.mc.parallel import cpu_seconds, run_jobs
from sssbench.mc.transport import Ball, Medium, Slab, _norm, refract_in, transport, warm_up
from sssbench.mc.walk import mean_stderr

__all__ = [
    "PROFILE_MATERIALS",
    "SceneMC",
    "check_options",
    "medium_for",
    "scene_mc",
    "noise_corrected_rel_rms",
]

_F64 = torch.float64
#: photons of the half-space walk that gives the normaliser ρ per channel
ALBEDO_PHOTONS = 1_000_000
#: sub-rays per pixel side for the sphere's per-pixel area
AREA_SUBSAMPLES = 8
#: default photons of a flat scene (per lit face): every photon serves every pixel
FLAT_PHOTONS = 4_000_000
#: default photons of the sphere per pixel that shows it
SPHERE_PHOTONS_PER_PIXEL = 8_000
#: runs of at least this many photons use two worker processes by default
PARALLEL_PHOTONS = 1_000_000


@dataclass
class SceneMC:
    """The Monte Carlo exitance of a scene.

    Attributes:
        batches: ``(B, 3, H, W)`` normalised exitance ``M/ρ`` of each independent batch.
        mask: ``(H, W)`` bool, pixels where the MC has a value (the object's visible surface).
        rho, rho_stderr: ``(3,)`` the normaliser ``(1 − F(0)) R_d`` and its standard error.
        far: ``(3,)`` flat scenes: fraction of the light entering a pixel that leaves the
            camera face more than ``P`` pixels away (left out of ``K``); 0 for the sphere.
        photons: photons launched over all batches (a third per channel).
        interactions: collisions simulated.
        seconds: wall time of the walks (of the run that filled the cache).
    """

    batches: torch.Tensor
    mask: torch.Tensor
    rho: torch.Tensor
    rho_stderr: torch.Tensor
    far: torch.Tensor
    photons: int
    interactions: int
    seconds: float

    @property
    def image(self) -> torch.Tensor:
        """``(1, 3, H, W)`` mean over batches."""
        return self.batches.mean(0, keepdim=True)

    @property
    def stderr(self) -> torch.Tensor:
        """``(1, 3, H, W)`` standard error of :attr:`image` (from the batches)."""
        b = self.batches.shape[0]
        return (self.batches.var(0, keepdim=True) / b).sqrt()

    @property
    def rate(self) -> float:
        """Interactions per second."""
        return self.interactions / max(self.seconds, 1e-9)


# ----------------------------------------------------------------------------- sources, scores
@dataclass(frozen=True)
class _PlaneSource:
    """Normal incidence, entry uniform over one pixel ``[0, cell)²`` of the face at ``z``
    (front face ``z = 0`` going ``+z``, back face going ``−z``)."""

    cell: float
    z: float
    down: bool
    weight: float

    def __call__(self, n: int, chan: torch.Tensor, gen: torch.Generator) -> tuple:
        xy = torch.rand(2, n, generator=gen, dtype=torch.float32) * self.cell
        pos = torch.cat([xy, torch.full((1, n), self.z, dtype=torch.float32)])
        dirn = torch.zeros(3, n, dtype=torch.float32)
        dirn[2] = 1.0 if self.down else -1.0
        return pos, dirn, torch.full((n,), self.weight, dtype=torch.float32)


@dataclass(frozen=True)
class _KernelScore:
    """Exits through the camera face ``z = 0`` binned by pixel offset ``(dy, dx)`` in
    ``[−P, P]²``; one extra bin (the last) for exits further away; back-face exits unscored."""

    cell: float
    radius: int

    def __call__(self, pos: torch.Tensor, dirn: torch.Tensor) -> torch.Tensor:
        p = self.radius
        side = 2 * p + 1
        mx = torch.floor(pos[0] / self.cell).long() + p
        my = torch.floor(pos[1] / self.cell).long() + p
        inside = (mx >= 0) & (mx < side) & (my >= 0) & (my < side)
        idx = torch.where(inside, my * side + mx, side * side)
        return torch.where(dirn[2] < 0, idx, -1)


@dataclass(frozen=True)
class _SphereSource:
    """Entry over the whole ball (local frame: centre at the origin) ∝ its irradiance."""

    radius: float
    light: tuple[float, float, float]
    p_directional: float
    eta: float

    def __call__(self, n: int, chan: torch.Tensor, gen: torch.Generator) -> tuple:
        r = self.radius
        # float32, the walk's photon state (sssbench.mc.transport); the frame in float64
        u = torch.rand(5, n, generator=gen, dtype=torch.float32)
        lt = torch.tensor(self.light, dtype=_F64)
        a = torch.linalg.cross(lt, torch.tensor([0.0, 0.0, 1.0], dtype=_F64))
        if float(a.norm()) < 1e-6:
            a = torch.linalg.cross(lt, torch.tensor([1.0, 0.0, 0.0], dtype=_F64))
        a = a / a.norm()
        b = torch.linalg.cross(lt, a)
        lt, a, b = lt.float(), a.float(), b.float()
        # directional: uniform over the disc of radius R perpendicular to l, onto the lit half
        rho, phi = r * u[0].sqrt(), 2 * math.pi * u[1]
        off = a[:, None] * (rho * torch.cos(phi)) + b[:, None] * (rho * torch.sin(phi))
        p_dir = off + lt[:, None] * torch.sqrt((r * r - rho * rho).clamp_min(0.0))
        # ambient: uniform over the sphere; incoming direction cosine-distributed about −n
        z = 2 * u[0] - 1
        s = torch.sqrt((1 - z * z).clamp_min(0.0))
        n_amb = torch.stack([s * torch.cos(phi), s * torch.sin(phi), z])
        directional = u[4] < self.p_directional
        normal = torch.where(directional, p_dir / r, n_amb)
        hemi = _cosine_hemisphere(normal, u[2], u[3])
        incoming = torch.where(directional, -lt[:, None].expand(3, n), -hemi)
        dirn, weight = refract_in(incoming, normal, self.eta)
        # start a hair inside: the first flight's distance to the boundary is then positive
        return normal * (r * (1 - 1e-7)), dirn, weight


def _cosine_hemisphere(normal: torch.Tensor, u1: torch.Tensor, u2: torch.Tensor) -> torch.Tensor:
    """Cosine-distributed unit vectors about unit ``normal`` (3, n) (Malley's method)."""
    t = (normal[0].abs() < 0.9).to(normal.dtype)
    helper = torch.stack([t, 1 - t, torch.zeros_like(t)])
    a = torch.linalg.cross(normal, helper, dim=0)
    a = a / _norm(a)
    b = torch.linalg.cross(normal, a, dim=0)
    rr, phi = u1.sqrt(), 2 * math.pi * u2
    return a * (rr * torch.cos(phi)) + b * (rr * torch.sin(phi)) + normal * (1 - u1).sqrt()


@dataclass(frozen=True)
class _CameraScore:
    """Exits from points that face the camera, binned into the pixel they project to."""

    center: tuple[float, float, float]
    height: int
    width: int
    fov_y: float

    def __call__(self, pos: torch.Tensor, dirn: torch.Tensor) -> torch.Tensor:
        c = torch.tensor(self.center, dtype=pos.dtype).view(3, 1)
        world = pos + c
        facing = (pos * world).sum(0) < 0  # outward normal ∝ pos, camera at the origin
        return _pixel_index(world, self.height, self.width, self.fov_y, facing)


def _pixel_index(
    world: torch.Tensor, h: int, w: int, fov_y: float, valid: torch.Tensor
) -> torch.Tensor:
    """Row-major pixel index of camera-frame points (3, n) (``view_positions``' convention),
    -1 outside the frame or where not ``valid``."""
    scale = (h / 2) / math.tan(fov_y / 2)
    j = torch.floor(world[0] / world[2] * scale + w / 2).long()
    i = torch.floor(h / 2 - world[1] / world[2] * scale).long()
    ok = valid & (world[2] > 0) & (i >= 0) & (i < h) & (j >= 0) & (j < w)
    return torch.where(ok, i * w + j, -1)


# ----------------------------------------------------------------------------- the runs
def _job(args: tuple) -> tuple[torch.Tensor, int, float]:
    medium, geometry, source, score, nbins, photons, seed, progress = args
    torch.set_num_threads(1)
    t = transport(
        medium, geometry, source, score, nbins, photons=photons, seed=seed, progress=progress
    )
    return t.sums, t.interactions, t.seconds


def _run_batches(jobs: list[tuple], workers: int) -> list[tuple[torch.Tensor, int, float]]:
    """Run independent walks (:func:`_job`), in ``workers`` processes when > 1
    (:func:`sssbench.mc.parallel.run_jobs`), the fused step compiled before the fork."""
    if workers > 1 and len(jobs) > 1:
        warm_up(jobs[0][1])  # compile the step once, here: the forked workers inherit it
    return run_jobs(_job, jobs, workers)


def _albedo(medium: Medium, photons: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``ρ = (1 − F(0)) R_d`` per channel and its standard error (module doc): ``R_d`` of the
    half-space under normal incidence by the scenes' own transport (``photons`` per channel,
    entering at one point, every exit scored)."""
    t_in = 1.0 - normal_specular(medium.eta)
    t = transport(medium, Slab(0.0), _PlaneSource(0.0, 0.0, True, 1.0), _every_exit, 1,
                  photons=3 * photons, seed=seed, progress=False)  # fmt: skip
    r, se = mean_stderr(t.sums[0, :, 0], t.sums[1, :, 0], photons)
    return t_in * r, t_in * se


def _every_exit(pos: torch.Tensor, dirn: torch.Tensor) -> torch.Tensor:
    """Score of :func:`_albedo`: every leaving photon in bin 0."""
    return torch.zeros(pos.shape[1], dtype=torch.long)


def _flat(model, medium, photons, batches, seed, workers, progress):  # noqa: ANN001, ANN202
    h, w = model.front.shape
    cell = model.pixel_mm
    p = max(h, w)
    side = 2 * p + 1
    weight = 1.0 - normal_specular(medium.eta)
    geometry = Slab(0.0, model.thickness)
    score = _KernelScore(cell, p)
    faces = [(model.front, _PlaneSource(cell, 0.0, True, weight))]
    if model.back is not None and bool((model.back > 0).any()):
        faces.append((model.back, _PlaneSource(cell, model.thickness, False, weight)))
    per = max(3, photons // (batches * len(faces)) // 3 * 3)
    out = torch.zeros(batches, 3, h, w, dtype=_F64)
    far = torch.zeros(3, dtype=_F64)
    inter, secs = 0, 0.0
    for f, (irr, source) in enumerate(faces):
        jobs = [
            (
                medium,
                geometry,
                source,
                score,
                side * side + 1,
                per,
                derive_seed(seed, "scene face batch", f, b),
                progress,
            )  # fmt: skip
            for b in range(batches)
        ]
        for b, (sums, n_int, s) in enumerate(_run_batches(jobs, workers)):
            k = sums[0] / (per // 3)  # (3, side² + 1): fraction per offset, per photon entering
            far += k[:, -1] / batches / len(faces)
            out[b] += _convolve(irr, k[:, :-1].reshape(3, side, side), p)
            inter += n_int
            secs += s
    total = batches * per * len(faces)
    return out, torch.ones(h, w, dtype=torch.bool), far, total, inter, secs


def _convolve(irr: torch.Tensor, kernel: torch.Tensor, p: int) -> torch.Tensor:
    """``M_k = Σ_j E_j K_{k−j}`` (3, H, W): ``irr`` (H, W) clamped at the border (replicate)
    by ``p`` pixels, ``kernel`` (3, 2p+1, 2p+1) indexed by offset + p; exact, by FFT."""
    h, w = irr.shape
    e = torch.nn.functional.pad(irr.view(1, 1, h, w), (p, p, p, p), mode="replicate")[0, 0]
    size = (h + 4 * p, w + 4 * p)
    full = torch.fft.irfft2(torch.fft.rfft2(e, size) * torch.fft.rfft2(kernel, size), size)
    return full[:, 2 * p : 2 * p + h, 2 * p : 2 * p + w]


def sphere_pixel_area(model, sub: int = AREA_SUBSAMPLES) -> torch.Tensor:  # noqa: ANN001
    """``(H, W)`` area (mm²) of the sphere seen through each pixel: ``sub × sub`` sub-rays,
    each ``τ² dΩ / |cos|`` (``τ``: distance to the hit, ``dΩ = du dv / |d|³``)."""
    h, w = model.resolution
    t = math.tan(model.fov_y / 2)
    k = (torch.arange(sub, dtype=_F64) + 0.5) / sub
    cols = (torch.arange(w, dtype=_F64)[:, None] + k[None, :]).reshape(-1)
    rows = (torch.arange(h, dtype=_F64)[:, None] + k[None, :]).reshape(-1)
    u = (cols - w / 2) / (h / 2) * t
    v = (h / 2 - rows) / (h / 2) * t
    d = torch.stack(torch.broadcast_tensors(u[None, :], v[:, None], torch.ones(1, 1, dtype=_F64)))
    norm = d.norm(dim=0)
    e = d / norm
    c = torch.tensor(model.center, dtype=_F64).view(3, 1, 1)
    b = (e * c).sum(0)
    disc = b * b - (c * c).sum() + model.radius**2
    hit = disc > 0
    tau = b - torch.sqrt(disc.clamp_min(0.0))
    nrm = (e * tau - c) / model.radius
    cos = (-(e * nrm).sum(0)).clamp_min(1e-12)
    d_omega = (2 * t / h / sub) ** 2 / norm**3
    area = torch.where(hit, tau * tau * d_omega / cos, 0.0)
    return area.view(h, sub, w, sub).sum((1, 3))


def _sphere_jobs(model, medium, per, batches, seed, progress):  # noqa: ANN001, ANN202
    """The batches' walks of the sphere (arguments of :func:`_job`)."""
    h, w = model.resolution
    r = model.radius
    phi_dir = model.intensity * math.pi * r * r
    p_dir = phi_dir / (phi_dir + model.ambient * 4 * math.pi * r * r)
    source = _SphereSource(r, model.light, p_dir, medium.eta)
    score = _CameraScore(model.center, h, w, model.fov_y)
    geometry = Ball((0.0, 0.0, 0.0), r)
    return [
        (medium, geometry, source, score, h * w, per, derive_seed(seed, "scene batch", b), progress)
        for b in range(batches)
    ]


def sphere_walk_rate(
    gbuffer: object,
    material: str | tuple = "skin1",
    *,
    photons: int,
    batches: int = 4,
    workers: int = 1,
    params: dict | None = None,
) -> tuple[int, float, float]:
    """``(collisions, wall seconds, CPU seconds)`` of the ``sphere`` scene's walks alone (no
    cache, no normaliser, no pixel areas): the cost measurement of docs/mc.md. CPU time is
    this process's plus that of the worker processes (Unix; this process's only elsewhere);
    both include compiling the fused step if this process has not yet
    (:func:`sssbench.mc.transport.warm_up`)."""
    import time

    from data_synth.mc_scenes import mc_model

    model = mc_model("sphere", gbuffer, params)
    per = max(3, photons // batches // 3 * 3)
    jobs = _sphere_jobs(model, medium_for(material), per, batches, 0, False)
    c0, t0 = cpu_seconds(), time.perf_counter()
    out = _run_batches(jobs, workers)
    return sum(o[1] for o in out), time.perf_counter() - t0, cpu_seconds() - c0


def _sphere(model, medium, photons, batches, seed, workers, progress):  # noqa: ANN001, ANN202
    h, w = model.resolution
    r = model.radius
    phi_dir = model.intensity * math.pi * r * r  # ∫ I max(0, n·l) dA over the sphere
    phi_amb = model.ambient * 4 * math.pi * r * r
    total_power = phi_dir + phi_amb
    per = max(3, photons // batches // 3 * 3)
    jobs = _sphere_jobs(model, medium, per, batches, seed, progress)
    area = sphere_pixel_area(model)
    covered = area > 0
    out = torch.zeros(batches, 3, h, w, dtype=_F64)
    inter, secs = 0, 0.0
    for b, (sums, n_int, s) in enumerate(_run_batches(jobs, workers)):
        flux = sums[0].view(3, h, w) * (total_power / (per // 3))
        out[b] = torch.where(covered, flux / area.clamp_min(1e-300), 0.0)
        inter += n_int
        secs += s
    return out, covered, torch.zeros(3, dtype=_F64), batches * per, inter, secs


def scene_mc(
    scene: str,
    gbuffer: object,
    params: dict | None = None,
    material: str | tuple = "skin1",
    *,
    photons: int | None = None,
    batches: int = 8,
    seed: int = 0,
    workers: int | None = None,
    cache: bool = True,
    progress: bool | None = None,
) -> SceneMC:
    """The Monte Carlo exitance of ``scene`` (module doc), from the cache or new walks.

    Args:
        scene: a name of :data:`data_synth.mc_scenes.MC_SCENES`.
        gbuffer: the scene's G-buffer (B = 1) as built with ``params`` (its camera, size and
            painted irradiance are used; the geometry is the analytic one).
        params: the scene's parameters (defaults of its builder otherwise).
        material: a material or profile-table name, or ``(σs′, σa[, η])`` (:func:`medium_for`).
        photons: photons over all batches (and faces), a third per channel; None:
            :data:`FLAT_PHOTONS` for a flat scene, :data:`SPHERE_PHOTONS_PER_PIXEL` per pixel
            showing the sphere.
        batches: independent walks (>= 2: the standard errors come from them).
        seed: base seed, an integer in [0, 2³² − 1] (checked here, on entry: the batches'
            seeds are hashes of it, :func:`~sssbench._checks.derive_seed`).
        workers: processes running the batches (1 = in this process); None: 2 for runs of
            at least :data:`PARALLEL_PHOTONS` photons, else 1.
        cache: read and write the disk cache.
        progress: tqdm bars per batch (None: for walks longer than ~3 s).

    Raises:
        ValueError: the scene has no Monte Carlo model.
    """
    from data_synth.mc_scenes import SphereMC, mc_model
    from sssbench._digest import code_digest

    seed, medium, batches = check_options(
        material, photons=photons, batches=batches, seed=seed, workers=workers
    )
    model = mc_model(scene, gbuffer, params)
    if photons is None:
        sphere = isinstance(model, SphereMC)
        covered = int((sphere_pixel_area(model) > 0).sum()) if sphere else 0
        photons = SPHERE_PHOTONS_PER_PIXEL * covered if sphere else FLAT_PHOTONS
    photons = check_int("photons", photons, 6)
    if workers is None:
        workers = 2 if photons >= PARALLEL_PHOTONS else 1
    workers = check_int("workers", workers, 1)
    key = {
        "kind": "scene",
        "scene": scene,
        "model": _model_key(model),
        "medium": [medium.sigma_s_prime, medium.sigma_a, medium.eta],
        "photons": photons,
        "batches": batches,
        "seed": seed,
        "albedo_photons": ALBEDO_PHOTONS,
        "code": code_digest(),
    }

    def compute() -> dict:
        run = _sphere if isinstance(model, SphereMC) else _flat
        raw, mask, far, total, inter, secs = run(
            model, medium, photons, batches, seed, workers, progress
        )
        rho, rho_se = _albedo(medium, ALBEDO_PHOTONS, derive_seed(seed, "scene albedo"))
        if not bool((rho > 0).all()):  # no albedo photon came back: M/ρ would be 0/0
            _no_albedo(material, rho)
        return {
            "batches": raw / rho.view(1, 3, 1, 1),
            "mask": mask,
            "rho": rho,
            "rho_stderr": rho_se,
            "far": far,
            "photons": total,
            "interactions": inter,
            "seconds": secs,
        }

    return SceneMC(**cached_entry("scene", key, compute, cache))


_CHANNELS = ("R", "G", "B")


def _no_albedo(material: object, rho: torch.Tensor) -> None:
    """Raise: the albedo walk returned no photon in some channel (ρ estimated as 0)."""
    dead = [c for c, r in zip(_CHANNELS, rho.tolist(), strict=True) if not r > 0]
    raise ValueError(
        f"material {material!r} scatters too little back in channel(s) {', '.join(dead)}: "
        f"none of {ALBEDO_PHOTONS} albedo photons returned (rho = 0), so the normalised "
        "exitance M/rho is undefined; use a material with more scattering"
    )


def _model_key(model: object) -> dict:
    out = {}
    for name, value in vars(model).items():
        if isinstance(value, torch.Tensor):
            out[name] = hashlib.sha256(value.double().contiguous().numpy().tobytes()).hexdigest()
        else:
            out[name] = value if not isinstance(value, float) or math.isfinite(value) else "inf"
    return json.loads(json.dumps(out, default=str))


# ----------------------------------------------------------------------------- the error
def noise_corrected_rel_rms(
    result: torch.Tensor, batches: torch.Tensor, mask: torch.Tensor | None = None
) -> tuple[float, float]:
    """Relative RMS error of ``result`` against the MC, with the MC's noise taken out.

    With ``x̂`` the mean of ``B`` independent batch images and ``se²`` its variance
    (``var_b / B``), ``E[(m − x̂)²] = (m − x)² + Var(x̂)``, so per pixel ``(m − x̂)² − se²`` is
    an unbiased estimate of the squared error against the noise-free ``x``; likewise
    ``x̂² − se²`` for ``x²``. The value is
    ``sqrt(max(0, Σ((m − x̂)² − se²)) / Σ(x̂² − se²))`` over the mask and the channels, and its
    standard error is the jackknife over batches (delete one batch, recompute; valid for
    noise correlated across pixels).

    Args:
        result: ``(1, 3, H, W)`` or ``(3, H, W)`` the image to score.
        batches: ``(B, 3, H, W)`` the batch images (B >= 3 for the jackknife).
        mask: ``(H, W)`` pixels to score (bool or 0/1), or None (all).

    Returns:
        ``(rel_rms, stderr)``.
    """
    m = result.reshape(1, *batches.shape[1:]).double()
    x = batches.double()
    sel = (
        torch.ones(x.shape[-2:], dtype=torch.bool)
        if mask is None
        else mask.reshape(x.shape[-2:]).bool()
    )
    if not bool(sel.any()):
        raise ValueError("mask must select at least one pixel")
    m, x = m[..., sel], x[..., sel]

    def value(xb: torch.Tensor) -> float:
        b = xb.shape[0]
        mean = xb.mean(0)
        var = xb.var(0) / b
        num = ((m[0] - mean) ** 2 - var).sum()
        den = (mean**2 - var).sum()
        return math.sqrt(max(0.0, float(num)) / float(den)) if float(den) > 0 else math.nan

    b = x.shape[0]
    full = value(x)
    if b < 3:
        return full, math.nan
    jack = torch.tensor([value(torch.cat([x[:i], x[i + 1 :]])) for i in range(b)], dtype=_F64)
    se = math.sqrt((b - 1) / b * float(((jack - jack.mean()) ** 2).sum()))
    return full, se

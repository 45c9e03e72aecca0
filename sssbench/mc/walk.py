"""Monte Carlo photon transport in a homogeneous medium (physical ground truth).

An analog random walk, vectorised in torch on the CPU: a batch of photons is advanced one free
flight at a time; a photon that leaves or is absorbed hands its slot to a new photon until all
``photons`` have been launched, then the batch drains (and is compacted). Lengths are in mean
free paths (σt = 1 without loss of generality; :mod:`sssbench.mc.searchlight` converts to mm).

Model (radiative transfer equation of a homogeneous medium, e.g. van de Hulst, *Multiple Light
Scattering*, 1980, ch. 2):

* free flights ``s = −ln(1 − ξ)`` (exponential, σt = 1);
* at a collision the photon is absorbed with probability ``1 − a`` (analog absorption, ``a`` =
  single-scattering albedo σs/σt), else scattered: isotropically (``cos θ = 2ξ − 1``) or by
  Henyey–Greenstein with anisotropy ``g`` (HG 1941; inversion
  ``cos θ = (1 + g² − ((1 − g²)/(1 − g + 2gξ))²)/(2g)``, the direction rotated about the old
  one as in Wang, Jacques & Zheng, MCML, 1995, eq. 3.30);
* the medium fills ``0 < z < thickness`` (``inf``: a half-space) and is entered at the origin
  along +z (normal incidence, which refraction does not deflect);
* boundary: index-matched (``eta = 1``: every photon reaching a face leaves) or a smooth
  dielectric of relative index ``eta``: a photon reaching a face from inside is reflected
  with the exact unpolarised Fresnel probability :func:`~sssbench.mc.boundary.fresnel_dielectric`
  (total internal reflection beyond the critical angle) and otherwise leaves. The specular
  reflection at entry, ``((η−1)/(η+1))²`` for normal incidence, is deterministic and kept out
  of the walk: every estimate is per photon that *entered* the medium (the convention of the
  dipole's ``R_d`` and of the searchlight profiles); :func:`slab` reports it separately.
  After a boundary event the next flight starts afresh at the face (the exponential flight is
  memoryless, so this is exact).

Estimators: each photon scores its weight in exactly one of top / bottom / absorbed (or is
lost to Russian roulette, below). Tallies are float64 sums of the weight and of its square, so
every estimate is a sample mean over photons with standard error ``√(var/N)``. Without
roulette the walk is analog (weights stay 1) and ``R + T + A = 1`` holds for every photon.

Russian roulette (only when ``roulette_radius`` is finite, for media without absorption where
the expected walk length is unbounded): each time a photon's distance from the entry point
doubles past ``roulette_radius`` it survives with probability 1/4 and its weight is multiplied
by 4 (unbiased; the expected work stays finite because a photon at distance D costs ~D² flights
while reaching it has probability ~1/D and surviving 1/D²).

Truncation (only when ``kill_radius`` is finite): a photon farther than ``kill_radius`` from the
entry point is terminated and its weight tallied as ``escaped`` (biased: it could still have come
back; the escaped fraction is reported so the bias is bounded by it). This bounds the number
of *serial* steps of the draining batch, ~``kill_radius²`` flights, which dominates the wall
time of lossless media (Spectralon: 25 mm are 290–510 mean free paths).

Cost: ``interactions`` counts collisions (scattering or absorption events; boundary
reflections are not interactions).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass

import torch

from sssbench._checks import check_int, check_scalar, check_seed
from sssbench.mc.boundary import fresnel_dielectric, normal_specular
from sssbench.mc.parallel import run_jobs

__all__ = ["WalkTally", "walk", "total_reflectance", "slab", "mean_stderr"]

_F64 = torch.float64
#: photon state (positions, directions, weights) is float32: positions stay below ~1e4 mfp,
#: where float32 resolves 1e-3 mfp, far below any bin; tallies are float64 sums
_F32 = torch.float32
#: photon fates, tally codes 1..5 (0 = still walking)
_FATES = ("top", "bottom", "absorbed", "roulette", "escaped")


def mean_stderr(s1: torch.Tensor, s2: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample mean and its standard error from the sums of per-photon scores ``s1 = Σx`` and
    ``s2 = Σx²`` over ``n`` photons (unbiased variance, ``n − 1``)."""
    mean = s1 / n
    var = (s2 / n - mean * mean).clamp_min(0.0) * (n / max(n - 1, 1))
    return mean, torch.sqrt(var / n)


@dataclass
class WalkTally:
    """Float64 sums of one run of :func:`walk` (weights ``w``: 1 without roulette).

    Attributes:
        photons: photons launched (N).
        interactions: collisions simulated (scattering + absorption events).
        seconds: wall time of the walk.
        top, bottom, absorbed, roulette, escaped: ``(2,)`` = ``(Σw, Σw²)`` of photons leaving
            through z = 0, through z = thickness, absorbed, killed by roulette (their weight
            before the kill) and terminated beyond ``kill_radius``.
        counts: photons per fate ``{"top", "bottom", "absorbed", "roulette", "escaped"}``
            (they sum to N).
        radial: ``(2, K)`` = ``(Σw, Σw²)`` of top exits per radial bin ``[edges[k], edges[k+1])``
            of the exit point's distance from the entry point (mfp), or ``None``.
        by_group: ``(G, 5 + K)`` = Σw per group of photons (photon ``i`` of the launch order
            is in group ``i mod G``) of each fate (the order of ``_FATES``: top, bottom,
            absorbed, roulette, escaped) and of each radial bin: independent batch
            estimates for jackknife standard errors of non-linear statistics
            (:mod:`sssbench.mc.significance`). ``G = 1`` unless ``groups`` was given.
        group_photons: ``(G,)`` photons per group.
    """

    photons: int
    interactions: int
    seconds: float
    top: torch.Tensor
    bottom: torch.Tensor
    absorbed: torch.Tensor
    roulette: torch.Tensor
    escaped: torch.Tensor
    counts: dict[str, int]
    radial: torch.Tensor | None = None
    by_group: torch.Tensor | None = None
    group_photons: torch.Tensor | None = None

    def estimate(self, which: str) -> tuple[float, float]:
        """``(mean, stderr)`` per photon of ``"top"``, ``"bottom"``, ``"absorbed"`` or
        ``"escaped"``, or of several fates together (``"top+escaped"``: each photon ends in
        one fate, so the sums add, squares included)."""
        s = sum(getattr(self, f) for f in which.split("+"))
        m, e = mean_stderr(s[0], s[1], self.photons)
        return float(m), float(e)

    @property
    def rate(self) -> float:
        """Interactions per second of wall time."""
        return self.interactions / max(self.seconds, 1e-9)

    @classmethod
    def total(cls, parts: list[WalkTally], seconds: float) -> WalkTally:
        """The tally of independent walks together (sums of their float64 sums and counts)."""
        radial = None if parts[0].radial is None else sum(p.radial for p in parts)
        by_group = None if parts[0].by_group is None else sum(p.by_group for p in parts)
        gphot = None if parts[0].group_photons is None else sum(p.group_photons for p in parts)
        return cls(
            photons=sum(p.photons for p in parts),
            interactions=sum(p.interactions for p in parts),
            seconds=seconds,
            counts={f: sum(p.counts[f] for p in parts) for f in _FATES},
            radial=radial,
            by_group=by_group,
            group_photons=gphot,
            **{f: sum(getattr(p, f) for p in parts) for f in _FATES},
        )


#: largest finite distance in mean free paths (thickness, roulette and kill radii): the walk
#: runs in float32 and squares radii (1e30 stays finite); farther than this is "never" for every
#: photon — pass inf
MAX_MFP = 1e15


def _check_distance(name: str, value: object) -> None:
    """A distance in mean free paths: > 0, and ``inf`` or at most :data:`MAX_MFP` (1e300 mfp
    overflowed float32 inside the walk: a torch message without the argument's name)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a number of mean free paths, got {value!r}")
    if not (value > 0 and (math.isinf(value) or value <= MAX_MFP)):
        raise ValueError(
            f"{name} must be > 0 and at most {MAX_MFP:g} mean free paths, or inf, got {value}"
        )


def _share_seed(seed: int, share: int) -> int:
    """Seed of the ``share``-th worker's generator: ``seed`` itself for the first, else a
    32-bit hash of both (the CPU generator keeps only 32 bits of a seed: ``seed + 2³²``
    would repeat the first share's photons)."""
    if share == 0:
        return seed
    digest = hashlib.blake2b(f"sssbench.mc.walk {seed} {share}".encode(), digest_size=4)
    return int.from_bytes(digest.digest(), "little")


def _walk_share(job: tuple) -> WalkTally:
    """One worker's walk of :func:`walk` (``workers`` > 1)."""
    albedo, photons, seed, kwargs = job
    return walk(albedo, photons=photons, seed=seed, **kwargs)


def _new_directions(
    dirn: torch.Tensor, xi_cos: torch.Tensor, xi_phi: torch.Tensor, g: float
) -> torch.Tensor:
    """Scattered directions ``(3, n)`` for every photon (caller keeps those that scattered)."""
    if g == 0.0:
        cost = 2 * xi_cos - 1  # isotropic: a fresh uniform direction
    else:  # HG inversion (module doc)
        frac = (1 - g * g) / (1 - g + 2 * g * xi_cos)
        cost = ((1 + g * g - frac * frac) / (2 * g)).clamp(-1.0, 1.0)
    sint = torch.sqrt((1 - cost * cost).clamp_min(0.0))
    phi = 2 * math.pi * xi_phi
    cphi, sphi = torch.cos(phi), torch.sin(phi)
    if g == 0.0:
        return torch.stack([sint * cphi, sint * sphi, cost])
    ux, uy, uz = dirn
    # MCML eq. 3.30 rotation about the old direction; near the poles the frame is the lab's
    tmp = torch.sqrt((1 - uz * uz).clamp_min(1e-300))
    polar = uz.abs() > 0.99999
    nx = torch.where(polar, sint * cphi, sint * (ux * uz * cphi - uy * sphi) / tmp + ux * cost)
    ny = torch.where(polar, sint * sphi, sint * (uy * uz * cphi + ux * sphi) / tmp + uy * cost)
    nz = torch.where(polar, torch.sign(uz) * cost, -sint * cphi * tmp + uz * cost)
    out = torch.stack([nx, ny, nz])
    return out / out.norm(dim=0, keepdim=True)  # renormalise against rounding drift


def _progress(total: int, enabled: bool | None):  # noqa: ANN202 - tqdm or a no-op
    """A tqdm bar on a terminal only, that appears only for runs longer than ~3 s
    (``enabled=None``; :func:`sssbench._console.bar`)."""
    from sssbench._console import bar

    return bar(enabled, total=total, unit="photon", unit_scale=True,
               delay=0 if enabled else 3.0, leave=False, desc="mc walk")  # fmt: skip


def walk(
    albedo: float,
    *,
    photons: int,
    g: float = 0.0,
    eta: float = 1.0,
    thickness: float = math.inf,
    seed: int = 0,
    radial_edges: torch.Tensor | None = None,
    roulette_radius: float = math.inf,
    kill_radius: float = math.inf,
    batch: int = 1 << 17,
    progress: bool | None = None,
    threads: int | None = 1,
    workers: int = 1,
    groups: int = 1,
) -> WalkTally:
    """Run the walk (module doc) and return its tallies.

    Args:
        albedo: single-scattering albedo σs/σt in [0, 1].
        photons: number of photons N >= 2.
        g: Henyey–Greenstein anisotropy in (−1, 1) (0 = isotropic).
        eta: relative refractive index of the medium in [1, 3] (1 = index-matched).
        thickness: slab thickness in mean free paths (> 0; ``inf`` = half-space).
        seed: seed of the ``torch.Generator`` (the result also depends on ``batch``).
        radial_edges: increasing bin edges (mfp, ``(K+1,)``) of the top-exit radius, or None.
        roulette_radius: distance (mfp) from the entry point beyond which roulette starts.
        kill_radius: distance (mfp) beyond which photons are terminated (module doc).
        batch: photons advanced together.
        progress: tqdm bar: None = only if the run takes more than ~3 s.
        threads: torch intra-op threads during the walk (restored after); None = leave as
            is. Default 1: on the shared 2-core development machine the walk ran ~10× *slower*
            on 2 threads than on 1 while other jobs loaded it (1.2 vs 11.7 M interactions/s)
            and equally fast when it was quiet (12.6 vs 12.7 M/s).
        workers: processes, each walking its share of the photons with its own generator
            (:func:`_share_seed`; one thread each), their tallies
            summed (:func:`sssbench.mc.parallel.run_jobs`). The result depends on
            ``workers``; ``seconds`` is the wall time of the whole.
        groups: independent groups of photons tallied apart (``WalkTally.by_group``; photon
            ``i`` of the launch order in group ``i mod groups``; with ``workers`` > 1 group
            ``g`` of every share is pooled). Changes no draw: the estimates are the same
            for every ``groups``.
    """
    a = check_scalar("albedo", albedo, 0.0, 1.0)
    photons = check_int("photons", photons, 2)
    g = check_scalar("g", g, -1.0, 1.0, low_inclusive=False, high_inclusive=False)
    eta = check_scalar("eta", eta, 1.0, 3.0)
    for name, value in (("thickness", thickness), ("roulette_radius", roulette_radius),
                        ("kill_radius", kill_radius)):  # fmt: skip
        _check_distance(name, value)
    if math.isinf(thickness) and a == 1.0 and math.isinf(kill_radius):
        raise ValueError(
            "albedo=1 in a half-space needs a finite kill_radius: the expected walk "
            "length is unbounded (and the reflectance is exactly 1)"
        )
    seed = check_seed("seed", seed)
    batch = check_int("batch", batch, 1)
    workers = check_int("workers", workers, 1)
    groups = check_int("groups", groups, 1)
    if workers > 1:
        kwargs = dict(g=g, eta=eta, thickness=thickness, radial_edges=radial_edges,
                      roulette_radius=roulette_radius, kill_radius=kill_radius, batch=batch,
                      progress=False, threads=1, groups=groups)  # fmt: skip
        shares = [photons // workers + (i < photons % workers) for i in range(workers)]
        jobs = [(a, n, _share_seed(seed, i), kwargs) for i, n in enumerate(shares) if n >= 2]
        t0 = time.perf_counter()
        return WalkTally.total(run_jobs(_walk_share, jobs, workers), time.perf_counter() - t0)
    if threads is not None:
        threads = check_int("threads", threads, 1)
        saved = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return walk(
                albedo,
                photons=photons,
                g=g,
                eta=eta,
                thickness=thickness,
                seed=seed,
                radial_edges=radial_edges,
                roulette_radius=roulette_radius,
                kill_radius=kill_radius,
                batch=batch,
                progress=progress,
                threads=None,
                groups=groups,
            )
        finally:
            torch.set_num_threads(saved)
    edges = None
    if radial_edges is not None:
        edges = torch.as_tensor(radial_edges, dtype=_F64)
        if edges.ndim != 1 or edges.numel() < 2 or not bool((edges[1:] > edges[:-1]).all()):
            raise ValueError("radial_edges must be a 1D strictly increasing tensor of >= 2 edges")
        if bool(edges[0] < 0) or not bool(torch.isfinite(edges).all()):
            raise ValueError("radial_edges must be finite and >= 0 (mean free paths)")

    gen = torch.Generator().manual_seed(seed)
    slab_ = math.isfinite(thickness)
    roul = math.isfinite(roulette_radius)
    r02 = roulette_radius**2 if roul else math.inf
    kill2 = kill_radius**2

    def fresh(n: int, first: int) -> tuple[torch.Tensor, ...]:
        pos = torch.zeros(3, n, dtype=_F32)
        dirn = torch.zeros(3, n, dtype=_F32)
        dirn[2] = 1.0
        grp = torch.arange(first, first + n, dtype=torch.int64) % groups
        return pos, dirn, torch.ones(n, dtype=_F32), torch.full((n,), r02, dtype=_F32), grp

    pos, dirn, w, thr2, grp = fresh(min(batch, photons), 0)
    launched = pos.shape[1]
    nbins = 0 if edges is None else edges.numel() - 1
    edges32 = None if edges is None else edges.to(_F32)
    # per-step tallies in one bincount: code 0 = alive, 1.. = _FATES, 6 + k = top exit in bin k
    acc = torch.zeros(3, len(_FATES) + 1 + nbins, dtype=_F64)  # Σw, Σw², count
    gacc = torch.zeros(groups * acc.shape[1], dtype=_F64)  # Σw per (group, code)
    inter = torch.zeros((), dtype=torch.int64)
    bar = _progress(photons, progress)

    t0 = time.perf_counter()
    while pos.shape[1] > 0:
        n = pos.shape[1]
        xi = torch.rand(5, n, generator=gen, dtype=_F32)
        s = -torch.log1p(-xi[0])  # ξ in [0, 1): s finite
        uz = dirn[2]
        if slab_:
            db = torch.where(uz < 0, -pos[2] / uz, torch.where(uz > 0, (thickness - pos[2]) / uz,
                                                                 math.inf))  # fmt: skip
        else:
            db = torch.where(uz < 0, -pos[2] / uz, math.inf)
        hit = s >= db
        pos += dirn * torch.minimum(s, db)
        at_top = hit & (uz < 0)
        pos[2] = torch.where(at_top, 0.0, torch.where(hit, thickness, pos[2]))
        if eta != 1.0:
            reflect = hit & (xi[1] < fresnel_dielectric(uz, eta))
            leave = hit & ~reflect
            dirn[2] = torch.where(reflect, -uz, uz)
        else:
            leave = hit
        coll = ~hit
        absorb = coll & (xi[1] >= a)  # ξ₁ also drew the Fresnel event: disjoint photons
        scatter = coll & ~absorb
        inter += coll.sum()
        dirn = torch.where(scatter, _new_directions(dirn, xi[2], xi[3], g), dirn)
        fate = torch.where(leave, torch.where(at_top, 1, 2), torch.where(absorb, 3, 0))
        if roul or math.isfinite(kill2):
            d2 = (pos * pos).sum(0)
        if math.isfinite(kill2):
            fate = torch.where((fate == 0) & (d2 >= kill2), 5, fate)
        if roul:
            cross = (fate == 0) & (d2 >= thr2)
            survive = xi[4] < 0.25
            fate = torch.where(cross & ~survive, 4, fate)  # scored with its weight before
            w = torch.where(cross & survive, 4 * w, w)
            thr2 = torch.where(cross, 4 * thr2, thr2)  # next doubling of the distance
        if nbins:
            k = torch.bucketize(torch.hypot(pos[0], pos[1]), edges32, right=True) - 1
            binned = (fate == 1) & (k >= 0) & (k < nbins)
            fate_idx = torch.where(binned, len(_FATES) + 1 + k, fate)
        else:
            fate_idx = fate
        dead_idx = torch.nonzero(fate > 0).flatten()  # tally only the photons that ended
        n_dead = dead_idx.numel()
        bar.update(n_dead)
        if n_dead == 0:
            continue
        wd = w[dead_idx].double()
        fi = fate_idx[dead_idx]
        m = acc.shape[1]
        acc[0] += torch.bincount(fi, weights=wd, minlength=m)
        acc[1] += torch.bincount(fi, weights=wd * wd, minlength=m)
        acc[2] += torch.bincount(fi, minlength=m)
        if groups > 1:
            gacc += torch.bincount(grp[dead_idx] * m + fi, weights=wd, minlength=groups * m)
        n_new = min(n_dead, photons - launched)
        if n_new:
            slots = dead_idx[:n_new]
            p0, d0, w0, t0_, g0 = fresh(n_new, launched)
            pos[:, slots], dirn[:, slots], w[slots], thr2[slots] = p0, d0, w0, t0_
            grp[slots] = g0
            launched += n_new
        if n_new < n_dead:  # draining: keep only live photons
            dead = torch.zeros(n, dtype=torch.bool)
            dead[dead_idx[n_new:]] = True
            keep = torch.nonzero(~dead).flatten()
            pos, dirn, w, thr2 = pos[:, keep], dirn[:, keep], w[keep], thr2[keep]
            grp = grp[keep]
    bar.close()
    seconds = time.perf_counter() - t0
    radial = acc[:, len(_FATES) + 1 :]
    sums = {f: acc[:2, i + 1].clone() for i, f in enumerate(_FATES)}
    sums["top"] += radial[:2].sum(1)
    counts = {f: int(acc[2, i + 1]) for i, f in enumerate(_FATES)}
    counts["top"] += int(radial[2].sum())
    if groups > 1:
        gsum = gacc.view(groups, acc.shape[1])[:, 1:].clone()  # drop code 0 (alive)
    else:
        gsum = acc[0, 1:].clone().view(1, -1)
    gsum[:, 0] += gsum[:, len(_FATES) :].sum(1)  # binned top exits are top exits too
    gphot = torch.tensor([photons // groups + (i < photons % groups) for i in range(groups)],
                         dtype=torch.int64)  # fmt: skip
    return WalkTally(
        by_group=gsum,
        group_photons=gphot,
        photons=photons,
        interactions=int(inter),
        seconds=seconds,
        radial=radial[:2].clone() if nbins else None,
        counts=counts,
        **sums,
    )


def total_reflectance(
    albedo: float, eta: float = 1.0, photons: int = 200_000, seed: int = 0
) -> tuple[float, float]:
    """Total diffuse reflectance of a semi-infinite medium, normal incidence, isotropic
    scattering, per photon entering (specular reflection excluded; module doc).

    Args:
        albedo: single-scattering albedo in [0, 1) (at 1 the reflectance is exactly 1 and the
            analog walk's expected length unbounded).
        eta: relative refractive index in [1, 3].
        photons: number of photons.
        seed: generator seed.

    Returns:
        ``(R, stderr)``.

    Oracle (η = 1): ``1 − H(1)√(1 − a)`` (:func:`sssbench.mc.hfunction.halfspace_reflectance`).
    """
    a = check_scalar("albedo", albedo, 0.0, 1.0, high_inclusive=False)
    return walk(a, photons=photons, eta=eta, seed=seed).estimate("top")


def slab(
    albedo: float,
    thickness: float,
    eta: float = 1.0,
    g: float = 0.0,
    photons: int = 200_000,
    seed: int = 0,
) -> dict[str, float]:
    """Reflectance, transmittance and absorptance of a slab under normal incidence.

    Args:
        albedo: single-scattering albedo in [0, 1].
        thickness: optical thickness (mean free paths), > 0 and finite.
        eta: relative refractive index of the slab (same medium, air, on both sides).
        g: Henyey–Greenstein anisotropy.
        photons, seed: as :func:`walk`.

    Returns:
        ``{"R", "R_stderr", "T", "T_stderr", "A", "A_stderr"}`` per photon entering,
        ``"specular"`` (the entry reflection, not part of R), ``"photons"``, ``"counts_sum"``
        (photons whose fate was counted: equals ``photons``), ``"interactions"``, ``"seconds"``.
    """
    thickness = check_scalar("thickness", thickness, 0.0, None, low_inclusive=False)
    t = walk(albedo, photons=photons, g=g, eta=eta, thickness=thickness, seed=seed)
    out: dict[str, float] = {}
    for key, which in (("R", "top"), ("T", "bottom"), ("A", "absorbed")):
        out[key], out[f"{key}_stderr"] = t.estimate(which)
    out["specular"] = normal_specular(eta)
    out["photons"] = t.photons
    out["counts_sum"] = sum(t.counts.values())
    out["interactions"] = t.interactions
    out["seconds"] = t.seconds
    return out

"""Monte Carlo transport in a homogeneous body of any convex shape, with sources and scores.

The general form of the walk of :mod:`sssbench.mc.walk` (same physics: exponential free
flights, analog absorption, isotropic scattering with the reduced coefficient σs′, the smooth
dielectric boundary with exact unpolarised Fresnel reflection), for whole scenes:

* **implicit capture** instead of analog absorption: every collision scatters and keeps the
  fraction ``α′`` of the photon's weight; Russian roulette ends light photons (weight below
  :data:`ROULETTE_WEIGHT`, survival ``1/``:data:`ROULETTE_GAIN`, unbiased). Far more photons
  reach the surface than in an analog walk of a strongly absorbing channel (skin's blue),
  which is what a per-pixel estimate needs;
* lengths in **mm**, the three RGB channels in one batch (photon ``i`` carries channel
  ``i mod 3``, so every channel gets exactly a third of the photons), each with its own
  ``σt′ = σs′ + σa`` and albedo ``α′ = σs′/σt′`` (:class:`Medium`);
* a **geometry** (:class:`Slab`: ``z0 < z < z1`` in the camera frame, ``z1 = inf`` a
  half-space; :class:`Ball`) gives the distance to the boundary along a ray from inside
  and the outward normal at a boundary point;
* a **source** ``source(n, chan, gen) -> (pos (3, n), dirn (3, n), w (n,))`` launches photons
  just inside the surface, already refracted, with their entry weight (``1 − F`` of the
  entry Fresnel reflection: implicit capture of the specular part, which is not diffuse
  exitance);
* a **score** ``score(pos, dirn) -> bin (n,)`` (``-1``: not scored) bins every photon that
  leaves; the tallies are float64 sums of the weight and its square per ``(channel, bin)``.

Reflection at the boundary: a photon reaching the surface from inside is reflected with
probability ``F(cos θ, η)`` (mirror about the normal) and otherwise leaves (Born & Wolf §1.5;
:func:`~sssbench.mc.boundary.fresnel_dielectric`). The exit direction is not needed by the
scores here (exitance counts all the flux leaving a patch, whatever its direction).

Cost choices (docs/mc.md, "Cost"): photon state in float32, updated in place; the flights and
collisions of :data:`SUBSTEPS` steps per call in one function (:func:`_fly_and_collide`)
compiled by ``torch.compile`` into a single loop over the photons (eager when compilation is
unavailable: :mod:`sssbench.mc.fused`), fed by one 64-bit random draw per photon and step
(three uniforms, :func:`_uniforms`); boundary events (a minority of the steps) and Russian
roulette handled between calls on the indexed subset only; photons launched and scored in
chunks of ``batch`` (one source and one score call per chunk); a finished photon's slot is
refilled in place, and the batch is compacted only when it has drained to less than half.
The walk runs on one torch thread (a second core is used by a second walk process,
:mod:`sssbench.mc.scene`). ``interactions`` counts collisions (scattering + absorption).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from sssbench._checks import check_int, check_seed
from sssbench.mc.boundary import fresnel_dielectric
from sssbench.mc.fused import MIN_COMPILED, Fused, torch_threads

__all__ = [
    "Medium",
    "Slab",
    "Ball",
    "TransportTally",
    "transport",
    "refract_in",
    "exit_distance",
    "warm_up",
]

_F32 = torch.float32
_F64 = torch.float64
#: implicit capture: Russian roulette below this weight ...
ROULETTE_WEIGHT = 1e-2
#: ... survival 1/ROULETTE_GAIN, surviving weight multiplied by it
ROULETTE_GAIN = 10.0
#: a photon reflected at a face with |cos θ| below this is ended (see the walk loop)
GRAZING_COS = 1e-4


@dataclass(frozen=True)
class Medium:
    """A homogeneous medium per RGB channel (mm⁻¹): reduced scattering σs′, absorption σa,
    relative refractive index η (isotropic scattering with σs′: the similarity relation)."""

    sigma_s_prime: tuple[float, float, float]
    sigma_a: tuple[float, float, float]
    eta: float = 1.3

    def __post_init__(self) -> None:
        for name in ("sigma_s_prime", "sigma_a"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != 3 or not all(math.isfinite(x) and x >= 0 for x in v):
                raise ValueError(f"{name} must be 3 finite values >= 0 mm^-1, got {v}")
            object.__setattr__(self, name, v)
        if not all(s + a > 0 for s, a in zip(self.sigma_s_prime, self.sigma_a, strict=True)):
            raise ValueError("sigma_s_prime + sigma_a must be > 0 in every channel")
        if not 1.0 <= float(self.eta) <= 3.0:
            raise ValueError(f"eta must be in [1, 3], got {self.eta}")

    @property
    def sigma_t(self) -> torch.Tensor:
        """``(3,)`` σt′ = σs′ + σa, mm⁻¹."""
        return torch.tensor(self.sigma_s_prime, dtype=_F64) + torch.tensor(self.sigma_a, dtype=_F64)

    @property
    def albedo(self) -> torch.Tensor:
        """``(3,)`` single-scattering albedo α′ = σs′/σt′."""
        return torch.tensor(self.sigma_s_prime, dtype=_F64) / self.sigma_t


@dataclass(frozen=True)
class Slab:
    """The medium ``z0 < z < z1`` (camera frame, mm; ``z1 = inf``: a half-space). The face
    ``z = z0`` looks toward the camera (outward normal ``−z``)."""

    z0: float
    z1: float = math.inf

    def params(self) -> torch.Tensor:
        """``(2,)`` float32 ``(z0, z1)`` for :func:`exit_distance`."""
        return torch.tensor([self.z0, self.z1], dtype=_F32)

    def normal(self, pos: torch.Tensor) -> torch.Tensor:
        """Outward normal at boundary points: ``−z`` on the front face, ``+z`` on the back."""
        if math.isinf(self.z1):
            nz = torch.full_like(pos[2], -1.0)
        else:
            nz = torch.where(pos[2] < 0.5 * (self.z0 + self.z1), -1.0, 1.0)
        return torch.stack([torch.zeros_like(nz), torch.zeros_like(nz), nz])


@dataclass(frozen=True)
class Ball:
    """The medium ``|p − center| < radius`` (camera frame, mm)."""

    center: tuple[float, float, float]
    radius: float

    def params(self) -> torch.Tensor:
        """``(4,)`` float32 ``(cx, cy, cz, radius)`` for :func:`exit_distance`."""
        return torch.tensor([*self.center, self.radius], dtype=_F32)

    def _local(self, pos: torch.Tensor) -> torch.Tensor:
        if self.center == (0.0, 0.0, 0.0):
            return pos
        return pos - torch.tensor(self.center, dtype=pos.dtype).view(3, 1)

    def normal(self, pos: torch.Tensor) -> torch.Tensor:
        return self._local(pos) * (1.0 / self.radius)


def refract_in(
    incoming: torch.Tensor, normal: torch.Tensor, eta: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Light arriving from air along unit ``incoming`` (3, n) at a surface with outward unit
    ``normal`` (3, n): the refracted direction inside (Snell, ``sin θt = sin θi / η``) and the
    transmitted fraction ``1 − F(cos θi, 1/η)`` (Born & Wolf §1.5.2)."""
    cos_i = (-(incoming * normal).sum(0)).clamp(0.0, 1.0)
    k = 1.0 / eta
    cos_t = torch.sqrt((1 - k * k * (1 - cos_i * cos_i)).clamp_min(0.0))
    t = incoming * k + normal * (k * cos_i - cos_t)
    return t / _norm(t), 1.0 - fresnel_dielectric(cos_i, k)


def exit_distance(
    pos: torch.Tensor | list[torch.Tensor],
    dirn: torch.Tensor | list[torch.Tensor],
    geo: torch.Tensor,
) -> torch.Tensor:
    """Distance ``(n,)`` along unit ``dirn`` (3, n) from ``pos`` (3, n) inside the medium to its
    boundary (``pos``, ``dirn`` may also be given as their three rows): ``geo`` =
    :meth:`Slab.params` ``(z0, z1)`` (``inf`` beyond a face it never
    reaches) or :meth:`Ball.params` ``(cx, cy, cz, R)`` (the far root of
    ``|p + t d − c|² = R²``, ``t = −b + √(b² − |p − c|² + R²)``, ``b = (p − c)·d``)."""
    if geo.shape[0] == 4:
        px, py, pz = pos[0] - geo[0], pos[1] - geo[1], pos[2] - geo[2]
        b = px * dirn[0] + py * dirn[1] + pz * dirn[2]
        cc = px * px + py * py + pz * pz - geo[3] * geo[3]
        return ((b * b - cc).clamp_min(0.0).sqrt() - b).clamp_min(0.0)
    uz = dirn[2]
    front = uz < 0  # uz = ±0: parallel to the faces, +inf (|uz| turns −0 into +0)
    return torch.where(front, geo[0] - pos[2], geo[1] - pos[2]) / torch.where(front, uz, uz.abs())


def _fly_and_collide(
    pos: torch.Tensor,
    dirn: torch.Tensor,
    w: torch.Tensor,
    inv_st: torch.Tensor,
    alb: torch.Tensor,
    x: torch.Tensor,
    geo: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:data:`SUBSTEPS` steps of every photon, stopping at the boundary (fused by
    :class:`~sssbench.mc.fused.Fused`).

    Each step is a free flight ``s = −ln ξ/σt`` (ξ in (0, 1): finite; 0 for a parked
    photon, ``1/σt = 0``), or up to the boundary when that is nearer: the photon then stands
    on the face (``hit``) for the caller's boundary event and is frozen for the remaining
    steps (direction and weight as it arrived). Otherwise it collides: implicit capture keeps
    the fraction ``α′`` of the weight (MCML, Wang et al. 1995 §3.6) and isotropic scattering
    draws a fresh uniform direction (``cos θ = 2ξ − 1``, ``φ = 2πξ``). Several steps per
    call share one pass over the photon state; Russian roulette, applied by the caller
    between calls, sees the weights a few collisions late, which changes the work, not the
    expectation.

    Args:
        pos, dirn: ``(3, n)`` position (mm) and unit direction; w, inv_st, alb: ``(n,)``
            weight, ``1/σt′`` (mm) and ``α′`` per photon — updated in place;
            x: ``(SUBSTEPS, n)`` int64 of 63 random bits each, the three uniforms of a step
            (flight, cos θ, φ; :func:`_uniforms`);
            geo: the geometry's :meth:`params`.

    Returns:
        ``(hit (n,) bool, collisions (n,) int32)`` per photon.
    """
    hit = torch.zeros_like(w, dtype=torch.bool)
    coll = torch.zeros_like(w, dtype=torch.int32)
    # per component, so that the compiled steps are one loop over the photons
    p, d, ww = list(pos.unbind(0)), list(dirn.unbind(0)), w
    for k in range(SUBSTEPS):
        u0, u1, u2 = _uniforms(x[k])
        s = torch.log(u0) * -inv_st
        db = exit_distance(p, d, geo)
        arrive = (s >= db) & ~hit
        collide = ~(hit | arrive)
        t = torch.where(hit, 0.0, torch.minimum(s, db))
        p = [pi + di * t for pi, di in zip(p, d, strict=True)]
        cost = 2 * u1 - 1
        sint = (1 - cost * cost).clamp_min(0.0).sqrt()
        phi = (2 * math.pi) * u2
        new = (sint * torch.cos(phi), sint * torch.sin(phi), cost)
        d = [torch.where(collide, ni, di) for ni, di in zip(new, d, strict=True)]
        ww = torch.where(collide, ww * alb, ww)
        hit = hit | arrive
        coll = coll + collide.to(torch.int32)
    pos.copy_(torch.stack(p))
    dirn.copy_(torch.stack(d))
    w.copy_(ww)
    return hit, coll


#: steps per call of the fused step function
SUBSTEPS = 4
#: bits per uniform of :func:`_uniforms` (three from one 63-bit draw)
_UBITS = 21


def _uniforms(r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Three independent uniforms in (0, 1) (float32) from 63 random bits ``r`` (int64 >= 0):
    bits ``[42, 63)``, ``[21, 42)``, ``[0, 21)``, each ``(k + ½)/2²¹``. One 64-bit draw of
    the generator costs about as much as one float32 draw: a third of the random-number
    time. The resolution, 2⁻²¹ ≈ 5·10⁻⁷, is far below any Monte Carlo error here; the
    midpoint keeps ξ off 0 and 1 (the free flight ``−ln ξ`` is at most 15.2 mean free paths,
    which cuts a tail of probability 2.4·10⁻⁷)."""
    mask = (1 << _UBITS) - 1
    scale = 1.0 / (1 << _UBITS)
    out = [(((r >> (_UBITS * i)) & mask).to(torch.float32) + 0.5) * scale for i in (2, 1, 0)]
    return out[0], out[1], out[2]


_STEP = Fused(_fly_and_collide)


def warm_up(geometry: Slab | Ball) -> None:
    """Compile the fused step for this kind of geometry now (no-op when compilation is off or
    failed): before forking walk processes, so that they inherit it instead of each
    compiling it (sssbench.mc.scene)."""
    if not _STEP.active:
        return
    n = MIN_COMPILED
    pos = _parking(geometry, _F32, n).contiguous()
    dirn = torch.zeros(3, n, dtype=_F32)
    dirn[2] = 1.0
    w, inv_st, alb = (torch.ones(n, dtype=_F32) for _ in range(3))  # distinct: no aliasing
    x = torch.zeros(SUBSTEPS, n, dtype=torch.int64)
    with torch_threads(1):
        _STEP(pos, dirn, w, inv_st, alb, x, geometry.params())


def _norm(v: torch.Tensor) -> torch.Tensor:
    """``|v|`` of the columns of ``(3, n)`` (elementwise: faster than a strided reduction)."""
    return (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt_()


@dataclass
class TransportTally:
    """Float64 tallies of one :func:`transport` run.

    Attributes:
        photons: photons launched (a third per channel).
        sums: ``(2, 3, nbins)``: Σw and Σw² of the leaving photons per channel and bin.
        interactions: collisions simulated.
        seconds: wall time.
    """

    photons: int
    sums: torch.Tensor
    interactions: int
    seconds: float

    @property
    def rate(self) -> float:
        """Interactions per second of wall time."""
        return self.interactions / max(self.seconds, 1e-9)


Source = Callable[[int, torch.Tensor, torch.Generator], tuple[torch.Tensor, ...]]
Score = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def transport(
    medium: Medium,
    geometry: Slab | Ball,
    source: Source,
    score: Score,
    nbins: int,
    *,
    photons: int,
    seed: int = 0,
    batch: int = 1 << 16,
    progress: bool | None = None,
) -> TransportTally:
    """Run the walk (module doc); return the per-channel, per-bin tallies of leaving photons.

    Args:
        medium: coefficients per channel.
        geometry: :class:`Slab` or :class:`Ball`.
        source: launches ``n`` photons of channels ``chan (n,)`` (module doc).
        score: bins leaving photons, ``(n,)`` long in ``[-1, nbins)``.
        nbins: number of bins.
        photons: photons to launch (>= 3).
        seed: seed of the ``torch.Generator``.
        batch: photons advanced together.
        progress: tqdm bar (None: only if the run takes more than ~3 s).
    """
    from sssbench.mc.walk import _progress

    photons = check_int("photons", photons, 3)
    nbins = check_int("nbins", nbins, 1)
    batch = check_int("batch", batch, 3)
    gen = torch.Generator().manual_seed(check_seed("seed", seed))
    inv_st_c = (1.0 / medium.sigma_t).to(_F32)
    alb_c = medium.albedo.to(_F32)
    eta = float(medium.eta)
    sums = torch.zeros(2, 3 * nbins, dtype=_F64)
    inter = 0
    bar = _progress(photons, progress)

    launch = _Launcher(source, photons, batch, gen)
    tally = _Tally(score, nbins, sums, batch)
    n = min(batch, photons)
    pos, dirn, w, chan = launch(n)
    launched = n
    inv_st, alb = inv_st_c[chan], alb_c[chan]
    xi = torch.empty(SUBSTEPS, n, dtype=torch.int64)
    geo = geometry.params()
    parked = 0  # finished photons left in place (no flight, no collision) until compaction
    with torch_threads(1):  # the fused step is compiled for one thread (sssbench.mc.fused)
        t0 = time.perf_counter()
        while n > parked:
            x = xi.random_(generator=gen)  # 63 bits per step: flight, cos θ, φ (_uniforms)
            hit, coll = _STEP(pos, dirn, w, inv_st, alb, x, geo)
            hidx = hit.nonzero().squeeze(1)
            # parked photons (s = 0 < db) count a collision every step
            inter += int(coll.sum(dtype=torch.int64)) - SUBSTEPS * parked
            # boundary events on the subset: reflected (Fresnel) or leaving
            leave_idx, grazing = hidx, None
            if hidx.numel() and eta != 1.0:
                d_h = dirn[:, hidx]
                nrm = geometry.normal(pos[:, hidx])
                cosn = (d_h * nrm).sum(0)
                u = torch.rand(hidx.numel(), generator=gen, dtype=_F32)
                refl = u < fresnel_dielectric(cosn, eta)
                dirn[:, hidx[refl]] = (d_h - 2 * cosn * nrm)[:, refl]  # mirror about the normal
                # a photon gliding along a curved face in total internal reflection would advance
                # by rounding errors only, forever: it is ended (unscored) instead; fraction of the
                # flux reaching a face that grazing, ~GRAZING_COS²
                graze = refl & (cosn.abs() < GRAZING_COS)
                if bool(graze.any()):
                    grazing = hidx[graze]
                leave_idx = hidx[~refl]
            # Russian roulette below ROULETTE_WEIGHT: survive with probability 1/ROULETTE_GAIN,
            # weight multiplied by it (unbiased), repeated until the weight is above the threshold
            low = (w < ROULETTE_WEIGHT).nonzero().squeeze(1)
            killed = [] if grazing is None else [grazing]
            if low.numel() and (leave_idx.numel() or grazing is not None):
                live = torch.ones(n, dtype=torch.bool)  # a photon ends once: not rouletted too
                live[leave_idx] = False
                if grazing is not None:
                    live[grazing] = False
                low = low[live[low]]
            while low.numel():
                u = torch.rand(low.numel(), generator=gen, dtype=_F32) * ROULETTE_GAIN
                killed.append(low[u >= 1.0])
                low = low[u < 1.0]
                w[low] *= ROULETTE_GAIN
                low = low[w[low] < ROULETTE_WEIGHT]
            if leave_idx.numel():  # leaving photons keep the weight and direction they arrived with
                tally.add(pos[:, leave_idx], dirn[:, leave_idx], w[leave_idx], chan[leave_idx])
            didx = torch.cat([leave_idx, *killed])
            n_dead = didx.numel()
            if n_dead == 0:
                continue
            bar.update(n_dead)
            n_new = min(n_dead, photons - launched)
            if n_new:
                slots = didx[:n_new]
                p0, d0, w0, c0 = launch(n_new)
                pos[:, slots], dirn[:, slots], w[slots], chan[slots] = p0, d0, w0, c0
                inv_st[slots], alb[slots] = inv_st_c[c0], alb_c[c0]
                launched += n_new
            if n_new == n_dead:
                continue
            gone = didx[n_new:]
            parked += gone.numel()
            inv_st[gone], alb[gone], w[gone] = 0.0, 1.0, 1.0  # park: no flight, weight kept at 1
            pos[:, gone] = _parking(geometry, pos.dtype, gone.numel())
            if 2 * parked >= n:  # drained to half: compact
                keep = (inv_st > 0).nonzero().squeeze(1)
                pos, dirn, w, chan = pos[:, keep], dirn[:, keep], w[keep], chan[keep]
                inv_st, alb = inv_st[keep], alb[keep]
                n, parked = keep.numel(), 0
                xi = torch.empty(SUBSTEPS, n, dtype=torch.int64)
        tally.flush()
        bar.close()
    seconds = time.perf_counter() - t0
    return TransportTally(photons, sums.view(2, 3, nbins), inter, seconds)


class _Launcher:
    """Photons ``0, 1, …, photons − 1`` of the source, handed out in order (photon ``i`` carries
    channel ``i mod 3``) and generated in chunks of ``chunk``: a source is tens of torch calls
    whatever the number of photons, and the walk refills only a few slots per step."""

    def __init__(self, source: Source, photons: int, chunk: int, gen: torch.Generator) -> None:
        self.source, self.photons, self.chunk, self.gen = source, photons, chunk, gen
        self.made = 0  # photons generated so far
        self.pool: tuple[torch.Tensor, ...] = ()
        self.at = 0  # next unused photon of the pool

    def __call__(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The next ``n`` photons: ``pos (3, n)``, ``dirn (3, n)``, ``w (n,)`` float32, ``chan``."""
        parts = []
        while n > 0:
            if not self.pool or self.at == self.pool[-1].numel():
                m = min(self.chunk, self.photons - self.made)
                chan = torch.arange(self.made, self.made + m) % 3
                pos, dirn, w = self.source(m, chan, self.gen)
                self.pool, self.at = (pos.to(_F32), dirn.to(_F32), w.to(_F32), chan), 0
                self.made += m
            k = min(n, self.pool[-1].numel() - self.at)
            parts.append(tuple(t[..., self.at : self.at + k] for t in self.pool))
            self.at += k
            n -= k
        if len(parts) == 1:
            return parts[0]  # type: ignore[return-value]
        return tuple(torch.cat(ts, dim=-1) for ts in zip(*parts, strict=True))  # type: ignore[return-value]


class _Tally:
    """Float64 sums of the weight and its square per ``(channel, bin)`` of the photons that
    left, scored in chunks of at least ``chunk`` photons (one score call per chunk)."""

    def __init__(self, score: Score, nbins: int, sums: torch.Tensor, chunk: int) -> None:
        self.score, self.nbins, self.sums, self.chunk = score, nbins, sums, chunk
        self.pending: list[tuple[torch.Tensor, ...]] = []
        self.count = 0

    def add(
        self, pos: torch.Tensor, dirn: torch.Tensor, w: torch.Tensor, chan: torch.Tensor
    ) -> None:  # noqa: E501
        self.pending.append((pos, dirn, w, chan))
        self.count += w.numel()
        if self.count >= self.chunk:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        pos, dirn, w, chan = (torch.cat(ts, dim=-1) for ts in zip(*self.pending, strict=True))
        self.pending, self.count = [], 0
        bins = self.score(pos, dirn)
        ok = bins >= 0
        wl = w[ok].double()
        flat = chan[ok] * self.nbins + bins[ok]
        self.sums[0].index_add_(0, flat, wl)
        self.sums[1].index_add_(0, flat, wl * wl)


def _parking(geometry: Slab | Ball, dtype: torch.dtype, n: int) -> torch.Tensor:
    """A point deep inside the geometry for parked photons (they fly 0 and are absorbed)."""
    if isinstance(geometry, Ball):
        p = torch.tensor(geometry.center, dtype=dtype)
    else:
        z = geometry.z0 + (1.0 if math.isinf(geometry.z1) else 0.5 * (geometry.z1 - geometry.z0))
        p = torch.tensor([0.0, 0.0, z], dtype=dtype)
    return p.view(3, 1).expand(3, n)

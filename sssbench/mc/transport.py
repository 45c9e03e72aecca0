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

Cost choices (docs/mc.md, "Cost"): photon state in float32 in preallocated buffers updated in
place; random numbers drawn into one reused buffer; boundary events (a minority of the steps)
handled on the indexed subset only; a finished photon's slot is refilled in place, and the
batch is compacted only when it has drained to less than half. ``interactions`` counts
collisions (scattering + absorption).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from sssbench._checks import check_int
from sssbench.mc.boundary import fresnel_dielectric

__all__ = ["Medium", "Slab", "Ball", "TransportTally", "transport", "refract_in"]

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

    def exit_distance(self, pos: torch.Tensor, dirn: torch.Tensor) -> torch.Tensor:
        uz = dirn[2]
        front = (self.z0 - pos[2]) / uz
        if math.isinf(self.z1):
            return torch.where(uz < 0, front, math.inf)
        return torch.where(uz < 0, front, (self.z1 - pos[2]) / uz)

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

    def _local(self, pos: torch.Tensor) -> torch.Tensor:
        if self.center == (0.0, 0.0, 0.0):
            return pos
        return pos - torch.tensor(self.center, dtype=pos.dtype).view(3, 1)

    def exit_distance(self, pos: torch.Tensor, dirn: torch.Tensor) -> torch.Tensor:
        p = self._local(pos)
        b = (p * dirn).sum(0)
        cc = (p * p).sum(0).sub_(self.radius**2)
        return (b * b).sub_(cc).clamp_min_(0.0).sqrt_().sub_(b).clamp_min_(0.0)

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
    gen = torch.Generator().manual_seed(check_int("seed", seed, 0))
    inv_st_c = (1.0 / medium.sigma_t).to(_F32)
    alb_c = medium.albedo.to(_F32)
    eta = float(medium.eta)
    sums = torch.zeros(2, 3 * nbins, dtype=_F64)
    inter = 0
    bar = _progress(photons, progress)

    def launch(start: int, n: int) -> tuple[torch.Tensor, ...]:
        chan = torch.arange(start, start + n) % 3
        pos, dirn, w = source(n, chan, gen)
        return pos.to(_F32), dirn.to(_F32), w.to(_F32), chan

    n = min(batch, photons)
    pos, dirn, w, chan = launch(0, n)
    launched = n
    inv_st, alb = inv_st_c[chan], alb_c[chan]
    xi = torch.empty(3, n, dtype=_F32)
    parked = 0  # finished photons left in place (no flight, no collision) until compaction
    t0 = time.perf_counter()
    while n > parked:
        x = torch.rand(3, n, generator=gen, out=xi)  # flight, cos θ, φ
        # s = −ln(1 − ξ)/σt, in place; finite for every ξ in [0, 1); 0 for parked photons
        s = x[0].neg_().log1p_().mul_(inv_st).neg_()
        db = geometry.exit_distance(pos, dirn)
        hit = s >= db
        torch.minimum(s, db, out=s)
        pos.addcmul_(dirn, s)
        hidx = hit.nonzero().squeeze(1)
        inter += n - parked - hidx.numel()  # every other photon collided (parked: s = 0 < db)
        # boundary events on the subset: reflected (Fresnel, ξ₁) or leaving; their direction
        # and weight are saved here and restored after the collision updates below
        leave_idx, p_h, d_h, w_h = hidx, pos[:, hidx], dirn[:, hidx], w[hidx]
        d_keep = d_h
        grazing = None
        if hidx.numel() and eta != 1.0:
            nrm = geometry.normal(p_h)
            cosn = (d_h * nrm).sum(0)
            u = torch.rand(hidx.numel(), generator=gen, dtype=_F32)
            refl = u < fresnel_dielectric(cosn, eta)
            d_keep = torch.where(refl, d_h - 2 * cosn * nrm, d_h)
            # a photon gliding along a curved face in total internal reflection would advance
            # by rounding errors only, forever: it is ended (unscored) instead; fraction of the
            # flux reaching a face that grazing, ~GRAZING_COS²
            graze = refl & (cosn.abs() < GRAZING_COS)
            if bool(graze.any()):
                grazing = hidx[graze]
            leave_idx, p_h, d_h = hidx[~refl], p_h[:, ~refl], d_h[:, ~refl]
        # collisions, written for every photon (cheaper than selecting the colliders):
        # implicit capture (MCML, Wang et al. 1995 §3.6) keeps the fraction a of the weight
        # (parked photons: a = 1), and isotropic scattering draws a fresh uniform direction
        w.mul_(alb)
        cost = x[1].mul_(2).sub_(1)
        sint = (1 - cost * cost).clamp_min_(0.0).sqrt_()
        phi = x[2].mul_(2 * math.pi)
        dirn[2].copy_(cost)
        torch.cos(phi, out=dirn[0]).mul_(sint)
        torch.sin(phi, out=dirn[1]).mul_(sint)
        if hidx.numel():  # photons at the boundary did not collide
            w[hidx], dirn[:, hidx] = w_h, d_keep
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
        if leave_idx.numel():
            bins = score(p_h, d_h)
            ok = bins >= 0
            if bool(ok.any()):
                wl = w_h[~refl][ok].double() if eta != 1.0 else w_h[ok].double()
                flat = chan[leave_idx][ok] * nbins + bins[ok]
                sums[0].index_add_(0, flat, wl)
                sums[1].index_add_(0, flat, wl * wl)
        didx = torch.cat([leave_idx, *killed])
        n_dead = didx.numel()
        if n_dead == 0:
            continue
        bar.update(n_dead)
        n_new = min(n_dead, photons - launched)
        if n_new:
            slots = didx[:n_new]
            p0, d0, w0, c0 = launch(launched, n_new)
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
            xi = torch.empty(3, n, dtype=_F32)
    bar.close()
    seconds = time.perf_counter() - t0
    return TransportTally(photons, sums.view(2, 3, nbins), inter, seconds)


def _parking(geometry: Slab | Ball, dtype: torch.dtype, n: int) -> torch.Tensor:
    """A point deep inside the geometry for parked photons (they fly 0 and are absorbed)."""
    if isinstance(geometry, Ball):
        p = torch.tensor(geometry.center, dtype=dtype)
    else:
        z = geometry.z0 + (1.0 if math.isinf(geometry.z1) else 0.5 * (geometry.z1 - geometry.z0))
        p = torch.tensor([0.0, 0.0, z], dtype=dtype)
    return p.view(3, 1).expand(3, n)

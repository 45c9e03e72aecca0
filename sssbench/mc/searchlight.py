"""Searchlight profiles of the measured materials by Monte Carlo (ground truth for R(r)).

A pencil beam enters a semi-infinite medium at normal incidence; the light leaving the
surface is binned by the distance ``r`` of its exit point from the entry point into annuli
``[radii[k], radii[k+1])`` and divided by the annulus area, giving the radial exitance ``R(r)``
in mm⁻² per unit flux *entering* the medium — the quantity the dipole's ``R(r)`` and every
profile of :mod:`sssbench.profiles` model (their ``total()`` is ``R_d``).

Model: the walk of :mod:`sssbench.mc.walk` per RGB channel with isotropic scattering of
coefficient σs′ (the similarity relation σs′ = σs(1 − g) that the dipole also rests on),
absorption σa, ``σt′ = σs′ + σa``, single-scattering albedo ``α′ = σs′/σt′`` and the smooth
dielectric boundary of relative index η (1.3 for the table of
:data:`sssbench.profiles.dipole.MATERIALS`). Lengths in mean free paths are converted to mm
by ``1/σt′``. Russian roulette starts at the largest radius (photons wandering further are
kept with probability 1/4 per doubling of their distance, unbiased) and photons farther than
twice the largest radius from the entry point (at least 200 mean free paths in absorbing
channels) are terminated (biased; their fraction is reported as ``escaped`` and bounds the
bias: such a photon must travel at least the largest radius back to reach any annulus).
Without that cut lossless media (Spectralon) need ~(2 r_max σt′)² serial flights to drain.

Results are cached on disk (``$SSSBENCH_CACHE_DIR/mc`` else ``~/.cache/sssbench/mc``), keyed
by the coefficients, η, radii, photons, seed, batch and the SHA-256 of every source file of
this package, so an edited walk never serves an old profile.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import torch

from sssbench._checks import check_int, check_scalar, check_seed, derive_seed
from sssbench.mc.cache import cached_entry, mc_cache_dir
from sssbench.mc.walk import mean_stderr, walk
from sssbench.profiles.dipole import MATERIALS

__all__ = ["SearchlightResult", "searchlight", "searchlight_result", "mc_cache_dir", "mc_digest"]

_F64 = torch.float64


def _source_digest() -> str:
    h = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:24]


#: digest of the source as imported (read once: an edit on disk after import must not label
#: results of the code still running in this process as the edited code's)
_SOURCE_DIGEST = _source_digest()


def mc_digest() -> str:
    """SHA-256 (24 hex digits) of every ``*.py`` of :mod:`sssbench.mc`, as imported."""
    return _SOURCE_DIGEST


@dataclass
class SearchlightResult:
    """Radial exitance of a pencil beam, per RGB channel.

    Attributes:
        radii: ``(K+1,)`` annulus edges in mm.
        fraction, fraction_stderr: ``(K, 3)`` fraction of the entering flux that leaves
            through each annulus (``∫ 2πr R dr`` over it) and its standard error.
        total, total_stderr: ``(3,)`` total diffuse reflectance (all radii) and its error.
        escaped: ``(3,)`` weight fraction terminated beyond ``2·radii[-1]`` (module doc): the
            energy the walk cuts off. ``total + escaped`` bounds the true diffuse reflectance
            from above (exact for a lossless medium, whose cut-off photons all return).
        escaped_stderr: ``(3,)`` its standard error.
        reflected, reflected_stderr: ``(3,)`` ``total + escaped`` per photon and its standard
            error (each photon ends in one fate: the scores add).
        groups: ``(G, K + 2, 3)`` independent batch sums per group of photons (photon ``i``
            in group ``i mod G``): rows ``0..K−1`` the annuli, ``K`` all top exits (total),
            ``K + 1`` the cut-off (escaped); divide by ``group_photons`` for per-group
            estimates (jackknife standard errors, :mod:`sssbench.mc.significance`).
        group_photons: ``(G,)`` photons per group (per channel).
        photons: photons per channel.
        interactions: collisions simulated over the three channels.
        seconds: wall time of the three walks of the run that produced it (a cache hit
            keeps the original run's time).
    """

    radii: torch.Tensor
    fraction: torch.Tensor
    fraction_stderr: torch.Tensor
    total: torch.Tensor
    total_stderr: torch.Tensor
    escaped: torch.Tensor
    escaped_stderr: torch.Tensor
    reflected: torch.Tensor
    reflected_stderr: torch.Tensor
    groups: torch.Tensor
    group_photons: torch.Tensor
    photons: int
    interactions: int
    seconds: float

    @property
    def area(self) -> torch.Tensor:
        """``(K, 1)`` annulus areas, mm²."""
        return (math.pi * (self.radii[1:] ** 2 - self.radii[:-1] ** 2))[:, None]

    @property
    def R(self) -> torch.Tensor:  # noqa: N802 - the physics symbol
        """``(K, 3)`` radial exitance per annulus, mm⁻²."""
        return self.fraction / self.area

    @property
    def R_stderr(self) -> torch.Tensor:  # noqa: N802
        return self.fraction_stderr / self.area

    def band(self, lo: float, hi: float) -> tuple[torch.Tensor, torch.Tensor]:
        """``(energy, stderr)`` ``(3,)`` of the light leaving through ``lo <= r < hi`` (mm),
        which must be annulus edges. The standard error is the exact per-photon one: a
        photon leaves through at most one annulus, so the band's second moment is the sum of
        the annuli's, ``Σw²/N = (N − 1) se_k² + m_k²`` each."""
        r = self.radii
        inside = (r[:-1] >= lo - 1e-12) & (r[1:] <= hi + 1e-12)
        edges = set(r.tolist())
        if (
            not inside.any()
            or not any(abs(lo - e) < 1e-12 for e in edges)
            or not any(abs(hi - e) < 1e-12 for e in edges)
        ):
            raise ValueError(f"band [{lo}, {hi}) is not a union of annuli of {r.tolist()}")
        n = self.photons
        m = self.fraction[inside]
        second = ((n - 1) * self.fraction_stderr[inside] ** 2 + m * m).sum(0)
        mean = m.sum(0)
        var = (second - mean * mean).clamp_min(0.0) * (n / max(n - 1, 1))
        return mean, torch.sqrt(var / n)


#: independent groups of photons per walk (jackknife standard errors of relative errors and
#: of comparisons between models; :mod:`sssbench.mc.significance`)
GROUPS = 16

#: absorbing channels are cut no closer than this many mean free paths (their walks end by
#: absorption anyway; a cut at twice a radius of a few mean free paths — Chicken1 red: 25 mm
#: are 4 — would lose ~5 % of R_d)
KILL_MFP_MIN = 200.0


def _kill_radius(r_max_mfp: float, sigma_a: float) -> float:
    """Truncation distance (mfp): ``2 r_max``, and at least :data:`KILL_MFP_MIN` when the
    channel absorbs (module doc)."""
    return max(2 * r_max_mfp, KILL_MFP_MIN) if sigma_a > 0 else 2 * r_max_mfp


def _coefficients(material: object) -> tuple[torch.Tensor, torch.Tensor, float]:
    """``(σs′ (3,), σa (3,), η)`` of a material name or a ``(σs′, σa[, η])`` tuple."""
    if isinstance(material, str):
        key = material.strip().lower()
        if key not in MATERIALS:
            raise ValueError(f"material must be one of {sorted(MATERIALS)}, got {material!r}")
        ss, sa = MATERIALS[key]
        eta = 1.3
    elif isinstance(material, (tuple, list)) and len(material) in (2, 3):
        ss, sa = material[0], material[1]
        eta = check_scalar("eta", material[2] if len(material) == 3 else 1.3, 1.0, 3.0)
    else:
        raise TypeError(
            "material must be a name of sssbench.profiles.MATERIALS or a (sigma_s_prime, "
            f"sigma_a[, eta]) tuple in mm^-1, got {type(material).__name__}"
        )
    ss_t = torch.as_tensor(ss, dtype=_F64).expand(3).clone()
    sa_t = torch.as_tensor(sa, dtype=_F64).expand(3).clone()
    if not bool((ss_t > 0).all()) or not bool(torch.isfinite(ss_t).all()):
        raise ValueError(f"sigma_s_prime must be finite and > 0 mm^-1, got {ss_t.tolist()}")
    if not bool((sa_t >= 0).all()) or not bool(torch.isfinite(sa_t).all()):
        raise ValueError(f"sigma_a must be finite and >= 0 mm^-1, got {sa_t.tolist()}")
    return ss_t, sa_t, eta


def _radii(radii: object) -> torch.Tensor:
    r = torch.as_tensor(radii, dtype=_F64)
    if r.ndim != 1 or r.numel() < 2:
        raise ValueError(
            f"radii_mm must be a 1D sequence of >= 2 edges, got shape {tuple(r.shape)}"
        )
    if not bool(torch.isfinite(r).all()) or bool(r[0] < 0) or not bool((r[1:] > r[:-1]).all()):
        raise ValueError(f"radii_mm must be finite, >= 0 and strictly increasing, got {r.tolist()}")
    return r


def searchlight_result(
    material: object,
    radii_mm: object,
    photons: int = 200_000,
    seed: int = 0,
    *,
    batch: int = 1 << 17,
    cache: bool = True,
    progress: bool | None = None,
    groups: int = GROUPS,
    workers: int = 1,
) -> SearchlightResult:
    """The searchlight profile of ``material`` (module doc), from the cache or a new walk.

    Args:
        material: a name of :data:`sssbench.profiles.MATERIALS` (η = 1.3) or a tuple
            ``(σs′, σa[, η])`` of scalars or RGB triples in mm⁻¹.
        radii_mm: annulus edges in mm, ``(K+1,)``, finite, >= 0, increasing.
        photons: photons per channel.
        seed: base seed in [0, 2³² − 1] (channel c uses ``derive_seed(seed, …, c)``).
        batch: photons advanced together (part of the cache key: it orders the draws).
        cache: read and write the disk cache.
        progress: tqdm bars (None = only for runs longer than ~3 s).
        groups: independent groups of photons tallied apart (jackknife standard errors).
        workers: processes per channel walk (:func:`sssbench.mc.walk.walk`; part of the key:
            the draws differ).
    """
    ss, sa, eta = _coefficients(material)
    radii = _radii(radii_mm)
    photons = check_int("photons", photons, 2)
    seed = check_seed("seed", seed)
    key = {
        "sigma_s_prime": ss.tolist(),
        "sigma_a": sa.tolist(),
        "eta": eta,
        "radii": radii.tolist(),
        "photons": photons,
        "seed": seed,
        "batch": batch,
        "groups": groups,
        "workers": workers,
        "code": mc_digest(),
    }

    def compute() -> dict:
        return _walk_channels(ss, sa, eta, radii, photons, seed, batch, progress, groups,
                              workers)  # fmt: skip

    return SearchlightResult(radii=radii, **cached_entry("searchlight", key, compute, cache))


def _walk_channels(
    ss: torch.Tensor,
    sa: torch.Tensor,
    eta: float,
    radii: torch.Tensor,
    photons: int,
    seed: int,
    batch: int,
    progress: bool | None,
    groups: int = 1,
    workers: int = 1,
) -> dict:
    """One walk per channel; the fields of :class:`SearchlightResult` but ``radii``."""
    st = ss + sa
    frac, frac_se, tot, tot_se, esc, esc_se, refl, refl_se, grp = ([] for _ in range(9))
    inter, secs = 0, 0.0
    for c in range(3):
        t = walk(
            float(ss[c] / st[c]),
            photons=photons,
            eta=eta,
            seed=derive_seed(seed, "searchlight channel", c),
            radial_edges=radii * st[c],
            roulette_radius=float(radii[-1] * st[c]),
            kill_radius=_kill_radius(float(radii[-1] * st[c]), float(sa[c])),
            batch=batch,
            progress=progress,
            groups=groups,
            workers=workers,
        )
        m, e = mean_stderr(t.radial[0], t.radial[1], photons)
        frac.append(m)
        frac_se.append(e)
        m, e = mean_stderr(t.top[0], t.top[1], photons)
        tot.append(m)
        tot_se.append(e)
        m, e = mean_stderr(t.escaped[0], t.escaped[1], photons)
        esc.append(m)
        esc_se.append(e)
        m, e = t.estimate("top+escaped")
        refl.append(torch.tensor(m, dtype=_F64))
        refl_se.append(torch.tensor(e, dtype=_F64))
        k = t.radial.shape[1]
        # (G, K + 2): annuli, all top exits, escaped (by_group: 5 fates, then the K bins)
        grp.append(torch.cat([t.by_group[:, 5 : 5 + k], t.by_group[:, [0, 4]]], 1))
        gphot = t.group_photons
        inter += t.interactions
        secs += t.seconds
    result = {
        "fraction": torch.stack(frac, 1),
        "fraction_stderr": torch.stack(frac_se, 1),
        "total": torch.stack(tot),
        "total_stderr": torch.stack(tot_se),
        "escaped": torch.stack(esc),
        "escaped_stderr": torch.stack(esc_se),
        "reflected": torch.stack(refl),
        "reflected_stderr": torch.stack(refl_se),
        "groups": torch.stack(grp, 2),
        "group_photons": gphot,
        "photons": photons,
        "interactions": inter,
        "seconds": secs,
    }
    return result


def searchlight(
    material: object, radii_mm: object, photons: int = 200_000, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(R, stderr)``: radial exitance per annulus and channel, ``(K, 3)`` in mm⁻² (module
    doc; cached). See :func:`searchlight_result` for the totals and the cost."""
    res = searchlight_result(material, radii_mm, photons, seed)
    return res.R, res.R_stderr

"""One significance rule for every verdict drawn from Monte Carlo light transport.

A Monte Carlo estimate is a sample mean: any error computed against it carries noise, and a
difference between two models' errors ("the dipole is closer than Burley", "method X beats
doing nothing") is a finding only when it exceeds its own noise. Every MC-based verdict of the
project goes through :func:`compare`:

* ``diff`` = (error of A) − (error of B), lower is better, and its standard error ``se``;
* ``|diff| > k·se`` (default ``k = 3``): A is ``"closer"`` (diff < 0) or ``"worse"`` (diff > 0)
  than B;
* otherwise ``"not resolved at N photons"`` — never a ranking.

Standard errors of statistics of MC estimates come from one of two resamplings, both paired
(the two errors of a comparison are computed from the *same* resampled MC, so noise they share
cancels in the difference):

* the **jackknife over independent batches** of photons (:func:`jackknife`,
  :func:`scene_errors`): the walk tallies each photon into one of ``G`` groups
  (:func:`sssbench.mc.walk.walk`, ``groups``; the scene references run ``batches``
  independent walks), the statistic is recomputed with one group left out, and
  ``se² = (G − 1)/G · Σ (θ₋g − θ̄)²``. Right for smooth statistics (RMS errors, ratios);
* the **parametric bootstrap** (:func:`bootstrap`) from independent estimates and their
  standard errors (normal draws): for statistics with kinks — absolute errors ``|A − T|``,
  differences ``|A − T| − |B − T|`` of two fixed models when the MC value ``T`` may lie
  between them, medians — where the jackknife's leave-one-out values never cross the kink
  and understate the noise.

A difference below a stated practical tolerance ``tol`` (e.g. two images equal to 1e-8) is
``"no difference"``, however small its noise.

Consumers: ``experiments/mc_profiles.py`` and ``experiments/mc_gap.py`` (every verdict
sentence); the app's ``reference=mc`` (``sssbench/run/runner.py``, ``_mc_metrics``) and the HTML
report should call :func:`scene_errors` / :func:`compare` for any "better"/"worse" they state
(docs/mc.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

__all__ = [
    "K_SIGMA",
    "Comparison",
    "compare",
    "bootstrap",
    "jackknife",
    "jackknife_se",
    "leave_one_out",
    "paired",
    "group_means",
    "scene_errors",
    "rel_rms_batches",
    "fmt_pm",
]

#: default multiple of the standard error a difference must exceed to be called resolved
K_SIGMA = 3.0

_F64 = torch.float64


@dataclass(frozen=True)
class Comparison:
    """The verdict of :func:`compare`.

    Attributes:
        verdict: ``"closer"``, ``"worse"`` or ``"not resolved at N photons"``.
        diff, se: the difference (A − B, lower is better) and its standard error.
        k: the multiple of ``se`` it had to exceed.
        photons: the photon count named in an unresolved verdict (None: not named).
    """

    verdict: str
    diff: float
    se: float
    k: float
    photons: int | None = None

    @property
    def resolved(self) -> bool:
        return self.verdict in ("closer", "worse")

    @property
    def z(self) -> float:
        """``diff / se`` (±inf for a noiseless non-zero difference, nan for 0/0)."""
        if self.se > 0:
            return self.diff / self.se
        return math.nan if self.diff == 0 else math.copysign(math.inf, self.diff)

    def __str__(self) -> str:
        return self.verdict


def _photons_text(photons: int | None) -> str:
    return "not resolved" if photons is None else f"not resolved at {photons:.3g} photons"


def compare(
    diff: float, se: float, k: float = K_SIGMA, photons: int | None = None, tol: float = 0.0
) -> Comparison:
    """The significance rule (module doc): A vs B from ``diff = err_A − err_B`` and its
    standard error.

    Args:
        diff: difference of the two errors (lower error is better).
        se: its standard error (>= 0; nan: nothing is resolved).
        k: multiple of ``se`` the difference must exceed (> 0).
        photons: photon count to name in an unresolved verdict.
        tol: practical tolerance: ``|diff| <= tol`` is ``"no difference"`` (>= 0).

    Returns:
        A :class:`Comparison` whose ``verdict`` is ``"closer"`` (A better), ``"worse"``
        (A worse), ``"not resolved at N photons"`` or ``"no difference"`` (below ``tol``).
    """
    diff, se, k = float(diff), float(se), float(k)
    if not k > 0:
        raise ValueError(f"k must be > 0, got {k}")
    if se < 0:
        raise ValueError(f"se must be >= 0, got {se}")
    if tol < 0:
        raise ValueError(f"tol must be >= 0, got {tol}")
    if math.isfinite(diff) and abs(diff) <= tol:
        return Comparison("no difference", diff, se, k, photons)
    if not (math.isfinite(diff) and not math.isnan(se)) or abs(diff) <= k * se:
        return Comparison(_photons_text(photons), diff, se, k, photons)
    return Comparison("closer" if diff < 0 else "worse", diff, se, k, photons)


def group_means(sums: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """Per-group sample means ``sums[g] / counts[g]`` (``sums``: ``(G, ...)``)."""
    c = counts.to(_F64).reshape(-1, *([1] * (sums.ndim - 1)))
    return sums.to(_F64) / c


def jackknife(
    stat: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    sums: torch.Tensor,
    counts: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Value and jackknife standard error of ``stat`` over ``G`` independent groups.

    Args:
        stat: ``stat(mean, weight)`` of the pooled sample mean ``mean`` (shape of
            ``sums[0]``); it may return any tensor shape. ``weight`` is the photon count it
            pools (for statistics that need it).
        sums: ``(G, ...)`` per-group sums of the per-photon scores.
        counts: ``(G,)`` photons per group.

    Returns:
        ``(value, se)``: ``stat`` of all groups pooled and ``√((G−1)/G · Σ(θ₋g − θ̄)²)``;
        ``se`` is nan with fewer than 2 groups. Non-finite leave-one-out values make ``se``
        nan (never a silently resolved difference).
    """
    sums = sums.to(_F64)
    counts = counts.to(_F64)
    g = sums.shape[0]
    total, n = sums.sum(0), counts.sum()
    value = torch.as_tensor(stat(total / n, n), dtype=_F64)
    if g < 2:
        return value, torch.full_like(value, math.nan)
    loo = torch.stack(
        [
            torch.as_tensor(stat((total - sums[i]) / (n - counts[i]), n - counts[i]), dtype=_F64)
            for i in range(g)
        ]  # fmt: skip
    )
    se = torch.sqrt((g - 1) / g * ((loo - loo.mean(0)) ** 2).sum(0))
    return value, se


def bootstrap(
    stat: Callable[[torch.Tensor], torch.Tensor],
    mean: torch.Tensor,
    se: torch.Tensor,
    draws: int = 2000,
    seed: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Value and parametric-bootstrap standard error of ``stat`` of independent estimates.

    Args:
        stat: maps ``(D, *mean.shape)`` draws to ``(D, ...)`` statistics (vectorised).
        mean, se: the estimates and their standard errors (same shape; independent).
        draws: bootstrap draws ``D``.
        seed: generator seed (the standard errors are reproducible).

    Returns:
        ``(stat(mean), std over D draws of stat(mean + se·z))``, ``z`` standard normal.
    """
    mean = mean.to(_F64)
    gen = torch.Generator().manual_seed(seed)
    z = torch.randn((draws, *mean.shape), generator=gen, dtype=_F64)
    value = stat(mean[None])[0]
    boot = stat(mean[None] + se.to(_F64)[None] * z)
    return value, boot.std(0)


def jackknife_se(loo: torch.Tensor) -> torch.Tensor:
    """Jackknife standard error from the ``G`` leave-one-group-out values ``loo`` ``(G, ...)``
    of any statistic: ``√((G−1)/G · Σ(θ₋g − θ̄)²)`` (nan where a value is not finite)."""
    loo = loo.to(_F64)
    g = loo.shape[0]
    if g < 2:
        return torch.full_like(loo[0], math.nan)
    return torch.sqrt((g - 1) / g * ((loo - loo.mean(0)) ** 2).sum(0))


def leave_one_out(sums: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """``(G + 1, ...)`` pooled means: all groups (index 0), then each group left out."""
    sums = sums.to(_F64)
    counts = counts.to(_F64).reshape(-1, *([1] * (sums.ndim - 1)))
    total, n = sums.sum(0), counts.sum(0)
    return torch.cat([(total / n)[None], (total[None] - sums) / (n[None] - counts)])


def paired(
    err_a: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    err_b: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    sums: torch.Tensor,
    counts: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(err_a − err_b, se)`` by the jackknife over the same groups (paired: the noise the
    two errors share cancels)."""
    return jackknife(lambda m, n: err_a(m, n) - err_b(m, n), sums, counts)


def rel_rms_batches(
    image: torch.Tensor, batches: torch.Tensor, mask: torch.Tensor | None = None
) -> float:
    """Noise-corrected relative RMS error of ``image`` against the mean of ``batches``
    (``(B, 3, H, W)``; :func:`sssbench.mc.scene.noise_corrected_rel_rms` without its standard
    error): ``sqrt(max(0, Σ((m − x̂)² − se²)) / Σ(x̂² − se²))``."""
    m = image.reshape(1, *batches.shape[1:]).double()
    x = batches.double()
    if mask is not None:
        sel = mask.reshape(x.shape[-2:]).bool()
        m, x = m[..., sel], x[..., sel]
    b = x.shape[0]
    mean = x.mean(0)
    var = x.var(0) / b if b > 1 else torch.zeros_like(mean)
    num = float(((m[0] - mean) ** 2 - var).sum())
    den = float((mean**2 - var).sum())
    return math.sqrt(max(0.0, num) / den) if den > 0 else math.nan


def scene_errors(
    images: dict[str, torch.Tensor],
    batches: torch.Tensor,
    mask: torch.Tensor | None = None,
) -> tuple[dict[str, tuple[float, float]], Callable[[str, str], tuple[float, float]]]:
    """Noise-corrected relative RMS errors of several images against the same MC batches,
    with jackknife standard errors, and their paired differences.

    Args:
        images: name -> ``(1, 3, H, W)`` or ``(3, H, W)`` image.
        batches: ``(B, 3, H, W)`` independent MC batch images (B >= 3).
        mask: ``(H, W)`` pixels scored, or None.

    Returns:
        ``(errors, diff)``: ``errors[name] = (rel_rms, se)``; ``diff(a, b)`` returns
        ``(err_a − err_b, se)`` jackknifed over the same deleted batches (feed it to
        :func:`compare`).
    """
    x = batches.double()
    b = x.shape[0]
    if b < 3:
        raise ValueError(f"need >= 3 batches for a jackknife, got {b}")
    subsets = [x] + [torch.cat([x[:i], x[i + 1 :]]) for i in range(b)]
    vals = {
        name: torch.tensor([rel_rms_batches(img, xs, mask) for xs in subsets], dtype=_F64)
        for name, img in images.items()
    }

    def jk(v: torch.Tensor) -> tuple[float, float]:
        loo = v[1:]
        return float(v[0]), math.sqrt((b - 1) / b * float(((loo - loo.mean()) ** 2).sum()))

    errors = {name: jk(v) for name, v in vals.items()}

    def diff(a: str, c: str) -> tuple[float, float]:
        return jk(vals[a] - vals[c])

    return errors, diff


def fmt_pm(value: float, se: float, scale: float = 100.0, digits: int = 3) -> str:
    """``"v ± s"`` (scaled, e.g. to %): ``v`` to ``digits`` significant figures, ``s`` to 2."""
    if not math.isfinite(value):
        return "–"
    if not math.isfinite(se):
        return f"{scale * value:.{digits}g} ± ?"
    return f"{scale * value:.{digits}g} ± {scale * se:.2g}"

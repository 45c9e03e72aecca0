"""Decision helpers: skill against doing nothing, visibility, Pareto set, recommendation and
verdict sentences computed from the numbers of a run.

Everything here is a pure function of plain numbers (or a pandas table of them), except
:func:`sss_visibility` which measures one pair of images. Definitions:

- **skill** of a configuration with error ``err`` on a scene where doing nothing (the
  unblurred input, :class:`~sssbench.ops.IdentitySSS`) has error ``err_identity``:
  ``skill = 1 − err / err_identity``. 1 is perfect, 0 is no better than doing nothing,
  negative is worse than doing nothing. ``err_identity = 0`` means the reference equals the
  input on the mask (SSS changes nothing at this scale): there is nothing to gain and skill
  is undefined, ``NaN``.
- **visible**: SSS is visible at this scale when the FLIP between the reference and the
  unblurred input over the mask is either at least :data:`VISIBLE_FLIP` (0.005) on average
  (a change spread over the image) or at least :data:`VISIBLE_LOCAL_FLIP` (0.1) at its
  :data:`VISIBLE_QUANTILE` (99.9th percentile; a local change: the glow around a small light,
  a softened shadow edge); see :func:`visibility_stats`.
- **Pareto set**: the configurations no other one beats in both time and error.
- **recommendation**: per scene and scale, the cheapest configuration whose skill is within
  ``tolerance`` (10 %) of the best skill, doing nothing (skill 0 at cost 0) included.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from sssbench._checks import check_scalar

__all__ = [
    "VISIBLE_FLIP",
    "VISIBLE_LOCAL_FLIP",
    "VISIBLE_QUANTILE",
    "RECOMMEND_TOLERANCE",
    "BASELINE",
    "skill",
    "sss_visibility",
    "visibility_stats",
    "is_visible",
    "visible",
    "pareto_set",
    "recommend",
    "verdict_sentence",
    "recommendation_sentence",
]

#: mean FLIP (reference vs unblurred input, over the mask) from which SSS counts as visible.
#: FLIP is 0 for identical images and 1 for the largest perceptual difference; 0.005 is half
#: a percent of that range on the average masked pixel. Measured (skin_jg10, 128²): the
#: benchmark scenes lie above it (head_close 0.016, step_edge 0.040, light_dot 0.052), the
#: scenes whose pixels are as wide as the profile below it (head_mid 0.0037, crowd 0.0025,
#: sphere 0.0016, head_far 1e-5, where the reference equals the input: rel RMS 0).
VISIBLE_FLIP = 0.005
#: per-pixel FLIP from which a local change counts as visible, and the fraction of masked pixels
#: that must reach it (1 − VISIBLE_QUANTILE). The mean alone dilutes a local effect by the
#: area around it: measured (skin_deon6, 256²), a 1 mm light dot at 0.3 mm/px has a mean FLIP
#: of 0.0015 yet its glow is plain to see (99.9th percentile 0.26; the unblurred input is 13 %
#: rel RMS off the reference), and a shadow edge at 1 mm/px has a mean of 0.004 with a 99.9th
#: percentile of 0.22; smooth shading (a sphere at 0.1–1 mm/px) stays below 0.04 and the same
#: dot at 1 mm/px reaches 0.05.
VISIBLE_LOCAL_FLIP = 0.1
VISIBLE_QUANTILE = 0.999
#: a configuration is "as good as the best" when its skill is within this fraction of it
RECOMMEND_TOLERANCE = 0.1
#: name of the do-nothing configuration (skill 0, cost 0) in recommendations
BASELINE = "identity"
_MINUS = "\u2212"


def skill(err: float | np.ndarray, err_identity: float | np.ndarray) -> float | np.ndarray:
    """``1 − err / err_identity``: the fraction of doing nothing's error a method removes.

    Args:
        err: the method's error (any non-negative error measure, e.g. rel RMS), a number or
            an array (pandas Series work too).
        err_identity: the same measure of the unblurred input against the same reference.

    Returns:
        skill, same shape; ``NaN`` where ``err_identity == 0`` (SSS changes nothing there,
        so no method can gain anything: the question has no answer) or where an input is
        NaN.

    Example:
        >>> skill(0.01, 0.04)
        0.75
    """
    e = np.asarray(err, dtype=np.float64)
    e0 = np.asarray(err_identity, dtype=np.float64)
    if bool(np.any(e < 0)) or bool(np.any(e0 < 0)):
        raise ValueError(f"err and err_identity must be >= 0, got {err!r} and {err_identity!r}")
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(e0 > 0, 1.0 - e / np.where(e0 > 0, e0, 1.0), np.nan)
    return float(out) if out.ndim == 0 else out


def visibility_stats(
    reference: torch.Tensor, diffuse: torch.Tensor, mask: torch.Tensor | None = None
) -> tuple[float, float]:
    """The mean FLIP and its :data:`VISIBLE_QUANTILE` between the reference and the
    unblurred input over the mask (:func:`sssbench.score.metrics.flip_map`, tone-mapped LDR at 67
    pixels per degree).

    Args:
        reference: ``(B, 3, H, W)`` exact SSS of the scene.
        diffuse: ``(B, 3, H, W)`` the unblurred input (``gbuffer.diffuse``).
        mask: ``(B, 1, H, W)`` weights, or ``None``. The mean is weighted by it; the quantile
            is taken over the pixels with a positive weight (all images of the batch pooled).

    Returns:
        ``(mean, local)``: the mean FLIP (as :func:`sssbench.score.metrics.flip`) and the
        :data:`VISIBLE_QUANTILE` quantile of the per-pixel FLIP; compare with
        :func:`is_visible`.
    """
    from sssbench.score.metrics import flip_map

    fmap = flip_map(diffuse, reference).astype(np.float64)
    if mask is None:
        return float(fmap.mean()), float(np.quantile(fmap, VISIBLE_QUANTILE))
    if tuple(mask.shape) != (fmap.shape[0], 1, *fmap.shape[1:]):
        raise ValueError(
            f"mask must have shape {(fmap.shape[0], 1, *fmap.shape[1:])}, got {tuple(mask.shape)}"
        )
    wgt = mask.detach().double().cpu()[:, 0].numpy()
    if bool((wgt.reshape(wgt.shape[0], -1).sum(1) <= 0).any()):
        raise ValueError("mask must select at least one pixel in every image")
    mean = float(np.mean((fmap * wgt).sum(axis=(1, 2)) / wgt.sum(axis=(1, 2))))
    return mean, float(np.quantile(fmap[wgt > 0], VISIBLE_QUANTILE))


def is_visible(mean: float, local: float) -> bool:
    """Whether SSS is visible given :func:`visibility_stats`: a mean FLIP of at least
    :data:`VISIBLE_FLIP` or a :data:`VISIBLE_QUANTILE` quantile of at least
    :data:`VISIBLE_LOCAL_FLIP`."""
    return bool(mean >= VISIBLE_FLIP or local >= VISIBLE_LOCAL_FLIP)


def sss_visibility(
    reference: torch.Tensor, diffuse: torch.Tensor, mask: torch.Tensor | None = None
) -> float:
    """Mean FLIP between the reference and the unblurred input over the mask (the first
    number of :func:`visibility_stats`)."""
    return visibility_stats(reference, diffuse, mask)[0]


def visible(
    reference: torch.Tensor,
    diffuse: torch.Tensor,
    mask: torch.Tensor | None = None,
    threshold: float = VISIBLE_FLIP,
    local_threshold: float = VISIBLE_LOCAL_FLIP,
) -> bool:
    """Whether SSS is visible at this scale: mean FLIP ``>= threshold`` or its
    :data:`VISIBLE_QUANTILE` quantile ``>= local_threshold`` (:func:`visibility_stats`)."""
    threshold = check_scalar("threshold", threshold, 0.0, 1.0)
    local_threshold = check_scalar("local_threshold", local_threshold, 0.0, 1.0)
    mean, local = visibility_stats(reference, diffuse, mask)
    return bool(mean >= threshold or local >= local_threshold)


def _vector(name: str, values: Sequence[float] | np.ndarray) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {v.shape}")
    if not bool(np.all(np.isfinite(v))):
        raise ValueError(f"{name} must be finite, got {v.tolist()}")
    return v


def pareto_set(times: Sequence[float], errors: Sequence[float]) -> list[int]:
    """Indices of the configurations on the time / error Pareto front, fastest first.

    A configuration is dominated when another one is at most as slow and at most as wrong,
    and strictly better in one of the two; the front is every configuration that is not.
    Identical points are all kept.

    Args:
        times: cost of each configuration (any unit, >= 0).
        errors: error of each configuration (lower is better).

    Returns:
        indices into the inputs, sorted by time (ties: by error).

    Example:
        >>> pareto_set([1.0, 2.0, 3.0], [0.5, 0.6, 0.1])
        [0, 2]
    """
    t = _vector("times", times)
    e = _vector("errors", errors)
    if t.shape != e.shape:
        raise ValueError(f"times and errors must have the same length, got {t.size}, {e.size}")
    keep = []
    for i in range(t.size):
        no_worse = (t <= t[i]) & (e <= e[i])
        better = (t < t[i]) | (e < e[i])
        if not bool(np.any(no_worse & better)):
            keep.append(i)
    return sorted(keep, key=lambda i: (t[i], e[i]))


def recommend(
    rows,
    *,
    by: Sequence[str] = ("scene", "resolution"),
    config: str = "config",
    time: str = "time_ms",
    skill_col: str = "skill",
    tolerance: float = RECOMMEND_TOLERANCE,
):
    """Per group (scene and scale), the cheapest configuration within ``tolerance`` of the
    best skill.

    Doing nothing is always a candidate, with skill 0 at cost 0 (:data:`BASELINE`), whether
    or not the table holds an identity row: the best skill is ``b = max(0, max skill)`` and a
    configuration qualifies when ``skill >= b − tolerance · b``; the cheapest qualifying one
    is recommended (ties: the higher skill). When nothing beats doing nothing (``b = 0``),
    the recommendation is :data:`BASELINE`. Rows with a NaN skill (identity error 0: SSS
    changes nothing there) do not compete; a group with no finite skill is recommended
    :data:`BASELINE` with reason ``"no visible SSS"``.

    Args:
        rows: a pandas DataFrame with the columns named by ``by``, ``config``, ``time``,
            ``skill_col`` (e.g. one row per run, skill from :func:`skill`).
        by: columns that define a group.
        config: column naming a configuration.
        time: column of the cost (>= 0).
        skill_col: column of the skill.
        tolerance: in [0, 1].

    Returns:
        DataFrame, one row per group: the ``by`` columns, ``config``, ``time``, ``skill_col``
        of the recommendation, ``best_config`` / ``best_skill`` (the highest skill, the
        baseline if none is > 0), ``candidates`` (how many qualified) and ``reason``.
    """
    import pandas as pd

    if not isinstance(rows, pd.DataFrame):
        raise TypeError(f"rows must be a pandas DataFrame, got {type(rows).__name__}")
    by = list(by)
    missing = [c for c in (*by, config, time, skill_col) if c not in rows.columns]
    if missing:
        raise ValueError(f"rows must have the columns {missing}; it has {list(rows.columns)}")
    tolerance = check_scalar("tolerance", tolerance, 0.0, 1.0)
    if bool((rows[time] < 0).any()):
        raise ValueError(f"column {time!r} must be >= 0")
    out = []
    for key, grp in rows.groupby(by, sort=True, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        rec = dict(zip(by, key, strict=True))
        g = grp[np.isfinite(grp[skill_col].to_numpy(dtype=np.float64))]
        base = {config: BASELINE, time: 0.0, skill_col: 0.0}
        if g.empty:
            out.append(
                {
                    **rec,
                    **base,
                    "best_config": BASELINE,
                    "best_skill": math.nan,
                    "candidates": 0,
                    "reason": "no visible SSS",
                }
            )
            continue
        top = g.loc[g[skill_col].idxmax()]
        best = max(0.0, float(top[skill_col]))
        bar = best - tolerance * best
        cands = [dict(base)] if 0.0 >= bar else []
        cands += [
            {config: r[config], time: float(r[time]), skill_col: float(r[skill_col])}
            for _, r in g.iterrows()
            if float(r[skill_col]) >= bar
        ]
        pick = min(cands, key=lambda c: (c[time], -c[skill_col]))
        out.append(
            {
                **rec,
                **pick,
                "best_config": top[config] if best > 0 else BASELINE,
                "best_skill": best,
                "candidates": len(cands),
                "reason": "nothing beats doing nothing"
                if best == 0
                else f"cheapest within {tolerance:.0%} of the best skill",
            }
        )
    return pd.DataFrame(out)


def _signed(x: float) -> str:
    return f"{_MINUS}{abs(x):.2f}" if x < 0 else f"{x:.2f}"


def verdict_sentence(
    name: str, skill_value: float, err: float | None = None, err_identity: float | None = None
) -> str:
    """One sentence on a configuration, computed from its skill (and errors if given).

    - NaN: SSS is not visible (nothing to gain);
    - ``skill < 0``: "X is worse than doing nothing (skill −0.27)";
    - ``0 <= skill < 0.3``: "X barely beats doing nothing (skill 0.10)";
    - otherwise: "X removes 57% of the error of doing nothing (skill 0.57)".

    With ``err`` and ``err_identity`` the two errors are quoted too.

    Example:
        >>> verdict_sentence("preintegrated", -0.27)
        'preintegrated is worse than doing nothing (skill −0.27).'
    """
    s = float(skill_value)
    errs = ""
    if err is not None and err_identity is not None:
        errs = f"; error {err:.3g} vs {err_identity:.3g} unblurred"
    if math.isnan(s):
        return f"{name}: SSS is not visible here, nothing to gain (skill undefined{errs})."
    if s < 0:
        return f"{name} is worse than doing nothing (skill {_signed(s)}{errs})."
    if s < 0.3:
        return f"{name} barely beats doing nothing (skill {_signed(s)}{errs})."
    return f"{name} removes {s:.0%} of the error of doing nothing (skill {_signed(s)}{errs})."


def recommendation_sentence(
    row: dict,
    *,
    config: str = "config",
    time: str = "time_ms",
    skill_col: str = "skill",
    by: Sequence[str] = ("scene", "resolution"),
) -> str:
    """A sentence for one row of :func:`recommend` (a dict or a pandas row).

    Example:
        >>> recommendation_sentence({"scene": "step_edge", "resolution": 128, "config": "a",
        ...     "time_ms": 1.0, "skill": 0.8, "best_config": "b", "best_skill": 0.85,
        ...     "candidates": 2, "reason": ""})
        'step_edge, 128: use a (skill 0.80, 1 ms); the best, b, reaches 0.85.'
    """
    where = ", ".join(str(row[c]) for c in by)
    if row["reason"] == "no visible SSS":
        return f"{where}: SSS is not visible, do nothing."
    if row[config] == BASELINE:
        return (
            f"{where}: do nothing; no configuration beats the unblurred input "
            f"(best skill {_signed(float(row['best_skill']))})."
        )
    s = f"{where}: use {row[config]} (skill {_signed(float(row[skill_col]))}, {row[time]:.3g} ms)"
    if row["best_config"] == row[config]:
        return s + ", also the best."
    return s + f"; the best, {row['best_config']}, reaches {_signed(float(row['best_skill']))}."

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
  (a change spread over the image) or at least :data:`VISIBLE_LOCAL_FLIP` (0.08) averaged over
  the most-changed :data:`VISIBLE_WINDOW` × :data:`VISIBLE_WINDOW` pixel window (7 × 7, about
  0.1° at FLIP's 67 pixels per degree: a local change, the glow around a small light, a
  softened shadow edge, a thin rim); see :func:`visibility_stats`.
- **error visible**: the same rule applied to a method's result instead of the unblurred input
  (:func:`error_visibility`): its error is visible when its FLIP against the reference passes
  either bar. A method can be visibly wrong where SSS itself is not visible (it adds an error
  the scene does not have).
- **Pareto set**: the configurations no other one beats in both time and error.
- **recommendation**: per scene and scale, the cheapest configuration whose skill is within
  ``tolerance`` (10 %) of the best skill, doing nothing (skill 0 at cost 0) included.
- **not resolved as cheaper** (:func:`not_resolved_cheaper`): a run's times are one draw of
  the machine; a qualifying configuration whose time is within ``time_spread`` (the
  run-to-run spread of the ratio of two configurations' times, one standard deviation) of
  the pick's is named beside it: which of them is cheaper, that run does not resolve.
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
    "VISIBLE_WINDOW",
    "CALIBRATION",
    "RECOMMEND_TOLERANCE",
    "BASELINE",
    "skill",
    "sss_visibility",
    "visibility_stats",
    "is_visible",
    "visible",
    "error_visibility",
    "pareto_set",
    "recommend",
    "not_resolved_cheaper",
    "verdict_sentence",
    "recommendation_sentence",
]

#: mean FLIP (reference vs unblurred input, over the mask) from which SSS counts as visible.
#: FLIP is 0 for identical images and 1 for the largest perceptual difference; 0.005 is half
#: a percent of that range on the average masked pixel. Measured (skin_jg10, 128²): the
#: benchmark scenes lie above it (head_closeup 0.016, step_edge 0.040, light_dot 0.052), the
#: scenes whose pixels are as wide as the profile below it (head_mid 0.0037, crowd 0.0025,
#: sphere 0.0016, head_far 1e-5, where the reference equals the input: rel RMS 0).
VISIBLE_FLIP = 0.005
#: FLIP averaged over the most-changed :data:`VISIBLE_WINDOW`² window of masked pixels from
#: which a local change counts as visible (the "local" statistic of :func:`visibility_stats`).
#: The mean alone dilutes a local effect by the area around it, and a quantile over the mask
#: (the rule before this one: the 99.9th percentile >= 0.1) by the size of the mask: the same
#: 1 mm light dot at 0.5 mm/px had a 99.9th percentile of 0.22 at 128² but 0.022 at 512², where
#: 0.1 % of the frame is larger than its glow. A window of fixed size in pixels does not depend
#: on the resolution (FLIP is computed at a fixed 67 pixels per degree, so 7 pixels are a fixed
#: visual angle). Calibrated on :data:`CALIBRATION` (skin_jg10, measured values in
#: ``tests/test_visibility_calibration.py``): the light dot at 0.5 mm/px 0.17 and a shadow edge
#: at 1 mm/px 0.11 count; one pixel changed from 0.2 to 1.0 (0.051), smooth shading of a
#: sphere at 0.1–1 mm/px (<= 0.013) and a crowd at 3 mm/px (0.037) do not.
VISIBLE_LOCAL_FLIP = 0.08
#: side, in pixels, of the square window the local statistic averages the FLIP map over
VISIBLE_WINDOW = 7
#: the calibration set of the local rule: ``(case, expected visible)``. The cases are scenes at
#: a scale (``scene@pixel_mm``, 128², skin_jg10, the unblurred input against the reference) or
#: synthetic pairs on a 128² grey 0.2 frame (``pixel``: one pixel at 1.0; ``rim1px@0.5``: a
#: one-pixel-wide circle of radius 30 px at 0.5; ``rim2px@0.3``: two pixels wide at 0.3). The
#: answers are what a person sees: a small light's glow, a softened shadow edge, a thin rim and
#: a head framed close enough to show its features are visible; a single pixel, smooth shading
#: and a face a few pixels wide are not. Kept in a test (``tests/test_visibility_calibration.py``).
CALIBRATION = (
    ("light_dot@0.5", True),
    ("step_edge@1.0", True),
    ("head_closeup@0.6", True),
    ("rim1px@0.5", True),
    ("rim2px@0.3", True),
    ("pixel", False),
    ("sphere@0.1", False),
    ("sphere@0.3", False),
    ("sphere@1.0", False),
    ("head_cheek@0.3", False),
    ("head_far@6.0", False),
    ("crowd@3.0", False),
)
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
    reference: torch.Tensor,
    diffuse: torch.Tensor,
    mask: torch.Tensor | None = None,
    window: int = VISIBLE_WINDOW,
    fmap: np.ndarray | None = None,
) -> tuple[float, float]:
    """The mean FLIP and the local FLIP (the largest window mean) between the reference and
    an image over the mask (:func:`sssbench.score.metrics.flip_map`, tone-mapped LDR at 67
    pixels per degree).

    Args:
        reference: ``(B, 3, H, W)`` exact SSS of the scene.
        diffuse: ``(B, 3, H, W)`` the image to test: the unblurred input (``gbuffer.diffuse``)
            for SSS's visibility, a method's result for the visibility of its error.
        mask: ``(B, 1, H, W)`` weights, or ``None``. The mean is weighted by it; the local
            statistic averages the FLIP of the pixels with a positive weight in each
            ``window × window`` window that is at least half inside the mask (any window with
            a masked pixel when none is), all images of the batch pooled.
        window: side of the window in pixels (odd, >= 1).
        fmap: ``flip_map(diffuse, reference)`` or ``flip_map_over(diffuse, reference,
            mask)`` when the caller has it already (the same numbers, one FLIP evaluation
            fewer), ``(B, H, W)``; only its pixels with a positive weight are read (a
            ``ValueError`` if one is NaN). Without it, :func:`flip_map_over` computes FLIP
            on the mask's bounding box only.

    Returns:
        ``(mean, local)``: the mean FLIP (as :func:`sssbench.score.metrics.flip`) and the
        largest window mean of the per-pixel FLIP; compare with :func:`is_visible`.
    """
    from sssbench.score.metrics import check_flip_map, flip_map_over, masked_flip_map

    if not isinstance(window, int) or window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd int >= 1, got {window!r}")
    if fmap is None:
        fmap = flip_map_over(diffuse, reference, mask)
    fmap = check_flip_map(fmap, diffuse)
    if mask is None:
        wgt = np.ones_like(fmap)
    else:
        if tuple(mask.shape) != (fmap.shape[0], 1, *fmap.shape[1:]):
            raise ValueError(
                f"mask must have shape {(fmap.shape[0], 1, *fmap.shape[1:])}, "
                f"got {tuple(mask.shape)}"
            )
        wgt = mask.detach().double().cpu()[:, 0].numpy()
        if bool((wgt.reshape(wgt.shape[0], -1).sum(1) <= 0).any()):
            raise ValueError("mask must select at least one pixel in every image")
    fmap = masked_flip_map(fmap, wgt)  # the pixels with weight 0 (maybe NaN) never read
    mean = float(np.mean((fmap * wgt).sum(axis=(1, 2)) / wgt.sum(axis=(1, 2))))
    return mean, _local(fmap, (wgt > 0).astype(np.float64), window)


def _local(fmap: np.ndarray, inside: np.ndarray, window: int) -> float:
    """The largest mean of ``fmap`` over the inside pixels of a ``window``² window, over the
    windows at least half inside (any window with an inside pixel if none is)."""
    import torch.nn.functional as F

    f = torch.from_numpy(fmap * inside)[:, None]
    w = torch.from_numpy(inside)[:, None]
    pad = window // 2
    num = F.avg_pool2d(f, window, stride=1, padding=pad, count_include_pad=True)
    den = F.avg_pool2d(w, window, stride=1, padding=pad, count_include_pad=True)
    pooled = num / den.clamp_min(1e-12)
    ok = den >= 0.5 - 1e-9
    if not bool(ok.any()):
        ok = den > 0
    return float(pooled[ok].max())


def error_visibility(
    result: torch.Tensor,
    reference: torch.Tensor,
    mask: torch.Tensor | None = None,
    fmap: np.ndarray | None = None,
) -> tuple[float, float, bool]:
    """Whether a method's error is visible: :func:`visibility_stats` of its result against
    the reference, ``(mean, local, visible)`` with ``visible`` by :func:`is_visible` — the
    same calibrated rule as for SSS itself, so a method is "visibly wrong" exactly when its
    result differs from the reference as much as a visible SSS effect would. ``fmap``:
    ``flip_map(result, reference)`` if the caller has it (the runner: one map for this and
    the mean FLIP metric)."""
    mean, local = visibility_stats(reference, result, mask, fmap=fmap)
    return mean, local, is_visible(mean, local)


def is_visible(mean: float, local: float) -> bool:
    """Whether SSS (or an error) is visible given :func:`visibility_stats`: a mean FLIP of at
    least :data:`VISIBLE_FLIP` or a local FLIP (largest :data:`VISIBLE_WINDOW`² window mean)
    of at least :data:`VISIBLE_LOCAL_FLIP`."""
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
    """Whether SSS is visible at this scale: mean FLIP ``>= threshold`` or its local FLIP
    ``>= local_threshold`` (:func:`visibility_stats`)."""
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


def not_resolved_cheaper(
    times: Sequence[float], pick_time: float, time_spread: float = 0.0
) -> np.ndarray:
    """Which of ``times`` are not resolved as slower than ``pick_time`` (the cheapest one's):
    ``time <= pick_time · (1 + time_spread)``.

    A time ratio measured in one run has a run-to-run spread (the machine's state moves a
    configuration's time by tens of percent between runs of the same code); a ratio within
    one such standard deviation of 1 is not a finding. The caller passes the spread it
    measured (e.g. the sample standard deviation, between runs, of ``log(t_a / t_b)`` for
    pairs of configurations, as ``exp(sd) − 1``); 0 names only equal times.

    Args:
        times: the other candidates' times (ms, >= 0; NaN is never tied).
        pick_time: the cheapest candidate's time (ms, >= 0).
        time_spread: relative spread of a time ratio, >= 0 (0.25 = 25 %).

    Returns:
        bool array, one per time.

    Example:
        >>> not_resolved_cheaper([10.0, 11.0, 13.0], 10.0, 0.2).tolist()
        [True, True, False]
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    pick_time = check_scalar("pick_time", pick_time, 0.0)
    time_spread = check_scalar("time_spread", time_spread, 0.0)
    with np.errstate(invalid="ignore"):
        return t <= pick_time * (1.0 + time_spread)  # NaN compares False


def recommend(
    rows,
    *,
    by: Sequence[str] = ("scene", "resolution"),
    config: str = "config",
    time: str = "time_ms",
    skill_col: str = "skill",
    tolerance: float = RECOMMEND_TOLERANCE,
    time_spread: float = 0.0,
):
    """Per group (scene and scale), the cheapest configuration within ``tolerance`` of the
    best skill, and the qualifying ones it is not resolved as cheaper than.

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
        time_spread: the run-to-run spread of a time ratio (>= 0, relative; the default 0
            names only equal times): :func:`not_resolved_cheaper`.

    Returns:
        DataFrame, one row per group: the ``by`` columns, ``config``, ``time``, ``skill_col``
        of the recommendation, ``best_config`` / ``best_skill`` (the highest skill, the
        baseline if none is > 0), ``candidates`` (how many qualified), ``tied`` (a tuple of
        the other qualifying configurations whose time is within ``time_spread`` of the
        recommendation's, cheapest first: which of them is cheaper is not resolved) and
        ``reason``.
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
                    "tied": (),
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
        others = sorted((c for c in cands if c is not pick), key=lambda c: c[time])
        near = not_resolved_cheaper([c[time] for c in others], pick[time], time_spread)
        out.append(
            {
                **rec,
                **pick,
                "best_config": top[config] if best > 0 else BASELINE,
                "best_skill": best,
                "candidates": len(cands),
                "tied": tuple(c[config] for c, n in zip(others, near, strict=True) if n),
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
    tied = tuple(row.get("tied") or ())
    if tied:
        s += f"; not resolved as cheaper than {', '.join(str(t) for t in tied)}"
    if row["best_config"] == row[config]:
        return s + ", also the best."
    return s + f"; the best, {row['best_config']}, reaches {_signed(float(row['best_skill']))}."

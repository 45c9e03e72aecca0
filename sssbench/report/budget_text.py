"""The error budget per ranking group as sentences: which part dominates each method's error
(:func:`sssbench.score.budget_verdict.budget_sentence`), for ``summary.md``, the console, the
HTML page and the benchmark section."""

from __future__ import annotations

import math

import pandas as pd

from sssbench.report.tables import BASELINE, REFERENCE, group_keys, label
from sssbench.score.budget_verdict import PARTS, budget_sentence, budget_shares, dominant_part

__all__ = ["BUDGET_COLUMNS", "budget_verdicts"]

#: the budget's four parts (rel RMS norms) as table columns, in the sentence's order
BUDGET_COLUMNS = [f"err_{p}" for p in PARTS]


def _parts(row: pd.Series, prefix: str) -> dict[str, float]:
    """``{part: row[prefix + part]}`` (NaN where missing)."""
    out = {}
    for p in PARTS:
        v = row.get(f"{prefix}{p}")
        out[p] = math.nan if v is None or pd.isna(v) else float(v)
    return out


def budget_verdicts(table: pd.DataFrame) -> pd.DataFrame:
    """Per ranking group (:func:`~sssbench.report.tables.group_keys`) and screen-space method:
    the method's configuration with the best skill among its runs with a budget (the most
    taps where no skill is known), its parts' shares of the error (``share_taps`` …, NaN
    where not measured), the dominant part (:func:`~sssbench.score.budget_verdict.dominant_part`)
    and the sentence. Groups or methods without a budget give no row."""
    keys = group_keys(table)
    shares = [f"share_{p}" for p in PARTS]
    cols = [*keys, "method", "config", "rel_rms", *shares, "dominant", "sentence"]
    rows = []
    if table.empty or "contribution_model" not in table.columns:
        return pd.DataFrame(columns=cols)
    ok = table[(table["status"] == "ok") & ~table["method"].isin((BASELINE, REFERENCE))]
    ok = ok[ok["contribution_model"].notna()]
    for key, group in ok.groupby([*keys, "method"], dropna=False, sort=True):
        info = dict(zip([*keys, "method"], key, strict=True))
        skill = group["skill"].astype(float)
        if skill.notna().any():
            row = group.loc[skill.idxmax()]
        else:
            row = group.sort_values("samples", na_position="first").iloc[-1]
        subject = f"{info['scene']} · {info['scale']} · {label(row)}"
        contrib, norms = _parts(row, "contribution_"), _parts(row, "err_")
        sentence = budget_sentence(subject, contrib, norms)
        if sentence is None:
            continue
        shares = budget_shares(contrib) or {}
        rows.append(
            {
                **info,
                "config": label(row),
                "rel_rms": float(sum(contrib[p] for p in shares)),
                **{f"share_{p}": shares.get(p, math.nan) for p in PARTS},
                "dominant": dominant_part(contrib, norms),
                "sentence": sentence,
            }
        )
    return pd.DataFrame(rows, columns=cols)

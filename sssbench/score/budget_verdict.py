"""The error budget's verdict: which part dominates a method's error, and what is left to gain.

The budget (:mod:`sssbench.score.budget`, docs/error_budget.md) splits ``M_N − R`` into taps,
model, reconstruction and screen images. Their *contributions* ``⟨part, M_N − R⟩ / (‖R‖
‖M_N − R‖)`` add up to the method's rel RMS exactly, so each part's **share** of the error is
its contribution over their sum (the shares add up to 1; a part that cancels another has a
negative share). The sentence names the part with the largest share and says what would
remove it, every number from the shares it is given.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

__all__ = ["PARTS", "NO_HELP", "budget_shares", "dominant_part", "budget_sentence"]

#: the budget's parts, in the order the sentence lists them
PARTS = ("taps", "model", "recon", "screen")
#: names of the parts in sentences
PART_NAMES = {
    "taps": "taps",
    "model": "model (kernel shape)",
    "recon": "reconstruction",
    "screen": "screen-space",
}
#: below this share, "more taps will not help"
NO_HELP = 0.10


def budget_shares(contributions: Mapping[str, float]) -> dict[str, float] | None:
    """Each measured part's share of the error, ``c_k / Σ c`` over the parts of :data:`PARTS`
    whose contribution is a finite number (a store written before ``err_recon`` was measured
    on every scene has it NaN: it is left out); ``None`` when no part is measured or the sum
    is not positive (an exact method: nothing to split).

    Args:
        contributions: ``{"taps": …, "model": …, "recon": …, "screen": …}`` (rel RMS units),
            missing or NaN where a part was not measured.
    """
    got = {}
    for k in PARTS:
        v = contributions.get(k)
        if v is not None and isinstance(v, (int, float)) and math.isfinite(float(v)):
            got[k] = float(v)
    total = sum(got.values())
    if not got or not total > 0:
        return None
    return {k: v / total for k, v in got.items()}


def dominant_part(shares: Mapping[str, float]) -> str:
    """The part with the largest share (the first in :data:`PARTS` order on a tie)."""
    return max((k for k in PARTS if k in shares), key=lambda k: shares[k])


def _pct(share: float) -> str:
    return f"{100 * share:.0f} %"


def budget_sentence(subject: str, contributions: Mapping[str, float]) -> str | None:
    """One sentence for one configuration: the dominant part and its share, every part's
    share with the total rel RMS, and the advice that follows from them; ``None`` where
    :func:`budget_shares` is.

    E.g. ``"face · 0.3 mm/px · sum_of_gaussians 17: the screen-space part is 62 % of the
    error (rel RMS 0.0312 = taps 5 % + model (kernel shape) 8 % + reconstruction 25 % +
    screen-space 62 %): more taps will not help (5 %); a pass that handles this geometry
    better (depth steps, silhouettes, curvature, borders) would address 62 %."``

    The advice: where taps dominate, more taps can remove up to their share; otherwise more
    taps "will not help" below :data:`NO_HELP` and "can remove at most" their share above it,
    and the dominant part's remedy is named: a kernel closer to the profile (model), a pass
    that handles the geometry better (screen); the reconstruction part is the same for every
    method (the bilinear reads against the reference's pixel cells), so neither a kernel nor
    taps remove it.
    """
    shares = budget_shares(contributions)
    if shares is None:
        return None
    total = sum(float(contributions[k]) for k in shares)
    top = dominant_part(shares)
    listed = " + ".join(f"{PART_NAMES[k]} {_pct(shares[k])}" for k in PARTS if k in shares)
    if "recon" not in shares:
        listed += ", reconstruction not measured"
    head = (
        f"{subject}: the {PART_NAMES[top]} part is {_pct(shares[top])} of the error "
        f"(rel RMS {total:.3g} = {listed})"
    )
    taps = shares.get("taps")
    if top == "taps":
        return f"{head}: more taps can remove up to {_pct(taps)} of it."
    if taps is None:
        advice = "the taps part is not measured"
    elif taps < NO_HELP:
        advice = f"more taps will not help ({_pct(taps)})"
    else:
        advice = f"more taps can remove at most {_pct(taps)}"
    if top == "model":
        advice += f"; a kernel closer to the profile would address {_pct(shares[top])}"
    elif top == "screen":
        advice += (
            "; a pass that handles this geometry better (depth steps, silhouettes, curvature,"
            f" borders) would address {_pct(shares[top])}"
        )
    else:
        advice += (
            f"; the reconstruction part ({_pct(shares[top])}) is the passes' bilinear reads "
            "against the reference's pixel cells: neither a kernel nor taps remove it"
        )
    return f"{head}: {advice}."

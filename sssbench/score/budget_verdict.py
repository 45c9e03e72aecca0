"""The error budget's verdict: which part dominates a method's error, and what is left to gain.

The budget (:mod:`sssbench.score.budget`, docs/error_budget.md) splits ``M_N − R`` into taps,
model, reconstruction and screen images. Their *contributions* ``⟨part, M_N − R⟩ / (‖R‖
‖M_N − R‖)`` add up to the method's rel RMS exactly, so each part's **share** of the error is
its contribution over their sum (the shares add up to 1; a part that cancels another has a
negative share). The sentence names the part whose removal would lower the error most (the
error left without it follows exactly from its contribution and its own norm) and says
what would remove it, every number from the numbers it is given.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

__all__ = [
    "PARTS",
    "NO_HELP",
    "budget_shares",
    "dominant_part",
    "error_without",
    "budget_sentence",
]

#: the budget's parts, in the order the sentence lists them
PARTS = ("taps", "model", "recon", "screen")
#: names of the parts in sentences
PART_NAMES = {
    "taps": "taps",
    "model": "model (kernel shape)",
    "recon": "reconstruction",
    "screen": "screen-space",
}
#: "more taps will not help" where converged taps would lower the error by less than this
#: fraction of it
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


def _pct(share: float) -> str:
    return f"{100 * share:.0f} %"


def _delta(change: float) -> str:
    """A relative change of the error, signed (``−44 %``, ``+6 %``)."""
    return f"{100 * change:+.0f} %"


def error_without(total: float, contribution: float, norm: float) -> float:
    """The rel RMS left when one part is taken out of the error: ``‖E − P‖ / ‖R‖`` from the
    error's ``total = ‖E‖/‖R‖``, the part's ``contribution = ⟨P, E⟩/(‖R‖ ‖E‖)`` and its
    ``norm = ‖P‖/‖R‖`` (``‖E − P‖² = ‖E‖² − 2⟨P, E⟩ + ‖P‖²``; exact, whatever the other
    parts do)."""
    return math.sqrt(max(0.0, total * total - 2.0 * contribution * total + norm * norm))


def _without(
    contributions: Mapping[str, float], norms: Mapping[str, float]
) -> tuple[float, dict[str, float], dict[str, float]] | None:
    """The total, the shares and the rel RMS left without each part whose norm is known."""
    shares = budget_shares(contributions)
    if shares is None:
        return None
    total = sum(float(contributions[k]) for k in shares)
    left = {}
    for k in shares:
        n = norms.get(k)
        if n is not None and isinstance(n, (int, float)) and math.isfinite(float(n)):
            left[k] = error_without(total, float(contributions[k]), float(n))
    return (total, shares, left) if left else None


def dominant_part(contributions: Mapping[str, float], norms: Mapping[str, float]) -> str | None:
    """The part whose removal lowers the error most (:func:`error_without`; the first in
    :data:`PARTS` order on a tie), ``None`` where no sentence is made."""
    got = _without(contributions, norms)
    if got is None:
        return None
    left = got[2]
    return min((k for k in PARTS if k in left), key=lambda k: left[k])


def budget_sentence(
    subject: str, contributions: Mapping[str, float], norms: Mapping[str, float]
) -> str | None:
    """One sentence for one configuration; ``None`` where :func:`budget_shares` is.

    Args:
        subject: what the sentence is about (scene · scale · configuration).
        contributions: each part's contribution (rel RMS units, they add up to the error).
        norms: each part's own rel RMS ``‖part‖ / ‖R‖`` (``err_taps`` …).

    The **dominant** part is the one whose removal lowers the error most
    (:func:`error_without`, a part is left out where its norm is not finite). The sentence
    states the rel RMS without it, the shares of every part (:func:`budget_shares`), and the
    advice that follows: more taps "will not help" where taking out the taps part lowers the
    error by less than :data:`NO_HELP` of it, otherwise they can bring it down to the rel
    RMS stated; the dominant part's remedy: a kernel closer to the profile (model), a pass
    that handles the geometry better (screen); the reconstruction part is the same for every
    method (the passes' bilinear reads against the reference's pixel cells), neither a kernel
    nor taps remove it.

    E.g. ``"face · 0.3 mm/px · sum_of_gaussians uniform 17: the screen-space part dominates:
    without it the rel RMS would be 0.011 instead of 0.0312 (-65 %; shares of the error: taps
    5 % + model (kernel shape) 8 % + reconstruction 25 % + screen-space 62 %); more taps will
    not help (+3 %); a pass that handles this geometry better (depth steps, silhouettes,
    curvature, borders) would."``
    """
    got = _without(contributions, norms)
    if got is None:
        return None
    total, shares, left = got
    top = dominant_part(contributions, norms)
    assert top is not None
    listed = " + ".join(f"{PART_NAMES[k]} {_pct(shares[k])}" for k in PARTS if k in shares)
    if "recon" not in shares:
        listed += ", reconstruction not measured"
    text = (
        f"{subject}: the {PART_NAMES[top]} part dominates: without it the rel RMS would be "
        f"{left[top]:.3g} instead of {total:.3g} ({_delta(left[top] / total - 1)}; shares of the "
        f"error: {listed})"
    )
    if "taps" not in left:
        taps = "the taps part is not measured"
    elif left["taps"] > (1 - NO_HELP) * total:
        taps = f"more taps will not help ({_delta(left['taps'] / total - 1)})"
    else:
        change = _delta(left["taps"] / total - 1)
        taps = f"more taps can bring it down to {left['taps']:.3g} ({change})"
    if top == "taps":
        return f"{text}; {taps}."
    remedy = {
        "model": "a kernel closer to the profile would",
        "screen": "a pass that handles this geometry better (depth steps, silhouettes, "
        "curvature, borders) would",
        "recon": "the reconstruction part is the passes' bilinear reads against the "
        "reference's pixel cells: neither a kernel nor taps remove it",
    }[top]
    return f"{text}; {taps}; {remedy}."

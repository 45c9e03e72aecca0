"""Decision helpers: skill, visibility, Pareto set, recommendation, sentences (closed forms)."""

import math

import numpy as np
import pandas as pd
import pytest
import torch

from sssbench.score.verdict import (
    BASELINE,
    VISIBLE_FLIP,
    VISIBLE_LOCAL_FLIP,
    is_visible,
    not_resolved_cheaper,
    pareto_set,
    recommend,
    recommendation_sentence,
    skill,
    sss_visibility,
    verdict_sentence,
    visibility_stats,
    visible,
)


def test_skill_closed_forms():
    assert skill(0.01, 0.04) == pytest.approx(0.75)
    assert skill(0.04, 0.04) == 0.0  # as good as doing nothing
    assert skill(0.047, 0.037) == pytest.approx(-10 / 37)  # worse than doing nothing
    assert skill(0.0, 0.5) == 1.0
    assert math.isnan(skill(0.1, 0.0))  # SSS changes nothing: undefined
    got = skill(np.array([0.0, 0.02, 0.1]), np.array([0.04, 0.04, 0.0]))
    np.testing.assert_allclose(got[:2], [1.0, 0.5])
    assert math.isnan(got[2])
    s = skill(pd.Series([0.01, 0.03]), pd.Series([0.02, 0.02]))
    np.testing.assert_allclose(s, [0.5, -0.5])
    with pytest.raises(ValueError, match="err"):
        skill(-0.1, 0.2)


def test_visibility_is_flip_of_reference_against_input():
    a = torch.full((1, 3, 64, 64), 0.4)
    assert sss_visibility(a, a.clone()) == 0.0  # identical images: FLIP 0, not visible
    assert not visible(a, a.clone())
    b = a.clone()
    b[..., :, 32:] *= 0.3  # a strong difference on half the image
    v = sss_visibility(b, a)
    assert v > VISIBLE_FLIP and visible(b, a)
    mask = torch.zeros(1, 1, 64, 64)
    mask[..., :, :8] = 1.0  # the mask covers only unchanged pixels, far from the change
    assert sss_visibility(b, a, mask) < 1e-3 < v


def test_a_local_change_is_visible_though_the_mean_is_diluted():
    """A bright 8×8 spot on 0.4 % of a 128² frame: the mean FLIP is below the spread-out bar,
    yet the most-changed 7×7 window differs strongly, so it counts as visible; a single pixel
    does not (its window mean stays under the local bar)."""
    a = torch.full((1, 3, 128, 128), 0.2)
    b = a.clone()
    b[..., 60:68, 60:68] = 1.0  # 64 pixels = 0.39 % of the frame
    mean, local = visibility_stats(b, a)
    assert mean < VISIBLE_FLIP  # diluted by the unchanged area
    assert local >= VISIBLE_LOCAL_FLIP
    assert is_visible(mean, local) and visible(b, a)
    assert not is_visible(0.0, 0.0) and is_visible(VISIBLE_FLIP, 0.0)
    c = a.clone()
    c[..., 64, 64] = 1.0  # one pixel (FLIP spreads it over a few): its 7x7 mean is 0.05
    mean_c, local_c = visibility_stats(c, a)
    assert mean_c < VISIBLE_FLIP and local_c < VISIBLE_LOCAL_FLIP
    assert not visible(c, a)
    # the mask weights the mean: around the spot only, the change is widespread
    mask = torch.zeros(1, 1, 128, 128)
    mask[..., 56:72, 56:72] = 1.0
    assert visibility_stats(b, a, mask)[0] > VISIBLE_FLIP


def test_pareto_set_hand_example():
    # (time, error): 0 (1, .5), 1 (2, .6) dominated by 0, 2 (3, .1), 3 (3, .2) dominated by
    # 2, 4 (0.5, .9), 5 = copy of 2 (kept: identical points do not dominate each other)
    times = [1.0, 2.0, 3.0, 3.0, 0.5, 3.0]
    errors = [0.5, 0.6, 0.1, 0.2, 0.9, 0.1]
    assert pareto_set(times, errors) == [4, 0, 2, 5]
    with pytest.raises(ValueError, match="same length"):
        pareto_set([1.0], [1.0, 2.0])


def _rows():
    return pd.DataFrame(
        [
            # step_edge: best 0.90 (c), bar 0.81: a (0.82, 2 ms) is cheapest qualifying
            ("step_edge", 128, "a", 2.0, 0.82),
            ("step_edge", 128, "b", 1.0, 0.80),
            ("step_edge", 128, "c", 9.0, 0.90),
            ("step_edge", 128, "identity", 0.0, 0.0),
            # head_cheek: nothing beats doing nothing
            ("head_cheek", 128, "a", 2.0, -0.27),
            ("head_cheek", 128, "b", 1.0, -0.01),
            # invisible: identity error 0
            ("head_far", 128, "a", 2.0, math.nan),
        ],
        columns=["scene", "resolution", "config", "time_ms", "skill"],
    )


def test_recommend_cheapest_within_ten_percent():
    rec = recommend(_rows()).set_index("scene")
    assert rec.loc["step_edge", "config"] == "a"
    assert rec.loc["step_edge", "best_config"] == "c"
    assert rec.loc["step_edge", "best_skill"] == pytest.approx(0.9)
    assert rec.loc["step_edge", "candidates"] == 2  # a and c
    assert rec.loc["head_cheek", "config"] == BASELINE
    assert rec.loc["head_cheek", "skill"] == 0.0
    assert rec.loc["head_far", "config"] == BASELINE
    assert rec.loc["head_far", "reason"] == "no visible SSS"
    # a wider tolerance lets the 1 ms configuration in (0.80 >= 0.9 - 0.2 * 0.9 = 0.72)
    assert recommend(_rows(), tolerance=0.2).set_index("scene").loc["step_edge", "config"] == "b"
    with pytest.raises(ValueError, match="columns"):
        recommend(_rows().drop(columns="time_ms"))


def test_a_time_within_the_run_to_run_spread_is_not_resolved_as_slower():
    """``t <= pick · (1 + spread)``, by hand: 10 ms against a 10 ms pick is tied at any
    spread; 11 ms at 10 % (bound 11.000000000000002) and 20 %, not at 5 %; NaN never."""
    times = [10.0, 11.0, 13.0, math.nan]
    assert not_resolved_cheaper(times, 10.0, 0.0).tolist() == [True, False, False, False]
    assert not_resolved_cheaper(times, 10.0, 0.05).tolist() == [True, False, False, False]
    assert not_resolved_cheaper(times, 10.0, 0.1).tolist() == [True, True, False, False]
    assert not_resolved_cheaper(times, 10.0, 0.2).tolist() == [True, True, False, False]
    assert not_resolved_cheaper(times, 10.0, 0.3).tolist() == [True, True, True, False]
    with pytest.raises(ValueError, match="time_spread"):
        not_resolved_cheaper(times, 10.0, -0.1)
    with pytest.raises(ValueError, match="time_spread"):
        not_resolved_cheaper(times, 10.0, math.inf)


def test_recommend_names_the_candidates_it_is_not_resolved_as_cheaper_than():
    """step_edge qualifies a (2 ms) and c (9 ms): c is within the spread of a when
    2 · (1 + s) >= 9, i.e. s >= 3.5; the recommendation is a either way."""
    for spread, tied in ((0.0, ()), (3.4, ()), (3.5, ("c",)), (5.0, ("c",))):
        rec = recommend(_rows(), time_spread=spread).set_index("scene", drop=False)
        assert rec.loc["step_edge", "config"] == "a"
        assert rec.loc["step_edge", "tied"] == tied
        assert rec.loc["head_far", "tied"] == ()
    # doing nothing (0 ms) is the pick where nothing beats it; no other candidate costs 0
    rec = recommend(_rows(), time_spread=5.0).set_index("scene", drop=False)
    assert rec.loc["head_cheek", "tied"] == ()
    assert recommendation_sentence(rec.loc["step_edge"]) == (
        "step_edge, 128: use a (skill 0.82, 2 ms); not resolved as cheaper than c; the best, "
        "c, reaches 0.90."
    )
    with pytest.raises(ValueError, match="time_spread"):
        recommend(_rows(), time_spread=-1.0)


def test_sentences_follow_the_numbers():
    assert verdict_sentence("X", skill(0.047, 0.037)) == (
        "X is worse than doing nothing (skill \u22120.27)."
    )
    assert "barely beats" in verdict_sentence("X", 0.1)
    assert verdict_sentence("X", 0.575).startswith("X removes 57% of the error")
    assert "not visible" in verdict_sentence("X", math.nan)
    assert "0.047 vs 0.037" in verdict_sentence("X", -0.27, 0.047, 0.037)
    rec = recommend(_rows()).set_index("scene", drop=False)
    assert recommendation_sentence(rec.loc["step_edge"]) == (
        "step_edge, 128: use a (skill 0.82, 2 ms); the best, c, reaches 0.90."
    )
    assert recommendation_sentence(rec.loc["head_cheek"]).startswith("head_cheek, 128: do nothing")
    assert "not visible" in recommendation_sentence(rec.loc["head_far"])


def test_a_shared_flip_map_gives_the_same_numbers_and_a_wrong_one_is_refused():
    """The runner evaluates FLIP once per run and hands the map to the mean metric and to the
    error's visibility: the numbers equal those of two separate evaluations, bit for bit; a
    map of another shape is refused naming ``fmap``."""
    from sssbench.score import verdict
    from sssbench.score.metrics import compute_all, flip, flip_map

    g = torch.Generator().manual_seed(3)
    ref = torch.rand(1, 3, 20, 24, generator=g, dtype=torch.float64)
    res = (ref + 0.2 * torch.rand(1, 3, 20, 24, generator=g, dtype=torch.float64)).clamp(0)
    mask = (torch.rand(1, 1, 20, 24, generator=g, dtype=torch.float64) > 0.3).double()
    fmap = flip_map(res, ref)
    assert compute_all(res, ref, mask, fmap=fmap) == compute_all(res, ref, mask)
    assert verdict.error_visibility(res, ref, mask, fmap) == verdict.error_visibility(
        res, ref, mask
    )
    with pytest.raises(ValueError, match="fmap must be the"):
        flip(res, ref, mask, fmap=fmap[:, :10])
    with pytest.raises(ValueError, match="fmap must be the"):
        verdict.visibility_stats(ref, res, mask, fmap=fmap.T)

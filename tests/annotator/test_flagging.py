"""Flags from failure probabilities: the online span flagger decides exactly what a plain offline pass decides,
budget mode flags exactly the most doubtful frames, and every reason is explained.

The reference below is a second, obviously-correct implementation of the
span rules (:mod:`annotator.flagging`): a frame is doubtful when ``p_fail``
exceeds the threshold (never a keyframe or an outside frame); gaps of at most
``merge_gap`` frames between doubtful frames merge (no keyframe or outside
frame inside); spans shorter than ``min_span`` are dropped; outside frames
are flagged ``outside``.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from _paths import ROOT
from hypothesis import given, settings
from hypothesis import strategies as st

from annotator.flagging import (
    REASONS,
    FlagParams,
    FlagResult,
    SpanFlagger,
    budget_flags,
    flag_p_fail,
    keyframe_request,
    span_flags,
    spans_from_mask,
    with_keyframe_request,
)


def reference(p_fail, groups, threshold, keyframe, outside, p: FlagParams) -> tuple[list[bool], list[str]]:
    n = len(p_fail)
    doubtful = [bool(np.isfinite(p_fail[t]) and p_fail[t] > threshold and not keyframe[t] and not outside[t])
                for t in range(n)]
    in_gap = [False] * n
    positions = [t for t in range(n) if doubtful[t]]
    for a, b in zip(positions, positions[1:]):
        gap = range(a + 1, b)
        if 0 < len(gap) <= p.merge_gap and not any(keyframe[t] or outside[t] for t in gap):
            for t in gap:
                in_gap[t] = True
    merged = [d or g for d, g in zip(doubtful, in_gap)]
    final = list(merged)
    t = 0
    while t < n:
        if not merged[t]:
            t += 1
            continue
        end = t
        while end < n and merged[end]:
            end += 1
        if end - t < p.min_span:
            final[t:end] = [False] * (end - t)
        t = end
    flagged = [final[t] or bool(outside[t]) for t in range(n)]
    reasons = ["outside" if outside[t] else (f"doubt:{groups[t]}" if doubtful[t] else "span") if final[t] else ""
               for t in range(n)]
    # A lost track (mean p_fail of its tracked frames above lost_threshold) asks for keyframes instead.
    tracked = [p_fail[t] for t in range(n) if not keyframe[t] and not outside[t] and np.isfinite(p_fail[t])]
    if (p.lost_threshold is not None and n > p.keyframe_every and tracked
            and sum(tracked) / len(tracked) > p.lost_threshold):
        asked = {t for t in range(n) if (t % p.keyframe_every == 0 and t > 0) or t == n - 1}
        asked = {t for t in asked if not keyframe[t] and not outside[t]}
        if asked:  # nothing left to ask for: the doubtful spans stay
            flagged = [bool(outside[t]) or t in asked for t in range(n)]
            reasons = ["outside" if outside[t] else "keyframe" if t in asked else "" for t in range(n)]
    return flagged, reasons


track_st = st.integers(0, 60).flatmap(lambda n: st.tuples(
    st.lists(st.floats(0, 1), min_size=n, max_size=n),
    st.lists(st.sampled_from(["flow", "score", "appearance"]), min_size=n, max_size=n),
    st.lists(st.sampled_from([False, False, False, True]), min_size=n, max_size=n),
    st.lists(st.sampled_from([False, False, False, True]), min_size=n, max_size=n),
))
params_st = st.builds(FlagParams, merge_gap=st.integers(0, 6), min_span=st.integers(1, 5),
                      lost_threshold=st.sampled_from([None, 0.3, 0.6]), keyframe_every=st.integers(2, 7))


@settings(max_examples=100, deadline=None)
@given(track_st, params_st, st.floats(0.05, 0.95))
def test_online_spans_equal_the_offline_reference(track, params, threshold):
    p_fail, groups, keyframe, outside = (np.array(track[0]), track[1], np.array(track[2], bool),
                                         np.array(track[3], bool))
    keyframe &= ~outside
    expected = reference(p_fail, groups, threshold, keyframe, outside, params)
    result = flag_p_fail(p_fail, groups, threshold, params, keyframe=keyframe, outside=outside)
    assert result.flagged.tolist() == expected[0]
    assert list(result.reasons) == expected[1]
    np.testing.assert_array_equal(result.spans, spans_from_mask(result.flagged))


@settings(max_examples=200, deadline=None)
@given(track_st, params_st, st.floats(0.05, 0.95))
def test_vectorised_span_flags_equal_the_offline_reference(track, params, threshold):
    p_fail, keyframe = np.array(track[0]), np.array(track[2], bool)
    no_request = FlagParams(merge_gap=params.merge_gap, min_span=params.min_span, lost_threshold=None)
    expected, _ = reference(p_fail, track[1], threshold, keyframe, np.zeros(len(p_fail), bool), no_request)
    assert span_flags(p_fail > threshold, no_request, blocked=keyframe).tolist() == expected


@settings(max_examples=100, deadline=None)
@given(track_st, params_st)
def test_each_decision_is_final_exactly_lag_frames_later(track, params):
    p_fail = np.array(track[0])
    flagger = SpanFlagger(params)
    for t, p in enumerate(p_fail):
        emitted = flagger.push(p > 0.5, "doubt:flow")
        assert [pos for pos, _, _ in emitted] == ([t - params.lag] if t >= params.lag else [])
    tail = flagger.finish()
    assert [pos for pos, _, _ in tail] == list(range(max(0, len(p_fail) - params.lag), len(p_fail)))


def test_hand_made_spans():
    p = FlagParams(merge_gap=1, min_span=2, lost_threshold=None)  # its mean p_fail, 0.61, would ask for keyframes
    p_fail = np.array([0.9, 0.1, 0.9, 0.9, 0.1, 0.1, 0.9, 0.1, 0.9, 0.9, 0.9])
    groups = ["flow"] * 11
    keyframe = np.zeros(11, bool)
    keyframe[7] = True  # a human box between two doubtful frames: no merging across it
    result = flag_p_fail(p_fail, groups, 0.5, p, keyframe=keyframe)
    assert result.flagged.tolist() == [True, True, True, True, False, False, False, False, True, True, True]
    assert result.reasons[:4] == ("doubt:flow", "span", "doubt:flow", "doubt:flow")
    assert result.spans.tolist() == [[0, 4], [8, 11]]


def test_budget_flags_exactly_the_most_doubtful_share():
    p_fail = np.array([0.0, 0.2, 0.9, 0.4, 0.9, np.nan, 0.8, 0.1, 0.3, 0.95])
    keyframe = np.zeros(10, bool)
    keyframe[0] = True
    outside = np.zeros(10, bool)
    outside[5] = True
    result = budget_flags(p_fail, ["score"] * 10, 30, keyframe=keyframe, outside=outside)
    # 30% of 10 frames = 3: p_fail 0.95 (9), 0.9 (2, earlier of the tie), 0.9 (4); the outside frame is always flagged.
    assert np.flatnonzero(result.flagged).tolist() == [2, 4, 5, 9]
    assert result.reasons[5] == "outside" and result.reasons[9] == "budget+doubt:score"
    assert budget_flags(p_fail, ["score"] * 10, 1, keyframe=keyframe, outside=outside).flagged.sum() == 2  # ceil
    via = flag_p_fail(p_fail, ["score"] * 10, 0.5, FlagParams(review_budget=30), keyframe=keyframe, outside=outside)
    assert via.flagged.tolist() == result.flagged.tolist()


def test_a_lost_track_asks_for_every_kth_frame_and_the_last_instead_of_its_spans():
    n = 23
    p_fail = np.full(n, 0.7)
    keyframe = np.zeros(n, bool)
    keyframe[[0, 10]] = True  # the given box, and a correction that is one of the frames asked for
    outside = np.zeros(n, bool)
    outside[15] = True  # absent: neither asked for nor counted in the mean
    p_fail[keyframe], p_fail[outside] = 0.0, np.nan
    params = FlagParams(keyframe_every=5)
    assert keyframe_request(p_fail, keyframe=keyframe, outside=outside, params=params).tolist() == [5, 20, 22]
    result = flag_p_fail(p_fail, ["score"] * n, 0.9, params, keyframe=keyframe, outside=outside)
    assert np.flatnonzero(result.flagged).tolist() == [5, 15, 20, 22]
    assert [result.reasons[t] for t in (5, 15, 20, 22)] == ["keyframe", "outside", "keyframe", "keyframe"]
    assert result.spans.tolist() == [[5, 6], [15, 16], [20, 21], [22, 23]]
    # The mean of the tracked frames decides: 0.7 is above 0.6 (the default) and below 0.75.
    for low in (FlagParams(lost_threshold=0.75), FlagParams(lost_threshold=None)):
        assert keyframe_request(p_fail, keyframe=keyframe, outside=outside, params=low).size == 0
        plain = flag_p_fail(p_fail, ["score"] * n, 0.6, low, keyframe=keyframe, outside=outside)
        assert "keyframe" not in plain.reasons and plain.flagged[1:10].all()
    # With a review budget the budget decides, lost or not.
    budget = flag_p_fail(p_fail, ["score"] * n, 0.9, FlagParams(review_budget=10), keyframe=keyframe, outside=outside)
    assert "keyframe" not in budget.reasons


def test_once_the_asked_frames_are_boxed_the_track_is_flagged_as_usual():
    n = 12
    p_fail = np.full(n, 0.95)
    keyframe = np.zeros(n, bool)
    keyframe[[0, 4, 8, 11]] = True
    p_fail[keyframe] = 0.0
    outside = np.zeros(n, bool)
    params = FlagParams(keyframe_every=4, min_span=1)
    assert keyframe_request(p_fail, keyframe=keyframe, outside=outside, params=params).size == 0
    current = flag_p_fail(p_fail, ["score"] * n, 0.9, params, keyframe=keyframe, outside=outside)
    assert current.flagged.tolist() == (~keyframe).tolist()
    # Nothing asked for: the result passes through unchanged.
    assert with_keyframe_request(current, p_fail, keyframe=keyframe, outside=outside, params=params) is current
    # A track no longer than the interval, or with no tracked frame, never asks.
    short = np.full(4, 0.99)
    assert keyframe_request(short, keyframe=np.zeros(4, bool), outside=np.zeros(4, bool), params=params).size == 0
    assert keyframe_request(np.full(5, 0.99), keyframe=np.zeros(5, bool), outside=np.zeros(5, bool),
                            params=params).tolist() == [4]
    one = FlagResult(flagged=np.zeros(1, bool), reasons=("",), spans=spans_from_mask(np.zeros(1, bool)))
    assert with_keyframe_request(one, np.array([0.99]), keyframe=np.zeros(1, bool), outside=np.zeros(1, bool),
                                 params=params) is one
    assert keyframe_request(np.zeros(3), keyframe=np.ones(3, bool), outside=np.zeros(3, bool), params=params).size == 0


@pytest.mark.parametrize("field, value, expected", [
    ("threshold", 1.0, "(0, 1)"), ("threshold", 0.0, "(0, 1)"), ("review_budget", 0.0, "(0, 100]"),
    ("review_budget", 101.0, "(0, 100]"), ("merge_gap", -1, ">= 0"), ("min_span", 0, ">= 1"),
    ("lost_threshold", 1.0, "(0, 1)"), ("lost_threshold", 0.0, "(0, 1)"), ("keyframe_every", 1, ">= 2")])
def test_bad_flag_parameters_name_the_field(field, value, expected):
    with pytest.raises(ValueError, match=rf"flag parameter {field}={value!r} is invalid: expected "
                                         rf".*{re.escape(expected)}"):
        FlagParams(**{field: value})


def test_every_reason_a_flag_can_carry_is_explained():
    from annotator.failure.model import FEATURE_GROUPS

    for group in set(FEATURE_GROUPS.values()):
        assert f"doubt:{group}" in REASONS
    assert {"span", "budget", "outside", "keyframe"} <= set(REASONS)


def test_docs_explain_every_flag_reason_as_the_code_does():
    """docs/flags.md's "Flag reasons" table is REASONS, row for row (the report's legend is built from REASONS)."""
    page = (ROOT / "docs" / "flags.md").read_text(encoding="utf-8")
    section = page.split("## Flag reasons", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([^`]+)` \| (.*) \|$", section, re.M)
    assert rows == list(REASONS.items())

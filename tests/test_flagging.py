"""Flagging: the online flagger decides exactly what a plain offline pass over the whole track decides.

The reference below is written from the rules in :mod:`annotator.flagging`
(module docstring and :class:`FlagParams` field notes), as a second,
obviously-correct implementation: per-frame rules in one causal loop, then
gap merging and the minimum span length over the complete sequence. The
online flagger, which sees only ``lag`` frames of look-ahead and a sliding
window of the past, must agree with it frame for frame, and must emit each
decision exactly ``lag`` frames after the frame itself.
"""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from annotator.flagging import FlagParams, OnlineFlagger, flag_frames, spans_from_mask

# --------------------------------------------------------------------------- the offline reference


def reference_raw(log_likelihood, confidence, scoring, keyframe, p: FlagParams) -> list[list[str]]:
    """Per-frame reasons from the causal rules (Phi, drop, hysteresis, low confidence)."""
    reasons: list[list[str]] = []
    trusted: list[float] = []  # log-likelihoods of frames the tracker trusted: the running level
    holding = False
    for ll, conf, how, key in zip(log_likelihood, confidence, scoring, keyframe):
        frame: list[str] = []
        if key:  # a box a person gave: never flagged, and the hysteresis starts afresh
            holding = False
            reasons.append(frame)
            continue
        if p.min_confidence > 0 and conf < p.min_confidence:
            frame.append("low_confidence")
        if how == "subspace":
            level = statistics.median(trusted[-p.window :]) if trusted else None
            if not math.isfinite(ll) or ll <= p.accept_threshold:
                frame.append("rejected")
            elif ll <= p.accept_threshold + p.margin:
                frame.append("low_likelihood")
            elif level is not None and level > 0 and ll < level * (1 - p.drop):
                frame.append("drop")
            if frame:
                holding = True
            elif holding:
                # Back to the running level; with no level yet there is nothing to climb back to.
                if level is None or ll >= level * p.recover:
                    holding = False
                else:
                    frame.append("held")
            if not frame and ll > p.accept_threshold + p.margin:
                trusted.append(ll)
        reasons.append(frame)
    return reasons


def reference_spans(raw_reasons: list[list[str]], keyframe, p: FlagParams) -> tuple[list[bool], list[str]]:
    """Merge gaps of <= merge_gap frames between flagged frames (no keyframe inside), drop spans < min_span."""
    n = len(raw_reasons)
    flagged = [bool(r) for r in raw_reasons]
    in_gap = [False] * n
    positions = [t for t in range(n) if flagged[t]]
    for a, b in zip(positions, positions[1:]):
        gap = range(a + 1, b)
        if 0 < len(gap) <= p.merge_gap and not any(keyframe[t] for t in gap):
            for t in gap:
                in_gap[t] = True
    merged = [f or g for f, g in zip(flagged, in_gap)]
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
    reasons = ["+".join(raw_reasons[t] + (["span"] if in_gap[t] else [])) if final[t] else "" for t in range(n)]
    return final, reasons


def reference(log_likelihood, confidence, scoring, keyframe, p: FlagParams) -> tuple[list[bool], list[str]]:
    return reference_spans(reference_raw(log_likelihood, confidence, scoring, keyframe, p), keyframe, p)


def run_online(log_likelihood, confidence, scoring, keyframe, p: FlagParams):
    """Push every frame; return the decisions in emission order and, per push, the positions emitted."""
    flagger = OnlineFlagger(p)
    decided, emitted_per_push = [], []
    for ll, conf, how, key in zip(log_likelihood, confidence, scoring, keyframe):
        out = flagger.push(ll, conf, how, keyframe=key)
        emitted_per_push.append([pos for pos, _, _ in out])
        decided += out
    tail = flagger.finish()
    decided += tail
    return flagger, decided, emitted_per_push, [pos for pos, _, _ in tail]


# --------------------------------------------------------------------------- strategies

params_st = st.builds(
    FlagParams,
    accept_threshold=st.sampled_from([0.0, 0.0, 1.0, -1.0]),
    window=st.integers(1, 12),
    drop=st.sampled_from([0.0, 0.3, 0.5, 0.9, 1.0]),
    recover=st.sampled_from([0.0, 0.5, 0.8, 1.0]),
    min_confidence=st.sampled_from([0.0, 0.0, 0.2, 0.5]),
    merge_gap=st.integers(0, 6),
    min_span=st.integers(1, 5),
)

score_st = st.one_of(
    st.floats(-3.0, 12.0, allow_nan=False),
    st.sampled_from([0.0, 1.0, 5.0, float("inf"), float("-inf"), float("nan")]),
)
frame_st = st.tuples(
    score_st,
    st.floats(0.0, 1.0),
    st.sampled_from(["subspace"] * 6 + ["bootstrap"]),
    st.sampled_from([False] * 15 + [True]),
)


@st.composite
def tracks(draw, max_size: int = 150):
    frames = draw(st.lists(frame_st, min_size=0, max_size=max_size))
    if frames and draw(st.booleans()):
        frames[0] = (frames[0][0], 1.0, "init", True)  # the first frame is a keyframe, as in the pipeline
    columns = list(zip(*frames)) if frames else [(), (), (), ()]
    return [list(c) for c in columns]


# --------------------------------------------------------------------------- online == offline reference


@settings(max_examples=300, deadline=None)
@given(track=tracks(), p=params_st)
def test_online_flags_equal_the_offline_reference(track, p):
    ll, conf, scoring, key = track
    expected_flags, expected_reasons = reference(ll, conf, scoring, key, p)
    _, decided, _, _ = run_online(ll, conf, scoring, key, p)
    assert [pos for pos, _, _ in decided] == list(range(len(ll)))  # every frame once, in order
    assert [f for _, f, _ in decided] == expected_flags
    assert [r for _, _, r in decided] == expected_reasons
    assert not any(f for f, k in zip(expected_flags, key) if k)  # keyframes are never flagged


@st.composite
def masks(draw):
    """Raw flags set directly: bootstrap frames are flagged exactly when confidence < min_confidence."""
    raw = draw(st.lists(st.booleans(), min_size=0, max_size=120))
    key = [draw(st.sampled_from([False] * 10 + [True])) if not r else False for r in raw]
    return raw, key


@settings(max_examples=300, deadline=None)
@given(mask=masks(), merge_gap=st.integers(0, 8), min_span=st.integers(1, 8))
def test_span_rules_on_arbitrary_raw_flags(mask, merge_gap, min_span):
    raw, key = mask
    p = FlagParams(min_confidence=0.5, merge_gap=merge_gap, min_span=min_span)
    n = len(raw)
    conf = [0.1 if r else 0.9 for r in raw]
    expected_flags, expected_reasons = reference([1.0] * n, conf, ["bootstrap"] * n, key, p)
    assert expected_flags == reference_spans([["low_confidence"] if r else [] for r in raw], key, p)[0]
    result = flag_frames(np.ones(n), np.array(conf), np.array(["bootstrap"] * n, dtype=object), p,
                         keyframe=np.array(key, bool))
    assert result.flagged.tolist() == expected_flags
    assert list(result.reasons) == expected_reasons
    # Every flagged span is at least min_span long and every merged gap was short.
    for start, stop in result.spans:
        assert stop - start >= min_span
    assert all(not (r and k) for r, k in zip(result.flagged, key))


@settings(max_examples=200, deadline=None)
@given(track=tracks(), p=params_st)
def test_offline_flag_frames_equals_online(track, p):
    ll, conf, scoring, key = track
    _, decided, _, _ = run_online(ll, conf, scoring, key, p)
    result = flag_frames(np.array(ll, float), np.array(conf, float), np.array(scoring, dtype=object), p,
                         keyframe=np.array(key, bool))
    assert result.flagged.tolist() == [f for _, f, _ in decided]
    assert list(result.reasons) == [r for _, _, r in decided]
    assert result.spans.tolist() == spans_from_mask(result.flagged).tolist()
    assert all(bool(f) == bool(r) for f, r in zip(result.flagged, result.reasons))


@settings(max_examples=200, deadline=None)
@given(track=tracks(), p=params_st)
def test_each_decision_is_emitted_exactly_lag_frames_later(track, p):
    ll, conf, scoring, key = track
    flagger, _, per_push, tail = run_online(ll, conf, scoring, key, p)
    lag = p.merge_gap + p.min_span
    assert flagger.lag == lag
    for i, emitted in enumerate(per_push):
        assert emitted == ([i - lag] if i >= lag else []), f"push {i} emitted {emitted}, lag {lag}"
    assert tail == list(range(max(len(ll) - lag, 0), len(ll)))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("merge_gap, min_span", [(0, 1), (5, 3), (2, 7), (9, 2)])
def test_long_tracks_match_the_reference(seed, merge_gap, min_span):
    """Hundreds of frames, far beyond the flagger's sliding window of 2 lags: still the whole-sequence answer."""
    rng = np.random.default_rng(seed)
    n = 600
    # Stretches of good tracking (high scores) and of trouble (low or rejected scores), with noise.
    regime = np.repeat(rng.random(n // 20) < 0.35, 20)
    ll = np.where(regime, rng.normal(1.0, 2.0, n), rng.normal(8.0, 2.0, n))
    conf = rng.random(n)
    scoring = np.where(np.arange(n) < 5, "bootstrap", "subspace").astype(object)
    key = rng.random(n) < 0.01
    key[0], scoring[0] = True, "init"
    p = FlagParams(merge_gap=merge_gap, min_span=min_span, window=10, min_confidence=0.05)
    expected_flags, expected_reasons = reference(ll.tolist(), conf.tolist(), scoring.tolist(), key.tolist(), p)
    result = flag_frames(ll, conf, scoring, p, keyframe=key)
    assert result.flagged.tolist() == expected_flags and list(result.reasons) == expected_reasons
    assert 0 < result.flagged.sum() < n  # the case is not trivial


# --------------------------------------------------------------------------- exact cases


def bootstrap_flags(pattern: str, *, merge_gap: int, min_span: int, keyframes: str = "") -> str:
    """Run a raw pattern like ``'..XX.X..'`` (X = raw flag, K = keyframe) and draw the result the same way."""
    raw = [c == "X" for c in pattern]
    key = [c == "K" for c in pattern]
    p = FlagParams(min_confidence=0.5, merge_gap=merge_gap, min_span=min_span)
    result = flag_frames(np.ones(len(raw)), np.where(raw, 0.1, 0.9), np.array(["bootstrap"] * len(raw)), p,
                         keyframe=np.array(key))
    return "".join("X" if f else ("K" if k else ".") for f, k in zip(result.flagged, key))


@pytest.mark.parametrize(
    "pattern, merge_gap, min_span, expected",
    [
        ("..X..X.....", 2, 3, "..XXXX....."),  # a 2-frame gap merges; the span is long enough
        ("..X...X....", 2, 3, "..........."),  # a 3-frame gap does not; two single frames are dropped
        ("XX.........", 0, 3, "..........."),  # too short at the start
        (".........XX", 0, 2, ".........XX"),  # a span at the end of the sequence is judged as it is
        (".........XX", 0, 3, "..........."),
        ("..X.K.X....", 5, 1, "..X.K.X...."),  # a keyframe in the gap stops the merge
        ("..XXX......", 0, 3, "..XXX......"),
        ("X.X.X.X.X.X", 1, 11, "XXXXXXXXXXX"),  # many short gaps make one long span
        ("", 3, 2, ""),
    ],
)
def test_span_rules_exact(pattern, merge_gap, min_span, expected):
    assert bootstrap_flags(pattern, merge_gap=merge_gap, min_span=min_span) == expected


def test_reasons_name_each_rule():
    p = FlagParams(merge_gap=0, min_span=1, window=5, drop=0.5, recover=0.8, min_confidence=0.3)
    ll = [np.inf, 5.0, 10.0, 10.0, 4.0, 6.0, 9.0, -1.0, 10.0, 10.0]
    conf = [1.0, 0.2, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9]
    scoring = ["init", "bootstrap"] + ["subspace"] * 8
    key = [True] + [False] * 9
    result = flag_frames(np.array(ll), np.array(conf), np.array(scoring), p, keyframe=np.array(key))
    assert list(result.reasons) == [
        "",  # keyframe
        "low_confidence",  # bootstrap frame under min_confidence
        "",  # first subspace frame: no level yet
        "",
        "drop",  # 4 < 10 * (1 - 0.5)
        "held",  # 6 < 10 * 0.8: still below the level
        "",  # 9 >= 8: recovered
        "rejected",  # <= Phi
        "",  # 10 >= level 10 * 0.8: recovered at once
        "",
    ]
    assert result.spans.tolist() == [[1, 2], [4, 6], [7, 8]]
    # With merge_gap=1 the recovered frame between two flagged stretches joins them as 'span'.
    merged = flag_frames(np.array(ll), np.array(conf), np.array(scoring), FlagParams(**{**p.__dict__, "merge_gap": 1}),
                         keyframe=np.array(key))
    assert list(merged.reasons)[4:8] == ["drop", "held", "span", "rejected"]


def test_a_rejected_frame_before_any_level_does_not_flag_the_rest_of_the_track():
    """With no running level yet, hysteresis has nothing to wait for: the next good frame clears it."""
    p = FlagParams(merge_gap=0, min_span=1)
    ll = [np.inf, -2.0] + [5.0] * 20
    scoring = ["init"] + ["subspace"] * 21
    result = flag_frames(np.array(ll), np.ones(22), np.array(scoring), p, keyframe=np.arange(22) == 0)
    assert result.flagged.tolist() == [False, True] + [False] * 20


@pytest.mark.parametrize(
    "field, value, expected",
    [
        ("window", 0, "an integer >= 1"),
        ("drop", 1.5, "[0, 1]"),
        ("recover", -0.1, "[0, 1]"),
        ("min_confidence", 2.0, "[0, 1]"),
        ("merge_gap", -1, "an integer >= 0"),
        ("min_span", 0, "an integer >= 1"),
    ],
)
def test_flag_params_name_the_bad_value(field, value, expected):
    with pytest.raises(ValueError) as caught:
        FlagParams(**{field: value})
    message = str(caught.value)
    assert f"{field}={value!r}" in message and expected in message


def test_flag_frames_rejects_mismatched_lengths():
    with pytest.raises(ValueError, match="same length"):
        flag_frames(np.zeros(3), np.zeros(2), np.array(["subspace"] * 3))

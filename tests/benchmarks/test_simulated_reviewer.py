"""The simulated reviewer's accounting (benchmarks/simulated_reviewer.py), with a scripted tracker.

The benchmark's numbers are human seconds, so what it counts must be exact:
the tracker is replaced by a fake whose boxes and flags are known, and the
frames looked at, corrections and costs are checked against hand counts.
"""

from __future__ import annotations

import types

import numpy as np
import pytest
from _benchmark_scripts import load_script


@pytest.fixture(scope="module")
def sr():
    return load_script("simulated_reviewer")


N = 20
GT = np.stack([np.arange(N) * 2.0, np.full(N, 10.0), np.full(N, 20.0), np.full(N, 20.0)], axis=1)
WRONG = np.arange(5, 10)  # the fake tracker loses the object here until a person boxes one of these frames


def fake_retrack(false_alarm: int | None):
    """A ``retrack_tracks`` stand-in: wrong boxes on WRONG until an anchor lands in it, flagged when
    ``false_alarm`` is given (else nothing is flagged)."""
    true_flags = false_alarm is not None

    def retrack(frames, indices, anchors, config, *, previous=None, **_):
        keyframe = np.zeros(N, bool) if previous is None else previous[1].track.keyframe.copy()
        for position in anchors[1]:
            keyframe[position] = True
        boxes = GT.copy()
        flagged = np.zeros(N, bool)
        confidence = np.full(N, 0.9)
        if not keyframe[WRONG].any():
            boxes[WRONG, 0] += 100.0
            flagged[WRONG] = true_flags
            confidence[WRONG] = 0.2
            confidence[7] = 0.1
        if false_alarm is not None:  # a flagged frame whose box is right and never changes
            flagged[false_alarm], confidence[false_alarm] = True, 0.3
        track = types.SimpleNamespace(boxes_xywh=boxes, flagged=flagged, keyframe=keyframe, confidence=confidence,
                                      reasons=doubt_reasons(flagged))
        return types.SimpleNamespace(tracks=[track], scoring={1: np.full(N, "subspace")}, frames_tracked=N)

    return retrack


def doubt_reasons(flagged: np.ndarray) -> tuple[str, ...]:
    return tuple("doubt:score" if f else "" for f in flagged)


def run(sr, monkeypatch, false_alarm, fallback="first-wrong", policy="worst", retrack=None, accept=False):
    monkeypatch.setattr(sr, "retrack_tracks", retrack or fake_retrack(false_alarm))
    monkeypatch.setattr(sr, "PreviousTrack", lambda track, scoring: types.SimpleNamespace(track=track))
    frames = [np.zeros((4, 4, 3), np.uint8)] * N
    return sr.simulated_reviewer(frames, GT, None, merge="anchored", target=0.95, threshold=0.5, budget=5,
                                 fallback=fallback, policy=policy, accept=accept)


def test_flagged_frames_are_looked_at_once_per_box(sr, monkeypatch):
    # Round 1 shows 5..9 and 15 (6 looks), corrects 7 (lowest confidence); round 2 shows only 15, whose box
    # the reviewer has already judged: no new look, and the target is met.
    out = run(sr, monkeypatch, false_alarm=15)
    assert out["corrected_frames"] == [7]
    assert out["flagged_per_round"] == [6, 1]
    assert out["inspected"] == 6
    assert out["inspected_every_round"] == 7
    assert out["fallbacks"] == 0 and out["reached"]


def test_fallback_pays_for_the_frames_scrubbed_through(sr, monkeypatch):
    # Nothing flagged: the reviewer scrubs frames 1..5 (frame 0 is an anchor) and corrects 5, the first wrong one.
    out = run(sr, monkeypatch, false_alarm=None)
    assert out["corrected_frames"] == [5]
    assert out["fallbacks"] == 1
    assert out["inspected"] == 5


def test_human_seconds(sr):
    record = {"frames": 200,
              "reviewer": {"inspected": 30, "inspected_every_round": 50, "corrections": 4},
              "baseline": {"keyframes": 10}}
    cost = sr.human_seconds(record, 1.0, 6.0)
    assert cost == {"reviewer": 54.0, "reviewer_every_round": 74.0, "baseline": 70.0,
                    "baseline_check_all": 199.0 + 60.0}


def test_baseline_takes_the_fewest_keyframes(sr):
    # A box moving at constant speed is interpolated exactly from the first and last frames.
    best = sr.interpolation_baseline(GT, 0.95, 0.5)
    assert best["keyframes"] == 1 and best["k"] == N - 1
    # Every frame off the line: only k = 1 (every frame boxed) is exact.
    zigzag = GT.copy()
    zigzag[1::2, 0] += 100.0
    assert sr.interpolation_baseline(zigzag, 1.0, 0.5) == {"k": 1, "keyframes": N - 1, "success": 1.0}


def scripted_retrack(calls: list, losses, right_flags=()):
    """A ``retrack_tracks`` stand-in: for each ``(lo, hi, flagged_lo, flagged_hi)`` of ``losses`` the boxes on
    ``lo..hi-1`` are wrong, and ``flagged_lo..flagged_hi-1`` flagged, until an anchor lands in ``lo..hi-1``; the
    frames in ``right_flags`` are flagged with right boxes. Records the anchors of every call in ``calls``."""
    def retrack(frames, indices, anchors, config, *, previous=None, **_):
        calls.append(sorted(anchors[1]))
        keyframe = np.zeros(N, bool) if previous is None else previous[1].track.keyframe.copy()
        keyframe[list(anchors[1])] = True
        boxes, flagged = GT.copy(), np.zeros(N, bool)
        flagged[list(right_flags)] = True
        for lo, hi, flagged_lo, flagged_hi in losses:
            if not keyframe[lo:hi].any():
                boxes[lo:hi, 0] += 100.0
                flagged[flagged_lo:flagged_hi] = True
        track = types.SimpleNamespace(boxes_xywh=boxes, flagged=flagged, keyframe=keyframe,
                                      confidence=np.where(flagged, 0.2, 0.9), reasons=doubt_reasons(flagged))
        return types.SimpleNamespace(tracks=[track], scoring={1: np.full(N, "subspace")}, frames_tracked=N)
    return retrack


def two_losses_retrack(calls: list):
    """Wrong boxes on 3..5 and on 12..16; the spans flagged are 2..6 (its first frame right) and 12..16, and a
    right frame, 9, is flagged alone."""
    return scripted_retrack(calls, [(3, 6, 2, 7), (12, 17, 12, 17)], right_flags=[9])


def test_spans_policy_corrects_the_first_wrong_box_of_every_flagged_span_before_one_retrack(sr, monkeypatch):
    calls = []
    out = run(sr, monkeypatch, None, policy="spans", retrack=two_losses_retrack(calls))
    # Span 2..6 starts with a right box: its first wrong one is 3; span 12..16 is wrong from 12; the lone right
    # flag on 9 gets no correction. Both go in one re-track.
    assert out["corrected_frames"] == [3, 12]
    assert calls == [[0], [3, 12]]
    assert out["flagged_per_round"] == [11, 1] and out["inspected"] == 11
    assert out["fallbacks"] == 0 and out["reached"]


def test_worst_policy_corrects_one_box_a_round(sr, monkeypatch):
    calls = []
    out = run(sr, monkeypatch, None, policy="worst", retrack=two_losses_retrack(calls))
    # All flagged frames share one p_fail, so the first flagged is taken each round, right box or not: 2, 3, 9, 12.
    assert out["corrected_frames"] == [2, 3, 9, 12]
    assert calls == [[0], [2], [3], [9], [12]]


def lost_retrack(calls: list):
    """Lost from frame 2 on, and the tool asks for keyframes 4, 8, 12, 16 and 19 (reason ``keyframe``) until they
    are boxed; then the boxes are right except 13, flagged as doubtful."""
    asked = [4, 8, 12, 16, 19]

    def retrack(frames, indices, anchors, config, *, previous=None, **_):
        calls.append(sorted(anchors[1]))
        keyframe = np.zeros(N, bool) if previous is None else previous[1].track.keyframe.copy()
        keyframe[list(anchors[1])] = True
        boxes, flagged, reasons = GT.copy(), np.zeros(N, bool), [""] * N
        if not keyframe[asked].all():
            boxes[2:][~keyframe[2:], 0] += 100.0
            flagged[asked] = True
            reasons = ["keyframe" if f else "" for f in flagged]
        elif not keyframe[13]:
            boxes[13, 0] += 100.0
            flagged[13], reasons[13] = True, "doubt:score"
        track = types.SimpleNamespace(boxes_xywh=boxes, flagged=flagged, keyframe=keyframe,
                                      confidence=np.where(flagged, 0.2, 0.9), reasons=tuple(reasons))
        return types.SimpleNamespace(tracks=[track], scoring={1: np.full(N, "subspace")}, frames_tracked=N)
    return retrack


@pytest.mark.parametrize("policy", ["worst", "worst-wrong", "spans"])
def test_keyframes_the_tool_asks_for_are_boxed_in_one_round_whatever_the_policy(sr, monkeypatch, policy):
    calls = []
    monkeypatch.setattr(sr, "retrack_tracks", lost_retrack(calls))
    monkeypatch.setattr(sr, "PreviousTrack", lambda track, scoring: types.SimpleNamespace(track=track))
    frames = [np.zeros((4, 4, 3), np.uint8)] * N
    out = sr.simulated_reviewer(frames, GT, None, merge="anchored", target=1.0, threshold=0.5, budget=10,
                                fallback="first-wrong", policy=policy)
    # Round 1: the five asked-for frames, looked at and boxed, one re-track; round 2: frame 13, flagged and wrong.
    assert calls == [[0], [4, 8, 12, 16, 19], [13]]
    assert out["keyframes_requested"] == 5
    assert out["corrected_frames"] == [4, 8, 12, 16, 19, 13]
    assert out["inspected"] == 6 and out["reached"]


def test_keyframes_asked_for_stop_at_the_correction_budget(sr, monkeypatch):
    calls = []
    monkeypatch.setattr(sr, "retrack_tracks", lost_retrack(calls))
    monkeypatch.setattr(sr, "PreviousTrack", lambda track, scoring: types.SimpleNamespace(track=track))
    frames = [np.zeros((4, 4, 3), np.uint8)] * N
    out = sr.simulated_reviewer(frames, GT, None, merge="anchored", target=1.0, threshold=0.5, budget=3,
                                fallback="first-wrong", policy="worst")
    assert calls == [[0], [4, 8, 12]]
    assert out["keyframes_requested"] == 3 and not out["reached"]


def three_losses_retrack(calls: list):
    """Wrong (and flagged) boxes on 2..3, 8..9 and 14..15, each until an anchor lands in it."""
    return scripted_retrack(calls, [(lo, lo + 2, lo, lo + 2) for lo in (2, 8, 14)])


def test_spans_policy_stops_at_the_budget(sr, monkeypatch):
    calls = []
    monkeypatch.setattr(sr, "retrack_tracks", three_losses_retrack(calls))
    monkeypatch.setattr(sr, "PreviousTrack", lambda track, scoring: types.SimpleNamespace(track=track))
    out = sr.simulated_reviewer([np.zeros((4, 4, 3), np.uint8)] * N, GT, None, merge="anchored", target=1.0,
                                threshold=0.5, budget=2, fallback="first-wrong", policy="spans")
    # Three wrong spans, a budget of two boxes: the first two spans are corrected, then the reviewer stops.
    assert out["corrected_frames"] == [2, 8] and calls == [[0], [2, 8]]
    assert not out["reached"] and out["inspected"] == 6


def test_spans_policy_falls_back_when_every_flagged_box_is_right(sr, monkeypatch):
    # Only frame 15 is flagged, and its box is right; the wrong boxes on WRONG are not flagged.
    retrack = scripted_retrack([], [(WRONG[0], WRONG[-1] + 1, 0, 0)], right_flags=[15])
    out = run(sr, monkeypatch, None, policy="spans", retrack=retrack)
    # The reviewer looks at 15 (right), scrubs 1..5 and corrects 5, the first wrong box.
    assert out["corrected_frames"] == [5] and out["fallbacks"] == 1
    assert out["inspected"] == 6 and out["reached"]


def test_worst_wrong_policy_skips_flagged_boxes_seen_to_be_right(sr, monkeypatch):
    calls = []
    out = run(sr, monkeypatch, None, policy="worst-wrong", retrack=two_losses_retrack(calls))
    # Same flags as for "worst" (2, 3, 9, 12 in turn), but 2 and 9 are right: the reviewer boxes 3, then 12.
    assert out["corrected_frames"] == [3, 12] and calls == [[0], [3], [12]]
    assert out["right_picks"] == 0
    worst = run(sr, monkeypatch, None, policy="worst", retrack=two_losses_retrack([]))
    assert worst["right_picks"] == 2  # 2 and 9


def test_accepting_sends_the_right_boxes_seen_as_anchors_and_pays_per_run(sr, monkeypatch):
    calls = []
    out = run(sr, monkeypatch, None, policy="worst-wrong", retrack=two_losses_retrack(calls), accept=True)
    # Round 1 looks at 2..6, 9 and 12..16: right are 2, 6 and 9 (three runs), sent with the correction of 3.
    assert calls[:2] == [[0], [2, 3, 6, 9]]
    assert out["accepted"] == 3 and out["accept_spans"] == 3
    record = {"frames": N, "reviewer": {**out}, "baseline": {"keyframes": 1}}
    assert sr.human_seconds(record, 1.0, 6.0, 2.0)["reviewer"] == out["inspected"] + 6.0 * out["corrections"] + 6.0


def test_accepting_ignores_the_unflagged_frames_the_fallback_scrubs_through(sr, monkeypatch):
    calls = []
    retrack = scripted_retrack(calls, [(WRONG[0], WRONG[-1] + 1, 0, 0)], right_flags=[15])
    out = run(sr, monkeypatch, None, policy="worst-wrong", retrack=retrack, accept=True)
    # Only 15 is flagged (right); the scrub through 1..4 (right, unflagged) accepts nothing.
    assert calls[1] == [5, 15] and out["accepted"] == 1


def test_tolerant_look_counts_skip_boxes_that_barely_moved(sr, monkeypatch):
    def jitter(calls):
        inner = scripted_retrack(calls, [(12, 17, 12, 17)], right_flags=[9])

        def retrack(*args, **kwargs):
            result = inner(*args, **kwargs)
            if len(calls) > 1:  # after the first correction the right flagged box 9 moves by 1 px of 20
                result.tracks[0].boxes_xywh[9, 0] += 1.0
            return result
        return retrack

    out = run(sr, monkeypatch, None, policy="worst-wrong", retrack=jitter([]))
    # Strict: 9 counts again after it moved; at IoU 0.9 (1 px of 20 is IoU 0.905) it does not, at 0.95 it does.
    assert out["inspected"] == 7 and out["inspected_moved"] == {"0.95": 7, "0.9": 6, "0.8": 6}


def _pass_choice_of(sequence: str) -> dict:
    from annotator.failure.model import PASS_CHOICE_FEATURES, PASS_OPTIONS

    k = len(PASS_CHOICE_FEATURES)
    return {"features": list(PASS_CHOICE_FEATURES), "options": list(PASS_OPTIONS), "mean": [0.0] * k,
            "scale": [1.0] * k, "coef": [[0.0] * k] * 3, "intercept": [0.0] * 3, "disagree_below": 0.5,
            "max_gap": 10, "info": {"held_out": sequence}}


@pytest.mark.parametrize("section, value", [
    ("between_anchors", {"log_odds": 1.0, "pass_iou": -4.0, "intercept": 1.0, "info": {"held_out": "Other"}}),
    ("pass_choice", "Other"),
    (None, None),
])
def test_fold_models_must_be_each_sequences_own(tmp_path, section, value):
    import json

    from _benchmark_scripts import run_benchmark

    from annotator.failure import load_model

    otb = tmp_path / "otb"
    (otb / "Seq" / "img").mkdir(parents=True)
    (otb / "Seq" / "groundtruth_rect.txt").write_text("1,1,5,5\n")
    import cv2
    cv2.imwrite(str(otb / "Seq" / "img" / "0001.jpg"), np.zeros((8, 8, 3), np.uint8))
    folds = tmp_path / "folds"
    folds.mkdir()
    data = load_model().to_json()
    data.pop("between_anchors", None)
    data.pop("pass_choice", None)  # the installed model's sections are fitted on every sequence
    if section is not None:  # a section fitted without another sequence; or none at all
        data[section] = _pass_choice_of(value) if section == "pass_choice" else value
    (folds / "Seq.json").write_text(json.dumps(data))
    done = run_benchmark("simulated_reviewer", "--otb", str(otb), "--sequences", "Seq", "--fold-models", str(folds),
                         "--no-record")
    assert done.returncode == 2
    assert "is not the fold model of Seq" in done.stderr.strip().splitlines()[-1]


def test_spans_policy_with_the_lowest_confidence_fallback_is_refused_in_one_line():
    from _benchmark_scripts import run_benchmark

    done = run_benchmark("simulated_reviewer", "--policy", "spans", "--fallback", "lowest-confidence")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith(
        "simulated_reviewer.py: error: --policy spans needs --fallback first-wrong")

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
        track = types.SimpleNamespace(boxes_xywh=boxes, flagged=flagged, keyframe=keyframe, confidence=confidence)
        return types.SimpleNamespace(tracks=[track], scoring={1: np.full(N, "subspace")}, frames_tracked=N)

    return retrack


def run(sr, monkeypatch, false_alarm, fallback="first-wrong"):
    monkeypatch.setattr(sr, "retrack_tracks", fake_retrack(false_alarm))
    monkeypatch.setattr(sr, "PreviousTrack", lambda track, scoring: types.SimpleNamespace(track=track))
    frames = [np.zeros((4, 4, 3), np.uint8)] * N
    return sr.simulated_reviewer(frames, GT, None, merge="anchored", target=0.95, threshold=0.5, budget=5,
                                 fallback=fallback)


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

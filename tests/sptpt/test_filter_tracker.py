"""The correlation-filter tracker (``sptpt.filter_tracker``) that votes in ``robust``'s consensus: it follows a moving
and a growing object on its own, is deterministic, and is exactly its two filters stepped in its documented order."""

from __future__ import annotations

import numpy as np
import pytest
from _tracker_clips import growing_clip, moving_clip

from sptpt.affine import box_xywh_from_states, state_from_box_xywh
from sptpt.boxes import iou_xywh
from sptpt.filter_tracker import FilterTracker
from sptpt.scale import ScaleFilter
from sptpt.translation import TranslationFilter


def _track(frames: np.ndarray, first_box: np.ndarray) -> np.ndarray:
    tracker = FilterTracker(32)
    tracker.init(frames[0], first_box)
    return np.array([tracker.update(frame) for frame in frames[1:]])


def test_it_follows_a_moving_object():
    frames, boxes = moving_clip()
    got = _track(frames, boxes[0])
    assert iou_xywh(got, boxes[1:]).min() > 0.8, iou_xywh(got, boxes[1:]).round(2)


def test_it_follows_a_growing_object():
    frames, boxes = growing_clip()
    got = _track(frames, boxes[0])
    sides = np.sqrt(got[:, 2] * got[:, 3]) / np.sqrt(boxes[1:, 2] * boxes[1:, 3])
    assert 0.85 < sides[-1] < 1.15, sides[-5:].round(3)  # the object is 1.6x its first size by the end
    assert iou_xywh(got, boxes[1:]).mean() > 0.7


def test_it_is_its_two_filters_stepped_in_order_and_deterministic():
    frames, boxes = moving_clip(12)
    got = _track(frames, boxes[0])
    np.testing.assert_array_equal(_track(frames, boxes[0]), got)
    # Reference: translate to the translation filter's peak, size there by the scale filter, then both learn there.
    translation, scale = TranslationFilter(32), ScaleFilter(32)
    state = state_from_box_xywh(boxes[0], 32)
    translation.init(frames[0], state)
    scale.init(frames[0], state)
    for frame, box in zip(frames[1:], got):
        dx, dy = translation.shift(frame, state)
        state = state + np.array([dx, dy, 0, 0, 0, 0])
        state[2] = max(state[2] * scale.factor(frame, state), 1 / 32)
        translation.update(frame, state)
        scale.update(frame, state)
        np.testing.assert_array_equal(box, box_xywh_from_states(state, 32))


def test_on_featureless_frames_its_box_stops_at_the_frame_size():
    # A black frame (black as the samples' padding outside the frame) gives the scale filter a flat response, whose
    # peak is its largest scale: without the bound the box would grow by 1.37 a frame (to 6e5 px after 30 frames).
    frames, boxes = moving_clip(2)
    tracker = FilterTracker(32)
    tracker.init(frames[0], boxes[0])
    flat = np.zeros_like(frames[0])
    got = np.array([tracker.update(flat) for _ in range(30)])
    assert np.isfinite(got).all()
    assert got[:, 2].max() == max(flat.shape[:2])  # width at most the frame's longer side


def test_update_before_init_is_refused():
    with pytest.raises(RuntimeError, match="before init"):
        FilterTracker(32).update(np.zeros((40, 40, 3), np.uint8))


def test_a_frame_the_runs_refuse_does_not_move_the_voter():
    from sptpt.params import get_preset
    from sptpt.tracker import Tracker

    frames, boxes = moving_clip()
    params = get_preset("robust")

    def track(bad_frame_at: int | None) -> np.ndarray:
        tracker = Tracker(params, seed=1)
        tracker.init(frames[0], boxes[0])
        out = []
        for k, frame in enumerate(frames[1:5], start=1):
            if k == bad_frame_at:
                with pytest.raises(ValueError, match="same size"):
                    tracker.update(frame[:-2])
            out.append(tracker.update(frame).box_xywh)
        return np.array(out)

    np.testing.assert_array_equal(track(2), track(None))

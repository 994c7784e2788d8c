"""A learned tracker beside SPTPT (``guide_particles``, ``guide_prior``, ``guide_vote``): the Tracker's side.

The guide here is a stand-in that knows the true boxes of a synthetic clip (or is wrong on purpose), so each test
says what the fusion does with a guide that is right, or wrong, without NanoTrack
(``tests/annotator/test_nanotrack.py``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _tracker_clips import GAP, jumping_clip, reappearing_clip

from sptpt.boxes import iou_xywh
from sptpt.params import get_preset
from sptpt.tracker import Tracker

FUSED = dataclasses.replace(get_preset("robust"), guide_particles=30, guide_prior=2.0, guide_vote=True)


class KnownBoxes:
    """A guide whose box on the k-th frame is ``boxes[k]``; NaN rows: it has none."""

    def __init__(self, boxes: np.ndarray, score: float = 0.9) -> None:
        self.boxes, self.score, self.seen = np.asarray(boxes, dtype=np.float64), score, 0

    def init(self, rgb, box_xywh) -> None:
        self.seen = 1

    def update(self, rgb):
        box = self.boxes[self.seen]
        self.seen += 1
        return box.copy(), self.score


def _track(frames, first_box, params, guide, seed=0, *, submit=False):
    tracker = Tracker(params, seed=seed, guide=guide)
    results = [tracker.init(frames[0], first_box)]
    if submit:
        for frame in frames[1:]:
            tracker.submit(frame)
            if tracker.submitted > 2:
                results.append(tracker.collect())
        while tracker.submitted:
            results.append(tracker.collect())
    else:
        results += [tracker.update(frame) for frame in frames[1:]]
    return results


def test_guide_and_its_parameters_come_together():
    with pytest.raises(ValueError, match="need a guide"):
        Tracker(FUSED, seed=0)
    with pytest.raises(ValueError, match="set one, or drop the guide"):
        Tracker(get_preset("robust"), seed=0, guide=KnownBoxes(np.zeros((2, 4))))
    assert FUSED.uses_guide and not get_preset("robust").uses_guide
    with pytest.raises(ValueError, match="guide_prior"):
        dataclasses.replace(FUSED, guide_prior=-1.0)


def test_a_right_guide_brings_the_runs_along_where_they_alone_are_left_behind():
    # robust alone cannot follow the jump until its re-detection search starts, after several missed frames; with a
    # guide that knows where the object is, the runs' candidates around the guide's box find it at once.
    frames, boxes, at = jumping_clip()
    alone = np.array([r.box_xywh for r in _track(frames, boxes[0], get_preset("robust"), None)])
    guided = _track(frames, boxes[0], FUSED, KnownBoxes(boxes))
    with_guide = np.array([r.box_xywh for r in guided])
    assert (iou_xywh(with_guide[at:at + 3], boxes[at:at + 3]) >= 0.5).all()
    assert not (iou_xywh(alone[at:at + 3], boxes[at:at + 3]) >= 0.5).any()
    assert iou_xywh(with_guide, boxes).mean() > iou_xywh(alone, boxes).mean() + 0.1
    # Every frame reports the guide's own box and score.
    np.testing.assert_array_equal(guided[at].guide_box_xywh, boxes[at])
    assert guided[at].guide_score == 0.9


def test_a_wrong_guide_does_not_take_the_runs_off_the_object():
    # The guide stays where the object was at first while the object moves on: SPTPT's models judge its
    # candidates, and a box with nothing of the object does not win, nor is it reported alone.
    frames, boxes, back = reappearing_clip()
    stuck = np.repeat(boxes[:1] + [0.0, 60.0, 0.0, 0.0], len(boxes), axis=0)
    results = _track(frames[: back - GAP], boxes[0], FUSED, KnownBoxes(stuck))
    tracked = np.array([r.box_xywh for r in results])
    assert iou_xywh(tracked, boxes[: back - GAP]).mean() >= 0.6


def test_a_guide_without_a_box_is_reported_as_nan_and_left_out():
    frames, boxes, back = reappearing_clip()
    none = np.full_like(boxes, np.nan)
    results = _track(frames[:12], boxes[0], FUSED, KnownBoxes(none))
    assert np.isnan(results[5].guide_box_xywh).all()
    assert iou_xywh(np.array([r.box_xywh for r in results]), boxes[:12]).mean() >= 0.6


def test_guided_submit_gives_the_boxes_of_update_and_one_seed_one_result():
    frames, boxes, _ = reappearing_clip()
    frames, boxes = frames[:24], boxes[:24]
    once = _track(frames, boxes[0], FUSED, KnownBoxes(boxes), seed=3)
    again = _track(frames, boxes[0], FUSED, KnownBoxes(boxes), seed=3)
    ahead = _track(frames, boxes[0], FUSED, KnownBoxes(boxes), seed=3, submit=True)
    for a, b, c in zip(once, again, ahead):
        np.testing.assert_array_equal(a.box_xywh, b.box_xywh)
        np.testing.assert_array_equal(a.box_xywh, c.box_xywh)
        assert a.log_likelihood == b.log_likelihood == c.log_likelihood


def test_the_guide_round_scores_the_guides_box_itself():
    frames, boxes, _ = reappearing_clip()
    offset = boxes + [7.0, -5.0, 0.0, 0.0]
    tracker = Tracker(dataclasses.replace(FUSED, guide_prior=0.0, guide_vote=False), seed=0,
                      guide=KnownBoxes(offset))
    tracker.init(frames[0], boxes[0])
    result = tracker.update(frames[1], details=True)
    assert np.isclose(result.particles_xywh, offset[1], atol=1e-6).all(axis=1).any()


def test_a_guide_changes_nothing_of_a_preset_without_one():
    # The guide's code paths are off without a guide: robust's boxes and scores are those of the golden tests
    # (test_robust.test_preset_boxes_are_unchanged); here, one run alone is unchanged by the guide's one-run path.
    frames, boxes, _ = reappearing_clip()
    one_run = get_preset("fast")
    plain = _track(frames[:10], boxes[0], one_run, None)
    guided = _track(frames[:10], boxes[0], dataclasses.replace(one_run, guide_particles=0, guide_vote=True),
                    KnownBoxes(boxes))  # a vote with one run has nothing to vote in
    for a, b in zip(plain, guided):
        np.testing.assert_array_equal(a.box_xywh, b.box_xywh)

"""Easy frames (``TrackerParams.easy_after``, ``easy_share``, issue #44): while the runs agree, each draws fewer
candidates; the first frame that breaks the agreement brings the full search back on the next."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import sptpt.tracker as tracker_module
from sptpt.boxes import iou_xywh
from sptpt.params import get_preset
from sptpt.results import FrameResult
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip

FULL = 25 + 25  # robust's shortlists, of the wide round and of the refine round: the candidates evaluated in full


def _easy(after: int, share: float = 0.4):
    return dataclasses.replace(get_preset("robust"), easy_after=after, easy_share=share)


def _track(params, clip, seed: int = 2) -> list[FrameResult]:
    tracker = Tracker(params, seed=seed)
    results = [tracker.init(clip.frames[0], clip.boxes_xywh[0])]
    return results + [tracker.update(frame, details=True) for frame in clip.frames[1:]]


def _result(box, accepted: bool = True) -> FrameResult:
    return FrameResult(box_xywh=np.asarray(box, float), log_likelihood=1.0, confidence=0.7, accepted=accepted,
                       scoring="subspace")


def test_the_runs_agree_when_each_accepted_and_overlaps_the_reported_box_closely():
    reported = _result([10, 10, 40, 40])
    near = [_result([10, 10, 40, 40]), _result([11, 10, 40, 40]), _result([10, 12, 40, 40])]
    assert tracker_module._runs_agree(reported, near)
    # IoU 0.78 with the reported box: one run only a little off is enough to call the frame not easy.
    assert iou_xywh(np.array([15.0, 10, 40, 40]), reported.box_xywh) < 0.8
    assert not tracker_module._runs_agree(reported, near[:2] + [_result([15, 10, 40, 40])])
    assert not tracker_module._runs_agree(reported, near[:2] + [_result([10, 12, 40, 40], accepted=False)])
    assert not tracker_module._runs_agree(reported, near[:2] + [_result([np.nan, 12, 40, 40])])


@pytest.mark.parametrize("count, share, expected", [(150, 0.4, 60), (75, 0.4, 30), (25, 0.4, 10), (25, 1.0, 25),
                                                    (3, 0.1, 1), (0, 0.4, 0), (7, 0.5, 4),
                                                    (5, 0.5, 2)])  # halves to even, as round()
def test_a_share_of_the_candidates_is_rounded_and_at_least_one(count, share, expected):
    assert tracker_module._shared(count, share) == expected


def test_the_full_search_comes_back_on_the_frame_after_the_agreement_breaks(monkeypatch):
    # Whether the runs agreed is scripted, so the test sees only the tracker's count of frames in a row.
    agreed = iter([True, True, True, False, True, True, True, True])
    monkeypatch.setattr(tracker_module, "_runs_agree", lambda reported, results: next(agreed))
    clip = make_clip(9, seed=3)
    counts = [len(r.particles_xywh) for r in _track(_easy(2), clip)[1:]]
    easy = 10 + 10
    # Frame 1 and 2 follow fewer than two agreed frames; 3 and 4 follow two and three; 5 follows the broken one.
    assert counts == [FULL, FULL, easy, easy, FULL, FULL, easy, easy], counts


def test_a_clip_the_runs_agree_on_turns_easy_and_only_after_enough_agreed_frames():
    clip = make_clip(24, seed=3, occlusion=None)
    results = _track(_easy(4), clip)
    counts = np.array([len(r.particles_xywh) for r in results[1:]])
    assert set(counts) <= {FULL, 20}
    assert (counts == 20).any() and counts[0] == FULL, counts
    # Where a frame drew fewer, the four frames before it had every run on the reported box.
    run_iou = np.array([iou_xywh(r.run_boxes_xywh, r.box_xywh).min() for r in results[1:]])
    for i in np.flatnonzero(counts == 20):
        assert i >= 4 and (run_iou[i - 4:i] >= 0.8).all(), (i, run_iou.round(2))


def test_easy_frames_are_deterministic_and_a_share_of_one_changes_nothing():
    clip = make_clip(24, seed=3, occlusion=None)  # easy from its 5th frame on (the test above)
    boxes = lambda params: np.array([r.box_xywh for r in _track(params, clip)])  # noqa: E731
    easy = boxes(_easy(4))
    np.testing.assert_array_equal(easy, boxes(_easy(4)))
    full = boxes(get_preset("robust"))
    assert (easy != full).any()  # easy frames happened: fewer draws change the stream and the boxes
    np.testing.assert_array_equal(boxes(_easy(4, share=1.0)), full)
    assert iou_xywh(easy, clip.boxes_xywh).mean() >= iou_xywh(full, clip.boxes_xywh).mean() - 0.05


def test_easy_frames_need_several_runs_and_a_share_in_range():
    with pytest.raises(ValueError, match="easy_after"):
        dataclasses.replace(get_preset("robust"), easy_after=-1)
    with pytest.raises(ValueError, match="easy_after"):
        dataclasses.replace(get_preset("fast"), easy_after=10)  # one run: nothing to agree
    for share in (0.0, 1.5, -0.2):
        with pytest.raises(ValueError, match="easy_share"):
            dataclasses.replace(get_preset("robust"), easy_share=share)


def test_a_new_init_starts_with_the_full_search(monkeypatch):
    monkeypatch.setattr(tracker_module, "_runs_agree", lambda reported, results: True)
    clip = make_clip(5, seed=3)
    tracker = Tracker(_easy(1), seed=2)
    for _ in range(2):  # the second init must forget the first track's agreed frames
        tracker.init(clip.frames[0], clip.boxes_xywh[0])
        counts = [len(tracker.update(frame, details=True).particles_xywh) for frame in clip.frames[1:4]]
        assert counts == [FULL, 20, 20], counts

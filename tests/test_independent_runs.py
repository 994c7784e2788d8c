"""``independent_runs``: several SPTPT runs side by side, each frame reported by the more confident one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from annotator.synthetic import make_clip
from sptpt.params import get_preset
from sptpt.results import FrameResult
from sptpt.tracker import Tracker, _more_confident


def _result(ll: float, scoring: str = "subspace", x: float = 0.0) -> FrameResult:
    return FrameResult(box_xywh=np.array([x, 0.0, 1.0, 1.0]), log_likelihood=ll, confidence=0.5, accepted=True,
                       scoring=scoring)


def test_the_higher_score_of_the_same_stage_wins_and_subspace_outranks_bootstrap():
    assert _more_confident([_result(1.0), _result(2.0)]) == 1
    assert _more_confident([_result(2.0), _result(1.0)]) == 0
    assert _more_confident([_result(1.0), _result(1.0)]) == 0  # ties: the first run
    # A bootstrap intersection (tens) is on another scale than RE- - RE+ (a few units): the stage decides first.
    assert _more_confident([_result(25.0, "bootstrap"), _result(-3.0)]) == 1
    assert _more_confident([_result(float("nan")), _result(-40.0)]) == 1
    assert _more_confident([_result(-1.0), _result(3.0), _result(2.0)]) == 1


def _params(runs: int):
    return dataclasses.replace(get_preset("robust"), independent_runs=runs)


def test_each_frame_is_the_more_confident_of_two_single_runs_with_the_derived_seeds():
    clip = make_clip(25, seed=3)
    pair = Tracker(_params(2), seed=11)
    seeds = np.random.default_rng(11).integers(0, 2**63 - 1, size=2)
    singles = [Tracker(_params(1), seed=int(s)) for s in seeds]
    first = pair.init(clip.frames[0], clip.boxes_xywh[0])
    np.testing.assert_array_equal(first.run_boxes_xywh, np.stack([first.box_xywh] * 2))
    for single in singles:
        assert single.init(clip.frames[0], clip.boxes_xywh[0]).run_boxes_xywh is None
    picked_second = 0
    for frame in clip.frames[1:]:
        got = pair.update(frame, details=True)
        alone = [single.update(frame, details=True) for single in singles]
        want = alone[_more_confident(alone)]
        np.testing.assert_array_equal(got.box_xywh, want.box_xywh)
        assert got.log_likelihood == want.log_likelihood
        np.testing.assert_array_equal(got.particles_xywh, want.particles_xywh)
        # Every run's box comes along, in run order: what each run alone would have reported.
        np.testing.assert_array_equal(got.run_boxes_xywh, np.stack([a.box_xywh for a in alone]))
        picked_second += want is alone[1]
    assert 0 < picked_second < len(clip.frames) - 1  # the clip exercises both runs


def test_same_seed_same_boxes():
    clip = make_clip(15, seed=3)

    def boxes(seed):
        tracker = Tracker(_params(2), seed=seed)
        tracker.init(clip.frames[0], clip.boxes_xywh[0])
        return np.array([tracker.update(frame).box_xywh for frame in clip.frames[1:]])

    np.testing.assert_array_equal(boxes(4), boxes(4))
    assert not np.array_equal(boxes(4), boxes(5))


def test_update_before_init_and_a_bad_count_are_refused():
    with pytest.raises(RuntimeError, match="before init"):
        Tracker(_params(2), seed=0).update(np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match="independent_runs=0 is invalid"):
        _params(0)


def test_run_boxes_must_be_two_or_more_boxes():
    with pytest.raises(ValueError, match=r"run_boxes_xywh must be \(R, 4\) with R >= 2"):
        dataclasses.replace(_result(1.0), run_boxes_xywh=np.zeros((1, 4)))
    with pytest.raises(ValueError, match=r"run_boxes_xywh must be \(R, 4\)"):
        dataclasses.replace(_result(1.0), run_boxes_xywh=np.zeros((2, 3)))

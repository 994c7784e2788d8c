"""``Tracker.inspect``: what each run holds and how its current models score given boxes, read without changing
anything the tracker does."""

from __future__ import annotations

import contextlib
import copy
import dataclasses

import numpy as np
import pytest

from sptpt.params import get_preset
from sptpt.results import FrameResult
from sptpt.tracker import Tracker, TrackerInspection
from sptpt_dev.synthetic import make_clip

# Small runs: subspace scoring from the fourth frame on (update_every=3), a few particles.
SMALL = dataclasses.replace(get_preset("paper"), n_particles=40, n_negatives=30, update_every=3)
# Two runs reported by confidence, without the reported-box filters: each run's box is its estimate.
TWO_RUNS = dataclasses.replace(SMALL, independent_runs=2, run_choice="confidence")


@pytest.fixture(scope="module")
def clip():
    return make_clip(10, size=(160, 120), object_size=(36, 30), seed=3)


def _same(a: FrameResult, b: FrameResult) -> bool:
    boxes = (a.run_boxes_xywh is None and b.run_boxes_xywh is None) or np.array_equal(a.run_boxes_xywh,
                                                                                         b.run_boxes_xywh)
    return (np.array_equal(a.box_xywh, b.box_xywh) and a.log_likelihood == b.log_likelihood and boxes
            and (a.confidence, a.accepted, a.scoring) == (b.confidence, b.accepted, b.scoring))


@pytest.mark.parametrize("params", [SMALL, TWO_RUNS, dataclasses.replace(get_preset("robust"), n_particles=40,
                                                                         refine_particles=20, n_negatives=30,
                                                                         redetect_particles=20)],
                         ids=["one run", "two runs", "robust"])
def test_inspecting_between_updates_leaves_every_result_as_without_it(clip, params):
    inspected, plain = Tracker(params, seed=7), Tracker(params, seed=7)
    assert _same(inspected.init(clip.frames[0], clip.boxes_xywh[0]), plain.init(clip.frames[0], clip.boxes_xywh[0]))
    for k, frame in enumerate(clip.frames[1:], start=1):
        inspected.inspect(frame, np.stack([clip.boxes_xywh[k], clip.boxes_xywh[k - 1] + 3]))
        inspected.inspect(frame)
        assert _same(inspected.update(frame), plain.update(frame)), k


def test_the_first_box_scores_the_first_frames_code_mass_before_any_model(clip):
    tracker = Tracker(SMALL, seed=1)
    first = tracker.init(clip.frames[0], clip.boxes_xywh[0])
    inspection = tracker.inspect(clip.frames[0], clip.boxes_xywh[0])
    # Bootstrap score: the intersection of the box's code tensor with the first frame's, itself here.
    assert inspection.log_likelihood[0, 0] == first.log_likelihood
    assert not inspection.subspace[0] and inspection.positive_updates[0] == 0
    assert (inspection.positive_ranks == 0).all() and (inspection.negative_ranks == 0).all()
    for field in ("positive_error", "negative_error_modes", "negative_error_sample"):
        assert np.isnan(getattr(inspection, field)).all()
    np.testing.assert_array_equal(inspection.estimate_xywh[0], clip.boxes_xywh[0])


def test_boxes_score_as_the_tracker_scored_them_as_candidates(clip):
    tracker = Tracker(SMALL, seed=2)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    for k in range(1, 8):
        before = copy.deepcopy(tracker)  # the models this frame's candidates are scored with
        result = tracker.update(clip.frames[k], details=True)
        inspection = before.inspect(clip.frames[k], result.particles_xywh)
        assert inspection.subspace[0] == (result.scoring == "subspace")
        np.testing.assert_allclose(inspection.log_likelihood[0], result.particle_scores, rtol=1e-9, atol=1e-9)
    assert result.scoring == "subspace"


def test_the_log_likelihood_is_the_negative_error_less_the_positive_one(clip):
    tracker = Tracker(SMALL, seed=3)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    for frame in clip.frames[1:6]:
        tracker.update(frame)
    inspection = tracker.inspect(clip.frames[5], clip.boxes_xywh[3:7])
    assert inspection.subspace[0] and inspection.log_likelihood.shape == (1, 4)
    np.testing.assert_array_equal(inspection.log_likelihood, inspection.negative_error - inspection.positive_error)
    # re_mode "paper": gamma RE1 + (1 - gamma) RE2 of the two mode errors (paper eqs. 5-7).
    for model in ("positive", "negative"):
        np.testing.assert_allclose(getattr(inspection, f"{model}_error"),
                                   SMALL.gamma * getattr(inspection, f"{model}_error_modes")
                                   + (1 - SMALL.gamma) * getattr(inspection, f"{model}_error_sample"), rtol=1e-12)
        assert (getattr(inspection, f"{model}_error_modes") >= 0).all()


def test_positive_updates_count_the_batches_of_accepted_frames(clip):
    # paper: the first update_every = 5 frames (the first one's tensor and frames 2-5, all accepted in the
    # bootstrap) make the first batch, so the positive model exists after the fifth frame and not before.
    tracker = Tracker(dataclasses.replace(get_preset("paper"), n_particles=40, n_negatives=30), seed=11)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    counts, accepted = [], []
    for frame in clip.frames[1:]:
        accepted.append(tracker.update(frame).accepted)
        counts.append(int(tracker.inspect(frame).positive_updates[0]))
    assert all(accepted[:4]) and counts[:4] == [0, 0, 0, 1]
    assert counts == sorted(counts) and counts[-1] == 1 + sum(accepted[4:]) // 5
    assert tracker.inspect(clip.frames[-1]).positive_ranks[0, 2] >= 1


def test_one_row_per_run_with_each_runs_estimate(clip):
    tracker = Tracker(TWO_RUNS, seed=4)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    for frame in clip.frames[1:5]:
        result = tracker.update(frame)
    inspection = tracker.inspect(clip.frames[4], clip.boxes_xywh[2:5])
    np.testing.assert_array_equal(inspection.estimate_xywh, result.run_boxes_xywh)
    assert inspection.log_likelihood.shape == inspection.positive_error_sample.shape == (2, 3)
    assert inspection.positive_ranks.shape == (2, 3) and inspection.subspace.shape == (2,)
    empty = tracker.inspect(clip.frames[4])
    assert empty.log_likelihood.shape == (2, 0)
    np.testing.assert_array_equal(empty.estimate_xywh, inspection.estimate_xywh)


def test_rank_matched_negatives_are_inspected_as_they_are_scored(clip):
    params = dataclasses.replace(SMALL, negative_rank_matched=True)
    tracker = Tracker(params, seed=5)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    for frame in clip.frames[1:6]:
        tracker.update(frame)
    inspection = tracker.inspect(clip.frames[5], clip.boxes_xywh[5])
    assert (inspection.negative_ranks <= inspection.positive_ranks).all()


def test_inspecting_enters_no_stage_timer(clip):
    entered = []

    def timer(stage):
        entered.append(stage)
        return contextlib.nullcontext()

    tracker = Tracker(TWO_RUNS, seed=6, stage_timer=timer)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    entered.clear()
    tracker.inspect(clip.frames[0], clip.boxes_xywh[:3])
    assert entered == []
    # And once both runs score with their subspace models: the stages inspect() shares with update().
    for frame in clip.frames[1:6]:
        tracker.update(frame)
    assert entered  # the timer does see update()
    entered.clear()
    inspection = tracker.inspect(clip.frames[5], clip.boxes_xywh[3:6])
    assert inspection.subspace.all() and entered == []


def test_the_inspection_is_frozen_and_checks_its_shapes(clip):
    tracker = Tracker(SMALL, seed=6)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    inspection = tracker.inspect(clip.frames[0], clip.boxes_xywh[:2])
    assert isinstance(inspection, TrackerInspection)
    with pytest.raises(dataclasses.FrozenInstanceError):
        inspection.log_likelihood = np.zeros((1, 2))
    with pytest.raises(ValueError, match=r"positive_error must have shape \(1, 2\)"):
        dataclasses.replace(inspection, positive_error=np.zeros((1, 3)))


@pytest.mark.parametrize("boxes, error, match", [
    ([1, 2, 3], ValueError, r"\(N, 4\)"),
    (np.zeros((2, 5)), ValueError, r"\(N, 4\)"),
    ("a", ValueError, r"\(N, 4\)"),
    ([[1, 2, 0, 5]], ValueError, "positive width and height, got box 0"),
    ([[1, 2, 5, 5], [1, 2, 5, -1]], ValueError, "got box 1"),
    ([[1, np.nan, 5, 5]], ValueError, "finite"),
])
def test_bad_boxes_are_named(clip, boxes, error, match):
    tracker = Tracker(SMALL, seed=0)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    with pytest.raises(error, match=match):
        tracker.inspect(clip.frames[0], boxes)


def test_inspecting_before_init_or_another_frame_size_is_an_error(clip):
    tracker = Tracker(SMALL, seed=0)
    with pytest.raises(RuntimeError, match=r"Tracker.inspect\(\) called before init"):
        tracker.inspect(clip.frames[0], clip.boxes_xywh[0])
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    with pytest.raises(ValueError, match="same size"):
        tracker.inspect(clip.frames[0][:50], clip.boxes_xywh[0])

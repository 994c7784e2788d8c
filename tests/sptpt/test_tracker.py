"""The tracker end to end on synthetic video, its determinism and its input checks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _numba_threads import numba_threads

from sptpt._kernels import on_own_threads
from sptpt.boxes import iou_xywh
from sptpt.params import get_preset
from sptpt.results import FrameResult
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip


def run(clip, seed, params=None, n=None) -> list[FrameResult]:
    tracker = Tracker(params, seed=seed)
    frames = clip.frames[:n]
    results = [tracker.init(frames[0], clip.boxes_xywh[0])]
    results += [tracker.update(f, details=k % 7 == 0) for k, f in enumerate(frames[1:], start=1)]
    return results


@pytest.fixture(scope="module")
def clip():
    return make_clip(48, seed=3)


@pytest.fixture(scope="module")
def paper_run(clip):
    return run(clip, seed=11)


def test_follows_a_moving_scaling_partly_occluded_object(clip, paper_run):
    boxes = np.array([r.box_xywh for r in paper_run])
    overlap = iou_xywh(boxes, clip.boxes_xywh)
    assert overlap.mean() >= 0.7, overlap.round(2)
    assert clip.occluded.any()
    assert overlap[clip.occluded].mean() >= 0.5


def test_schedule_scores_with_subspaces_after_the_first_batch(paper_run):
    scoring = [r.scoring for r in paper_run]
    assert scoring[0] == "init"
    assert set(scoring[1:5]) == {"bootstrap"}
    # All of frames 2..5 accepted: both models exist after frame 5, so frame 6 is subspace-scored
    # (docs/design/tracker.md, "Update schedule").
    assert all(r.accepted for r in paper_run[1:5])
    assert scoring[5] == "subspace"
    for r in paper_run:
        assert 0.0 <= r.confidence <= 1.0 and np.isfinite(r.log_likelihood)


def test_same_seed_same_boxes_and_different_seed_different_particles(clip, paper_run):
    again = run(clip, seed=11, n=12)
    for a, b in zip(paper_run[:12], again):
        np.testing.assert_array_equal(a.box_xywh, b.box_xywh)
        assert a.log_likelihood == b.log_likelihood
    other = run(clip, seed=12, n=3)
    assert not np.array_equal(other[1].box_xywh, paper_run[1].box_xywh)


@pytest.mark.parametrize("preset", ["paper", "robust"])
def test_one_thread_or_two_give_the_same_boxes_to_the_bit(clip, preset):
    """Scoring, the subspace fits and a preset's runs are split over the kernel threads; nothing may move."""
    import numba

    params = get_preset(preset)
    if numba.get_num_threads() == 1:
        pytest.skip("numba has one thread here: nothing to compare")
    with numba_threads(1):
        alone = run(clip, 11, params, n=16)
    together = run(clip, 11, params, n=16)
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a.box_xywh, b.box_xywh)
        assert a.log_likelihood == b.log_likelihood and a.accepted == b.accepted
        if a.particle_scores is not None:
            np.testing.assert_array_equal(a.particle_scores, b.particle_scores)
            np.testing.assert_array_equal(a.superpixel_labels, b.superpixel_labels)


@pytest.mark.parametrize("runs, voter, all_at_once", [(3, False, True), (3, True, True), (4, False, False),
                                                    (4, True, False)])
def test_runs_go_all_at_once_up_to_one_more_than_the_kernel_threads(clip, monkeypatch, runs, voter, all_at_once):
    """Three runs on two kernel threads share the cores at once, the voter beside them; more runs would oversubscribe
    a batch worker's share."""
    import numba

    import sptpt.tracker as tracker_module

    if numba.get_num_threads() == 1:
        pytest.skip("numba has one thread here: the runs go one after the other")
    calls = []

    def spy(function, items):
        calls.append(len(items))
        return on_own_threads(function, items)

    monkeypatch.setattr(tracker_module, "on_own_threads", spy)
    params = dataclasses.replace(get_preset("fast"), independent_runs=runs)
    if voter:
        params = dataclasses.replace(params, run_choice="consensus", filter_vote=True)
    with numba_threads(2):
        together = run(clip, 5, params, n=3)
    assert calls == ([runs + voter] * 2 if all_at_once else [])
    with numba_threads(1):
        alone = run(clip, 5, params, n=3)
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a.box_xywh, b.box_xywh)
        np.testing.assert_array_equal(a.run_boxes_xywh, b.run_boxes_xywh)


def test_details_carry_particles_and_superpixels(clip, paper_run):
    detailed = paper_run[7]
    n = get_preset("paper").n_particles
    assert detailed.particles_xywh.shape == (n, 4) and detailed.particle_scores.shape == (n,)
    assert detailed.particle_scores.max() == detailed.log_likelihood
    labels = detailed.superpixel_labels
    assert labels.ndim == 2 and labels.max() == 24 and labels.min() == -1
    assert paper_run[8].particles_xywh is None


@pytest.mark.parametrize("preset", ["paper", "robust"])  # robust: two runs, chosen by colour contrast
def test_grayscale_frames_are_accepted(clip, preset):
    gray = clip.frames[:4].mean(axis=3).astype(np.uint8)
    tracker = Tracker(get_preset(preset), seed=0)
    tracker.init(gray[0], clip.boxes_xywh[0])
    result = tracker.update(gray[1])
    assert result.box_xywh.shape == (4,)


def test_target_leaving_the_frame_does_not_crash():
    clip = make_clip(12, seed=1)
    tracker = Tracker(seed=0)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    black = np.zeros_like(clip.frames[0])
    results = [tracker.update(black) for _ in range(8)]
    assert all(np.isfinite(r.box_xywh).all() for r in results)
    # Nothing of the target is left: the model must not be confident.
    assert results[-1].confidence < 0.5


@pytest.mark.parametrize(
    "box, message",
    [
        ((1, 2, 3), "4 numbers"),
        ((1, 2, 0, 5), "positive width"),
        ((1, 2, np.nan, 5), "finite"),
        ((500, 10, 20, 20), "outside"),
        ("a,b,c,d", "4 numbers"),
    ],
)
def test_bad_boxes_are_rejected(box, message):
    frame = np.zeros((50, 60, 3), np.uint8)
    with pytest.raises(ValueError, match=message):
        Tracker(seed=0).init(frame, box)


def test_bad_frames_and_call_order_are_rejected():
    tracker = Tracker(seed=0)
    with pytest.raises(RuntimeError, match="before init"):
        tracker.update(np.zeros((50, 60, 3), np.uint8))
    with pytest.raises(TypeError, match="uint8"):
        tracker.init(np.zeros((50, 60, 3), np.float32), (1, 1, 10, 10))
    with pytest.raises(ValueError, match="shape"):
        tracker.init(np.zeros((50, 60, 4), np.uint8), (1, 1, 10, 10))
    tracker.init(np.zeros((50, 60, 3), np.uint8), (1, 1, 10, 10))
    with pytest.raises(ValueError, match="same size"):
        tracker.update(np.zeros((40, 60, 3), np.uint8))
    with pytest.raises(TypeError, match="TrackerParams"):
        Tracker({"n_particles": 3})


def test_refinement_round_adds_candidates_around_the_first_winner(clip):
    from sptpt.params import params_from_mapping

    params = params_from_mapping({"n_particles": 40, "refine_particles": 20, "n_negatives": 20})
    results = run(clip, seed=5, params=params, n=8)
    detailed = results[7]
    assert detailed.particles_xywh.shape == (60, 4)
    assert detailed.particle_scores.max() == detailed.log_likelihood
    # The refined candidates sit closer together than the first round's.
    spread = lambda boxes: boxes[:, :2].std(axis=0).mean()  # noqa: E731
    assert spread(detailed.particles_xywh[40:]) < spread(detailed.particles_xywh[:40])


def test_repeated_states_are_computed_once_with_identical_results(clip):
    """Negatives often repeat a state; the tracker codes it once and copies the result."""
    frames = clip.frames
    tracker = Tracker(get_preset("paper"), seed=5)
    tracker.init(frames[0], clip.boxes_xywh[0])
    run = tracker._runs[0]
    states = run._draw(run._state, 6, run._sigma)
    repeated = states[[0, 1, 2, 1, 3, 0, 4, 5]]
    codes, labels = run._codes(frames[1], repeated)
    features, want_labels = run._features(frames[1], repeated)
    assert np.array_equal(codes, run._code(features))
    assert np.array_equal(labels, want_labels)


@pytest.mark.parametrize("ranks, ok", [((40, 30, 40), False), ((10, 16, 10), True)])
def test_check_params_raises_what_building_a_tracker_raises_without_building_one(ranks, ok):
    import sptpt

    params = dataclasses.replace(get_preset("paper"), ranks=ranks)
    if ok:
        sptpt.check_params(params)
        Tracker(params, seed=0)
        return
    with pytest.raises(ValueError, match="superpixel rank 30 exceeds") as checked:
        sptpt.check_params(params)
    with pytest.raises(ValueError) as built:
        Tracker(params, seed=0)
    assert str(checked.value) == str(built.value)

"""``independent_runs``: several SPTPT runs side by side, each frame reported by the more confident one, by the one
whose box stands out most from its surroundings, or by the runs that agree (``run_choice``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sptpt.affine import box_xywh_from_states, state_from_box_xywh
from sptpt.boxes import iou_xywh, mean_box
from sptpt.contrast import colour_contrast
from sptpt.filter_tracker import FilterTracker
from sptpt.params import get_preset
from sptpt.results import FrameResult
from sptpt.tracker import Tracker, _consensus, _more_confident, _most_contrasted, _most_contrasted_candidate
from sptpt_dev.synthetic import make_clip


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


def _params(runs: int, choice: str = "confidence"):
    return dataclasses.replace(get_preset("robust"), independent_runs=runs, run_choice=choice)


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A grey-textured frame with one red square: a box on the square, and one of its size on the background."""
    rng = np.random.default_rng(0)
    frame = np.repeat(rng.integers(90, 130, (120, 160, 1), dtype=np.uint8), 3, axis=2)
    frame[40:70, 50:80] = (200, 30, 30)
    return frame, np.array([50.0, 40.0, 30.0, 30.0]), np.array([110.0, 70.0, 30.0, 30.0])


def test_the_run_whose_box_stands_out_is_reported_even_when_less_confident():
    frame, on_object, on_background = _scene()
    object_run = FrameResult(box_xywh=on_object, log_likelihood=1.0, confidence=0.5, accepted=True, scoring="subspace")
    lost_run = FrameResult(box_xywh=on_background, log_likelihood=5.0, confidence=0.9, accepted=True,
                           scoring="subspace")
    results = [lost_run, object_run]
    assert colour_contrast(frame, on_object) > 0.5 > colour_contrast(frame, on_background)
    assert _more_confident(results) == 0 and _most_contrasted(results, frame, 0) == 1
    assert _most_contrasted(results[::-1], frame, 1) == 0
    # Equal contrast: the confident run stays; a box too small to measure ranks below a measured one.
    assert _most_contrasted([object_run, object_run], frame, 1) == 1
    assert _most_contrasted([object_run, object_run], frame, 0) == 0
    tiny = dataclasses.replace(object_run, box_xywh=np.array([55.0, 45.0, 5.0, 5.0]))
    assert _most_contrasted([tiny, lost_run], frame, 0) == 1
    assert _most_contrasted([tiny, tiny], frame, 1) == 1  # neither measured: the confident run
    assert _most_contrasted([tiny, tiny], frame, 0) == 0


def test_of_the_best_candidates_near_the_best_score_the_one_whose_box_stands_out_is_taken():
    frame, on_object, on_background = _scene()
    frame[80:110, 115:145] = (200, 30, 30)  # a look-alike far from the object
    look_alike = np.array([115.0, 80.0, 30.0, 30.0])
    straddling = on_object + [8.0, 0.0, 0.0, 0.0]  # IoU 0.58 with the object's box
    tiny = np.array([55.0, 45.0, 5.0, 5.0])

    def states(*boxes):
        return np.stack([state_from_box_xywh(b, 32) for b in boxes])

    np.testing.assert_allclose(box_xywh_from_states(states(on_object)[0], 32), on_object)
    assert colour_contrast(frame, on_object) > colour_contrast(frame, straddling)
    assert colour_contrast(frame, look_alike) > colour_contrast(frame, straddling)
    candidates = states(straddling, look_alike, on_object, on_background)
    scores = np.array([5.0, 4.0, 3.0, 2.0])

    def pick(candidates, scores, k):
        return _most_contrasted_candidate(frame, candidates, scores, int(np.argmax(scores)), k, 32)

    assert pick(candidates, scores, 3) == 2  # the look-alike is too far to compete
    assert pick(candidates, scores, 2) == 0  # neither the far look-alike nor the object's box (not among the best 2)
    assert pick(candidates, scores, 1) == 0
    assert pick(candidates, scores, 10) == 2  # more than there are: all of them
    # The best-scoring candidate is half on the far look-alike: the object's box, which stands out more but is not
    # near it, does not compete.
    half_on_look_alike = look_alike - [15.0, 0.0, 0.0, 0.0]
    assert colour_contrast(frame, on_object) > colour_contrast(frame, half_on_look_alike) > 0
    assert pick(states(straddling, half_on_look_alike, on_object), np.array([1.0, 4.0, 3.0]), 3) == 1
    # Equal contrast (the same box twice): the better score; no contrast measured: the best score.
    assert pick(states(on_object, on_object), np.array([1.0, 2.0]), 2) == 1
    small = np.array([53.0, 43.0, 7.0, 7.0])  # too small to measure as well, IoU 0.51 with tiny
    assert pick(states(tiny, small), np.array([2.0, 1.0]), 2) == 0
    assert pick(states(tiny, small), np.array([1.0, 2.0]), 2) == 1
    # A degenerate best box (zero width) overlaps nothing, not even itself: it stays the choice.
    flat = states(on_object, on_object)
    flat[0, 2] = 0.0
    assert pick(flat, np.array([2.0, 1.0]), 2) == 0
    # The best is whichever the caller chose, also when another candidate has the same score.
    assert _most_contrasted_candidate(frame, candidates, np.array([3.0, 0.0, 3.0, 0.0]), 2, 1, 32) == 2


def test_each_frame_takes_the_most_contrasted_of_its_best_candidates():
    # Without the scale and translation filters, which would resize and move the chosen candidate's box for the report.
    params = dataclasses.replace(_params(1), contrast_candidates=5, reported_scale_filter=False,
                                 reported_translation_filter=False)
    clip = make_clip(25, seed=3)
    tracker = Tracker(params, seed=2)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    overruled = 0
    for frame in clip.frames[1:]:
        got = tracker.update(frame, details=True)
        top = np.argsort(-got.particle_scores, kind="stable")[:5]
        boxes = got.particles_xywh[top]
        top = top[iou_xywh(boxes, boxes[0]) >= 0.5]  # near the best score
        contrast = np.array([colour_contrast(frame, got.particles_xywh[i]) for i in top])
        assert np.isfinite(contrast).all()  # every candidate's box is measured on this clip
        want = top[int(np.argmax(contrast))]
        np.testing.assert_allclose(got.box_xywh, got.particles_xywh[want], rtol=0, atol=1e-9)
        assert got.log_likelihood == got.particle_scores[want]
        overruled += want != top[0]
    assert overruled > 0  # the clip has frames where the best score is not the box that stands out most
    with pytest.raises(ValueError, match="contrast_candidates=-1 is invalid"):
        dataclasses.replace(params, contrast_candidates=-1)


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


def _beside_their_runs(runs: int, choice: str, **changes):
    """Per frame after the first of ``make_clip(25, seed=3)``: the frame, a ``runs``-run tracker's result, each of
    its runs tracked alone by a one-run tracker from the same child seed, and the box of a correlation-filter
    tracker (:class:`FilterTracker`) tracking alone."""
    clip = make_clip(25, seed=3)
    tracker = Tracker(dataclasses.replace(_params(runs, choice), **changes), seed=11)
    seeds = np.random.default_rng(11).integers(0, 2**63 - 1, size=runs)
    singles = [Tracker(_params(1), seed=int(s)) for s in seeds]
    for t in (tracker, *singles):
        t.init(clip.frames[0], clip.boxes_xywh[0])
    voter = FilterTracker(32)
    voter.init(clip.frames[0], clip.boxes_xywh[0])
    for frame in clip.frames[1:]:
        yield frame, tracker.update(frame), [single.update(frame) for single in singles], voter.update(frame)


def test_with_run_choice_contrast_each_frame_is_the_run_whose_box_stands_out():
    overruled = 0
    for frame, got, alone, _ in _beside_their_runs(2, "contrast"):
        contrast = [colour_contrast(frame, a.box_xywh) for a in alone]
        assert np.isfinite(contrast).all()  # on this clip every box is measured: the rule below needs no NaN case
        confident = _more_confident(alone)
        want = alone[int(np.argmax(contrast))] if contrast[0] != contrast[1] else alone[confident]
        np.testing.assert_array_equal(got.box_xywh, want.box_xywh)
        np.testing.assert_array_equal(got.run_boxes_xywh, np.stack([a.box_xywh for a in alone]))
        overruled += want is not alone[confident]
    assert overruled > 0  # the clip has frames where contrast and confidence pick different runs


def _consensus_of(*boxes, confident: int = 0, voters=()):
    """``_consensus`` of run boxes and voter boxes (rows after the runs')."""
    frame, _, _ = _scene()
    return _consensus(np.array([*boxes, *voters], dtype=float), len(boxes), frame, confident)


def test_consensus_reports_the_runs_that_agree_and_contrast_decides_the_rest():
    frame, on_object, on_background = _scene()
    near = on_object + [3.0, 0.0, 0.0, 0.0]  # IoU 0.82 with on_object
    elsewhere = np.array([5.0, 80.0, 30.0, 30.0])  # on background, away from both
    # Two runs that agree with each other and one lost run: the pair, however much the lost one stands out.
    assert _consensus_of(on_background, on_object, near) == (1, [1, 2])
    # All three agree: all three, reported from the one that stands out most.
    chosen, agreeing = _consensus_of(on_object, near, on_object + [0.0, 3.0, 0.0, 0.0])
    assert sorted(agreeing) == [0, 1, 2] and agreeing[0] == chosen
    # A chain (the middle box agrees with both ends, which do not agree with each other): all three, from the middle.
    chain = [on_object - [7.0, 0.0, 0.0, 0.0], on_object, on_object + [7.0, 0.0, 0.0, 0.0]]
    assert iou_xywh(chain[0], chain[2]) < 0.5 <= iou_xywh(chain[0], chain[1])
    assert _consensus_of(*chain, confident=2) == (1, [1, 0, 2])
    # No two agree: the box that stands out most, alone, as with run_choice="contrast".
    assert _consensus_of(on_background, on_object, elsewhere) == (1, [1])
    # Two runs: together when they agree, else the one that stands out.
    assert _consensus_of(near, on_object)[1] in ([0, 1], [1, 0])
    assert _consensus_of(on_background, on_object) == (1, [1])
    # Ties (same contrast, same votes): the confident run.
    assert _consensus_of(on_object, on_object, on_background, confident=1) == (1, [1, 0])
    # ... and when the confident run is not among the most agreed with, the first of those.
    assert _consensus_of(on_object, on_object, on_background, confident=2) == (0, [0, 1])


def test_a_voter_counts_in_the_vote_and_the_mean_but_is_never_reported_alone():
    frame, on_object, on_background = _scene()
    near = on_object + [3.0, 0.0, 0.0, 0.0]
    lower = on_object + [0.0, 3.0, 0.0, 0.0]
    elsewhere = np.array([5.0, 80.0, 30.0, 30.0])
    beside = on_background + [3.0, 0.0, 0.0, 0.0]
    # It joins the runs it agrees with: the mean is of the three boxes.
    chosen, agreeing = _consensus_of(on_background, on_object, near, voters=[lower])
    assert chosen in (1, 2) and sorted(agreeing) == [1, 2, 3]
    # It breaks a tie: one run lost on the background with another (a pair), one on the object with the voter (a
    # pair); of the two pairs, the one that stands out.
    assert _consensus_of(on_background, beside, on_object, voters=[near]) == (2, [2, 3])
    # Chosen itself (its box stands out most of a pair), the run reported is the run that agrees with it.
    assert colour_contrast(frame, on_object) > colour_contrast(frame, near)
    assert _consensus_of(near, on_background, elsewhere, voters=[on_object]) == (0, [3, 0])
    # Two voters that agree only with each other count for no run: the runs decide as without them.
    assert (_consensus_of(on_background, elsewhere, voters=[on_object, near])
            == _consensus_of(on_background, elsewhere))
    # Alone, however much it stands out: the runs decide as without it.
    assert _consensus_of(on_background, elsewhere, voters=[on_object]) == _consensus_of(on_background, elsewhere)
    chosen, agreeing = _consensus_of(on_background, elsewhere, voters=[on_object])
    assert chosen < 2 and agreeing == [chosen]


def test_with_run_choice_consensus_each_frame_is_the_mean_of_the_agreeing_runs():
    fused = 0
    for frame, got, alone, _ in _beside_their_runs(3, "consensus", filter_vote=False):
        np.testing.assert_array_equal(got.run_boxes_xywh, np.stack([a.box_xywh for a in alone]))
        # Slow reference of the rule: pairwise agreement, most votes, contrast among the tied, mean of the group.
        boxes = [a.box_xywh for a in alone]
        votes = [sum(iou_xywh(b, c) >= 0.5 for j, c in enumerate(boxes) if j != i) for i, b in enumerate(boxes)]
        tied = [i for i in range(3) if votes[i] == max(votes)]
        contrast = {i: colour_contrast(frame, boxes[i]) for i in tied}
        assert np.isfinite(list(contrast.values())).all()  # every box measured: the reference needs no NaN case
        confident = _more_confident(alone)
        best = max(tied, key=lambda i: (contrast[i], i == confident, -i))
        group = [best] + [j for j in range(3) if j != best and iou_xywh(boxes[best], boxes[j]) >= 0.5]
        np.testing.assert_array_equal(got.box_xywh, mean_box([boxes[i] for i in sorted(group)]))
        assert got.log_likelihood == alone[best].log_likelihood
        fused += len(group) > 1
    assert fused > 0  # the clip has frames where runs agree and are averaged


def test_with_filter_vote_the_filter_tracker_votes_and_the_runs_are_those_alone():
    joined = 0
    for frame, got, alone, voter in _beside_their_runs(3, "consensus", filter_vote=True):
        np.testing.assert_array_equal(got.run_boxes_xywh, np.stack([a.box_xywh for a in alone]))
        # Slow reference: the rule of the test above over four boxes, the voter's last, never reported alone.
        boxes = [a.box_xywh for a in alone] + [voter]
        confident = _more_confident(alone)

        def choose(candidates, boxes=boxes, frame=frame, confident=confident):
            votes = {i: sum(iou_xywh(boxes[i], boxes[j]) >= 0.5 for j in candidates if j != i) for i in candidates}
            tied = [i for i in candidates if votes[i] == max(votes.values())]
            contrast = {i: colour_contrast(frame, boxes[i]) for i in tied}
            assert np.isfinite(list(contrast.values())).all()
            best = max(tied, key=lambda i: (contrast[i], i == confident, -i))
            return best, [best] + [j for j in candidates if j != best and iou_xywh(boxes[best], boxes[j]) >= 0.5]

        best, group = choose([0, 1, 2, 3])
        if group == [3]:
            best, group = choose([0, 1, 2])
        np.testing.assert_array_equal(got.box_xywh, mean_box([boxes[i] for i in sorted(group)]))
        assert got.log_likelihood == alone[best if best < 3 else min(group)].log_likelihood
        joined += 3 in group
    assert joined > 0  # the clip has frames where the voter's box is averaged in


@pytest.mark.parametrize("runs, choice", [(1, "consensus"), (2, "contrast")])
def test_filter_vote_without_a_consensus_of_runs_changes_nothing(runs, choice):
    clip = make_clip(10, seed=3)

    def results(filter_vote):
        tracker = Tracker(dataclasses.replace(_params(runs, choice), filter_vote=filter_vote), seed=4)
        tracker.init(clip.frames[0], clip.boxes_xywh[0])
        return [tracker.update(frame) for frame in clip.frames[1:]]

    assert Tracker(dataclasses.replace(_params(runs, choice), filter_vote=True), seed=4)._filter_voter is None
    for with_it, without in zip(results(True), results(False)):
        np.testing.assert_array_equal(with_it.box_xywh, without.box_xywh)
        assert with_it.log_likelihood == without.log_likelihood


@pytest.mark.parametrize("choice, filter_vote", [("confidence", False), ("contrast", False), ("consensus", False),
                                                 ("consensus", True)])
def test_same_seed_same_boxes(choice, filter_vote):
    clip = make_clip(15, seed=3)

    def boxes(seed):
        tracker = Tracker(dataclasses.replace(_params(2, choice), filter_vote=filter_vote), seed=seed)
        tracker.init(clip.frames[0], clip.boxes_xywh[0])
        return np.array([tracker.update(frame).box_xywh for frame in clip.frames[1:]])

    first = boxes(4)
    np.testing.assert_array_equal(first, boxes(4))
    assert not np.array_equal(first, boxes(5))


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

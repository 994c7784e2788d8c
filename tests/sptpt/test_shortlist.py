"""The shortlist (``TrackerParams.shortlist``): a first pass of SPTPT's own score, with the superpixels of the run's
estimate, picks the candidates that get superpixels of their own and the full evaluation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sptpt.affine import warp_candidates
from sptpt.boxes import iou_xywh
from sptpt.coding import encode_tensors
from sptpt.features import superpixel_features
from sptpt.params import get_preset
from sptpt.superpixels import snic
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip


def _robust(shortlist: int, runs: int = 1, solves: int = 0):
    return dataclasses.replace(get_preset("robust"), shortlist=shortlist, independent_runs=runs,
                               shortlist_solves=solves)


def slow_shortlist(run, templates: np.ndarray, labels: np.ndarray, codes: np.ndarray, k: int) -> np.ndarray:
    """One template at a time: cut into ``labels``, described, coded (from nothing; with ``shortlist_solves``,
    from the atoms of ``codes`` and that many solves), scored by the run's models as they are; the ``k`` best,
    ties to the earlier, in draw order."""
    p = run.params
    capped = dict(start=codes, max_solves=p.shortlist_solves) if p.shortlist_solves else {}
    scores = []
    for template in templates:
        features = superpixel_features(template[None], labels[None], run.n_superpixels, n_bins=p.n_bins)
        scores.append(run._scores(encode_tensors(features, run._dictionary, lam=p.lasso_lambda, **capped))[0][0])
    order = sorted(range(len(templates)), key=lambda i: (-scores[i], i))
    return np.array(sorted(order[:k]))


@pytest.mark.parametrize("solves", [0, 2])  # exact codes, then codes capped at two solves
@pytest.mark.parametrize("frames_tracked", [1, 12])  # the bootstrap score, then the subspace models
def test_the_shortlist_is_the_best_of_the_first_pass(frames_tracked, solves):
    clip = make_clip(frames_tracked + 2, seed=3)
    tracker = Tracker(_robust(10, solves=solves), seed=4)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    for frame in clip.frames[1:frames_tracked]:
        tracker.update(frame)
    run = tracker._runs[0]
    frame = clip.frames[frames_tracked]
    states = np.repeat(run._state[None], 40, axis=0)
    states[:, :2] += np.random.default_rng(5).normal(0, 4, (40, 2))
    templates = warp_candidates(frame, states, 32)
    labels, codes = run._estimate
    kept = run._shortlisted(templates, labels, codes, 10)
    np.testing.assert_array_equal(kept, slow_shortlist(run, templates, labels, codes, 10))
    if frames_tracked == 1:  # before any update the estimate is the first box: its superpixels are SNIC's of it
        first = warp_candidates(clip.frames[0], run._state[None], 32)
        p = run.params
        np.testing.assert_array_equal(labels, snic(first, n_segments=p.n_superpixels, compactness=p.compactness,
                                                   seeding=p.seeding)[0])


def test_the_tracker_evaluates_only_the_shortlist_drawn_from_the_same_stream():
    clip = make_clip(4, seed=3)
    full, short = Tracker(_robust(0), seed=2), Tracker(_robust(25), seed=2)
    full.init(clip.frames[0], clip.boxes_xywh[0])
    short.init(clip.frames[0], clip.boxes_xywh[0])
    every = full.update(clip.frames[1], details=True)
    kept = short.update(clip.frames[1], details=True)
    p = _robust(25)
    assert len(every.particles_xywh) == p.n_particles + p.refine_particles
    assert len(kept.particles_xywh) == 2 * 25  # the wide round's and the refine round's shortlists
    # The first round draws the same candidates with and without the shortlist: the kept are among them.
    first_round = every.particles_xywh[: p.n_particles]
    for box in kept.particles_xywh[:25]:
        assert np.any(np.all(first_round == box, axis=1))
    assert kept.superpixel_labels is not None and kept.particle_scores.shape == (50,)


@pytest.mark.parametrize("solves", [0, 2])  # without a first pass, nothing to cap
def test_a_shortlist_as_long_as_the_round_changes_nothing(solves):
    clip = make_clip(8, seed=3)
    boxes = []
    for shortlist in (0, 150):  # the refine round (75) and the first (150) are evaluated whole either way
        tracker = Tracker(_robust(shortlist, runs=3, solves=solves if shortlist == 0 else 0), seed=7)
        out = [tracker.init(clip.frames[0], clip.boxes_xywh[0]).box_xywh]
        out += [tracker.update(frame).box_xywh for frame in clip.frames[1:]]
        boxes.append(np.array(out))
    np.testing.assert_array_equal(boxes[0], boxes[1])


@pytest.mark.parametrize("solves", [0, 2])
def test_the_shortlist_is_deterministic_and_follows_the_object_as_the_whole_search_does(solves):
    clip = make_clip(20, seed=3)

    def track(shortlist: int, solves: int = 0) -> np.ndarray:
        tracker = Tracker(_robust(shortlist, runs=3, solves=solves), seed=9)
        boxes = [tracker.init(clip.frames[0], clip.boxes_xywh[0]).box_xywh]
        boxes += [tracker.update(frame).box_xywh for frame in clip.frames[1:]]
        return np.array(boxes)

    short = track(25, solves)
    np.testing.assert_array_equal(short, track(25, solves))
    overlap, whole = iou_xywh(short, clip.boxes_xywh), iou_xywh(track(0), clip.boxes_xywh)
    assert overlap.mean() >= whole.mean() - 0.05, (overlap.round(2), whole.round(2))


def test_the_shortlist_is_a_count_and_not_with_the_prescreen():
    with pytest.raises(ValueError, match="shortlist"):
        dataclasses.replace(get_preset("robust"), shortlist=-1)
    with pytest.raises(ValueError, match="shortlist"):
        dataclasses.replace(get_preset("robust"), shortlist=25, prescreen_share=0.5)
    with pytest.raises(ValueError, match=r"shortlist_solves=-1 is invalid: expected an integer >= 0"):
        dataclasses.replace(get_preset("robust"), shortlist_solves=-1)


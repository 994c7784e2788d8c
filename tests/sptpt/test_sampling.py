"""Candidate and negative sampling."""

from __future__ import annotations

import numpy as np

from sptpt.affine import box_xywh_from_states, state_from_box_xywh
from sptpt.boxes import iou_xywh
from sptpt.sampling import draw_candidates, draw_negatives


def test_negatives_overlap_the_estimate_little():
    state = state_from_box_xywh(np.array([100.0, 100.0, 48.0, 40.0]), 32)
    negatives = draw_negatives(state, 2000, 32, np.random.default_rng(0))
    assert (negatives[:, 2:] == state[2:]).all()
    overlaps = iou_xywh(box_xywh_from_states(negatives, 32), box_xywh_from_states(state, 32))
    assert overlaps.max() <= 0.5625 / 1.4375 + 1e-9


def test_candidates_follow_sigma_and_respect_the_scale_floor():
    state = np.array([50.0, 60.0, 1.0, 0.0, 1.0, 0.0])
    sigma = np.array([10.0, 5.0, 0.5, 0.0, 0.0, 0.0])
    states = draw_candidates(state, 20000, sigma, np.random.default_rng(1), min_scale=0.5)
    np.testing.assert_allclose(states[:, :2].std(axis=0), [10.0, 5.0], rtol=0.05)
    assert states[:, 2].min() >= 0.5
    assert (states[:, 3:] == state[3:]).all()


def test_same_generator_state_gives_identical_samples():
    state = np.array([50.0, 60.0, 1.0, 0.0, 1.0, 0.0])
    sigma = np.array([10.0, 10.0, 0.015, 0.0, 0.0, 0.0])
    a = draw_candidates(state, 50, sigma, np.random.default_rng(7), min_scale=0.1)
    b = draw_candidates(state, 50, sigma, np.random.default_rng(7), min_scale=0.1)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(
        draw_negatives(state, 50, 32, np.random.default_rng(7)), draw_negatives(state, 50, 32, np.random.default_rng(7))
    )

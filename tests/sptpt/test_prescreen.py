"""The prescreen (``TrackerParams.prescreen_share``): a cheap grey NCC that picks the candidates SPTPT evaluates."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sptpt.params import get_preset
from sptpt.prescreen import LEARNING_RATE, AppearanceReference, grey_ncc
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip


def slow_ncc(templates: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Pearson correlation of each template's BT.601 luma with the reference, one template at a time, float64."""
    luma = np.array([0.299, 0.587, 0.114])
    ref = np.asarray(reference, np.float64).ravel()
    out = []
    for template in templates:
        grey = (template.astype(np.float64) @ luma).ravel()
        a, b = grey - grey.mean(), ref - ref.mean()
        denominator = np.sqrt((a * a).sum() * (b * b).sum())
        out.append(0.0 if denominator == 0 else float((a * b).sum() / denominator))
    return np.array(out)


def random_templates(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(n, 32, 32, 3), dtype=np.uint8)


def test_ncc_agrees_with_the_slow_reference():
    templates = random_templates(40)
    reference = np.random.default_rng(1).uniform(0, 255, size=(32, 32))
    np.testing.assert_allclose(grey_ncc(templates, reference), slow_ncc(templates, reference), rtol=0, atol=1e-5)


def test_ncc_ignores_brightness_and_contrast_and_is_0_on_flat_images():
    template = random_templates(1)[0]
    reference = template.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    dimmer = np.clip(np.rint(0.5 * template.astype(np.float64) + 20), 0, 255).astype(np.uint8)
    flat = np.full_like(template, 128)
    ncc = grey_ncc(np.stack([template, dimmer, flat]), reference)
    assert ncc[0] == pytest.approx(1.0, abs=1e-5)
    assert ncc[1] > 0.99  # only rounding to uint8 separates it from the reference's look
    assert ncc[2] == 0.0
    assert np.all(grey_ncc(np.stack([template, flat]), np.full((32, 32), 7.0)) == 0.0)


def test_most_alike_keeps_the_share_rounded_up_in_draw_order_and_the_object_first():
    templates = random_templates(150)
    reference = AppearanceReference(templates[97])
    kept = reference.most_alike(templates, 1 / 3)
    assert len(kept) == 50  # not 51: a third of 150 is 50.000000000000007 in floating point
    assert np.all(np.diff(kept) > 0)
    assert 97 in kept
    assert len(reference.most_alike(templates[:75], 1 / 3)) == 25
    assert len(reference.most_alike(templates[:10], 0.01)) == 1
    ncc = grey_ncc(templates, reference.grey)
    assert ncc[kept].min() >= np.delete(ncc, kept).max()


def test_the_reference_is_a_running_mean_of_accepted_templates():
    first, second = random_templates(2)
    reference = AppearanceReference(first)
    reference.learn(second)
    luma = np.array([0.299, 0.587, 0.114])
    expected = ((1 - LEARNING_RATE) * (first.astype(np.float64) @ luma)
                + LEARNING_RATE * (second.astype(np.float64) @ luma))
    np.testing.assert_allclose(reference.grey, expected, rtol=0, atol=1e-4)


def _robust(share: float):
    return dataclasses.replace(get_preset("robust"), independent_runs=1, run_choice="confidence", filter_vote=False,
                               shortlist=0, prescreen_share=share)


def test_the_tracker_scores_only_the_kept_candidates_drawn_from_the_same_stream():
    clip = make_clip(4, seed=3)
    frames, first_box = clip.frames, clip.boxes_xywh[0]
    full, screened = Tracker(_robust(1.0), seed=2), Tracker(_robust(1 / 3), seed=2)
    full.init(frames[0], first_box)
    screened.init(frames[0], first_box)
    every = full.update(frames[1], details=True).particles_xywh
    kept = screened.update(frames[1], details=True).particles_xywh
    p = _robust(1.0)
    assert len(every) == p.n_particles + p.refine_particles
    assert len(kept) == p.n_particles // 3 + p.refine_particles // 3
    # The first round draws the same candidates with and without the prescreen: the kept are among them.
    first_round = every[: p.n_particles]
    for box in kept[: p.n_particles // 3]:
        assert np.any(np.all(first_round == box, axis=1))


def test_the_prescreen_is_deterministic():
    clip = make_clip(12, seed=3)
    runs = []
    for _ in range(2):
        tracker = Tracker(_robust(1 / 3), seed=9)
        boxes = [tracker.init(clip.frames[0], clip.boxes_xywh[0]).box_xywh]
        boxes += [tracker.update(frame).box_xywh for frame in clip.frames[1:]]
        runs.append(np.array(boxes))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_share_must_be_in_0_1():
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match="prescreen_share"):
            dataclasses.replace(get_preset("robust"), prescreen_share=bad)

"""The DSST translation filter (``sptpt.translation``): its features against a slow reference, shifts it must find,
and the tracker switch that moves only the reported centre."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from _orientation_reference import edge_templates, numpy_orientation_split, slow_orientation_split
from _tracker_clips import background_and_object, moving_clip, paste, track_results

from sptpt.affine import state_from_box_xywh
from sptpt.gradients import GREY, orientation_channels
from sptpt.params import get_preset
from sptpt.translation import BINS, NEIGHBOURHOOD, ORIENTATION_WEIGHT, TranslationFilter, translation_features


def slow_translation_features(patch: np.ndarray) -> np.ndarray:
    """Pixel by pixel, as the docstring of translation_features says."""
    rgb = np.asarray(patch, dtype=np.float64)
    grey = (0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]) / 255.0
    rows, cols = grey.shape
    split = slow_orientation_split(grey, BINS)

    def mirror(i: int, n: int) -> int:  # reflect without repeating the edge: -1 -> 1, n -> n - 2
        return -i if i < 0 else 2 * (n - 1) - i if i >= n else i

    reach = range(-(NEIGHBOURHOOD // 2), NEIGHBOURHOOD - NEIGHBOURHOOD // 2)  # -2, -1, 0, 1
    out = np.zeros((1 + BINS, rows, cols))
    out[0] = grey - grey.mean()
    for b in range(BINS):
        for r in range(rows):
            for c in range(cols):
                total = sum(split[b, mirror(r + i, rows), mirror(c + j, cols)] for i in reach for j in reach)
                out[1 + b, r, c] = ORIENTATION_WEIGHT * total / NEIGHBOURHOOD ** 2
    return out


@pytest.mark.parametrize("shape", [(16, 16), (12, 20)])
def test_translation_features_match_the_slow_reference(shape):
    rng = np.random.default_rng(0)
    patch = rng.integers(0, 256, size=shape + (3,), dtype=np.uint8)
    np.testing.assert_allclose(translation_features(patch), slow_translation_features(patch), rtol=1e-10, atol=1e-12)
    flat = np.full(shape + (3,), 128, np.uint8)
    assert not translation_features(flat).any()  # no gradient, and grey less its mean is 0


@pytest.mark.parametrize("bins", [1, 2, 5, BINS])
def test_orientation_channels_match_the_slow_split_for_any_bin_count(bins):
    # With one bin a pixel's lower and upper bins are the same channel, which then holds the whole magnitude.
    grey = np.random.default_rng(bins).random((9, 13))
    channels = orientation_channels(grey, bins)
    np.testing.assert_allclose(channels, slow_orientation_split(grey, bins), rtol=1e-12, atol=1e-15)
    if bins == 1:
        np.testing.assert_allclose(channels[0], slow_orientation_split(grey, 2).sum(axis=0), rtol=1e-12)


def numpy_translation_features(patch: np.ndarray) -> np.ndarray:
    """``translation_features`` as NumPy computed it before the kernel, kept to show the kernel gives its bits."""
    grey = (np.asarray(patch, dtype=np.float64) @ GREY) / 255.0
    magnitude, lower, upper, upper_weight = numpy_orientation_split(grey, BINS)
    channels = np.empty((1 + BINS,) + grey.shape)
    channels[0] = grey - grey.mean()
    for b in range(BINS):
        split = magnitude * ((lower == b) * (1.0 - upper_weight) + (upper == b) * upper_weight)
        channels[1 + b] = ORIENTATION_WEIGHT * cv2.boxFilter(split, -1, (NEIGHBOURHOOD, NEIGHBOURHOOD))
    return channels


def test_translation_features_are_the_numpy_codes_bits():
    rng = np.random.default_rng(2)
    background, pattern = background_and_object(rng, 48, 40, 6)
    frame = np.clip(paste(background, pattern, 1.1, 136.3, 100.7), 0, 255).astype(np.uint8)
    patches = [rng.integers(0, 256, size=(64, 64, 3), dtype=np.uint8), frame[90:154, 120:184], *edge_templates(64)]
    for patch in patches:
        assert np.array_equal(translation_features(patch), numpy_translation_features(patch))


def _scene(dx: float, dy: float, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A 48x40 textured object with its top-left corner at (136 + dx, 100 + dy) on a textured background."""
    background, pattern = background_and_object(np.random.default_rng(seed), 48, 40, 6)
    x, y = 136 + dx, 100 + dy
    frame = np.clip(np.rint(paste(background, pattern, 1.0, x, y)), 0, 255).astype(np.uint8)
    return frame, np.array([x, y, 48.0, 40.0])


@pytest.mark.parametrize("dx, dy", [(0.0, 0.0), (3.0, -2.0), (-6.5, 4.25), (10.0, 9.0)])
def test_translation_filter_finds_a_known_shift(dx, dy):
    first, box = _scene(0.0, 0.0)
    later, _ = _scene(dx, dy)
    translation_filter = TranslationFilter(32)
    state = state_from_box_xywh(box, 32)
    translation_filter.init(first, state)
    found = translation_filter.shift(later, state)  # asked at the old box: the object is (dx, dy) away
    assert np.hypot(found[0] - dx, found[1] - dy) <= 0.75, found


def test_translation_filter_answers_no_shift_on_the_frame_it_learned_and_needs_init():
    first, box = _scene(0.0, 0.0)
    state = state_from_box_xywh(box, 32)
    with pytest.raises(RuntimeError, match="before init"):
        TranslationFilter(32).shift(first, state)
    with pytest.raises(RuntimeError, match="before init"):
        TranslationFilter(32).update(first, state)
    translation_filter = TranslationFilter(32)
    translation_filter.init(first, state)
    assert np.allclose(translation_filter.shift(first, state), 0.0, atol=1e-9)
    translation_filter.update(first, state)
    assert np.allclose(translation_filter.shift(first, state), 0.0, atol=1e-9)


def test_shift_that_learns_equals_shift_then_update():
    first, box = _scene(0.0, 0.0)
    state = state_from_box_xywh(box, 32)
    learning, called = TranslationFilter(32), TranslationFilter(32)
    learning.init(first, state)
    called.init(first, state)
    for dx, dy in [(3.0, -2.0), (5.0, -1.0), (7.5, 0.5)]:
        frame, _ = _scene(dx, dy)
        assert learning.shift(frame, state, learn=True) == called.shift(frame, state)
        called.update(frame, state)
        np.testing.assert_array_equal(learning.correlation.numerator, called.correlation.numerator)
        np.testing.assert_array_equal(learning.correlation.denominator, called.correlation.denominator)
    frame, _ = _scene(9.0, 1.0)
    before = learning.correlation.numerator.copy()
    learning.shift(frame, state)  # learn defaults to False: the filter is left as it was
    np.testing.assert_array_equal(learning.correlation.numerator, before)


def test_the_reported_translation_filter_moves_only_the_reported_centre_and_brings_it_nearer():
    frames, boxes = moving_clip()
    one_run = dataclasses.replace(get_preset("robust"), independent_runs=1, reported_translation_filter=False)

    def track(params):
        return track_results(params, frames, boxes[0])

    plain = track(one_run)
    moved = track(dataclasses.replace(one_run, reported_translation_filter=True))
    # SPTPT's own run is untouched: the same scores and acceptance, and the same size, frame by frame.
    assert [r.log_likelihood for r in moved] == [r.log_likelihood for r in plain]
    assert [r.accepted for r in moved] == [r.accepted for r in plain]
    np.testing.assert_allclose([r.box_xywh[2:] for r in moved], [r.box_xywh[2:] for r in plain], atol=1e-9)
    # Only the centre differs, and it is nearer the object's on average.
    def centre_error(results):
        b = np.array([r.box_xywh for r in results])
        return np.hypot(b[:, 0] + b[:, 2] / 2 - boxes[1:, 0] - 22, b[:, 1] + b[:, 3] / 2 - boxes[1:, 1] - 18)
    assert not np.allclose(centre_error(moved), centre_error(plain))
    assert centre_error(moved).mean() < centre_error(plain).mean(), (
        centre_error(moved).round(1), centre_error(plain).round(1))
    # Same seed, same boxes.
    again = track(dataclasses.replace(one_run, reported_translation_filter=True))
    np.testing.assert_array_equal([r.box_xywh for r in again], [r.box_xywh for r in moved])
    # The filter learns from SPTPT's box, never from the box it moved: a filter replayed beside the filter-free run,
    # shifting at its boxes and learning from them on accepted frames, moves them exactly as the tracker did.
    replay = TranslationFilter(32)
    replay.init(frames[0], state_from_box_xywh(boxes[0], 32))
    for frame, own, got in zip(frames[1:], plain, moved):
        state = state_from_box_xywh(own.box_xywh, 32)
        dx, dy = replay.shift(frame, state)
        np.testing.assert_allclose(got.box_xywh, own.box_xywh + np.array([dx, dy, 0.0, 0.0]), rtol=0, atol=1e-6)
        if own.accepted:
            replay.update(frame, state)

"""The DSST scale filter (``sptpt.scale``): its features against a slow reference, and scale changes it must find."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _orientation_reference import edge_templates, numpy_orientation_split, slow_orientation_split
from _tracker_clips import background_and_object, growing_clip, paste, track_results

from sptpt.affine import state_from_box_xywh, warp_candidates
from sptpt.gradients import GREY
from sptpt.params import get_preset
from sptpt.scale import BINS, CELL, CLIP, STEP, ScaleFilter, orientation_histograms
from sptpt.tracker import Tracker


def slow_orientation_histograms(templates: np.ndarray, cell: int = CELL, bins: int = BINS) -> np.ndarray:
    """Pixel by pixel, as the docstring of orientation_histograms says."""
    out = []
    for template in np.asarray(templates, dtype=np.float64):
        grey = 0.299 * template[..., 0] + 0.587 * template[..., 1] + 0.114 * template[..., 2]
        size = grey.shape[0]
        cells = size // cell
        split = slow_orientation_split(grey, bins)
        hist = np.zeros((cells, cells, bins))
        for r in range(size):
            for c in range(size):
                hist[min(r // cell, cells - 1), min(c // cell, cells - 1)] += split[:, r, c]
        for cr in range(cells):
            for cc in range(cells):
                norm = math.sqrt(float((hist[cr, cc] ** 2).sum())) + 1e-3
                hist[cr, cc] = np.minimum(hist[cr, cc] / norm, CLIP)
        out.append(hist.reshape(-1))
    return np.array(out)


@pytest.mark.parametrize("size, cell, bins", [(32, CELL, BINS), (30, CELL, BINS), (24, 5, 6)])
def test_orientation_histograms_match_the_slow_reference(size, cell, bins):
    # 30 and 24 px leave pixels past the last whole cell: they join the last cell, in both implementations.
    rng = np.random.default_rng(0)
    templates = rng.integers(0, 256, size=(3, size, size, 3), dtype=np.uint8)
    templates[1] = 128  # flat: every histogram is 0
    fast = orientation_histograms(templates, cell=cell, bins=bins)
    np.testing.assert_allclose(fast, slow_orientation_histograms(templates, cell, bins), rtol=1e-12, atol=1e-12)
    assert fast.shape == (3, (size // cell) ** 2 * bins)
    assert not fast[1].any()


def numpy_orientation_histograms(templates: np.ndarray, cell: int = CELL, bins: int = BINS) -> np.ndarray:
    """``orientation_histograms`` as NumPy computed it before the kernel (``np.bincount`` per bin side)."""
    grey = np.asarray(templates, dtype=np.float64) @ GREY
    n, size, _ = grey.shape
    magnitude, lower, upper, upper_weight = numpy_orientation_split(grey, bins)
    cells = size // cell
    cell_of_pixel = np.minimum(np.arange(size) // cell, cells - 1)
    cell_index = ((cell_of_pixel[:, None] * cells + cell_of_pixel[None, :])[None]
                  + (np.arange(n) * cells * cells)[:, None, None])
    total = n * cells * cells * bins
    hist = np.bincount((cell_index * bins + lower).ravel(), (magnitude * (1 - upper_weight)).ravel(), total)
    hist += np.bincount((cell_index * bins + upper).ravel(), (magnitude * upper_weight).ravel(), total)
    hist = hist.reshape(n, cells * cells, bins)
    hist /= np.sqrt((hist ** 2).sum(axis=2, keepdims=True)) + 1e-3
    return np.minimum(hist, CLIP).reshape(n, -1)


@pytest.mark.parametrize("source", ["random", "frames", "edges"])
def test_orientation_histograms_are_the_numpy_codes_bits(source):
    # The kernel replaced NumPy code; the scale filter's answers, and so robust's boxes, depend on every bit.
    rng = np.random.default_rng(1)
    if source == "random":
        templates = rng.integers(0, 256, size=(40, 32, 32, 3), dtype=np.uint8)
    elif source == "frames":  # smooth images, as the filter's samples are: textures warped at 33 scales
        background, pattern = background_and_object(rng, 48, 40, 6)
        frame = np.clip(paste(background, pattern, 1.1, 136.3, 100.7), 0, 255).astype(np.uint8)
        states = np.repeat(state_from_box_xywh(np.array([130.0, 95.0, 60.0, 50.0]), 32)[None], 33, axis=0)
        states[:, 2] *= STEP ** np.arange(-16, 17)
        templates = warp_candidates(frame, states, 32)
    else:
        templates = edge_templates()
    assert np.array_equal(orientation_histograms(templates), numpy_orientation_histograms(templates))


def _scene(side_scale: float, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A 48x40 textured object scaled by ``side_scale`` about the point (160, 120) of a textured background."""
    background, pattern = background_and_object(np.random.default_rng(seed), 48, 40, 6)
    w, h = 48 * side_scale, 40 * side_scale
    x, y = 160 - w / 2, 120 - h / 2
    frame = np.clip(np.rint(paste(background, pattern, side_scale, x, y)), 0, 255).astype(np.uint8)
    return frame, np.array([x, y, w, h])


@pytest.mark.parametrize("change", [0.9, 1.0, 1.12])
def test_scale_filter_finds_a_known_scale_change(change):
    first, box = _scene(1.0)
    later, _ = _scene(change)
    scale_filter = ScaleFilter(32)
    state = state_from_box_xywh(box, 32)
    scale_filter.init(first, state)
    factor = scale_filter.factor(later, state)
    assert abs(math.log(factor / change)) <= 1.5 * math.log(STEP), factor


def test_scale_filter_answers_one_on_the_frame_it_learned_and_needs_init():
    first, box = _scene(1.0)
    state = state_from_box_xywh(box, 32)
    with pytest.raises(RuntimeError, match="before init"):
        ScaleFilter(32).factor(first, state)
    with pytest.raises(RuntimeError, match="before init"):
        ScaleFilter(32).update(first, state)
    scale_filter = ScaleFilter(32)
    scale_filter.init(first, state)
    assert scale_filter.factor(first, state) == 1.0
    scale_filter.update(first, state)
    assert scale_filter.factor(first, state) == 1.0


@pytest.mark.parametrize("learn", [True, False])
def test_step_equals_factor_then_update_at_the_new_scale(learn):
    # A growing object (the scale moves on some frames and stays on others), a frame where min_scale lifts the
    # scale, and frames where max_scale holds it where it is (the reuse path through a bound): step's one sampling
    # must leave the same scales and the same filter as the two calls, bit for bit.
    first, box = _scene(1.0)
    state = state_from_box_xywh(box, 32)
    stepped, called = ScaleFilter(32), ScaleFilter(32)
    stepped.init(first, state)
    called.init(first, state)
    stayed = moved = 0
    held = 0
    bounds = [(1.0, 0.0, np.inf), (1.06, 0.0, np.inf), (1.06, 0.0, np.inf), (1.12, 0.0, np.inf), (1.12, 0.0, np.inf),
              (1.3, 0.0, "hold"), (1.3, 0.0, "hold"), (0.95, 10.0, np.inf)]
    for change, min_scale, max_scale in bounds:
        frame, _ = _scene(change)
        if max_scale == "hold":  # the object has grown past the state's scale; the bound keeps it there
            max_scale = float(state[2])
            held += called.factor(frame, state) > 1
        stepped.min_scale, stepped.max_scale = min_scale, max_scale
        scale = stepped.step(frame, state, learn=learn)
        expected = min(max(float(state[2]) * called.factor(frame, state), min_scale), max_scale)
        assert scale == expected
        if learn:
            new_state = state.copy()
            new_state[2] = expected
            called.update(frame, new_state)
        np.testing.assert_array_equal(stepped.correlation.numerator, called.correlation.numerator)
        np.testing.assert_array_equal(stepped.correlation.denominator, called.correlation.denominator)
        stayed, moved = stayed + (scale == state[2]), moved + (scale != state[2])
        state = state.copy()
        state[2] = scale
    assert stayed and moved and held == 2  # both of step's paths were taken, one through the upper bound
    assert scale == 10.0  # and the last frame was lifted to min_scale
    with pytest.raises(RuntimeError, match="before init"):
        ScaleFilter(32).step(first, state, learn=True)


#: Frames after the first that a same-seed rerun compares.
AGAIN = 16


def test_tracker_with_the_scale_filter_follows_a_growing_object():
    import dataclasses

    frames, boxes = growing_clip()
    params = dataclasses.replace(get_preset("robust"), scale_filter=True, reported_scale_filter=False,
                                 reported_translation_filter=False)
    tracker = Tracker(params, seed=0)
    tracker.init(frames[0], boxes[0])
    tracked = np.array([tracker.update(frame).box_xywh for frame in frames[1:]])
    side = np.sqrt(tracked[:, 2] * tracked[:, 3] / (boxes[1:, 2] * boxes[1:, 3]))
    assert np.all(np.abs(np.log(side[-10:])) < math.log(1.15)), side.round(2)
    # Same seed, same boxes: the scale filter learns from the first update on, so a third of the clip tells.
    again = Tracker(params, seed=0)
    again.init(frames[0], boxes[0])
    np.testing.assert_array_equal(tracked[:AGAIN], [again.update(frame).box_xywh for frame in frames[1 : AGAIN + 1]])


def test_the_reported_scale_filter_sizes_the_box_and_leaves_the_search_alone():
    import dataclasses

    frames, boxes = growing_clip()
    # Without the translation filter, which would move the reported centre.
    one_run = dataclasses.replace(get_preset("robust"), independent_runs=1, reported_scale_filter=False,
                                  reported_translation_filter=False)

    def track(params):
        return track_results(params, frames, boxes[0])

    plain = track(one_run)
    sized = track(dataclasses.replace(one_run, reported_scale_filter=True))
    # SPTPT's own run is untouched: the same scores, acceptance and centres, frame by frame.
    assert [r.log_likelihood for r in sized] == [r.log_likelihood for r in plain]
    assert [r.accepted for r in sized] == [r.accepted for r in plain]

    def centre(rs):
        return np.array([[r.box_xywh[0] + r.box_xywh[2] / 2, r.box_xywh[1] + r.box_xywh[3] / 2] for r in rs])

    np.testing.assert_allclose(centre(sized), centre(plain), atol=1e-9)
    # Only the size differs, and it follows the object where the candidates' scale lags.
    def side(rs):
        b = np.array([r.box_xywh for r in rs])
        return np.sqrt(b[:, 2] * b[:, 3] / (boxes[1:, 2] * boxes[1:, 3]))
    assert np.all(np.abs(np.log(side(sized)[-10:])) < math.log(1.15)), side(sized).round(2)
    assert np.mean(np.abs(np.log(side(sized)[-10:]))) < np.mean(np.abs(np.log(side(plain)[-10:]))), (
        side(sized).round(2), side(plain).round(2))
    # Same seed, same boxes.
    again = track_results(dataclasses.replace(one_run, reported_scale_filter=True), frames[: AGAIN + 1], boxes[0])
    np.testing.assert_array_equal([r.box_xywh for r in again], [r.box_xywh for r in sized[:AGAIN]])


def test_on_black_frames_the_reported_box_stops_at_the_frame_size():
    import dataclasses

    # Black as the samples' padding, the frames give the scale filter a flat response, whose peak is its largest
    # scale: unbounded, the reported box grew by 1.37 a frame.
    frames, boxes = growing_clip(6)
    black = np.zeros((25,) + frames.shape[1:], np.uint8)
    one_run = dataclasses.replace(get_preset("robust"), independent_runs=1)
    got = np.array([r.box_xywh for r in track_results(one_run, np.concatenate([frames, black]), boxes[0])])
    assert np.isfinite(got).all()
    assert got[:, 2].max() <= max(frames.shape[1:3]) + 1e-9
    assert got[-1, 2] > 2 * boxes[0, 2]  # it did grow, up to the bound


def test_the_two_scale_filters_are_exclusive():
    import dataclasses

    with pytest.raises(ValueError, match="reported_scale_filter=True is invalid.*scale_filter"):
        dataclasses.replace(get_preset("paper"), scale_filter=True, reported_scale_filter=True)

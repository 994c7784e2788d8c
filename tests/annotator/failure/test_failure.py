"""The failure probability: each signal moves where a synthetic track fails, online equals offline, the model
file is checked field by field and refits reproducibly, calibration metrics are exact, and bad input is refused.
"""

from __future__ import annotations

import dataclasses
import json
import re
import zlib

import cv2
import numpy as np
import pytest
from _paths import ROOT
from typer.testing import CliRunner

import sptpt.contrast as contrast_module
from annotator.cli import _with_default_command, app
from annotator.evaluation.calibration import auroc, expected_calibration_error, reliability
from annotator.failure import (
    FEATURES,
    SIGNALS,
    FailureModelError,
    SignalMeter,
    TrackDoubt,
    feature_matrix,
    load_model,
    particle_stats,
    score_track,
)
from annotator.failure.fit import (
    TARGET_PRECISION,
    TARGET_RECALL,
    THRESHOLD_FLAGS,
    THRESHOLD_GRID,
    UNCHOSEN_THRESHOLD,
    Sample,
    backward_elimination,
    choose_C,
    choose_groups,
    choose_threshold,
    fit_model,
    fit_pass_agreement,
    group_features,
    leave_one_video_out,
    platt,
    video,
)
from annotator.failure.model import MODEL_FORMAT, MODEL_VERSION, OnlineFailure, PassAgreement, model_from_fit
from annotator.failure.signals import MOTION_SIGNALS
from annotator.flagging import REASONS, FlagParams, flag_p_fail
from sptpt.contrast import CONTRAST_PIXELS, colour_contrast
from sptpt.params import get_preset
from sptpt_dev.synthetic import changing_object, make_clip

FAIL_AT = 12


@pytest.fixture(scope="module")
def clip():
    return make_clip(24, size=(160, 120), object_size=(32, 28), seed=3)


def measure(clip, boxes, frames=None) -> dict[str, np.ndarray]:
    """Signals of a pass that reports ``boxes`` over the clip (tracker scores fixed: only the images and boxes vary)."""
    frames = clip.frames if frames is None else frames
    meter = SignalMeter()
    rows = [meter.first(frames[0], boxes[0])]
    for k in range(1, len(frames)):
        rows.append(meter.next(frames[k], boxes[k], log_likelihood=5.0, scoring="subspace", accepted=True))
    return {name: np.array([r[name] for r in rows]) for name in SIGNALS}


def background_box(clip, k: int) -> np.ndarray:
    """A box of the object's size on background, far from the object at frame k."""
    x, y, w, h = clip.boxes_xywh[k]
    return np.array([(x + 70) % (160 - w), (y + 50) % (120 - h), w, h])


def test_flow_appearance_and_motion_signals_move_where_the_box_slides_onto_background(clip):
    truth = measure(clip, clip.boxes_xywh)
    lost = clip.boxes_xywh.copy()
    for k in range(FAIL_AT, len(lost)):
        lost[k] = background_box(clip, k)
    failed = measure(clip, lost)
    before = slice(1, FAIL_AT)
    # Up to the failure the signals are those of the true track.
    for name in SIGNALS:
        np.testing.assert_array_equal(failed[name][before], truth[name][before], err_msg=name)
    # At the failure: the flow no longer carries the previous box onto this one, the patch no longer looks
    # like the first frame's or the previous frame's, and the box jumped.
    assert failed["flow_iou"][FAIL_AT] < 0.2 < truth["flow_iou"][before].min()
    assert failed["ncc_first"][FAIL_AT] < truth["ncc_first"][before].min() - 0.2
    assert failed["ncc_prev"][FAIL_AT] < truth["ncc_prev"][before].min() - 0.2
    assert failed["ncc_memory"][FAIL_AT:].max() < truth["ncc_memory"][before].min() - 0.2
    assert failed["jump"][FAIL_AT] > 1.0 > truth["jump"][before].max()
    # On background the box's colours are those around it; on the object they differ, all along the track.
    assert failed["contrast"][FAIL_AT:].max() < 0.2 < 0.5 < truth["contrast"][1:].min()
    assert np.isnan(truth["contrast"][0])  # the given box: not measured, as re-tracking stores its anchors


def _lost_boxes(clip) -> np.ndarray:
    """The clip's true boxes, but on background from FAIL_AT on: a run that has lost the object."""
    lost = clip.boxes_xywh.copy()
    for k in range(FAIL_AT, len(lost)):
        lost[k] = background_box(clip, k)
    return lost


def _run_signals(clip, run_boxes) -> dict[str, np.ndarray]:
    """``run_iou`` and ``run_support`` of frames 1.. when the tracker reports the true box and its runs' boxes are
    ``run_boxes`` (``(F, R, 4)``)."""
    meter = SignalMeter()
    meter.first(clip.frames[0], clip.boxes_xywh[0])
    rows = [meter.next(clip.frames[k], clip.boxes_xywh[k], log_likelihood=5.0, scoring="subspace", accepted=True,
                       run_boxes_xywh=run_boxes[k]) for k in range(1, len(clip.frames))]
    return {name: np.array([row[name] for row in rows]) for name in ("run_iou", "run_support")}


def test_run_agreement_falls_where_one_run_slides_onto_background(clip):
    lost = _lost_boxes(clip)
    # The tracker reports the true box (the first run) while its second run has lost the object.
    signals = _run_signals(clip, np.stack([clip.boxes_xywh, lost], axis=1))
    agreement = signals["run_iou"]
    np.testing.assert_allclose(agreement[: FAIL_AT - 1], 1.0)  # both runs on the object: full agreement
    assert agreement[FAIL_AT - 1:].max() < 0.1
    # With two runs, the second nearest run is the farthest.
    np.testing.assert_array_equal(signals["run_support"], agreement)
    # One run: nothing to compare, not measured (NaN), and not measured on the given box either.
    assert np.isnan(measure(clip, lost)["run_iou"]).all()
    assert np.isnan(measure(clip, lost)["run_support"]).all()
    # Three runs: the lowest agreement with any of them, and the second highest.
    box = np.array([0.0, 0.0, 10.0, 10.0])
    meter = SignalMeter()
    meter.first(clip.frames[0], box)
    three = meter.next(clip.frames[1], box, log_likelihood=5.0, scoring="subspace", accepted=True,
                       run_boxes_xywh=np.array([box, [5.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 5.0]]))
    assert three["run_iou"] == pytest.approx(1 / 3)
    assert three["run_support"] == pytest.approx(1 / 2)


def test_run_support_stays_while_one_of_three_runs_is_lost_and_falls_when_two_are(clip):
    truth, lost = clip.boxes_xywh, _lost_boxes(clip)
    one_lost = _run_signals(clip, np.stack([truth, truth, lost], axis=1))
    # The reported box stays with the one run that kept the object; the two others have left it.
    two_lost = _run_signals(clip, np.stack([truth, lost, lost], axis=1))
    after = slice(FAIL_AT - 1, None)
    np.testing.assert_allclose(one_lost["run_support"], 1.0)  # a second run backs the box throughout
    assert one_lost["run_iou"][after].max() < 0.1  # while the farthest run has gone
    np.testing.assert_allclose(two_lost["run_support"][: FAIL_AT - 1], 1.0)
    assert two_lost["run_support"][after].max() < 0.1  # no second run backs the box once two have gone


def test_a_signal_not_measured_neither_raises_nor_lowers_p_fail():
    model = load_model()
    n = 12
    rng = np.random.default_rng(5)
    signals = {name: rng.uniform(0, 1, n) for name in SIGNALS}
    keyframe = np.zeros(n, bool)
    keyframe[0] = True
    one_run = {**signals, "run_iou": np.full(n, np.nan)}
    features = feature_matrix(one_run, keyframe)
    cols = [FEATURES.index("run_iou"), FEATURES.index("run_iou_w5")]
    assert np.isnan(features[:, cols]).all()
    # The same as the run features sitting at the model's training mean: they add nothing to the log-odds.
    at_mean = features.copy()
    at_mean[:, cols] = model.mean[cols]
    np.testing.assert_array_equal(model.p_fail(features), model.p_fail(at_mean))
    # Partly measured windows average what was measured: frame 0 (a given box) is NaN, frames 1-2 are not.
    two_runs = {**signals, "run_iou": np.concatenate([[np.nan], signals["run_iou"][1:]])}
    w5 = feature_matrix(two_runs, keyframe)[:, FEATURES.index("run_iou_w5")]
    assert w5[0] == pytest.approx(two_runs["run_iou"][1:3].mean())
    # Online, frame by frame, the same bits.
    online = OnlineFailure(model)
    scored = []
    for t in range(n):
        scored += online.push({k: v[t] for k, v in one_run.items()}, keyframe=bool(keyframe[t]))
    scored += online.finish()
    np.testing.assert_array_equal([p for _, p, _ in scored], model.p_fail(features))


def test_the_object_swapped_for_background_lowers_the_appearance_signals(clip):
    frames = [f.copy() for f in clip.frames]
    for k in range(FAIL_AT, len(frames)):
        x, y, w, h = (int(round(v)) for v in clip.boxes_xywh[k])
        frames[k][y:y + h, x:x + w] = cv2.blur(frames[k], (31, 31))[y:y + h, x:x + w]  # object gone, blur left
    truth = measure(clip, clip.boxes_xywh)
    swapped = measure(clip, clip.boxes_xywh, frames)
    assert swapped["ncc_first"][FAIL_AT] < truth["ncc_first"][1:FAIL_AT].min() - 0.3
    assert swapped["ncc_prev"][FAIL_AT] < truth["ncc_prev"][1:FAIL_AT].min() - 0.3
    assert swapped["ncc_memory"][FAIL_AT] < truth["ncc_memory"][1:FAIL_AT].min() - 0.3
    assert swapped["contrast"][FAIL_AT:].max() < truth["contrast"][1:FAIL_AT].min() - 0.1


def _turning_object(frames: int, seed: int = 7) -> tuple[list[np.ndarray], np.ndarray]:
    """A still box over an object whose texture turns, frame by frame, from one random pattern into another."""
    rng = np.random.default_rng(seed)
    before, after = (cv2.resize(rng.uniform(0, 255, (8, 8, 3)), (40, 40), interpolation=cv2.INTER_NEAREST)
                     for _ in range(2))
    video = []
    for k in range(frames):
        frame = np.full((120, 160, 3), 128.0)
        frame[40:80, 60:100] = before + (after - before) * k / (frames - 1)
        video.append(frame.astype(np.uint8))
    return video, np.tile([60.0, 40.0, 40.0, 40.0], (frames, 1))


def test_the_memory_signal_holds_while_the_object_turns_where_the_first_frame_loses_it():
    video, boxes = _turning_object(81)
    meter = SignalMeter()
    meter.first(video[0], boxes[0])
    rows = [meter.next(video[k], boxes[k], log_likelihood=5.0, scoring="subspace", accepted=True)
            for k in range(1, len(video))]
    last = rows[-1]
    # The object at the end looks unlike its first frame but like its recent past, which the memory holds.
    assert last["ncc_first"] < 0.2
    assert last["ncc_memory"] > last["ncc_first"] + 0.3


def slow_ncc_memory(patches: list, position: int, every: int, size: int) -> float:
    """``ncc_memory`` at ``position`` by its definition: the median NCC with the patches of the pass's first frame
    and of every ``every``-th frame after it, at least ``every`` frames old (frames whose box missed the image
    have no patch); when more than ``size`` would be kept, the spacing doubles until they fit."""
    from annotator.failure.signals import MEMORY_EVERY, _ncc

    spacing = every
    while True:
        kept = [j for j in range(0, position - MEMORY_EVERY + 1, spacing) if patches[j] is not None]
        if patches[0] is not None and 0 not in kept:
            kept.insert(0, 0)
        if len(kept) <= size:
            break
        spacing *= 2
    if patches[position] is None or not kept:
        return 0.0
    return float(np.median([_ncc(patches[position], patches[j]) for j in kept]))


@pytest.mark.parametrize("size", [200, 3])
def test_the_memory_signal_equals_its_definition_frame_by_frame(clip, monkeypatch, size):
    import annotator.failure.signals as signals_module
    from annotator.failure.signals import MEMORY_EVERY, _patch, grey_of

    monkeypatch.setattr(signals_module, "MEMORY_SIZE", size)
    rng = np.random.default_rng(11)
    frames = [clip.frames[k % len(clip.frames)] for k in range(95)]
    boxes = [clip.boxes_xywh[k % len(clip.frames)] + np.r_[rng.normal(0, 3, 2), 0, 0] for k in range(95)]
    for k in (30, 33, 50):  # off the image: no patch to compare (33) or to remember (30, 50)
        boxes[k] = np.array([400.0, 400.0, 20.0, 20.0])
    patches = [_patch(grey_of(f), b) for f, b in zip(frames, boxes)]
    got = measure(clip, boxes, frames)["ncc_memory"]
    assert got[0] == 1.0
    expected = [slow_ncc_memory(patches, k, MEMORY_EVERY, size) for k in range(1, len(frames))]
    np.testing.assert_allclose(got[1:], expected, atol=1e-12)


def test_the_memory_stays_bounded_where_thinning_alone_forgets_nothing(monkeypatch):
    import annotator.failure.signals as signals_module

    monkeypatch.setattr(signals_module, "MEMORY_SIZE", 4)
    memory = signals_module._PatchMemory()
    patch = np.full((32, 32), 1 / 32.0)
    for k in range(400):
        # No patch at 10, 30, 50, ...: the kept ones are already multiples of 20 when the spacing first doubles.
        memory.add(None if k % 20 == 10 else patch)
        assert len(memory._kept) <= 4


def test_a_flag_reason_never_names_a_group_the_model_leaves_out():
    from annotator.failure.model import FEATURE_GROUPS

    left_out = ("drift", "score")
    coef = np.array([0.0 if FEATURE_GROUPS[f] in left_out else -1.0 for f in FEATURES])
    model = model_from_fit(FEATURES, np.zeros(len(FEATURES)), np.ones(len(FEATURES)), coef, 0.0, 0.9, {})
    # Every feature above its mean: every group the model weighs lowers the log-odds, the left-out ones add 0.
    groups = model.main_group(np.ones((3, len(FEATURES))))
    assert groups and not set(groups) & set(left_out)


def slow_contrast(frame_rgb: np.ndarray, box, contrast_pixels: int = CONTRAST_PIXELS, min_pixels: int = 100) -> float:
    """The contrast signal written out pixel by pixel: HSV histograms (8 x 4 x 4 bins) of the box and of the ring
    around it (the box scaled by sqrt(2) about its centre, minus the box), then 1 - Bhattacharyya coefficient.
    A box with ``4 * contrast_pixels`` pixels or more inside the frame counts only the pixels of every k-th row and
    column from the ring's top left, k the largest that leaves ``contrast_pixels`` of the box's area inside the
    frame to each k x k block."""
    x, y, w, h = box
    height, width = frame_rgb.shape[:2]
    hsv = cv2.cvtColor(np.ascontiguousarray(frame_rgb), cv2.COLOR_RGB2HSV).astype(int)
    cx, cy, s = x + w / 2, y + h / 2, np.sqrt(2.0)
    inside_frame = max(min(x + w, width) - max(x, 0), 0) * max(min(y + h, height) - max(y, 0), 0)
    k = 1
    while inside_frame >= (k + 1) ** 2 * contrast_pixels:
        k += 1
    left, top = max(round(cx - w * s / 2), 0), max(round(cy - h * s / 2), 0)
    inside, around = np.zeros(128), np.zeros(128)
    for r in range(height):
        for c in range(width):
            if (r - top) % k or (c - left) % k:
                continue
            in_box = round(x) <= c < round(x + w) and round(y) <= r < round(y + h)
            in_ring = (round(cx - w * s / 2) <= c < round(cx + w * s / 2)
                       and round(cy - h * s / 2) <= r < round(cy + h * s / 2))
            b = (hsv[r, c, 0] * 8 // 180) * 16 + (hsv[r, c, 1] * 4 // 256) * 4 + hsv[r, c, 2] * 4 // 256
            if in_box:
                inside[b] += 1
            elif in_ring:
                around[b] += 1
    if inside.sum() < min_pixels or around.sum() < min_pixels:  # too few pixels to compare histograms
        return float("nan")
    return 1.0 - float(np.sqrt(inside / inside.sum() * around / around.sum()).sum())


@pytest.mark.parametrize("box", [(60.3, 40.6, 32.0, 28.0), (-8.0, 50.0, 30.0, 20.0), (140.0, 100.0, 30.0, 30.0),
                                 (20.0, -12.0, 24.0, 30.0), (10.0, 10.0, 10.0, 10.0), (10.0, 10.0, 11.0, 11.0)])
def test_the_contrast_signal_equals_its_pixel_by_pixel_definition(clip, box):
    frame = clip.frames[5]
    assert colour_contrast(frame, np.array(box)) == pytest.approx(slow_contrast(frame, box), abs=1e-6, nan_ok=True)


@pytest.mark.parametrize("contrast_pixels", [150, 120, 60])
@pytest.mark.parametrize("box", [(60.3, 40.6, 32.0, 28.0), (-8.0, 50.0, 40.0, 30.0), (131.0, 97.0, 30.0, 30.0),
                                 (20.0, -12.5, 33.0, 41.0), (10.0, 8.0, 140.0, 100.0), (70.0, 10.0, 27.0, 29.0)])
def test_a_big_box_is_measured_on_every_kth_pixel_as_its_definition_says(clip, box, contrast_pixels, monkeypatch):
    # The frame is small, so the sampling's threshold (and the fewest pixels compared) are lowered for the test:
    # steps of 2 to 15, boxes cut by the frame's edges on every side.
    monkeypatch.setattr(contrast_module, "CONTRAST_PIXELS", contrast_pixels)
    monkeypatch.setattr(contrast_module, "_MIN_PIXELS", 5)
    frame = clip.frames[5]
    x, y, w, h = box
    assert contrast_module.sampling_step(min(x + w, 160) - max(x, 0), min(y + h, 120) - max(y, 0)) > 1
    expected = slow_contrast(frame, box, contrast_pixels, min_pixels=5)
    assert np.isfinite(expected)
    assert colour_contrast(frame, np.array(box)) == pytest.approx(expected, abs=1e-6)


def test_boxes_of_otb_sizes_are_measured_whole_and_a_big_one_keeps_its_contrast():
    from sptpt.contrast import sampling_step

    # Every box under 4 x CONTRAST_PIXELS pixels, as every box of OTB's frame sizes is, is measured whole.
    assert sampling_step(255, 256) == 1 and sampling_step(2000, 32) == 1 and sampling_step(256, 256) == 2
    assert sampling_step(500, 500) == 3 and sampling_step(1900, 1000) == 10
    # A 1080p frame of an object in smooth colour (a small picture enlarged) and its sampled measure: within 0.01
    # of the whole box's, for boxes on the object, half on it and on the background.
    rng = np.random.default_rng(4)
    small = rng.integers(0, 256, (27, 48, 3), dtype=np.uint8)
    small[8:20, 15:30] = (200, 40, 40)
    frame = cv2.resize(small, (1920, 1080), interpolation=cv2.INTER_LINEAR)
    for box in ([600.0, 320.0, 600.0, 480.0], [900.0, 320.0, 600.0, 480.0], [40.0, 40.0, 300.0, 250.0]):
        sampled = colour_contrast(frame, np.array(box))
        assert sampling_step(box[2], box[3]) >= 2
        assert sampled == pytest.approx(slow_contrast_whole(frame, box), abs=0.01)


def test_the_sampling_step_follows_the_part_of_the_box_inside_the_frame():
    frame = cv2.resize(np.random.default_rng(5).integers(0, 256, (27, 48, 3), dtype=np.uint8), (1920, 1080))
    # 800x800 nominal, 40x80 inside the frame: read whole, as its visible part is small, not NaN for too few pixels.
    corner = [1880.0, 1000.0, 800.0, 800.0]
    assert colour_contrast(frame, np.array(corner)) == pytest.approx(slow_contrast_whole(frame, corner), abs=1e-9)
    # A box too big for w * h to be a number: no error; it covers the frame, so no ring is left to compare with.
    assert np.isnan(colour_contrast(frame, np.array([-10.0, -10.0, 1e200, 1e200])))


def slow_contrast_whole(frame_rgb: np.ndarray, box) -> float:
    """:func:`colour_contrast` on every pixel of the box and its ring, however big (OpenCV's histograms)."""
    x, y, w, h = box
    s = np.sqrt(2.0)
    cx, cy = x + w / 2, y + h / 2
    rows = np.arange(frame_rgb.shape[0])[:, None]
    cols = np.arange(frame_rgb.shape[1])[None, :]
    in_box = (round(x) <= cols) & (cols < round(x + w)) & (round(y) <= rows) & (rows < round(y + h))
    in_ring = ((round(cx - w * s / 2) <= cols) & (cols < round(cx + w * s / 2))
               & (round(cy - h * s / 2) <= rows) & (rows < round(cy + h * s / 2)) & ~in_box)
    hsv = cv2.cvtColor(np.ascontiguousarray(frame_rgb), cv2.COLOR_RGB2HSV)
    inside, around = (cv2.calcHist([hsv], [0, 1, 2], mask.astype(np.uint8), [8, 4, 4], [0, 180, 0, 256, 0, 256]).ravel()
                      for mask in (in_box, in_ring))
    return 1.0 - float(np.sqrt(inside / inside.sum() * around / around.sum()).sum())


def test_the_contrast_of_a_box_off_the_image_is_not_measured(clip):
    frame = clip.frames[0]
    for box in ([200.0, 10.0, 20.0, 20.0], [10.0, -60.0, 20.0, 20.0], [10.0, 10.0, 0.0, 5.0], [np.nan, 1.0, 5.0, 5.0]):
        assert np.isnan(colour_contrast(frame, np.array(box))), box
    # A uniform image: the box and its ring have the same colours.
    assert colour_contrast(np.full((50, 60, 3), 90, np.uint8), np.array([20.0, 15.0, 20.0, 15.0])) == pytest.approx(0.0)
    # Colour noise: box and ring are two samples of one distribution, which look alike once they are large enough;
    # histograms of fewer than 100 pixels are not compared at all.
    noise = np.random.default_rng(0).integers(0, 256, (200, 200, 3), dtype=np.uint8)
    assert colour_contrast(noise, np.array([70.0, 70.0, 48.0, 48.0])) < 0.05
    assert np.isnan(colour_contrast(noise, np.array([70.0, 70.0, 9.0, 9.0])))


def test_score_signals_follow_the_tracker_and_the_candidates():
    box = np.array([40.0, 40.0, 20.0, 20.0])
    rng = np.random.default_rng(0)
    centres = rng.normal(50, 1, (200, 2))
    particles = np.column_stack([centres - 10, np.full((200, 2), 20.0)])
    peaked = np.concatenate([[10.0], rng.normal(0, 0.1, 199)])
    flat = rng.normal(0, 0.1, 200)
    gap_peaked, spread_tight = particle_stats(particles, peaked, box)
    gap_flat, _ = particle_stats(particles, flat, box)
    assert gap_peaked > 5 * gap_flat
    wide = np.column_stack([rng.uniform(0, 150, (200, 2)) - 10, np.full((200, 2), 20.0)])
    _, spread_wide = particle_stats(wide, flat, box)
    assert spread_wide > 5 * spread_tight
    assert particle_stats(None, None, box) == (0.0, 0.0)


def random_signals(rng, n: int) -> dict[str, np.ndarray]:
    signals = {name: rng.uniform(0, 1, n) for name in SIGNALS}
    signals["log_likelihood"] = rng.normal(3, 4, n)
    signals["bootstrap"] = (np.arange(n) < 4).astype(float)
    return signals


def test_online_failure_equals_the_whole_track_computation():
    rng = np.random.default_rng(5)
    model = load_model()
    for n in (0, 1, 2, 3, 7, 40, 130):
        signals = random_signals(rng, n)
        keyframe = np.zeros(n, bool)
        keyframe[:1] = True
        keyframe[n // 2: n // 2 + 1] = n > 4
        expected = model.p_fail(feature_matrix(signals, keyframe)) if n else np.zeros(0)
        online = OnlineFailure(model)
        got = []
        for t in range(n):
            got += online.push({k: v[t] for k, v in signals.items()}, bool(keyframe[t]))
        got += online.finish()
        assert [pos for pos, _, _ in got] == list(range(n))
        np.testing.assert_allclose([p for _, p, _ in got], expected, rtol=0, atol=1e-12)


def test_track_doubt_equals_score_track_then_flags():
    rng = np.random.default_rng(6)
    model = load_model()
    params = FlagParams(threshold=0.4, merge_gap=2, min_span=2)
    n = 90
    signals = random_signals(rng, n)
    keyframe = np.zeros(n, bool)
    keyframe[[0, 50]] = True
    doubt = TrackDoubt(model, params)
    decided = []
    for t in range(n):
        out = doubt.push({k: v[t] for k, v in signals.items()}, bool(keyframe[t]))
        assert all(pos == t - doubt.lag for pos, *_ in out)
        decided += out
    decided += doubt.finish()
    p_fail, groups = score_track(signals, keyframe, np.zeros(n, bool), model)
    expected = flag_p_fail(p_fail, groups, 0.4, params, keyframe=keyframe)
    np.testing.assert_allclose([p for _, p, _, _ in decided], p_fail, atol=1e-12)
    assert [f for _, _, f, _ in decided] == expected.flagged.tolist()
    assert [r for _, _, _, r in decided] == list(expected.reasons)
    assert p_fail[0] == 0 and p_fail[50] == 0


@pytest.mark.parametrize("guided", [False, True])
def test_the_shipped_model_loads_with_its_fields_and_versions(guided):
    model = load_model(guided=guided)
    assert model.features == FEATURES and model.mean.shape == model.coef.shape == (len(FEATURES),)
    assert 0 < model.threshold < 1 and np.all(model.scale > 0)
    data = json.loads(json.dumps(model.to_json()))
    assert data["format"] == MODEL_FORMAT and data["version"] == MODEL_VERSION
    assert "fitted_by" in model.info or "note" in model.info  # says how it was made
    assert model.info["calibration"]["slope"] > 0  # recalibrated on held-out sequences (fit_model)


def test_runs_with_and_without_a_learned_tracker_each_get_the_model_fitted_on_their_kind():
    # The guided model leans on where SPTPT parts from the learned tracker; a run without one never measures that
    # (NaN sits at the training mean), so it must keep the model fitted on runs like it.
    plain, guided = load_model(), load_model(guided=True)
    guide_features = [FEATURES.index(name) for name in FEATURES if name.startswith("guide_")]
    assert not plain.coef[guide_features].any() and guided.coef[guide_features].any()
    assert get_preset(plain.info["data"]["preset"]).uses_guide is False
    assert get_preset(guided.info["data"]["preset"]).uses_guide is True


def test_the_flag_reasons_page_names_the_groups_each_shipped_model_reads():
    # docs/flags.md tells users which doubt:<group> reasons they will see; a refit that changes the model's
    # non-zero weights must change the page too (it went stale once, when the guided model was refitted).
    text = " ".join((ROOT / "docs" / "flags.md").read_text(encoding="utf-8").split())
    said = {}
    for who, pattern in (("fused", r"`fused`'s model reads the ([a-z, ]+?) groups"),
                         ("other", r"The model of the other presets reads the ([a-z, ]+?) groups")):
        found = re.search(pattern, text)
        assert found, f"docs/flags.md no longer says which groups {who}'s model reads"
        said[who] = set(re.split(r", | and ", found[1].replace(" and ", ", ")))
    assert said["fused"] == set(load_model(guided=True).weighed_groups)
    assert said["other"] == set(load_model().weighed_groups)


@pytest.mark.parametrize("edit, fragment", [
    (lambda d: d.update(format="something else"), "is not a sptpt-annotate failure model"),
    (lambda d: d.update(version=99), "has version 99"),
    (lambda d: d.update(features=d["features"][:-1]), f"(it lacks {FEATURES[-1]})"),
    (lambda d: d.update(features=[*d["features"][:-1], "tea_leaves"]),
     f"(it lacks {FEATURES[-1]}; has tea_leaves, which this version does not compute)"),
    (lambda d: d.update(features=d["features"][::-1]), "(it lists them in another order)"),
    (lambda d: d.update(coef=d["coef"][:3]), "coef must be"),
    (lambda d: d.update(threshold=1.5), "threshold in (0, 1)"),
    (lambda d: d.pop("intercept"), "lacks or garbles"),
    (lambda d: d.update(between_anchors={"log_odds": 1.0, "pass_iou": -4.0}), "between_anchors section lacks"),
    (lambda d: d.update(between_anchors={"log_odds": 1.0, "pass_iou": "x", "intercept": 1.0}), "garbles"),
    (lambda d: d.update(between_anchors={"log_odds": 1.0, "pass_iou": float("inf"), "intercept": 1.0}),
     "must be finite"),
    (lambda d: d.update(between_anchors=[1, 2, 3]), "between_anchors section lacks or garbles"),
])
def test_a_foreign_or_damaged_model_file_is_refused(tmp_path, edit, fragment):
    data = load_model().to_json()
    edit(data)
    path = tmp_path / "model.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FailureModelError, match=str(path)) as info:
        load_model(path)
    assert fragment in str(info.value) and "\n" not in str(info.value)
    (tmp_path / "broken.json").write_text('{"format": ')
    with pytest.raises(FailureModelError, match=r"broken.json:1: not valid JSON"):
        load_model(tmp_path / "broken.json")


def small_samples() -> list[Sample]:
    samples = []
    for k, name in enumerate(["A", "B", "C", "D"]):
        n = 60
        failed = np.arange(n) > 30 + 5 * k
        # Each column drawn from its own generator, named by the feature: a feature added later leaves the others'
        # numbers as they were.
        features = np.stack([np.random.default_rng([11, k, zlib.crc32(f.encode())]).normal(0, 1, n)
                             for f in FEATURES], axis=1)
        features[:, FEATURES.index("flow_iou")] -= 2.0 * failed
        use = np.ones(n, bool)
        use[0] = False
        samples.append(Sample(name, 0, features, failed, use))
    return samples


def test_refitting_on_fixed_input_reproduces_the_model_file():
    first = fit_model(small_samples(), C=0.1, info={"data": "fixed"})
    second = fit_model(small_samples(), C=0.1, info={"data": "fixed"})
    assert json.dumps(first.to_json()) == json.dumps(second.to_json())
    # The fitted signal is the one that separates failures, and the file round-trips exactly.
    assert first.coef[FEATURES.index("flow_iou")] < 0
    assert model_from_fit(FEATURES, first.mean, first.scale, first.coef, first.intercept, first.threshold,
                          first.info).to_json() == first.to_json()


def test_choose_C_takes_the_grid_value_that_ranks_held_out_failures_best():
    samples = small_samples()
    grid = [1.0, 0.01, 0.0001]
    scores = {}
    for c in grid:  # the reference: leave-one-video-out by hand, pooled AUROC of the uncalibrated folds
        p, y = [], []
        for model, held in leave_one_video_out(samples, C=c, calibrate=False).values():
            p += [model.p_fail(s.features)[s.use] for s in held]
            y += [s.failed[s.use] for s in held]
        scores[c] = auroc(np.concatenate(p), np.concatenate(y))
    assert len(set(scores.values())) == 3  # the grid matters on these samples
    assert choose_C(samples, grid) == max(grid, key=lambda c: (scores[c], -c))


def test_platt_recovers_a_known_slope_and_offset():
    rng = np.random.default_rng(3)
    logit = rng.normal(0, 2, 20000)
    failed = rng.random(20000) < 1 / (1 + np.exp(-(1.5 * logit - 0.5)))
    slope, offset = platt(1 / (1 + np.exp(-logit)), failed)
    assert abs(slope - 1.5) < 0.08 and abs(offset + 0.5) < 0.08
    with pytest.raises(ValueError, match="both failed and good"):
        platt(np.full(5, 0.3), np.zeros(5, bool))


def test_fit_model_folds_the_recalibration_into_its_coefficients(monkeypatch):
    samples = small_samples()
    raw = fit_model(samples, C=0.1, calibrate=False)
    calibrated = fit_model(samples, C=0.1)
    slope, offset = calibrated.info["calibration"]["slope"], calibrated.info["calibration"]["offset"]
    # The slope and offset are Platt's on the same samples' held-out predictions ...
    p, y = [], []
    for model, held in leave_one_video_out(samples, C=0.1, calibrate=False).values():
        p += [model.p_fail(s.features)[s.use] for s in held]
        y += [s.failed[s.use] for s in held]
    assert (slope, offset) == platt(np.concatenate(p), np.concatenate(y))
    # ... the strong regularisation left the raw model underconfident, so the slope is above 1 ...
    assert slope > 1
    # ... and the calibrated model is the raw one's log-odds, scaled and shifted: same ranking, other numbers.
    features = samples[0].features
    q = raw.p_fail(features)
    want = 1 / (1 + np.exp(-(slope * np.log(q / (1 - q)) + offset)))
    np.testing.assert_allclose(calibrated.p_fail(features), want, rtol=1e-9, atol=1e-12)
    assert "calibration" not in raw.info
    # The threshold is chosen on the recalibrated held-out predictions: a recalibration that shifts p_fail up
    # moves the threshold up with it (the same frames flagged), while the raw model's stays unchosen.
    monkeypatch.setattr("annotator.failure.fit.platt", lambda p, failed: (1.0, 2.0))
    shifted = fit_model(samples, C=0.1)
    assert np.all(shifted.p_fail(features) > raw.p_fail(features))
    assert raw.threshold == UNCHOSEN_THRESHOLD and "threshold" not in raw.info
    assert shifted.threshold > calibrated.threshold
    monkeypatch.undo()
    held = [(s, 1 / (1 + np.exp(-(slope * np.log(p / (1 - p)) + offset)))) for s, p in
            [(s, model.p_fail(s.features)) for model, hs in
             leave_one_video_out(samples, C=0.1, calibrate=False).values() for s in hs]]
    assert calibrated.threshold == choose_threshold(held)
    # One sequence has no held-out predictions to calibrate on: the model stays raw.
    assert "calibration" not in fit_model(samples[:1], C=0.1).info


def test_choose_threshold_takes_the_widest_margin_over_both_targets_as_the_tool_flags():
    rng = np.random.default_rng(21)
    held = []
    for k in range(5):
        n = 80
        failed = np.zeros(n, bool)
        failed[20 + 7 * k: 45 + 5 * k] = True
        p = np.clip(0.35 * failed + rng.normal(0.3, 0.18, n), 0.001, 0.999)
        use = rng.random(n) > 0.1
        held.append((Sample(f"S{k}", 0, np.zeros((n, len(FEATURES))), failed, use), p))
    # The reference: every grid threshold flagged by the tool's own span flagger, pooled, the margin by hand.
    margins = {}
    for t in THRESHOLD_GRID:
        flagged = hits = failures = 0
        for s, p in held:
            f = flag_p_fail(p, ["score"] * len(p), t, THRESHOLD_FLAGS, keyframe=~s.use).flagged[s.use]
            flagged += f.sum()
            hits += (f & s.failed[s.use]).sum()
            failures += s.failed[s.use].sum()
        margins[t] = min(hits / failures - TARGET_RECALL, (hits / flagged if flagged else 0.0) - TARGET_PRECISION)
    best = max(margins.values())
    assert choose_threshold(held) == max(t for t, m in margins.items() if m == best)
    assert len(set(np.round(list(margins.values()), 9))) > 10  # the grid matters on these predictions
    # Separable predictions: every threshold between the two levels flags exactly the failures; the highest wins.
    s = held[0][0]
    assert choose_threshold([(s, np.where(s.failed, 0.8, 0.2))]) == 0.79
    with pytest.raises(ValueError, match="failed frames"):
        choose_threshold([(Sample("A", 0, s.features, np.zeros_like(s.failed), s.use), held[0][1])])


def test_calibration_is_skipped_when_a_fold_has_frames_of_one_kind():
    a, b = small_samples()[:2]
    all_good = Sample("B", 0, b.features, np.zeros_like(b.failed), b.use)
    model = fit_model([a, all_good], C=0.1)  # the fold that holds A out trains on good frames only
    assert "both failed and good" in model.info["calibration"]["skipped"]
    np.testing.assert_array_equal(model.p_fail(a.features), fit_model([a, all_good], C=0.1, calibrate=False)
                                  .p_fail(a.features))
    # Without held-out predictions there is nothing to choose a threshold on.
    assert model.threshold == UNCHOSEN_THRESHOLD and "threshold" not in model.info


def test_a_model_whose_held_out_sequences_rank_backwards_is_not_turned_around():
    # flow_iou marks failures in A and good frames in B: each fold ranks the other sequence backwards.
    a, b = small_samples()[:2]
    column = FEATURES.index("flow_iou")
    flipped = b.features.copy()
    flipped[:, column] += 4.0 * b.failed
    samples = [a, Sample("B", 0, flipped, b.failed, b.use)]
    raw = fit_model(samples, C=0.1, calibrate=False)
    model = fit_model(samples, C=0.1)
    assert "is not positive" in model.info["calibration"]["skipped"]
    np.testing.assert_array_equal(model.p_fail(a.features), raw.p_fail(a.features))
    # The threshold is chosen on the probabilities the model gives: the raw held-out ones, and says so.
    assert "on the raw leave-one-video-out" in model.info["threshold"]["rule"]
    held = [(s, m.p_fail(s.features)) for m, hs in leave_one_video_out(samples, C=0.1, calibrate=False).values()
            for s in hs]
    assert model.threshold == choose_threshold(held)


def test_recalibration_lowers_the_held_out_calibration_error_of_an_underconfident_model():
    # One clear signal, six sequences; C = 0.01 shrinks the log-odds to about a quarter of what the data say.
    rng = np.random.default_rng(12)
    samples = []
    for k in range(6):
        failed = rng.random(200) < 0.3
        features = rng.normal(0, 1, (200, len(FEATURES)))
        features[:, FEATURES.index("flow_iou")] -= 3.0 * failed
        samples.append(Sample(f"S{k}", 0, features, failed, np.ones(200, bool)))
    errors = {}
    for calibrate in (False, True):
        p, y = [], []
        for model, held in leave_one_video_out(samples, C=0.01, calibrate=calibrate).values():
            p += [model.p_fail(s.features)[s.use] for s in held]
            y += [s.failed[s.use] for s in held]
        errors[calibrate] = expected_calibration_error(np.concatenate(p), np.concatenate(y))
    assert errors[False] > 0.1 and errors[True] < 0.03


def test_nested_folds_choose_C_without_seeing_their_held_out_sequence():
    samples = small_samples()
    grid = [1.0, 0.01, 0.0001]
    folds = leave_one_video_out(samples, C=grid)
    # Flip every label of sequence A: the fold that holds A out must not change at all.
    flipped = [Sample(s.sequence, s.seed, s.features, ~s.failed if s.sequence == "A" else s.failed, s.use)
               for s in samples]
    again = leave_one_video_out(flipped, C=grid)
    assert json.dumps(folds["A"][0].to_json()) == json.dumps(again["A"][0].to_json())
    for name, (model, _) in folds.items():
        train = [s for s in samples if s.sequence != name]
        assert model.info["C"] == choose_C(train, grid)
    assert json.dumps(folds["B"][0].to_json()) != json.dumps(again["B"][0].to_json())


def test_backward_elimination_drops_the_group_whose_absence_scores_best_while_it_gains_enough():
    table = {(): 0.80, ("a",): 0.79, ("b",): 0.85, ("c",): 0.84,
             ("b", "a"): 0.70, ("b", "c"): 0.851}
    score = lambda dropped: table[tuple(dropped)]  # noqa: E731
    assert backward_elimination(["a", "b", "c"], score, min_gain=0.002) == ("b",)  # c's extra 0.001 is too little
    assert backward_elimination(["a", "b", "c"], score, min_gain=0.0) == ("b", "c")  # and one group always stays
    assert backward_elimination(["a", "b", "c"], score, min_gain=0.1) == ()


def test_dropped_features_get_weight_zero_and_are_ignored():
    samples = small_samples()
    drop = group_features(["flow", "appearance"])
    assert "flow_iou" in drop and "ncc_first" in drop and "log_likelihood" not in drop
    model = fit_model(samples, C=0.1, drop=drop)
    cols = [FEATURES.index(f) for f in drop]
    assert np.all(model.coef[cols] == 0.0) and np.all(model.mean[cols] == 0.0) and np.all(model.scale[cols] == 1.0)
    features = samples[0].features.copy()
    changed = features.copy()
    changed[:, cols] += 100.0
    np.testing.assert_array_equal(model.p_fail(features), model.p_fail(changed))


def test_nested_folds_choose_groups_without_seeing_their_held_out_sequence():
    samples = small_samples()  # C = 1: weak enough that the L1 penalty keeps noise signals
    folds = leave_one_video_out(samples, C=1.0, select_groups=True)
    flipped = [Sample(s.sequence, s.seed, s.features, ~s.failed if s.sequence == "A" else s.failed, s.use)
               for s in samples]
    again = leave_one_video_out(flipped, C=1.0, select_groups=True)
    assert json.dumps(folds["A"][0].to_json()) == json.dumps(again["A"][0].to_json())
    for name, (model, _) in folds.items():
        train = [s for s in samples if s.sequence != name]
        assert model.info["dropped_groups"] == list(choose_groups(train, C=1.0))
        assert "flow" not in model.info["dropped_groups"]  # the one group that separates failures stays
    assert any(model.info["dropped_groups"] for model, _ in folds.values())  # noise groups do go


def test_auroc_and_calibration_error_on_hand_made_numbers():
    assert auroc([0.1, 0.2, 0.8, 0.9], [False, False, True, True]) == 1.0
    assert auroc([0.9, 0.8, 0.2, 0.1], [False, False, True, True]) == 0.0
    assert auroc([0.5, 0.5], [False, True]) == 0.5
    assert np.isnan(auroc([0.1, 0.2], [True, True]))
    # Two bins used: [0.1, 0.1] observed 0 -> error 0.1; [0.9, 0.9] observed 1 -> 0.1.
    assert expected_calibration_error([0.1, 0.1, 0.9, 0.9], [False, False, True, True]) == pytest.approx(0.1)
    r = reliability([0.05, 0.95, 0.95], [False, True, False])
    assert r.count.tolist() == [1, 0, 0, 0, 0, 0, 0, 0, 0, 2]
    assert r.observed[9] == 0.5 and r.predicted[9] == pytest.approx(0.95)


def _run(*args):
    result = CliRunner().invoke(app, _with_default_command([str(a) for a in args]))
    return result.exit_code, result.stdout + result.stderr


@pytest.mark.parametrize("budget", ["0", "101", "-5"])
def test_review_budget_out_of_range_is_one_line_exit_4(tmp_path, budget):
    code, output = _run(tmp_path, "--box", "1,2,3,4", "--review-budget", budget, "--out", tmp_path / "o")
    assert code == 4 and "--review-budget" in output and "0 < PCT <= 100" in output
    assert output.strip().count("\n") == 0 and not (tmp_path / "o").exists()


def test_a_damaged_failure_model_file_is_refused_before_any_work(tmp_path):
    (tmp_path / "m.json").write_text("[1, 2]")
    code, output = _run(tmp_path, "--box", "1,2,3,4", "--failure-model", tmp_path / "m.json", "--out", tmp_path / "o")
    assert code == 4 and "m.json is not a sptpt-annotate failure model" in output
    code, output = _run(tmp_path, "--box", "1,2,3,4", "--failure-model", tmp_path / "nope.json")
    assert code == 3 and "failure model " in output and "nope.json does not exist: give a model JSON" in output
    (tmp_path / "m.bin").write_bytes(b"\x00\xff\xfe\x9c" * 50)
    code, output = _run(tmp_path, "--box", "1,2,3,4", "--failure-model", tmp_path / "m.bin", "--out", tmp_path / "o")
    assert code == 4 and "m.bin is not text (UTF-8" in output and output.strip().count("\n") == 0
    (tmp_path / "folder").mkdir()
    code, output = _run(tmp_path, "--box", "1,2,3,4", "--failure-model", tmp_path / "folder")
    assert code == 3 and "folder is a folder: give a model JSON" in output
    assert not (tmp_path / "o").exists()


def test_the_fitting_module_imports_scikit_learn_only_to_fit():
    """A benchmark that refuses a bad option should not first spend a second importing scikit-learn."""
    import subprocess
    import sys

    code = "import sys, annotator.failure.fit; print('sklearn' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip() == "False", done.stderr


@pytest.mark.parametrize("value, message", [
    ("abc", "expected a number or comma-separated numbers such as 1,0.1,0.01,0.003,0.001,0.0003,0.0001"),
    ("0,1", "every value must be a finite number > 0"),
])
def test_failure_model_script_refuses_a_bad_C_in_one_line(value, message):
    from _benchmark_scripts import run_benchmark

    done = run_benchmark("failure_model", "--C", value)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == f"failure_model.py: error: --C {value!r}: {message}"


@pytest.mark.parametrize("name", ["failure_model", "failure_penalty"])
@pytest.mark.parametrize("argv, code, fragment", [
    (["--workers", "0"], 2, "--workers 0: expected an integer >= 1"),
    (["--C", "0"], 2, "--C '0': every value must be a finite number > 0"),
    (["--runs", "/nonexistent/run-*"], 1, "--runs /nonexistent/run-*: expected batch runs of one tracker preset, "
                                          "found none"),
])
def test_the_refit_scripts_refuse_bad_options_in_one_line(name, argv, code, fragment):
    from _benchmark_scripts import run_benchmark

    done = run_benchmark(name, "--no-record" if name == "failure_penalty" else "--C=1", *argv)
    assert done.returncode == code, done.stderr
    assert fragment in done.stderr.strip().splitlines()[-1] and "Traceback" not in done.stderr


def test_failure_model_script_describes_a_model_without_recalibration_too():
    from _benchmark_scripts import load_script

    fm = load_script("failure_model")
    fitted = {"calibration": {"slope": 1.1881, "offset": 0.1144}}
    assert fm.calibration_text(fitted) == "slope 1.19, offset 0.11" and fm.calibration_slope(fitted) == 1.19
    skipped = {"calibration": {"skipped": "held-out slope -0.2 is not positive"}}
    assert fm.calibration_text(skipped) == "not recalibrated (held-out slope -0.2 is not positive)"
    assert fm.calibration_text({}) == "not recalibrated (one sequence)" and fm.calibration_slope({}) == "one sequence"


def test_calibration_bounds_undo_one_shifted_base_rate_and_a_level_of_each_video_only_per_video():
    from _benchmark_scripts import load_script

    from annotator.failure.fit import Sample

    fm = load_script("failure_model")
    rng = np.random.default_rng(3)

    def results(shift_of_video):
        rows = []
        for seed in (0, 1):
            for name, shift in shift_of_video.items():
                truth = rng.normal(0.0, 2.0, 4000)  # the true log-odds of each frame
                failed = rng.random(4000) < 1 / (1 + np.exp(-truth))
                p = 1 / (1 + np.exp(-(truth - shift)))  # the model's probability: the truth, too low by `shift`
                rows.append((Sample(name, seed, np.zeros((4000, 1)), failed, np.ones(4000, bool)), p, [], 0.25))
        return rows

    one_level = fm.calibration_bounds(results({"A": 1.5, "B": 1.5}))
    assert all(b["ece"] > 0.1 and b["shift"] < 0.02 and b["platt"] < 0.02 for b in one_level.values())
    two_levels = fm.calibration_bounds(results({"A": 3.0, "B": -1.0}))
    assert all(b["shift"] > 0.03 and b["per_video"] < 0.02 for b in two_levels.values())
    text = "\n".join(fm.calibration_bounds_lines(one_level))
    assert "best single log-odds shift" in text and "each video shifted to its own failure rate" in text


# ---------------------------------------------------------------- between two anchors: the passes' agreement
SECTION = PassAgreement(log_odds=0.8, pass_iou=-5.0, intercept=1.5, info={"data": "hand-made"})


def test_the_passes_agreement_corrects_only_rows_measured_from_two_passes():
    model = dataclasses.replace(load_model(), between_anchors=SECTION)
    p_track = np.array([0.1, 0.1, 0.1, 0.6, 0.02])
    pass_iou = np.array([np.nan, 1.0, 0.0, 0.9, 0.95])
    p, raised = model.with_pass_agreement(p_track, pass_iou)
    expected = 1 / (1 + np.exp(-(0.8 * np.log(p_track / (1 - p_track)) - 5.0 * pass_iou + 1.5)))
    assert p[0] == 0.1 and not raised[0]  # one pass only: as the track says
    np.testing.assert_allclose(p[1:], expected[1:], rtol=1e-12)
    assert p[2] > 4 * p_track[2] and raised[2]  # the passes disagree completely: far more likely wrong
    assert p[1] < 0.1 and not raised[1]  # they agree: lower than the track alone
    # A model without the section, or no pass_iou at all, changes nothing.
    bare = dataclasses.replace(model, between_anchors=None)
    assert np.array_equal(bare.with_pass_agreement(p_track, pass_iou)[0], p_track)
    assert np.array_equal(model.with_pass_agreement(p_track, None)[0], p_track)


def test_score_track_names_the_passes_where_their_disagreement_raised_p_fail():
    rng = np.random.default_rng(3)
    n = 30
    signals = random_signals(rng, n)
    keyframe = np.zeros(n, bool)
    keyframe[[0, 29]] = True
    outside = np.zeros(n, bool)
    model = dataclasses.replace(load_model(), between_anchors=SECTION)
    plain, groups = score_track(signals, keyframe, outside, model)
    pass_iou = np.full(n, 0.95)
    pass_iou[10:15] = 0.0
    pass_iou[0] = pass_iou[29] = 0.0  # anchors stay 0 whatever is stored there
    p, named = score_track(signals, keyframe, outside, model, pass_iou=pass_iou)
    assert p[0] == 0 and p[29] == 0
    assert np.all(p[10:15] > plain[10:15]) and all(g == "passes" for g in named[10:15])
    assert p[20] < plain[20] and named[20] == groups[20]  # the passes agree: lower, and the track's own reason
    assert "doubt:passes" in REASONS


def test_the_section_round_trips_through_the_file_and_is_optional(tmp_path):
    model = dataclasses.replace(load_model(), between_anchors=SECTION)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(model.to_json()))
    again = load_model(path)
    assert again.between_anchors == SECTION and again.to_json() == model.to_json()
    data = model.to_json()
    data.pop("between_anchors")
    path.write_text(json.dumps(data))
    assert load_model(path).between_anchors is None


def test_fitting_the_section_recovers_a_known_model_and_is_reproducible():
    rng = np.random.default_rng(5)
    n = 20000
    p_track = rng.uniform(0.01, 0.99, n)
    pass_iou = rng.uniform(0, 1, n)
    truth = PassAgreement(log_odds=0.7, pass_iou=-5.0, intercept=1.4, info={})
    failed = rng.uniform(size=n) < 1 / (1 + np.exp(-truth.log_odds_of(p_track, pass_iou)))
    first = fit_pass_agreement(p_track, pass_iou, failed, info={"data": "fixed"})
    assert first == fit_pass_agreement(p_track, pass_iou, failed, info={"data": "fixed"})
    assert first.log_odds == pytest.approx(0.7, abs=0.05) and first.pass_iou == pytest.approx(-5.0, abs=0.25)
    assert first.intercept == pytest.approx(1.4, abs=0.15)
    with pytest.raises(ValueError, match="both failed and good"):
        fit_pass_agreement(p_track, pass_iou, np.zeros(n, bool))


@pytest.mark.parametrize("argv, code, fragment", [
    (["--every", "1"], 2, "--every intervals of at least 2 frames"),
    (["--seeds", "a,b"], 2, "must be comma-separated integers"),
    (["--sequences", "NoSuchSequence"], 2, "NoSuchSequence"),
    (["--data", "{empty}"], 1, "no data in"),
])
def test_the_between_anchors_script_refuses_bad_input_in_one_line(tmp_path, argv, code, fragment):
    from _benchmark_scripts import run_benchmark

    argv = [a.replace("{empty}", str(tmp_path)) for a in argv]
    done = run_benchmark("anchored_failure", "--no-record", *argv)
    assert done.returncode == code
    lines = done.stderr.strip().splitlines()
    assert fragment in lines[-1] and "Traceback" not in done.stderr


def test_the_regression_gives_signals_that_do_not_pay_weight_exactly_0():
    # In small_samples only flow_iou separates failures; the other columns are noise. An L2 penalty would only
    # shrink their weights; L1 sets most of them to exactly 0.
    model = fit_model(small_samples(), C=0.1, calibrate=False)
    assert model.coef[FEATURES.index("flow_iou")] < 0
    assert np.sum(model.coef == 0.0) >= len(FEATURES) - 3


def test_both_sequences_of_one_video_are_held_out_together():
    assert video("Jogging.1") == video("Jogging.2") == "Jogging" and video("Bolt2") == "Bolt2"
    a, b, c, d = small_samples()
    samples = [Sample("J.1", 0, a.features, a.failed, a.use), Sample("J.2", 0, b.features, b.failed, b.use), c, d]
    folds = leave_one_video_out(samples, C=0.1)
    assert sorted(folds) == ["C", "D", "J"]
    model, held = folds["J"]
    assert [s.sequence for s in held] == ["J.1", "J.2"]
    # Trained on C and D alone, which hold no two sequences of one video: its own folds are C and D.
    assert json.dumps(model.to_json()) == json.dumps(fit_model([c, d], C=0.1, info={"C": 0.1}).to_json())
    # The other folds train on both halves of J.
    assert json.dumps(folds["C"][0].to_json()) == json.dumps(fit_model([samples[0], samples[1], d], C=0.1,
                                                                       info={"C": 0.1}).to_json())


def test_no_fit_inside_the_folds_trains_on_one_sequence_of_a_video_without_the_other():
    # Every nested fit (the choice of C, the recalibration, the threshold) must hold out whole videos too. Each
    # sample carries its own value in since_anchor, so the rows a fit sees tell which sequences it trained on.
    import annotator.failure.fit as fit

    a, b, c, d = small_samples()
    column = FEATURES.index("since_anchor")
    samples = []
    for mark, (name, s) in enumerate(zip(["J.1", "J.2", "C", "D"], [a, b, c, d]), start=1):
        features = s.features.copy()
        features[:, column] = mark
        samples.append(Sample(name, 0, features, s.failed, s.use))
    seen = []

    def recording_fit(X, y, C):
        seen.append(set(np.unique(X[:, column]).tolist()))
        return fit.l1_fit(X, y, C)

    leave_one_video_out(samples, C=[0.1, 1.0], regression=recording_fit)
    assert len(seen) > 20
    assert all((1.0 in marks) == (2.0 in marks) for marks in seen)  # J.1 and J.2 together, or neither
    assert {1.0, 2.0, 3.0} in seen and {3.0, 4.0} in seen  # folds without D, and without J


def _moving_scene(frames: int = 16, speed=(3.0, 2.0), *, shape=(180, 240), start=(60, 60), lag=(0.0, 0.0)):
    """Frames (``shape``) of a textured object (40 x 32 px) moving at ``speed`` px a frame from ``start`` over a
    still textured background, and its boxes, ``lag`` px a frame further behind it each frame (none: its true
    boxes): textures everywhere, so every flow point has something to track."""
    rng = np.random.default_rng(7)
    background = cv2.GaussianBlur(rng.integers(0, 256, (*shape, 3), dtype=np.uint8), (0, 0), 1.5)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (32, 40, 3), dtype=np.uint8), (0, 0), 1.0)
    shown, boxes = [], []
    for k in range(frames):
        x, y = start[0] + speed[0] * k, start[1] + speed[1] * k
        frame = background.copy()
        frame[int(y):int(y) + 32, int(x):int(x) + 40] = texture
        shown.append(frame)
        boxes.append([int(x) - lag[0] * k, int(y) - lag[1] * k, 40.0, 32.0])
    return shown, np.array(boxes, dtype=np.float64)


def _motion(frames, boxes) -> dict[str, np.ndarray]:
    from annotator.failure.signals import MotionMeter, grey_of

    meter = MotionMeter()
    meter.first(grey_of(frames[0]), boxes[0])
    rows = [meter.next(grey_of(frames[k]), boxes[k]) for k in range(1, len(frames))]
    return {name: np.array([row[name] for row in rows]) for name in rows[0]}


def _scaled(boxes: np.ndarray, factor: float) -> np.ndarray:
    centre = boxes[:, :2] + boxes[:, 2:] / 2
    return np.concatenate([centre - boxes[:, 2:] * factor / 2, boxes[:, 2:] * factor], axis=1)


def test_motion_signals_tell_a_right_box_from_a_drifting_small_or_large_one():
    frames, truth = _moving_scene()
    right = _motion(frames, truth)
    # The box lags ever further behind the object (0.5 px a frame): no single frame shows it, ten frames do.
    lagging = truth - np.arange(len(truth))[:, None] * [0.5, 0.5, 0, 0]
    lag = _motion(frames, lagging)
    small, large = _motion(frames, _scaled(truth, 0.6)), _motion(frames, _scaled(truth, 1.6))
    # The right box moves as its points do, at their scale, with its ring still and its points with it.
    assert right["flow_drift"].max() < 0.05 and right["flow_scale_drift"].max() < 0.05
    assert right["ring_with_box"].max() < 0.2 and right["box_with_background"].max() < 0.1
    assert lag["flow_drift"][-1] > 0.1 > 0.05 > right["flow_drift"].max()
    assert lag["flow_drift"][-1] > lag["flow_drift"][1] * 3  # it adds up over the window
    # Too small: the object reaches past the box, its ring moves with it. Too large: the box holds background.
    assert small["ring_with_box"][2:].min() > 0.5 > right["ring_with_box"].max()
    assert large["box_with_background"][2:].min() > 0.3 > right["box_with_background"].max()
    # A box that grows while its points keep their scale.
    growing = _scaled(truth, 1.0) * 1.0
    growing[:, 2:] *= (1.03 ** np.arange(len(truth)))[:, None]
    assert _motion(frames, growing)["flow_scale_drift"][-1] > 0.2


def test_motion_extent_is_not_measured_where_the_box_moves_as_the_background():
    frames, truth = _moving_scene(speed=(0.0, 0.0))
    still = _motion(frames, truth)
    assert np.isnan(still["ring_with_box"]).all() and np.isnan(still["box_with_background"]).all()
    assert still["flow_drift"].max() < 0.05


def test_signal_meter_measures_the_motion_signals_of_the_motion_meter():
    """The tool's SignalMeter reports MotionMeter's signals as they are: what benchmarks/motion_signals.py
    measures again from a stored track's frames and boxes is what tracking stored."""
    frames, truth = _moving_scene()
    boxes = _scaled(truth, 0.8)
    meter = SignalMeter()
    meter.first(frames[0], boxes[0])
    rows = [meter.next(frames[k], boxes[k], log_likelihood=5.0, scoring="subspace", accepted=True)
            for k in range(1, len(frames))]
    motion = _motion(frames, boxes)
    assert tuple(motion) == MOTION_SIGNALS  # what benchmarks/motion_signals.py replays is all the meter measures
    for name, values in motion.items():
        np.testing.assert_array_equal(np.array([row[name] for row in rows]), values, err_msg=name)


def _parted_features(video, boxes, runs) -> np.ndarray:
    """The ncc_memory_parted features of a pass reporting ``boxes``, its runs at ``runs`` (None: one run)."""
    from annotator.failure.model import FEATURES

    meter = SignalMeter()
    rows = [meter.first(video[0], boxes[0])]
    for k in range(1, len(video)):
        rows.append(meter.next(video[k], boxes[k], log_likelihood=5.0, scoring="subspace", accepted=True,
                               run_boxes_xywh=None if runs is None else runs[k]))
    keyframe = np.zeros(len(rows), bool)
    keyframe[0] = True
    features = feature_matrix({name: np.array([r[name] for r in rows]) for name in SIGNALS}, keyframe)
    return features[:, [FEATURES.index("ncc_memory"), FEATURES.index("ncc_memory_parted"),
                        FEATURES.index("ncc_memory_parted_w5")]]


def test_appearance_counts_where_a_run_parts_from_the_box():
    """An object that changes its look, followed right by three runs: unlike its past (low ncc_memory), but no run
    parts, so ncc_memory_parted stays low. The box carried off it while one run stays on it: high. One run: not
    measured (NaN)."""
    video, boxes = changing_object(0.7)
    agree = [np.stack([b, b + [1, 0, 0, 0], b - [0, 1, 0, 0]]) for b in boxes]
    right = _parted_features(video, boxes, agree)
    assert np.median(right[30:, 0]) < 0.4  # the raw level: a right box that looks unlike the object's past
    assert right[30:, 1:].max() < 0.1
    lost = boxes.copy()
    lost[30:] = [100.0, 80.0, 32.0, 32.0]  # onto background from frame 30; one run stays on the object
    parted = [np.stack([lost[k], lost[k], boxes[k]]) for k in range(len(boxes))]
    wrong = _parted_features(video, lost, parted)
    assert wrong[32:, 1:].min() > 0.6
    # before the loss, as on the right track (the 5-frame means of frames 28 and 29 already see frames 30 and 31)
    assert np.isfinite(wrong[1:28, 1:]).all() and wrong[1:28, 1:].max() < 0.1
    alone = _parted_features(video, boxes, None)
    assert np.isnan(alone[1:, 1:]).all()


def test_the_shipped_model_reads_appearance_only_where_a_run_parts():
    """The shipped design (issue #43): no weight on an appearance level, whose normal value depends on the object;
    appearance enters through ncc_memory_parted."""
    from annotator.failure.fit import APPEARANCE_LEVELS

    model = load_model()
    weights = dict(zip(model.features, model.coef))
    assert all(weights[name] == 0.0 for name in APPEARANCE_LEVELS)
    assert weights["ncc_memory_parted"] > 0 or weights["ncc_memory_parted_w5"] > 0


def _large_scene(speed: tuple[float, float], start: tuple[int, int]):
    """Six 640 x 400 frames of :func:`_moving_scene` with boxes that fall behind the object: the flow points see
    the object, its edge and the background."""
    return _moving_scene(6, speed, shape=(400, 640), start=start, lag=(1.5, -0.5))


@pytest.mark.parametrize("speed,start", [((3.0, 2.0), (300, 180)), ((24.0, -17.0), (200, 300)),
                                         ((-5.0, -4.0), (30, 26)), ((6.0, 5.0), (560, 330))])
def test_the_flow_on_its_window_is_the_flow_on_the_whole_frame(monkeypatch, speed, start):
    """The flow looks at a window around its points (cost that follows the object, not the frame); the signals
    are those of the whole frame, to the points' stopping step: in the middle, moving fast, and at the corners."""
    import annotator.failure.signals as signals

    frames, boxes = _large_scene(speed, start)
    seen: list[tuple[int, ...]] = []
    real_flow = cv2.calcOpticalFlowPyrLK

    def spying(prev, nxt, *args, **kwargs):
        seen.append(prev.shape)
        return real_flow(prev, nxt, *args, **kwargs)

    monkeypatch.setattr(signals.cv2, "calcOpticalFlowPyrLK", spying)
    windowed = _motion(frames, boxes)
    assert all(h * w < 400 * 640 / 2 for h, w in seen)  # the window, not the frame
    seen.clear()
    monkeypatch.setattr(signals, "flow_window", lambda points, width, height: (0, 0, width, height))
    whole = _motion(frames, boxes)
    assert set(seen) == {(400, 640)}
    for name, values in whole.items():
        np.testing.assert_allclose(windowed[name], values, rtol=0, atol=1e-3, equal_nan=True, err_msg=name)


@pytest.mark.parametrize("speed,start", [((3.0, 2.0), (300, 180)), ((24.0, -17.0), (200, 300)),
                                         ((6.0, 5.0), (420, 200))])
def test_the_flow_window_reaches_far_enough_that_more_image_changes_no_point(speed, start):
    """To the bit: the points tracked on the window and on the window extended to the image's right and bottom
    edges (the same corner, so the same coordinates). A window 12 px past the points fails this. (Against the
    whole frame, a point's coordinates differ by the corner, and its rounding can change where Lucas-Kanade
    stops: the signal test above.)"""
    from annotator.failure.signals import _LK, flow_window, grey_of

    frames, boxes = _large_scene(speed, start)
    prev, grey = grey_of(frames[0]), grey_of(frames[1])
    x, y, w, h = boxes[0]
    rings = [(x + w / 2 + f * w / 2 * np.cos(t), y + h / 2 + f * h / 2 * np.sin(t))
             for f in (0.5, 1.3, 2.2) for t in np.linspace(0, 2 * np.pi, 24, endpoint=False)]
    points = np.array([p for p in rings if 0 <= p[0] <= 639 and 0 <= p[1] <= 399], dtype=np.float32)
    x0, y0, x1, y1 = flow_window(points, 640, 400)
    assert x1 < 640 or y1 < 400
    shifted = (points - np.array([x0, y0], dtype=np.float32)).reshape(-1, 1, 2)
    part = cv2.calcOpticalFlowPyrLK(prev[y0:y1, x0:x1], grey[y0:y1, x0:x1], shifted, None, **_LK)
    extended = cv2.calcOpticalFlowPyrLK(prev[y0:, x0:], grey[y0:, x0:], shifted, None, **_LK)
    assert (extended[1] == 1).mean() > 0.8
    np.testing.assert_array_equal(part[1], extended[1])
    np.testing.assert_array_equal(part[0], extended[0])


def test_the_flow_window_holds_the_points_and_their_reach_and_no_more():
    from annotator.failure.signals import FLOW_REACH, flow_window

    points = np.array([[900.3, 500.7], [1000.2, 610.1]])
    x0, y0, x1, y1 = flow_window(points, 1920, 1080)
    assert x0 % 4 == 0 and y0 % 4 == 0
    assert x0 <= 900 - FLOW_REACH - 42 and y0 <= 500 - FLOW_REACH - 42
    assert x1 >= 1001 + FLOW_REACH + 42 and y1 >= 611 + FLOW_REACH + 42
    assert (x1 - x0) * (y1 - y0) < 1920 * 1080 / 10  # a small object's flow reads a tenth of an HD frame
    assert flow_window(np.array([[3.0, 5.0], [630.0, 470.0]]), 640, 480) == (0, 0, 640, 480)
    assert flow_window(np.array([[900.3, 500.7], [np.nan, 5.0]]), 1920, 1080)[:2] == (x0, y0)
    assert flow_window(np.full((4, 2), np.nan), 640, 480) == (0, 0, 640, 480)


def test_a_box_without_coordinates_loses_the_flow_as_it_did_on_the_whole_frame():
    from annotator.failure.signals import MotionMeter

    grey = np.random.default_rng(0).integers(0, 256, (240, 320), dtype=np.uint8)
    meter = MotionMeter()
    meter.first(grey, np.array([10.0, 10.0, 40.0, 40.0]))
    meter.next(grey, np.array([np.nan, 10.0, 40.0, 40.0]))
    after = meter.next(grey, np.array([10.0, 10.0, 40.0, 40.0]))  # from the box without coordinates
    assert (after["flow_iou"], after["flow_fb"], after["flow_kept"]) == (0.0, 1.0, 0.0)

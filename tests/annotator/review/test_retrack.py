"""Re-tracking from corrections: the span logic, the passes, and the output folder rewritten atomically.

Three layers: pure logic with exact answers (segments, merges, scoring
replay, flags); the algorithm with the real tracker on a tiny synthetic clip
held in memory (60 particles, 20 negatives); and ``apply_corrections`` /
``retrack_command`` on the output folder of a real run, sharing one run per
module (copied per test) because tracking is the slow part.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import shutil
from pathlib import Path

import cv2
import numba
import numpy as np
import pytest
import typer
from _runs import CONFIG, GT, csv_row, snapshot, write_frames
from typer.testing import CliRunner

from annotator.commands.retrack import retrack_command
from annotator.config import resolve_config
from annotator.errors import EXIT_INPUT, EXIT_VALUE, ToolError
from annotator.exports import read_flags_csv
from annotator.failure import LOOKAHEAD, load_model
from annotator.failure.model import PassAgreement
from annotator.flagging import FlagParams
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from annotator.pipeline import track_source
from annotator.review import (
    ArrayFrames,
    PassResult,
    PreviousTrack,
    Segment,
    apply_corrections,
    correct_run,
    load_run,
    merge_passes,
    plan_segments,
    reflag,
    retrack_tracks,
    same_box,
)
from annotator.review.merge import track_p_fail
from annotator.run import annotate
from annotator.tracks import Target
from sptpt_dev.synthetic import make_clip

CLIP = make_clip(16, size=(96, 72), object_size=(24, 20))
INDICES = np.arange(16)


# --------------------------------------------------------------------------- pure logic


@pytest.mark.parametrize(
    "anchors, changed, n, expected",
    [
        # A first run: one forward segment over everything.
        ({0: (1, 1, 5, 5)}, {0}, 10, [(0, 10, True, False, True)]),
        # A new anchor in the middle: the two segments around it, forward and backward before it.
        ({0: (1, 1, 5, 5), 4: (2, 2, 5, 5)}, {4}, 10, [(0, 4, True, True, False), (4, 10, True, False, True)]),
        # Only the segments touching the changed anchor; (0, 3) keeps its rows.
        ({0: (1, 1, 5, 5), 3: (2, 2, 5, 5), 6: (3, 3, 5, 5), 8: (4, 4, 5, 5)}, {6}, 10,
         [(3, 6, True, True, False), (6, 8, True, True, True)]),
        # An absence: forward only into it, and nothing tracked after it up to the next anchor.
        ({0: (1, 1, 5, 5), 4: None, 7: (2, 2, 5, 5)}, {4}, 10,
         [(0, 4, True, False, False), (4, 7, False, False, True)]),
    ],
)
def test_plan_segments(anchors, changed, n, expected):
    got = plan_segments(1, anchors, changed, n)
    assert [(s.start, s.stop, s.forward, s.backward, s.set_start) for s in got] == expected
    assert all(isinstance(s, Segment) for s in got)


def _pass(conf, x) -> PassResult:
    n = len(conf)
    return PassResult(boxes_xywh=np.array([[xi, 0.0, 10.0, 10.0] for xi in x]), confidence=np.array(conf, float),
                      log_likelihood=np.array(conf, float) * 10, accepted=np.ones(n, bool),
                      scoring=np.array(["subspace"] * n, dtype=object), seconds=np.full(n, 0.5))


def test_merge_confidence_picks_the_more_confident_pass_per_frame():
    fwd, bwd = _pass([0.9, 0.4, 0.7, 0.2], [0, 1, 2, 3]), _pass([0.5, 0.6, 0.7, 0.3], [10, 11, 12, 13])
    merged = merge_passes(fwd, bwd, "confidence")
    assert merged.boxes_xywh[:, 0].tolist() == [0, 11, 2, 13]  # ties go forward
    assert merged.confidence.tolist() == [0.9, 0.6, 0.7, 0.3]
    assert merged.log_likelihood.tolist() == [9.0, 6.0, 7.0, 3.0]
    assert merged.seconds.tolist() == [1.0] * 4


def test_merge_anchored_trusts_the_pass_near_its_human_box():
    fwd, bwd = _pass([0.3, 0.9, 0.9, 0.4], [0, 1, 2, 3]), _pass([0.8, 0.8, 0.2, 0.5], [10, 11, 12, 13])
    fwd.scoring[:] = ["bootstrap", "subspace", "subspace", "subspace"]
    bwd.scoring[:] = ["subspace", "subspace", "bootstrap", "bootstrap"]
    merged = merge_passes(fwd, bwd, "anchored")
    # Frame 0: forward is fresh, backward is not; frames 2-3: backward is fresh; frame 1: by confidence.
    assert merged.boxes_xywh[:, 0].tolist() == [0, 1, 12, 13]
    assert merged.scoring.tolist() == ["bootstrap", "subspace", "bootstrap", "bootstrap"]


def test_merge_blend_weights_boxes_by_confidence():
    merged = merge_passes(_pass([0.75, 0.0], [0, 0]), _pass([0.25, 0.0], [8, 8]), "blend")
    assert merged.boxes_xywh[:, 0].tolist() == [2.0, 4.0]  # 0.75*0 + 0.25*8; no confidence at all: the mean
    assert merged.confidence[0] == pytest.approx(0.75 * 0.75 + 0.25 * 0.25)


def test_merge_records_how_far_the_two_passes_agree():
    fwd, bwd = _pass([0.9, 0.9, 0.9], [0, 0, 0]), _pass([0.1, 0.1, 0.1], [0, 5, 20])
    for method in ("anchored", "confidence", "blend", "handover"):
        merged = merge_passes(fwd, bwd, method)
        # Same box: 1; shifted by half its width: 50 / 150; apart: 0.
        np.testing.assert_allclose(merged.pass_iou, [1.0, 50 / 150, 0.0])
    assert np.isnan(merge_passes(fwd, None).pass_iou).all()  # one pass: nothing to compare
    bwd.boxes_xywh[1] = np.nan  # a row one pass has no box for: not compared, not a disagreement
    assert np.isnan(merge_passes(fwd, bwd).pass_iou[1]) and merge_passes(fwd, bwd).pass_iou[0] == 1.0


def test_merge_handover_switches_once():
    fwd, bwd = _pass([0.9, 0.2, 0.9, 0.1, 0.1], range(5)), _pass([0.1, 0.5, 0.3, 0.8, 0.9], range(10, 15))
    merged = merge_passes(fwd, bwd, "handover")
    assert merged.boxes_xywh[:, 0].tolist() == [0, 1, 2, 13, 14]
    assert merge_passes(fwd, None, "handover") is fwd
    with pytest.raises(ValueError, match="choose from"):
        merge_passes(fwd, bwd, "average")


def test_same_box_compares_after_clipping():
    assert same_box((-5.0, 10, 20, 20), (0.0, 10, 15, 20), width=96, height=72)
    assert same_box((10.0004, 10, 20, 20), (10.0, 10, 20, 20), width=96, height=72)
    assert not same_box((10.01, 10, 20, 20), (10.0, 10, 20, 20), width=96, height=72)
    assert same_box(None, None, width=96, height=72) and not same_box(None, (1, 1, 1, 1), width=96, height=72)


def test_reflag_never_flags_anchors_and_always_flags_absences():
    from annotator.failure import SIGNALS

    n = 12
    bad = {"log_likelihood": -50.0, "flow_iou": 0.0, "ncc_first": -1.0, "ncc_prev": -1.0, "flow_kept": 0.0}
    signals = {name: np.full(n, bad.get(name, 0.0)) for name in SIGNALS}
    keyframe = np.zeros(n, bool)
    keyframe[[0, 6]] = True
    outside = np.zeros(n, bool)
    outside[9:] = True
    # Any frame the model doubts at all is flagged: the test holds whatever the fitted model's weights.
    config = dataclasses.replace(CONFIG, flags=FlagParams(threshold=1e-9, merge_gap=0, min_span=1))
    flagged, reasons, p_fail = reflag(signals, keyframe, outside, config)
    assert not flagged[[0, 6]].any() and (p_fail[[0, 6]] == 0).all()
    assert flagged[1:6].all() and flagged[7:].all()
    assert all(r == "outside" for r in reasons[9:]) and np.isnan(p_fail[9:]).all()
    assert all(r.startswith("doubt:") for r in reasons[1:6])


def test_a_store_without_ncc_memory_reads_ncc_first_in_its_place():
    """Kept rows of a store from before ncc_memory existed: not a perfect match with the past (its neutral value,
    which would clear them of doubt) but the row's ncc_first."""
    from annotator.failure import SIGNALS
    from annotator.review.merge import filled_signals

    n = 6
    rng = np.random.default_rng(4)
    signals = {name: rng.uniform(0, 1, n) for name in SIGNALS}
    old = {name: v for name, v in signals.items() if name != "ncc_memory"}
    filled = filled_signals(old)
    np.testing.assert_array_equal(filled["ncc_memory"], signals["ncc_first"])
    # Rows a new pass measured keep their value; a row without either takes ncc_first's neutral value.
    part = {**signals, "ncc_memory": np.r_[np.nan, signals["ncc_memory"][1:]],
            "ncc_first": np.r_[np.nan, signals["ncc_first"][1:]]}
    filled = filled_signals(part)
    np.testing.assert_array_equal(filled["ncc_memory"], np.r_[1.0, signals["ncc_memory"][1:]])
    flagged_old = reflag(old, np.zeros(n, bool), np.zeros(n, bool), CONFIG)[2]
    np.testing.assert_array_equal(flagged_old, reflag({**old, "ncc_memory": signals["ncc_first"]}, np.zeros(n, bool),
                                                      np.zeros(n, bool), CONFIG)[2])


@pytest.mark.parametrize("name", ["run_iou", "run_support", "contrast"])
def test_reflag_reads_a_signal_not_measured_as_the_models_mean(name, tmp_path):
    """A one-run track, or a store from before the signal existed, has NaN there: the model neither raises nor lowers
    p_fail."""
    from annotator.failure import FEATURES, SIGNALS, feature_matrix
    from annotator.failure.model import model_from_fit

    n = 10
    rng = np.random.default_rng(2)
    signals = {signal: rng.uniform(0, 1, n) for signal in SIGNALS}
    keyframe, outside = np.zeros(n, bool), np.zeros(n, bool)
    keyframe[0] = True
    missing = {**signals, name: np.full(n, np.nan)}
    # A model that weighs every feature, so that what the missing signal is read as shows in p_fail.
    model = model_from_fit(FEATURES, rng.uniform(0.2, 0.8, len(FEATURES)), rng.uniform(0.5, 2.0, len(FEATURES)),
                           rng.uniform(0.5, 1.5, len(FEATURES)), -0.5, 0.4, {})
    path = tmp_path / "model.json"
    path.write_text(json.dumps(model.to_json()))
    config = dataclasses.replace(CONFIG, failure_model=str(path))
    features = feature_matrix(missing, keyframe)
    cols = [FEATURES.index(name), FEATURES.index(f"{name}_w5")]
    features[:, cols] = model.mean[cols]  # where the model reads a feature not measured
    p_missing = reflag(missing, keyframe, outside, config)[2]
    np.testing.assert_allclose(p_missing, np.where(keyframe, 0.0, model.p_fail(features)), rtol=0, atol=1e-12)
    assert not np.allclose(p_missing, reflag({**signals, name: np.ones(n)}, keyframe, outside, config)[2])
    # A store written before the signal existed lacks it altogether: the same as not measured.
    absent = {k: v for k, v in signals.items() if k != name}
    np.testing.assert_array_equal(reflag(absent, keyframe, outside, config)[2], p_missing)


def test_a_store_from_before_the_contrast_signal_is_retracked_and_exported(corrected, tmp_path):
    """Tracks stored without ``contrast`` (older versions) re-track, keep the signal not measured on the rows they
    keep, and write a flags file whose contrast cells are empty there."""
    from annotator.exports.flags import write_flags_csv

    old = corrected.tracks[0]  # anchors at 0 and 10
    old = dataclasses.replace(old, signals={k: v for k, v in old.signals.items() if k != "contrast"})
    result = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {14: tuple(CLIP.boxes_xywh[14])}}, CONFIG,
                            previous={1: PreviousTrack(old, corrected.scoring[1])}, width=96, height=72)
    track = result.tracks[0]
    contrast = track.signals["contrast"]
    np.testing.assert_array_equal(track.boxes_xywh[:11], old.boxes_xywh[:11])  # 0..10 kept as they were
    assert np.isnan(contrast[:11]).all() and np.isnan(contrast[14])  # kept rows and anchors: not measured
    assert np.isfinite(contrast[[11, 12, 13, 15]]).all()  # re-tracked from the anchors at 10 and 14: measured
    write_flags_csv(tmp_path / "flags.csv", [track])
    text = (tmp_path / "flags.csv").read_text().splitlines()
    column = text[0].split(",").index("contrast")
    cells = [line.split(",")[column] for line in text[1:]]
    assert cells[:11] == [""] * 11 and all(cells[k] for k in (11, 12, 13, 15))
    assert len(read_flags_csv(tmp_path / "flags.csv").frame) == 16


# --------------------------------------------------------------------------- the algorithm


@pytest.fixture(scope="module")
def first():
    """A from-scratch run of the algorithm, and the pipeline's run on the same clip."""
    result = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {0: tuple(CLIP.boxes_xywh[0])}}, CONFIG)
    return result


@pytest.fixture(scope="module")
def corrected(first):
    previous = {1: PreviousTrack(first.tracks[0], first.scoring[1])}
    return retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, CONFIG,
                          previous=previous, width=96, height=72)


class _Source:
    """The clip as a frame source for track_source."""

    name, path, width, height, fps, frame_count = "clip", "clip", 96, 72, 25.0, 16

    def __iter__(self):
        return iter(enumerate(CLIP.frames))

    def __len__(self):
        return 16


@pytest.mark.parametrize("preset", ["robust", "fused"])
def test_a_run_and_a_retrack_score_with_the_failure_model_of_their_preset(preset, monkeypatch):
    # A preset with a learned tracker gets the model fitted on such runs (annotator.failure.model.GUIDED_MODEL_PATH).
    # Every stage asks the run's config (RunConfig.load_failure_model), which reads the model module's loader.
    import annotator.failure.model

    asked = []

    def spy(path=None, *, guided=False):
        asked.append(guided)
        return load_model(path, guided=guided)

    monkeypatch.setattr(annotator.failure.model, "load_model", spy)
    config = resolve_config(preset=preset)
    track_source(_Source(), [Target(tuple(CLIP.boxes_xywh[0]), 1)], config)
    retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {0: tuple(CLIP.boxes_xywh[0]),
                                                           10: tuple(CLIP.boxes_xywh[10])}}, config)
    assert len(asked) >= 2 and set(asked) == {config.tracker.uses_guide}


def test_forward_from_the_first_frame_reproduces_the_main_command(first):
    run = track_source(_Source(), [Target(tuple(CLIP.boxes_xywh[0]), 1)], CONFIG)
    ours, theirs = first.tracks[0], run.tracks[0]
    np.testing.assert_array_equal(ours.boxes_xywh, theirs.boxes_xywh)
    np.testing.assert_array_equal(ours.confidence, theirs.confidence)
    assert ours.reasons == theirs.reasons and ours.keyframe.tolist() == theirs.keyframe.tolist()


def test_correction_is_an_anchor_and_only_its_spans_change(first, corrected):
    before, after = first.tracks[0], corrected.tracks[0]
    np.testing.assert_array_equal(after.boxes_xywh[10], CLIP.boxes_xywh[10])
    assert after.keyframe.tolist() == [p in (0, 10) for p in range(16)]
    assert after.confidence[10] == 1.0 and not after.flagged[10]
    assert [(s.first_frame, s.last_frame) for s in corrected.segments] == [(1, 9), (10, 15)]
    change = corrected.anchors[0]
    assert (change.frame, change.was_anchor) == (10, False)
    np.testing.assert_array_equal(change.box_before, before.boxes_xywh[10])
    # The first frame is an anchor too: untouched.
    np.testing.assert_array_equal(after.boxes_xywh[0], before.boxes_xywh[0])
    assert corrected.frames_tracked == 1 + 9 + 1 + 9 + 1 + 5  # fwd from 0, bwd from 10, fwd from 10


def test_retrack_is_reproducible_and_idempotent(first, corrected):
    previous = {1: PreviousTrack(first.tracks[0], first.scoring[1])}
    again = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, CONFIG,
                           previous=previous, width=96, height=72)
    np.testing.assert_array_equal(again.tracks[0].boxes_xywh, corrected.tracks[0].boxes_xywh)
    twice = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, CONFIG,
                           previous={1: PreviousTrack(corrected.tracks[0], corrected.scoring[1])}, width=96, height=72)
    assert not twice.changed and twice.frames_tracked == 0 and twice.segments == []
    np.testing.assert_array_equal(twice.tracks[0].boxes_xywh, corrected.tracks[0].boxes_xywh)
    assert twice.tracks[0].reasons == corrected.tracks[0].reasons


def test_retrack_starts_the_kernels_warm_up_only_when_it_tracks(corrected, monkeypatch):
    import annotator.review.retrack as retrack_module

    calls = []
    monkeypatch.setattr(retrack_module, "compile_kernels", lambda **kw: calls.append(kw))
    previous = {1: PreviousTrack(corrected.tracks[0], corrected.scoring[1])}
    same = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, CONFIG,
                          previous=previous, width=96, height=72)
    assert same.frames_tracked == 0 and calls == []
    later = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {13: tuple(CLIP.boxes_xywh[13])}}, CONFIG,
                           previous=previous)
    assert later.frames_tracked > 0 and calls == [{"wait": False}]


def test_segments_without_new_anchors_keep_their_rows(corrected):
    track = corrected.tracks[0]
    previous = {1: PreviousTrack(track, corrected.scoring[1])}
    later = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {13: tuple(CLIP.boxes_xywh[13])}}, CONFIG,
                           previous=previous)
    new = later.tracks[0]
    np.testing.assert_array_equal(new.boxes_xywh[:11], track.boxes_xywh[:11])
    np.testing.assert_array_equal(new.log_likelihood[:11], track.log_likelihood[:11])
    np.testing.assert_array_equal(new.signals["pass_iou"][:11], track.signals["pass_iou"][:11])
    assert [(s.first_frame, s.last_frame) for s in later.segments] == [(11, 12), (13, 15)]


def test_rows_between_two_anchors_carry_the_passes_agreement_and_are_scored_with_it(first, corrected, tmp_path):
    assert "pass_iou" not in first.tracks[0].signals  # nothing corrected: no second pass, no column
    track = corrected.tracks[0]
    pass_iou = track.signals["pass_iou"]
    between = np.zeros(16, bool)
    between[1:10] = True
    assert np.all((pass_iou[between] >= 0) & (pass_iou[between] <= 1))
    assert np.isnan(pass_iou[~between]).all()  # anchors, and the frames after the last one (forward only)
    # The shipped model has no between_anchors section (RESULTS.md "anchored-failure": it cost the simulated
    # reviewer time), so the rows between are scored as the track's own signals say.
    shipped = load_model(guided=CONFIG.tracker.uses_guide)  # the model of the run's kind
    assert shipped.between_anchors is None
    p_track, _ = track_p_fail(track.signals, track.keyframe, track.outside, shipped)
    np.testing.assert_array_equal(track.p_fail, p_track)
    # A model file with the section corrects exactly the rows between the two anchors.
    section = PassAgreement(log_odds=1.0, pass_iou=-4.7, intercept=2.0, info={})
    path = tmp_path / "model.json"
    path.write_text(json.dumps(dataclasses.replace(shipped, between_anchors=section).to_json()))
    config = dataclasses.replace(CONFIG, failure_model=str(path))
    previous = {1: PreviousTrack(first.tracks[0], first.scoring[1])}
    again = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, config,
                           previous=previous, width=96, height=72).tracks[0]
    np.testing.assert_array_equal(again.boxes_xywh, track.boxes_xywh)
    expected, _ = load_model(path).with_pass_agreement(p_track, np.where(track.keyframe, np.nan, pass_iou))
    np.testing.assert_allclose(again.p_fail, expected, rtol=0, atol=1e-15)
    assert not np.allclose(again.p_fail[between], p_track[between])
    np.testing.assert_array_equal(again.p_fail[~between], p_track[~between])


def test_a_lost_track_asks_for_keyframes_until_a_person_boxes_them(first):
    """With lost_threshold set below the track's mean p_fail, the re-track flags every 5th row and the last for a
    person to box; once they are human boxes the track is flagged by its doubtful spans again."""
    from annotator.failure import SIGNALS

    config = dataclasses.replace(CONFIG, flags=dataclasses.replace(CONFIG.flags, lost_threshold=1e-6,
                                                                   keyframe_every=5))
    asked = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {0: tuple(CLIP.boxes_xywh[0])}}, config).tracks[0]
    np.testing.assert_array_equal(asked.boxes_xywh, first.tracks[0].boxes_xywh)
    assert np.flatnonzero(asked.flagged).tolist() == [5, 10, 15]
    assert {asked.reasons[p] for p in (5, 10, 15)} == {"keyframe"}
    previous = {1: PreviousTrack(asked, first.scoring[1])}
    boxed = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {p: tuple(CLIP.boxes_xywh[p]) for p in (5, 10, 15)}},
                           config, previous=previous, width=96, height=72).tracks[0]
    assert "keyframe" not in boxed.reasons and boxed.keyframe[[0, 5, 10, 15]].all()
    reflagged, _, _ = reflag({name: boxed.signals[name] for name in SIGNALS}, boxed.keyframe, boxed.outside,
                             dataclasses.replace(config, flags=CONFIG.flags))
    np.testing.assert_array_equal(boxed.flagged, reflagged)


def test_backward_in_chunks_equals_buffered(first, corrected):
    previous = {1: PreviousTrack(first.tracks[0], first.scoring[1])}
    chunked = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, CONFIG,
                             previous=previous, max_buffer_frames=3)
    np.testing.assert_array_equal(chunked.tracks[0].boxes_xywh, corrected.tracks[0].boxes_xywh)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread here: no run goes ahead")
def test_passes_with_runs_ahead_store_the_rows_of_runs_in_step(first, monkeypatch):
    """Three runs and the voter on two kernel threads: the passes submit frames ahead; the same rows as when every
    frame is tracked at once (backward in chunks too)."""
    import sptpt.tracker as tracker_module

    config = resolve_config({"seed": 1, "tracker": {"n_particles": 30, "n_negatives": 10, "independent_runs": 3,
                                                    "run_choice": "consensus", "filter_vote": True}})
    previous = {1: PreviousTrack(first.tracks[0], first.scoring[1])}

    def run(max_buffer):
        return retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, config,
                              previous=previous, max_buffer_frames=max_buffer).tracks[0]

    previous_threads = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        submitted = []
        real_submit = tracker_module.InOrder.submit
        monkeypatch.setattr(tracker_module.InOrder, "submit",
                            lambda lane, call: submitted.append(1) or real_submit(lane, call))
        ahead, chunked = run(512), run(3)
        assert submitted  # the runs did go ahead
        monkeypatch.setattr(tracker_module, "_all_at_once", lambda threads, runs: False)
        in_step = run(512)
    finally:
        numba.set_num_threads(previous_threads)
    for name in ("boxes_xywh", "confidence", "log_likelihood", "accepted", "p_fail"):
        np.testing.assert_array_equal(getattr(ahead, name), getattr(in_step, name))
        np.testing.assert_array_equal(getattr(chunked, name), getattr(in_step, name))
    assert ahead.reasons == in_step.reasons


def test_pass_cache_reuses_passes_and_changes_no_number(corrected):
    cache: dict = {}
    start = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {0: tuple(CLIP.boxes_xywh[0])}}, CONFIG,
                           pass_cache=cache)
    again = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, CONFIG,
                           previous={1: PreviousTrack(start.tracks[0], start.scoring[1])}, width=96, height=72,
                           pass_cache=cache)
    assert again.frames_tracked == (1 + 9) + (1 + 5)  # the forward pass from frame 0 comes from the cache
    for key in ("boxes_xywh", "confidence", "log_likelihood", "accepted", "flagged"):
        np.testing.assert_array_equal(getattr(again.tracks[0], key), getattr(corrected.tracks[0], key))


def test_absence_marks_frames_outside_until_the_next_anchor(corrected):
    previous = {1: PreviousTrack(corrected.tracks[0], corrected.scoring[1])}
    absent = retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {4: None, 7: tuple(CLIP.boxes_xywh[7])}}, CONFIG,
                            previous=previous)
    track = absent.tracks[0]
    assert track.outside.tolist() == [4 <= p < 7 for p in range(16)]
    assert np.isnan(track.boxes_xywh[4:7]).all()
    assert track.reasons[4:7] == ("outside",) * 3 and track.flagged[4:7].all()
    assert track.keyframe[[0, 4, 7, 10]].all()
    assert not track.flagged[7]


# --------------------------------------------------------------------------- the output folder


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A real run on 28 PNG frames with --start 2 --step 2: 13 processed frames, source index = 2 * position + 2."""
    root = tmp_path_factory.mktemp("review")
    frames = write_frames(root / "seq", 28)
    box = tuple(make_clip(28, size=(96, 72), object_size=(24, 20)).boxes_xywh[2])
    annotate(frames, [Target(box, 1)], CONFIG, out_dir=root / "out", start=2, step=2, show_progress=False)
    return root / "out"


@pytest.fixture()
def out(run_dir, tmp_path):
    copy = tmp_path / "out"
    shutil.copytree(run_dir, copy)
    return copy


def test_kept_passes_give_the_boxes_of_passes_run_again_and_spare_their_tracking(out, tmp_path):
    """The run keeps its passes (passes.npz): a re-track reuses those its anchors still start, box for box."""
    from annotator.pass_cache import PASSES_NAME
    from annotator.track_store import STORE_NAME, read_store

    again = tmp_path / "again"
    shutil.copytree(out, again)
    tracked: dict[str, list[int]] = {}
    for folder in (out, again):
        for k, frame in enumerate((12, 20)):  # positions 5 and 9 of the 13 processed frames
            assert (folder / PASSES_NAME).is_file()  # written by the main command, then by every re-track
            if folder == again:
                (folder / PASSES_NAME).unlink()  # as before the passes were kept: every pass runs again
            fix = tmp_path / f"fix{k}.csv"
            fix.write_text(csv_row(frame, GT[frame]))
            result = apply_corrections(folder, fix, show_progress=False)
            tracked.setdefault(folder.name, []).append(result.retrack.frames_tracked)
    # Tracker calls (an init and the frames after it) of the passes run. Round 1, a correction at position 5:
    # forward from 0 over 1..4, backward from 5 over 4..1, forward from 5 over 6..12; the first is the main
    # command's track, kept. Round 2, at position 9: forward from 5 over 6..8 (kept from round 1), backward
    # from 9, forward from 9 over 10..12.
    assert tracked["again"] == [5 + 5 + 8, 4 + 4 + 4] and tracked["out"] == [5 + 8, 4 + 4]
    kept, rerun = read_store(out / STORE_NAME).tracks[0], read_store(again / STORE_NAME).tracks[0]
    for field in ("boxes_xywh", "confidence", "log_likelihood", "accepted", "flagged", "keyframe", "outside"):
        np.testing.assert_array_equal(getattr(kept, field), getattr(rerun, field), err_msg=field)
    assert kept.reasons == rerun.reasons and kept.scoring == rerun.scoring
    assert kept.signals.keys() == rerun.signals.keys()
    for name in kept.signals:
        np.testing.assert_array_equal(kept.signals[name], rerun.signals[name], err_msg=name)


def test_passes_are_kept_only_for_an_input_that_was_checked(out, tmp_path):
    """--no-verify may re-track changed bytes: their passes must not be stored under the recorded hash, nor
    the recorded hash's passes used on them. Right after the main command (track --corrections) the input counts
    as checked."""
    from annotator.pass_cache import PASSES_NAME

    (tmp_path / "fix.csv").write_text(csv_row(12, GT[12]))
    before = (out / PASSES_NAME).read_bytes()
    unchecked = apply_corrections(out, tmp_path / "fix.csv", show_progress=False, verify_input=False)
    assert unchecked.retrack.frames_tracked == 5 + 5 + 8  # every pass ran
    assert (out / PASSES_NAME).read_bytes() == before and PASSES_NAME not in [p.name for p in unchecked.written]
    assert json.loads((out / "run.json").read_text())["outputs"]["passes"] == [PASSES_NAME]  # still listed
    (tmp_path / "fix2.csv").write_text(csv_row(20, GT[20]))
    checked = correct_run(out, tmp_path / "fix2.csv", show_progress=False, verify_input=False, input_checked=True)
    assert checked.retrack.frames_tracked == 4 + 4 + 4  # forward from 12 not kept: that round wrote no passes
    (tmp_path / "fix3.csv").write_text(csv_row(24, GT[24]))
    again = correct_run(out, tmp_path / "fix3.csv", show_progress=False, verify_input=False, input_checked=True)
    assert again.retrack.frames_tracked == 2 + 2  # forward from 20 kept: backward from 24, forward from 24


def test_load_run_reads_back_what_annotate_wrote(run_dir):
    run = load_run(run_dir)
    track = run.tracks[0]
    assert track.frame_indices.tolist() == list(range(2, 28, 2))
    assert track.keyframe.tolist() == [True] + [False] * 12
    np.testing.assert_allclose(track.boxes_xywh, read_otb_boxes(run_dir / "seq.txt"), atol=5e-4)
    assert track.scoring[0] == "init" and set(track.scoring[1:]) <= {"bootstrap", "subspace"}


def test_a_run_json_from_before_a_flag_setting_reads_its_default_and_records_it_after_a_retrack(out):
    info = json.loads((out / "run.json").read_text())
    for key in ("lost_threshold", "keyframe_every"):
        del info["config"]["flags"][key]
    (out / "run.json").write_text(json.dumps(info))
    assert load_run(out).config.flags == FlagParams()
    fixes = out.parent / "fixes.csv"
    fixes.write_text(f"frame,x,y,w,h\n10,{','.join(f'{v:g}' for v in GT[10])}\n")
    apply_corrections(out, fixes, show_progress=False)
    flags = json.loads((out / "run.json").read_text())["config"]["flags"]
    assert flags["lost_threshold"] == 0.6 and flags["keyframe_every"] == 10


@pytest.mark.parametrize("edit", [
    lambda info: info.pop("input"),
    lambda info: info.pop("range"),
    lambda info: info.update(input="clip.mp4"),
    lambda info: info["range"].update(step="two"),
])
def test_a_hand_edited_run_json_is_refused_in_one_line(out, edit):
    info = json.loads((out / "run.json").read_text())
    edit(info)
    (out / "run.json").write_text(json.dumps(info))
    with pytest.raises(ToolError) as caught:
        load_run(out)
    assert caught.value.exit_code == EXIT_VALUE and "cannot use its configuration" in str(caught.value)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("damage, code", [("{", EXIT_VALUE), (None, EXIT_INPUT)])
def test_a_failure_model_damaged_or_gone_since_the_run_is_refused_before_tracking(out, tmp_path, damage, code):
    model = tmp_path / "model.json"
    model.write_text(json.dumps(load_model().to_json()))
    info = json.loads((out / "run.json").read_text())
    info["config"]["failure_model"] = str(model)
    (out / "run.json").write_text(json.dumps(info))
    assert load_run(out).config.failure_model == str(model)
    if damage is None:
        model.unlink()
    else:
        model.write_text(damage)
    with pytest.raises(ToolError) as caught:
        load_run(out)
    assert caught.value.exit_code == code and str(model) in str(caught.value) and "\n" not in str(caught.value)
    assert "run.json names" in str(caught.value)


def test_a_video_given_as_the_run_folder_is_named_as_a_file(run_dir, tmp_path):
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"\x00" * 10)
    with pytest.raises(ToolError, match="clip.mp4 is a file: give the output folder"):
        load_run(video)


def test_rewrite_without_changes_reproduces_the_exports(out):
    before = snapshot(out)
    (out.parent / "same.csv").write_text(csv_row(2, GT[2]))
    result = apply_corrections(out, out.parent / "same.csv", show_progress=False, rewrite_unchanged=True)
    assert not result.changed
    after = snapshot(out)
    for name in ("seq.txt", "times/seq_time.txt", "annotations.json", "flags.csv"):
        assert after[name] == before[name], name
    # And without rewrite_unchanged nothing is written at all.
    result = apply_corrections(out, out.parent / "same.csv", show_progress=False)
    assert snapshot(out) == after and "nothing re-tracked" in result.summary()


def test_apply_corrections_rewrites_every_output_consistently(out):
    fix = out.parent / "fix.csv"
    fix.write_text("frame,x,y,w,h\n" + csv_row(18, GT[18]))
    before = snapshot(out)
    result = apply_corrections(out, fix, show_progress=False)
    assert result.changed and {p.name for p in result.written} >= {
        "seq.txt", "annotations.json", "flags.csv", "overlay.mp4", "report.html", "run.json"}
    position = 8  # source frame 18
    # OTB (1-based) and COCO (0-based) hold the human box; COCO marks it a keyframe; flags do not flag it.
    otb = read_otb_boxes(out / "seq.txt")
    np.testing.assert_allclose(otb[position], GT[18], atol=1e-3)
    coco = json.loads((out / "annotations.json").read_text())
    image = next(i for i in coco["images"] if i["frame_index"] == 18)
    ann = next(a for a in coco["annotations"] if a["image_id"] == image["id"])
    assert ann["attributes"]["keyframe"] is True and ann["attributes"]["needs_review"] is False
    np.testing.assert_allclose(ann["bbox"], GT[18], atol=1e-3)
    assert sum(a["attributes"]["keyframe"] for a in coco["annotations"]) == 2
    flags = read_flags_csv(out / "flags.csv")
    assert flags.frame.tolist() == list(range(2, 28, 2)) and not flags.flagged[position]
    # The overlay has one frame per processed frame; the report lists the correction and what changed.
    assert len(open_frames(out / "overlay.mp4")) == 13
    report = (out / "report.html").read_text()
    assert "Corrections (1)" in report and "Last re-track" in report and 'class="corrected"' in report
    assert f"{fix}:2" in report
    info = json.loads((out / "run.json").read_text())
    assert info["review"]["anchors"] == [{"track_id": 1, "frame": 18, "box_xywh": [round(v, 3) for v in GT[18]],
                                          "source": f"{fix}:2"}]
    last = info["review"]["retracks"][-1]
    assert [(s["first_frame"], s["last_frame"]) for s in last["segments"]] == [(4, 16), (18, 26)]
    assert last["anchors"][0]["frame"] == 18 and last["anchors"][0]["box_before"] is not None
    assert info["created"] == json.loads(before["run.json"])["created"]
    # Applying the same file again changes nothing.
    again = snapshot(out)
    assert not apply_corrections(out, fix, show_progress=False).changed
    assert snapshot(out) == again


def test_rerendered_report_shows_each_span_by_expected_errors_with_its_worst_frame(out):
    """After a re-track the overlay is drawn again; each span's thumbnail is taken from its highest-p_fail frame."""
    from _report_page import parse, seek_seconds, shows_frame

    from annotator.run_report import by_expected_errors, flagged_spans

    info = json.loads((out / "run.json").read_text())
    # A model whose doubt grows with the distance from the last human box, so that a span's worst frame is not its
    # first whatever the shipped model's weights; and every frame it doubts at all flagged, one frame a span.
    model = load_model().to_json()
    model.update(coef=[float(name == "since_anchor") for name in model["features"]], intercept=-4.0,
                 mean=[0.0] * len(model["features"]), scale=[1.0] * len(model["features"]))
    (out.parent / "drift_model.json").write_text(json.dumps(model))
    info["config"]["failure_model"] = str(out.parent / "drift_model.json")
    info["config"]["flags"] = {**info["config"]["flags"], "threshold": 1e-9, "merge_gap": 0, "min_span": 1}
    (out / "run.json").write_text(json.dumps(info))
    (out.parent / "fix.csv").write_text("frame,x,y,w,h\n" + csv_row(12, GT[12]))
    result = apply_corrections(out, out.parent / "fix.csv", show_progress=False)
    spans = by_expected_errors([s for t in result.retrack.tracks for s in flagged_spans(t)])
    assert len(spans) >= 2 and any(s.worst != s.start for s in spans)
    rows = parse((out / "report.html").read_text()).rows
    assert [r["cells"][1] for r in rows] == [f"{s.first_frame}\u2013{s.last_frame}" for s in spans]
    fps = info["input"]["fps"]
    for row, span in zip(rows, spans):
        assert row["img"] and shows_frame(seek_seconds(row["thumb_seek"]), span.worst, fps), (row, span)
        assert shows_frame(seek_seconds(row["seek"]), span.start, fps)


def test_rows_before_the_retracked_segment_keep_their_boxes_and_signals(out):
    (out.parent / "a.csv").write_text(csv_row(10, GT[10]))
    apply_corrections(out, out.parent / "a.csv", show_progress=False)
    first = snapshot(out)
    (out.parent / "b.csv").write_text(csv_row(20, GT[20]) + csv_row(10, GT[10]))
    result = apply_corrections(out, out.parent / "b.csv", show_progress=False)
    assert [(c.frame) for c in result.retrack.anchors] == [20]  # frame 10 is already in force
    second = snapshot(out)
    kept = 5  # positions 0..4 = source frames 2..10: the segment before frame 10 is not re-tracked
    old, new = first["seq.txt"].decode().splitlines(), second["seq.txt"].decode().splitlines()
    assert old[:kept] == new[:kept] and old != new
    # A row's p_fail also reads the signals of the LOOKAHEAD frames after it (the failure model's centred windows):
    # the last LOOKAHEAD rows before the re-tracked segment may get another probability, and with it another
    # confidence, flag and reason. Their signals stay, and the rows before them stay byte for byte.
    old, new = (list(csv.DictReader(io.StringIO(first["flags.csv"].decode()))),
                list(csv.DictReader(io.StringIO(second["flags.csv"].decode()))))
    assert old[: kept - LOOKAHEAD] == new[: kept - LOOKAHEAD] and old != new
    def signals(row: dict[str, str]) -> dict[str, str]:
        return {k: v for k, v in row.items() if k not in ("confidence", "flagged", "reason", "p_fail")}

    for before, after in zip(old[kept - LOOKAHEAD : kept], new[kept - LOOKAHEAD : kept]):
        assert signals(before) == signals(after)
    info = json.loads(second["run.json"])
    assert [a["frame"] for a in info["review"]["anchors"]] == [10, 20] and len(info["review"]["retracks"]) == 2


def test_absent_rows_and_coco_corrections(out):
    (out.parent / "gone.csv").write_text(csv_row(14) + csv_row(20, GT[20], 1))
    apply_corrections(out, out.parent / "gone.csv", show_progress=False)
    flags = read_flags_csv(out / "flags.csv")
    assert [f for f, r in zip(flags.frame, flags.reason) if r == "outside"] == [14, 16, 18]
    assert np.isnan(read_otb_boxes(out / "seq.txt")[6:9]).all()
    coco = json.loads((out / "annotations.json").read_text())
    frame_of = {i["id"]: i["frame_index"] for i in coco["images"]}
    assert sorted(frame_of[a["image_id"]] for a in coco["annotations"]) == [f for f in range(2, 28, 2)
                                                                            if f not in (14, 16, 18)]
    # Edit the COCO file elsewhere: move the keyframe at 20 and add one at 6; apply it as corrections.
    for ann in coco["annotations"]:
        if frame_of[ann["image_id"]] == 6:
            ann["attributes"]["keyframe"] = True
            ann["bbox"] = [round(v, 3) for v in GT[6]]
    edited = out.parent / "edited.json"
    edited.write_text(json.dumps(coco))
    result = apply_corrections(out, edited, show_progress=False)
    assert [c.frame for c in result.retrack.anchors] == [6]  # 2, 20 are unchanged; absences are not in COCO
    assert read_flags_csv(out / "flags.csv").reason[6:9] == ("outside",) * 3


@pytest.mark.parametrize(
    "text, code, fragment",
    [
        ("frame,x,y,w,h\n3,10,10,20,20\n", EXIT_VALUE, "fix.csv:2: frame 3 was not processed"),
        ("frame,x,y,w,h,track_id\n4,10,10,20,20,2\n", EXIT_VALUE, "fix.csv:2: unknown track id 2"),
        ("4,10,10,20\n", EXIT_VALUE, "fix.csv:1: expected 5 or 6 fields"),
    ],
)
def test_bad_corrections_leave_the_folder_unchanged(out, text, code, fragment):
    before = snapshot(out)
    (out.parent / "fix.csv").write_text(text)
    with pytest.raises(ToolError) as info:
        apply_corrections(out, out.parent / "fix.csv", show_progress=False)
    assert info.value.exit_code == code and fragment in str(info.value)
    assert snapshot(out) == before


def test_failure_while_writing_leaves_the_folder_unchanged(out, monkeypatch):
    import annotator.publish

    def broken(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(annotator.publish, "render_report", broken)
    before = snapshot(out)
    (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
    with pytest.raises(RuntimeError, match="disk on fire"):
        apply_corrections(out, out.parent / "fix.csv", show_progress=False)
    assert snapshot(out) == before
    assert not [p for p in out.parent.iterdir() if "retrack" in p.name]


def test_changed_input_is_refused(out, tmp_path):
    info = json.loads((out / "run.json").read_text())
    moved = tmp_path / "seq2"
    shutil.copytree(info["input"]["path"], moved)
    frame = cv2.imread(str(moved / "0004.png"))
    cv2.imwrite(str(moved / "0004.png"), 255 - frame)
    info["input"]["path"] = str(moved)
    (out / "run.json").write_text(json.dumps(info))
    (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
    with pytest.raises(ToolError, match="changed since the run") as err:
        apply_corrections(out, out.parent / "fix.csv", show_progress=False)
    assert err.value.exit_code == EXIT_INPUT


def test_a_round_without_render_removes_the_overlay_and_the_next_that_renders_brings_it_back(out, tmp_path):
    (tmp_path / "fix.csv").write_text(csv_row(12, GT[12]))
    result = apply_corrections(out, tmp_path / "fix.csv", show_progress=False, render=False)
    assert result.changed and result.overlay_removed and "overlay.mp4 removed (--no-render)" in result.summary()
    assert not (out / "overlay.mp4").exists()
    info = json.loads((out / "run.json").read_text())
    assert "overlay" in info["formats"] and "overlay" not in info["outputs"]
    assert "overlay.mp4" not in (out / "report.html").read_text()
    # The same corrections again: nothing to re-track, but the overlay is rendered again.
    again = apply_corrections(out, tmp_path / "fix.csv", show_progress=False)
    assert not again.changed and "overlay.mp4 rendered again" in again.summary()
    assert len(open_frames(out / "overlay.mp4")) == 13 and "overlay.mp4" in (out / "report.html").read_text()
    assert json.loads((out / "run.json").read_text())["outputs"]["overlay"] == ["overlay.mp4"]
    # And once it is there, the same corrections change nothing.
    before = snapshot(out)
    assert not apply_corrections(out, tmp_path / "fix.csv", show_progress=False).written
    assert snapshot(out) == before


def test_a_round_without_render_that_fails_keeps_the_overlay(out, tmp_path, monkeypatch):
    """The stale overlay is moved aside first and back on a failure, so run.json never lists a missing file."""
    import os

    (tmp_path / "fix.csv").write_text(csv_row(12, GT[12]))
    real_replace = os.replace
    before = snapshot(out)

    def busy_overlay(src, dst):  # Windows, while a player holds the file open
        if Path(src).name == "overlay.mp4":
            raise PermissionError(13, "The process cannot access the file", str(src))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", busy_overlay)
    with pytest.raises(ToolError, match="overlay.mp4 cannot be removed.*nothing was changed") as caught:
        apply_corrections(out, tmp_path / "fix.csv", show_progress=False, render=False)
    assert caught.value.exit_code == 5 and snapshot(out) == before

    def full_disk(src, dst):
        if Path(dst) == out / "run.json":  # the last move in, not the write beside the folder
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(ToolError, match="run.json still describes the previous state"):
        apply_corrections(out, tmp_path / "fix.csv", show_progress=False, render=False)
    assert (out / "overlay.mp4").read_bytes() == before["overlay.mp4"]
    assert json.loads((out / "run.json").read_text())["outputs"]["overlay"] == ["overlay.mp4"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_without_render_only_an_overlay_that_was_there_is_removed(out, tmp_path):
    (tmp_path / "fix.csv").write_text(csv_row(12, GT[12]))
    first = apply_corrections(out, tmp_path / "fix.csv", show_progress=False, render=False)
    assert first.overlay_removed
    entry = json.loads((out / "run.json").read_text())["review"]["retracks"][-1]
    assert entry["overlay"] == "removed (--no-render)"
    (tmp_path / "fix2.csv").write_text(csv_row(20, GT[20]))
    second = apply_corrections(out, tmp_path / "fix2.csv", show_progress=False, render=False)
    assert second.changed and not second.overlay_removed and "removed" not in second.summary()
    # A run without an overlay in its formats: a file of that name is not the run's, and stays.
    info = json.loads((out / "run.json").read_text())
    info["formats"] = [f for f in info["formats"] if f != "overlay"]
    (out / "run.json").write_text(json.dumps(info))
    (out / "overlay.mp4").write_text("mine")
    (tmp_path / "fix3.csv").write_text(csv_row(24, GT[24]))
    third = apply_corrections(out, tmp_path / "fix3.csv", show_progress=False, render=False)
    assert third.changed and not third.overlay_removed and (out / "overlay.mp4").read_text() == "mine"


def test_retrack_command(out):
    app = typer.Typer()
    app.command()(retrack_command)
    (out.parent / "bad.csv").write_text("frame,x,y,w,h\n5,1,2,3,4\n")
    result = CliRunner().invoke(app, [str(out), "--corrections", str(out.parent / "bad.csv"), "--quiet"])
    assert result.exit_code == EXIT_VALUE
    assert result.output.strip().count("\n") == 0 and "bad.csv:2: frame 5 was not processed" in result.output
    (out.parent / "good.csv").write_text(csv_row(8, GT[8]))
    result = CliRunner().invoke(app, [str(out), "--corrections", str(out.parent / "good.csv"), "--merge", "blend",
                                      "--no-render"])
    assert result.exit_code == 0, result.output
    assert "1 new or changed correction" in result.output and "overlay.mp4 removed" in result.output
    assert not (out / "overlay.mp4").exists()
    assert json.loads((out / "run.json").read_text())["review"]["retracks"][0]["merge"] == "blend"


def _video_run(tmp_path):
    """A 12-frame clip as an H.264 video, annotated into ``tmp_path / "out"``."""
    import imageio_ffmpeg

    clip = make_clip(12, size=(96, 72), object_size=(24, 20))
    video = tmp_path / "clip.mp4"
    writer = imageio_ffmpeg.write_frames(str(video), (96, 72), fps=25.0, codec="libx264", macro_block_size=1,
                                         ffmpeg_log_level="error", output_params=["-g", "4"])
    writer.send(None)
    for frame in clip.frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    annotate(video, [Target(tuple(clip.boxes_xywh[0]), 1, "ball")], CONFIG, out_dir=tmp_path / "out",
             show_progress=False)
    return clip, video


def test_video_input(tmp_path):
    """A video source: one decoding sweep for the passes, a second for the overlay; frames checked by index."""
    clip, _ = _video_run(tmp_path)
    (tmp_path / "fix.csv").write_text(csv_row(4, clip.boxes_xywh[4], 1) + csv_row(9, clip.boxes_xywh[9], 1))
    result = apply_corrections(tmp_path / "out", tmp_path / "fix.csv", show_progress=False)
    assert [c.frame for c in result.retrack.anchors] == [4, 9]
    assert len(open_frames(tmp_path / "out" / "overlay.mp4")) == 12
    coco = json.loads((tmp_path / "out" / "annotations.json").read_text())
    assert coco["categories"][0]["name"] == "ball"
    assert [a["attributes"]["keyframe"] for a in coco["annotations"]].count(True) == 3


def test_a_verified_video_is_not_decoded_again_to_count_its_frames(tmp_path, monkeypatch):
    """The content hash says the bytes are the run's, so the recorded count stands; without that, ffmpeg counts."""
    import annotator.frame_sources

    clip, video = _video_run(tmp_path)
    out = tmp_path / "out"
    info = json.loads((out / "run.json").read_text())
    assert info["input"]["damage"] is None and info["input"]["frame_count"] == 12
    counted = []
    real_count = annotator.frame_sources._count_video_frames
    monkeypatch.setattr(annotator.frame_sources, "_count_video_frames",
                        lambda *a, **k: counted.append(1) or real_count(*a, **k))
    (tmp_path / "fix.csv").write_text(csv_row(4, clip.boxes_xywh[4], 1))
    apply_corrections(out, tmp_path / "fix.csv", show_progress=False)
    assert counted == []
    apply_corrections(out, tmp_path / "fix.csv", show_progress=False, verify_input=False)
    assert counted == [1]
    # A run made before run.json recorded the damage: counted.
    info = json.loads((out / "run.json").read_text())
    del info["input"]["damage"]
    (out / "run.json").write_text(json.dumps(info))
    apply_corrections(out, tmp_path / "fix.csv", show_progress=False)
    assert counted == [1, 1]
    # Other bytes: refused by the hash, before any decoding.
    video.write_bytes(video.read_bytes() + b"\0")
    with pytest.raises(ToolError, match="changed since the run"):
        apply_corrections(out, tmp_path / "fix.csv", show_progress=False)
    assert counted == [1, 1]


# --------------------------------------------------------------------------- retrack: moved input, interrupted (#14)


def _retrack_cli(*args):
    app = typer.Typer()
    app.command()(retrack_command)
    return CliRunner().invoke(app, [str(a) for a in args])


def test_retrack_follows_a_moved_input_given_with_input(out, tmp_path):
    info = json.loads((out / "run.json").read_text())
    moved = tmp_path / "moved" / "seq"
    shutil.move(info["input"]["path"], moved)
    try:
        (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
        refused = _retrack_cli(out, "--corrections", out.parent / "fix.csv", "--quiet")
        assert refused.exit_code == EXIT_INPUT and "give its new path with --input PATH" in refused.output
        done = _retrack_cli(out, "--corrections", out.parent / "fix.csv", "--input", moved, "--quiet")
        assert done.exit_code == 0, done.output
        assert json.loads((out / "run.json").read_text())["input"]["path"] == str(moved.resolve())
        assert load_run(out).video.path == str(moved.resolve())
        # A later re-track finds the input at its new place without --input.
        (out.parent / "fix2.csv").write_text(csv_row(20, GT[20]))
        again = _retrack_cli(out, "--corrections", out.parent / "fix2.csv", "--quiet")
        assert again.exit_code == 0, again.output
    finally:
        shutil.move(moved, info["input"]["path"])


def test_retrack_refuses_an_input_that_is_not_the_runs(out, tmp_path):
    info = json.loads((out / "run.json").read_text())
    other = tmp_path / "other"
    shutil.copytree(info["input"]["path"], other)
    frame = cv2.imread(str(other / "0004.png"))
    cv2.imwrite(str(other / "0004.png"), 255 - frame)
    before = snapshot(out)
    (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
    # --no-verify does not skip the check of an --input: the hash is what ties it to the run.
    result = _retrack_cli(out, "--corrections", out.parent / "fix.csv", "--input", other, "--no-verify", "--quiet")
    assert result.exit_code == EXIT_INPUT and "is not the input of this run" in result.output
    assert result.output.strip().count("\n") == 0
    assert snapshot(out) == before


def test_retrack_interrupted_says_so_and_changes_nothing(out, monkeypatch):
    import annotator.review

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(annotator.review, "apply_corrections", interrupted)
    before = snapshot(out)
    (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
    result = _retrack_cli(out, "--corrections", out.parent / "fix.csv", "--quiet")
    assert result.exit_code == 130
    assert "interrupted; nothing in" in result.output and "was changed" in result.output
    assert snapshot(out) == before


def test_report_shows_the_absolute_input_path_before_and_after_a_retrack(tmp_path, monkeypatch):
    frames = write_frames(tmp_path / "seq", 8)
    monkeypatch.chdir(tmp_path)
    truth = make_clip(8, size=(96, 72), object_size=(24, 20)).boxes_xywh
    annotate(Path("seq"), [Target(tuple(truth[0]), 1)], CONFIG, out_dir=Path("out"), show_progress=False)
    absolute = str(frames.resolve())
    header = f'<div class="muted">{absolute} &middot;'
    assert header in (tmp_path / "out" / "report.html").read_text()
    fix = tmp_path / "fix.csv"
    fix.write_text("frame,x,y,w,h\n" + csv_row(5, truth[5]))
    assert apply_corrections(Path("out"), fix, show_progress=False).changed
    assert header in (tmp_path / "out" / "report.html").read_text()


def test_a_run_that_read_photos_sideways_is_refused_and_a_current_one_is_not(out, tmp_path):
    """Runs made before EXIF orientations were applied hold boxes in the images as stored: re-tracking them on
    upright frames would give wrong boxes without a word."""
    from PIL import Image

    info = json.loads((out / "run.json").read_text())
    assert info["input"]["exif_orientation"] == "applied"
    folder = tmp_path / "seq"  # a copy: the module's runs share the original
    shutil.copytree(info["input"]["path"], folder)
    info["input"]["path"] = str(folder)
    for image_path in sorted(folder.glob("*.png"))[:3]:  # orientation 3 (upside down): same size, so it opens
        image = Image.open(image_path)
        exif = image.getexif()
        exif[274] = 3
        image.save(image_path, exif=exif)
    (tmp_path / "fix.csv").write_text(csv_row(8, GT[8]))
    del info["input"]["exif_orientation"]
    info["input"].pop("content_hash", None)  # the images were rewritten above; the hash is not what is checked
    (out / "run.json").write_text(json.dumps(info))
    before = snapshot(out)
    old = _retrack_cli(out, "--corrections", tmp_path / "fix.csv", "--quiet")
    assert old.exit_code == EXIT_INPUT and old.output.count("\n") == 1, old.output
    assert "3 of its images carry an EXIF orientation" in old.output and "re-run the annotation" in old.output
    assert snapshot(out) == before
    info["input"]["exif_orientation"] = "applied"
    (out / "run.json").write_text(json.dumps(info))
    assert _retrack_cli(out, "--corrections", tmp_path / "fix.csv", "--quiet").exit_code == 0

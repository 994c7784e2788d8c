"""benchmarks/_right_tracks.py: restarted segments and the true boxes' look, the two measures of how the failure model
flags tracks that are right."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from annotator.failure.fit import Sample
from annotator.failure.model import FEATURES, model_from_fit
from benchmarks._right_tracks import (
    LOOK,
    RIGHT_CAP,
    segment_id,
    segment_rows,
    segments_flagged,
    sequence_of,
    truth_flagged,
    truth_look,
)
from sptpt_dev.synthetic import changing_object


def _otb_root(tmp_path, name: str, frames: list[np.ndarray], boxes: np.ndarray):
    """An OTB-layout root holding one sequence: its images and 1-based ground truth."""
    (tmp_path / name / "img").mkdir(parents=True)
    for i, frame in enumerate(frames):
        cv2.imwrite(str(tmp_path / name / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    rows = [f"{x + 1:.2f},{y + 1:.2f},{w:.2f},{h:.2f}" for x, y, w, h in boxes]
    (tmp_path / name / "groundtruth_rect.txt").write_text("\n".join(rows) + "\n")
    return tmp_path


def test_segment_ids_name_their_sequence_and_are_safe_batch_ids():
    from annotator.manifest import safe_item_id

    for name in ("Jogging.1", "Bolt2", "FaceOcc1"):
        item = segment_id(name, 160)
        assert sequence_of(item) == name and safe_item_id(item) == item
    assert sequence_of("Jogging.2") == "Jogging.2"  # a whole run is its own sequence


def test_segments_start_every_so_many_frames_from_the_true_box_and_skip_short_tails(tmp_path):
    video, boxes = changing_object(0.1, frames=105)
    root = _otb_root(tmp_path, "Alpha", video, boxes)
    rows = segment_rows(root, length=40, every=40)
    # Starts 0, 40, 80; the last one runs 25 frames (the sequence ends), a start at 100 would leave 5: none.
    assert [(r["id"], r["start"], r["stop"]) for r in rows] == [
        ("Alpha-from-0", 0, 40), ("Alpha-from-40", 40, 80), ("Alpha-from-80", 80, 105)]
    assert rows[1]["box"] == "80.00,40.00,32.00,32.00"  # the true box of frame 40, 0-based
    assert rows[1]["video"] == str(root / "Alpha" / "img")


def test_the_segments_script_writes_a_manifest_the_batch_reads(tmp_path):
    from _benchmark_scripts import run_benchmark

    video, boxes = changing_object(0.1, frames=30)
    root = _otb_root(tmp_path / "otb", "Alpha", video, boxes)
    out = tmp_path / "runs" / "robust-s0"
    done = run_benchmark("segments", "--otb", str(root), "--out", str(out), "--length", "20", "--every", "20",
                         "--preset", "fast", "--workers", "1", timeout=600)
    assert done.returncode == 0, done.stderr
    with open(tmp_path / "runs" / "robust-s0.csv", newline="") as f:
        assert [row["id"] for row in csv.DictReader(f)] == ["Alpha-from-0"]
    assert (out / "Alpha-from-0" / "tracks.npz").is_file()


def _look_model() -> object:
    """A model that reads only ncc_memory: low on a box unlike the object's past."""
    coef = np.array([-3.0 if f == "ncc_memory" else 0.0 for f in FEATURES])
    mean = np.array([0.5 if f == "ncc_memory" else 0.0 for f in FEATURES])
    return model_from_fit(FEATURES, mean, np.full(len(FEATURES), 0.1), coef, -2.0, 0.5, {})


def test_the_true_boxes_of_an_object_that_changes_its_look_are_flagged_by_a_model_of_raw_appearance(tmp_path):
    assert "ncc_memory" in LOOK and "run_iou" not in LOOK and "box_with_background" not in LOOK
    rigid, rigid_boxes = changing_object(0.1)
    changing, changing_boxes = changing_object(0.8, seed=6)
    root = _otb_root(tmp_path, "Rigid", rigid, rigid_boxes)
    _otb_root(tmp_path, "Changing", changing, changing_boxes)
    medians = np.zeros(len(FEATURES))
    medians[FEATURES.index("run_iou")] = 0.9
    look = truth_look([root], ["Rigid", "Changing"], medians, workers=1)
    # The runs' signals sit at their right-frame level, and appearance features that read them see it.
    k = FEATURES.index("ncc_memory")
    parted = (1 - np.clip(look["Changing"][1:, k], 0, 1)) * (1 - 0.9)
    np.testing.assert_allclose(look["Changing"][1:, FEATURES.index("ncc_memory_parted")], parted)
    shares = truth_flagged({"Rigid": _look_model(), "Changing": _look_model()}, look, medians)
    assert shares["Rigid"] == 0.0
    assert shares["Changing"] > 0.8 > RIGHT_CAP  # right boxes, flagged for how the object looks
    without = model_from_fit(FEATURES, np.zeros(len(FEATURES)), np.ones(len(FEATURES)), np.zeros(len(FEATURES)),
                             -2.0, 0.5, {})
    assert truth_flagged({"Rigid": without, "Changing": without}, look, medians) == {"Rigid": 0.0, "Changing": 0.0}


def test_segment_figures_count_right_and_wrong_frames_of_every_seed_apart():
    k = FEATURES.index("run_iou")
    coef = np.where(np.arange(len(FEATURES)) == k, -10.0, 0.0)
    model = model_from_fit(FEATURES, np.zeros(len(FEATURES)), np.ones(len(FEATURES)), coef, 0.0, 0.5, {})

    def sample(seed, run_iou, failed):
        features = np.zeros((len(run_iou), len(FEATURES)))
        features[:, k] = run_iou
        use = np.ones(len(run_iou), bool)
        use[0] = False
        return Sample("Alpha", seed, features, np.array(failed), use)

    # Frame 0 is the given box. Frames 1-10 agree (not flagged), 11-20 disagree (one flagged span); in seed 0
    # frames 15-20 are wrong, in seed 1 none.
    agree = [1.0] * 11 + [-1.0] * 10
    figures = segments_flagged({"Alpha": model}, [sample(0, agree, [False] * 15 + [True] * 6),
                                                  sample(1, agree, [False] * 21)])
    assert figures["Alpha"]["wrong"] == pytest.approx(6 / 40)
    assert figures["Alpha"]["right_flagged"] == pytest.approx((4 + 10) / (14 + 20))
    assert figures["Alpha"]["wrong_flagged"] == 1.0

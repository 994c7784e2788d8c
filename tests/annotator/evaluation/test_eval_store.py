"""eval reads an output folder's track store: runs of part of a video score exactly the frames they hold.

Issue #14 item 2: a run made with ``--start``/``--stop`` (or a batch with
``--stop``) used to fail with "has 150 rows but the ground truth has 291".
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotator.cli import _with_default_command, app
from annotator.evaluation import EvaluationError, evaluate_result_file, evaluate_results_dir, evaluate_sequence
from annotator.otb_format import write_otb_boxes
from annotator.track_store import STORE_NAME, RunStore, write_store
from annotator.tracks import TrackResult, VideoInfo
from sptpt_dev.synthetic import make_clip

VIDEO = VideoInfo(path="Alpha", name="Alpha", width=96, height=72, fps=30.0, frame_count=20)


def _track(frames, boxes, track_id=1) -> TrackResult:
    n = len(frames)
    return TrackResult(track_id=track_id, label="object", frame_indices=np.asarray(frames), boxes_xywh=boxes,
                       confidence=np.full(n, 0.9), log_likelihood=np.ones(n), accepted=np.ones(n, bool),
                       flagged=np.zeros(n, bool), reasons=("",) * n, keyframe=np.eye(1, n, dtype=bool)[0],
                       outside=np.zeros(n, bool), seconds=np.zeros(n))


def _gt(n: int) -> np.ndarray:
    rng = np.random.default_rng(5)
    return np.column_stack([rng.uniform(0, 50, (n, 2)), rng.uniform(10, 30, (n, 2))])


def test_a_store_of_part_of_the_video_scores_exactly_its_frames(tmp_path):
    gt = _gt(20)
    write_otb_boxes(tmp_path / "gt.txt", gt)
    frames = np.arange(4, 16, 2)
    pred = gt[frames] + np.array([0.5, -0.25, 1.0, 0.0])
    out = tmp_path / "run"
    out.mkdir()
    write_store(out / STORE_NAME, RunStore(video=VIDEO, start=4, stop=16, step=2, tracks=[_track(frames, pred)]))
    pairs: list = []
    score = evaluate_result_file(out, tmp_path / "gt.txt", name="Alpha", pairs=pairs)
    expected = evaluate_sequence(pred, gt[frames], name="Alpha")
    assert score.auc == expected.auc and score.precision_20 == expected.precision_20
    assert [pair.note for pair, _ in pairs] == ["Alpha: scored the 6 frames the run processed (source frames 4-14, "
                                                "every 2nd) against those rows of the 20-row ground truth"]


def test_a_whole_run_needs_no_note_and_a_longer_store_is_refused(tmp_path):
    gt = _gt(8)
    write_otb_boxes(tmp_path / "gt.txt", gt)
    out = tmp_path / "run"
    out.mkdir()
    write_store(out / STORE_NAME, RunStore(video=dataclasses.replace(VIDEO, frame_count=8), start=0, stop=8, step=1,
                                           tracks=[_track(np.arange(8), gt)]))
    pairs: list = []
    assert evaluate_result_file(out, tmp_path / "gt.txt", pairs=pairs).auc > 0.95 and pairs[0][0].note is None
    assert pairs[0][0].name == "Alpha"  # the run's own name, not the ground truth's folder's


@pytest.mark.parametrize("frames", [9, 20])
def test_a_run_of_a_video_of_another_length_is_refused_unless_overlap(tmp_path, frames):
    """A ground truth of 8 rows for a 9- or 20-frame video is another video's (or another cut): refused, with the
    way out; --overlap scores the 8 frames both hold, and says so."""
    gt = _gt(8)
    write_otb_boxes(tmp_path / "gt.txt", gt)
    out = tmp_path / "run"
    out.mkdir()
    boxes = np.vstack([gt, np.repeat(gt[:1], frames - 8, axis=0)])
    write_store(out / STORE_NAME, RunStore(video=dataclasses.replace(VIDEO, frame_count=frames), start=0,
                                           stop=frames, step=1, tracks=[_track(np.arange(frames), boxes)]))
    with pytest.raises(EvaluationError, match=rf"is of a {frames}-frame video but the ground truth .* has 8 rows: "
                                              r".*--overlap to score the frames both hold"):
        evaluate_result_file(out, tmp_path / "gt.txt")
    code, _, err = _run("eval", out, tmp_path / "gt.txt")
    assert code == 4 and err.count("\n") == 1 and "--overlap" in err
    pairs: list = []
    assert evaluate_result_file(out, tmp_path / "gt.txt", pairs=pairs, overlap=True).auc > 0.95
    assert pairs[0][0].note == f"Alpha: {frames - 8} frame{'s' if frames > 9 else ''} of the run past the 8-row " \
                               "ground truth left out (--overlap)"
    code, table, err = _run("eval", out, tmp_path / "gt.txt", "--overlap")
    assert code == 0 and "ground truth left out (--overlap)" in err and "Alpha" in table


def test_a_multi_track_store_is_picked_by_otb_multi_target_name(tmp_path):
    gt = _gt(6)
    root = tmp_path / "otb"
    for k in (1, 2):
        (root / f"Jog.{k}").mkdir(parents=True)
        write_otb_boxes(root / f"Jog.{k}" / "groundtruth_rect.txt", gt + k)
    results = tmp_path / "res"
    store = RunStore(video=dataclasses.replace(VIDEO, frame_count=6), start=0, stop=6, step=1,
                     tracks=[_track(np.arange(6), gt + 1, 1),
                                                                   _track(np.arange(6), gt + 2, 2)])
    for k in (1, 2):
        (results / f"Jog.{k}").mkdir(parents=True)
        write_store(results / f"Jog.{k}" / STORE_NAME, store)
    score = evaluate_results_dir(root, results)
    assert all(s.auc > 0.95 for s in score.sequences.values())
    with pytest.raises(EvaluationError, match=r"holds tracks \[1, 2\]: name the sequence"):
        evaluate_result_file(results / "Jog.1", root / "Jog.1" / "groundtruth_rect.txt", name="Jog")


@pytest.fixture(scope="module")
def otb_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("otb")
    for seed, name in enumerate(("Alpha", "Beta")):
        clip = make_clip(24, size=(96, 72), object_size=(24, 20), seed=seed)
        (root / name / "img").mkdir(parents=True)
        for i, frame in enumerate(clip.frames):
            cv2.imwrite(str(root / name / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        write_otb_boxes(root / name / "groundtruth_rect.txt", clip.boxes_xywh)
    return root


def _run(*args) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, _with_default_command([str(a) for a in args]))
    return result.exit_code, result.stdout, result.stderr


def test_eval_of_a_start_stop_run_from_the_command_line(otb_root, tmp_path):
    box = ",".join(f"{v:.3f}" for v in make_clip(24, size=(96, 72), object_size=(24, 20), seed=0).boxes_xywh[3])
    out = tmp_path / "alpha"
    code, _, err = _run(otb_root / "Alpha", "--box", box, "--start", 3, "--stop", 15, "--out", out, "--no-render",
                        "--config", _fast(tmp_path), "--quiet")
    assert code == 0, err
    code, table, err = _run("eval", out, otb_root / "Alpha" / "groundtruth_rect.txt")
    assert code == 0, err
    assert "scored the 12 frames the run processed (source frames 3-14)" in err
    assert "Alpha" in table


def test_eval_of_a_batch_with_stop_and_sequences(otb_root, tmp_path):
    out = tmp_path / "batch"
    code, _, err = _run("batch", "--otb-root", otb_root, "--out", out, "--stop", 10, "--no-render", "--config",
                        _fast(tmp_path), "--quiet", "--workers", 1)
    assert code == 0, err
    code, table, err = _run("eval", out, otb_root)
    assert code == 0, err
    assert err.count("scored the 10 frames the run processed (source frames 0-9)") == 2
    # Only one sequence has results: the dataset eval scores it and names the one left out; --sequences naming a
    # sequence without a result is refused with the path expected.
    shutil.rmtree(out / "Beta")
    code, table, err = _run("eval", out, otb_root)
    assert code == 0, err
    assert "Alpha" in table and "Beta" not in table
    assert "1 sequence of" in err and "without a result left out: Beta" in err
    code, _, err = _run("eval", out, otb_root, "--sequences", "Alpha,Beta")
    assert code != 0 and "no result for 1 of 2" in err and str(out / "Beta") in err
    code, table, err = _run("eval", out, otb_root, "--sequences", "Alpha")
    assert code == 0, err
    assert "Alpha" in table and "Beta" not in table
    code, _, err = _run("eval", out, otb_root / "Alpha" / "groundtruth_rect.txt", "--sequences", "Alpha")
    assert code == 4 and "--sequences picks sequences of a dataset" in err


def _fast(tmp_path: Path) -> Path:
    config = tmp_path / "fast.yaml"
    config.write_text("tracker:\n  n_particles: 60\n  n_negatives: 20\n")
    return config


def test_eval_scores_the_failure_probability_of_stores_and_plots_its_calibration(tmp_path):
    gt = _gt(20)
    write_otb_boxes(tmp_path / "gt.txt", gt)
    pred = gt.copy()
    pred[10:] += [40.0, 40.0, 0.0, 0.0]  # lost from frame 10: IoU 0
    track = _track(np.arange(20), pred)
    p_fail = np.where(np.arange(20) >= 9, 0.9, 0.1)
    flagged = np.arange(20) >= 10
    track = TrackResult(**{**{k: getattr(track, k) for k in track.__dataclass_fields__},
                           "flagged": flagged, "reasons": tuple("doubt:flow" if f else "" for f in flagged),
                           "signals": {"p_fail": p_fail}})
    (tmp_path / "run").mkdir()
    write_store(tmp_path / "run" / STORE_NAME, RunStore(video=VIDEO, start=0, stop=20, step=1, tracks=[track]))
    code, table, err = _run("eval", tmp_path / "run", tmp_path / "gt.txt", "--out", tmp_path / "eval")
    assert code == 0, err
    assert "## Failure probability and flags (1 sequences, 20 frames)" in table
    assert "| AUROC of p_fail for failure frames (IoU < 0.5) | 0.950 |" in table  # frame 9: a tie, half
    assert "| flag precision | 1.000 |" in table and "| flag recall | 1.000 |" in table
    # Calibration: bin 0.1 holds 9 good frames (error 0.1), bin 0.9 holds 1 good and 10 failed (|10/11 - 0.9|).
    expected_ece = (9 * 0.1 + 11 * abs(10 / 11 - 0.9)) / 20
    assert f"| expected calibration error (10 bins) | {expected_ece:.3f} |" in table
    assert (tmp_path / "eval" / "calibration.png").stat().st_size > 1000


def test_eval_leaves_a_track_that_asks_for_keyframes_out_of_the_flag_metrics(tmp_path):
    """Its flags are the frames a person should box (every 10th), not predictions of wrong boxes; its p_fail
    still counts."""
    gt = _gt(20)
    write_otb_boxes(tmp_path / "gt.txt", gt)
    pred = gt + [40.0, 40.0, 0.0, 0.0]  # lost throughout
    pred[0] = gt[0]
    flagged = np.isin(np.arange(20), [10, 19])
    track = _track(np.arange(20), pred)
    track = TrackResult(**{**{k: getattr(track, k) for k in track.__dataclass_fields__},
                           "flagged": flagged, "reasons": tuple("keyframe" if f else "" for f in flagged),
                           "signals": {"p_fail": np.where(np.arange(20) > 0, 0.8, 0.0)}})
    (tmp_path / "run").mkdir()
    write_store(tmp_path / "run" / STORE_NAME, RunStore(video=VIDEO, start=0, stop=20, step=1, tracks=[track]))
    code, table, err = _run("eval", tmp_path / "run", tmp_path / "gt.txt")
    assert code == 0, err
    assert "| AUROC of p_fail for failure frames (IoU < 0.5) | 1.000 |" in table
    explained = "n/a: no track with doubtful-frame flags: every track looked lost and its flags ask for keyframes"
    assert f"| flag precision | {explained} |" in table and f"| flag recall | {explained} |" in table
    assert "nan" not in table
    assert "the track looked lost and its flags ask for keyframes" in err


def test_eval_of_binary_files_and_an_out_that_is_a_file_are_one_line_errors(tmp_path):
    gt = tmp_path / "gt.txt"
    write_otb_boxes(gt, _gt(5))
    binary = tmp_path / "clip.mp4"
    binary.write_bytes(b"\x00\x00\x00\x18ftypmp42\xff\xfe\x9c" * 20)
    for results, truth in ((gt, binary), (binary, gt)):
        code, _, err = _run("eval", results, truth)
        assert code == 4 and err.count("\n") == 1, err
        assert f"{binary} is not text (UTF-8, or UTF-16 with a byte-order mark)" in err and "x,y,w,h" in err
    (tmp_path / "taken").write_text("mine")
    code, table, err = _run("eval", gt, gt, "--out", tmp_path / "taken")
    assert code == 5 and err.count("\n") == 1 and "--out" in err and "is a file" in err
    assert (tmp_path / "taken").read_text() == "mine"


def test_eval_of_a_dataset_whose_ground_truth_holds_nul_is_a_one_line_error(tmp_path):
    gt_file = tmp_path / "root" / "A" / "groundtruth_rect.txt"
    gt_file.parent.mkdir(parents=True)
    write_otb_boxes(gt_file, _gt(5), origin=1)
    (tmp_path / "res").mkdir()
    write_otb_boxes(tmp_path / "res" / "A.txt", _gt(5))
    gt_file.write_bytes(gt_file.read_bytes() + b"\0\0\0\0")
    code, _, err = _run("eval", tmp_path / "res", tmp_path / "root")
    assert code == 4 and err.count("\n") == 1, err
    assert f"{gt_file} is not text" in err


def test_eval_of_a_missing_path_exits_3_as_other_unreadable_input(tmp_path):
    gt = tmp_path / "gt.txt"
    write_otb_boxes(gt, _gt(5))
    (tmp_path / "root" / "A").mkdir(parents=True)
    write_otb_boxes(tmp_path / "root" / "A" / "groundtruth_rect.txt", _gt(5), origin=1)
    for args, needle in (((tmp_path / "none.txt", gt), "no such result file"),
                         ((gt, tmp_path / "none_gt.txt"), "none_gt.txt does not exist"),
                         ((tmp_path / "no_results", tmp_path / "root"), "results folder does not exist")):
        code, _, err = _run("eval", *args)
        assert code == 3 and err.count("\n") == 1 and needle in err, (args, err)

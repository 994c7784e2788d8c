"""Tests of annotator.evaluation: OTB one-pass evaluation, flag quality, plots and tables."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from _paths import ROOT
from hypothesis import given, settings
from hypothesis import strategies as st

from annotator.evaluation import (
    INVALID_GT_CENTER_ERROR,
    INVALID_GT_IOU,
    SUCCESS_THRESHOLDS,
    DatasetScore,
    EvaluationError,
    center_error_xywh,
    discover_otb_sequences,
    evaluate_dataset,
    evaluate_result_file,
    evaluate_results_dir,
    evaluate_sequence,
    failure_spans,
    find_result_file,
    flag_quality,
    flag_quality_dataset,
    iou_xywh,
    load_dataset_pairs,
    plot_otb,
    plot_precision,
    plot_success,
    precision_curve,
    results_json,
    results_markdown,
    success_curve,
    write_report,
)
from annotator.otb_format import OTBFormatError, read_otb_boxes, write_otb_boxes

OTB_ROOT = ROOT.parent / "shared" / "otb"
needs_otb = pytest.mark.skipif(
    not (OTB_ROOT / "David" / "groundtruth_rect.txt").is_file(), reason=f"OTB sequences not found at {OTB_ROOT}"
)

# A perfect tracker: IoU = 1 passes the 20 thresholds below 1 but not "IoU > 1".
PERFECT_AUC = 20 / 21


def boxes(*rows) -> np.ndarray:
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


# ---------------------------------------------------------------------------------------
# Independent reference: per-frame loops written from the OTB MATLAB toolkit
# (calcSeqErrRobust.m, calcRectInt with inclusive pixel extents) rather than from
# the vectorised module, so that a shared mistake is unlikely.


def ref_calc_rect_int(a, b) -> float:
    left_a, bottom_a = a[0], a[1]
    right_a, top_a = left_a + a[2] - 1, bottom_a + a[3] - 1
    left_b, bottom_b = b[0], b[1]
    right_b, top_b = left_b + b[2] - 1, bottom_b + b[3] - 1
    tmp = max(0.0, min(right_a, right_b) - max(left_a, left_b) + 1) * max(
        0.0, min(top_a, top_b) - max(bottom_a, bottom_b) + 1
    )
    return tmp / (a[2] * a[3] + b[2] * b[3] - tmp)


def ref_ok(box) -> bool:
    return all(math.isfinite(v) for v in box) and box[2] > 0 and box[3] > 0


def ref_evaluate(pred, gt, *, replace_first=True, invalid_pred="previous"):
    pred = [list(map(float, r)) for r in pred]
    gt = [list(map(float, r)) for r in gt]
    n = len(gt)
    if replace_first:
        pred[0] = list(gt[0])
    usable = []
    last = None
    for i in range(n):
        if ref_ok(pred[i]):
            last = pred[i]
            usable.append(pred[i])
        elif invalid_pred == "previous" and last is not None:
            usable.append(last)
        else:
            usable.append(None)
    ious, errors = [], []
    for i in range(n):
        g, p = gt[i], usable[i]
        if not ref_ok(g):
            ious.append(-1.0)
            errors.append(-1.0)
        elif p is None:
            ious.append(0.0)
            errors.append(float("inf"))
        else:
            ious.append(ref_calc_rect_int(p, g))
            cx_p, cy_p = p[0] + (p[2] - 1) / 2, p[1] + (p[3] - 1) / 2
            cx_g, cy_g = g[0] + (g[2] - 1) / 2, g[1] + (g[3] - 1) / 2
            errors.append(math.sqrt((cx_p - cx_g) ** 2 + (cy_p - cy_g) ** 2))
    success = [sum(1 for v in ious if v > k * 0.05) / n for k in range(21)]
    # Threshold 1.0 exactly (k * 0.05 with k = 20 is 1.0 in floating point too).
    precision = [sum(1 for e in errors if e <= t) / n for t in range(51)]
    return np.array(ious), np.array(errors), np.array(success), np.array(precision)


def random_boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    xy = rng.uniform(-20, 200, (n, 2))
    wh = rng.uniform(1, 80, (n, 2))
    return np.hstack([xy, wh])


# ---------------------------------------------------------------------------------------
# IoU and centre error


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ((0, 0, 10, 10), (0, 0, 10, 10), 1.0),
        ((0, 0, 10, 10), (5, 0, 10, 10), 50 / 150),
        ((0, 0, 10, 10), (5, 5, 10, 10), 25 / 175),
        ((0, 0, 10, 10), (0, 0, 5, 10), 0.5),
        ((0, 0, 10, 10), (2, 2, 4, 4), 16 / 100),
        ((0, 0, 10, 10), (10, 0, 10, 10), 0.0),  # touching edges
        ((0, 0, 10, 10), (50, 50, 10, 10), 0.0),
        ((0, 0, 10, 10), (0, 0, 0, 10), 0.0),  # empty box
        ((-5.5, -5.5, 11, 11), (0, 0, 5.5, 5.5), 5.5**2 / 11**2),
    ],
)
def test_iou_hand_computed(a, b, expected):
    assert iou_xywh(boxes(a), boxes(b))[0] == pytest.approx(expected, abs=1e-15)
    assert iou_xywh(boxes(b), boxes(a))[0] == pytest.approx(expected, abs=1e-15)


def test_iou_nan_row_is_nan_and_identical_boxes_exactly_one():
    rng = np.random.default_rng(0)
    a = random_boxes(rng, 200)
    assert np.all(iou_xywh(a, a) == 1.0)
    b = a.copy()
    b[3] = np.nan
    out = iou_xywh(a, b)
    assert np.isnan(out[3]) and np.all(np.isfinite(np.delete(out, 3)))


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ((0, 0, 10, 10), (3, 4, 10, 10), 5.0),
        ((0, 0, 10, 10), (0, 0, 20, 20), math.hypot(5, 5)),  # centres 4.5 and 9.5
        ((0, 0, 1, 1), (0, 0, 1, 1), 0.0),
    ],
)
def test_center_error_hand_computed(a, b, expected):
    assert center_error_xywh(boxes(a), boxes(b))[0] == pytest.approx(expected, abs=1e-12)


def test_iou_shape_errors_say_what_was_given():
    with pytest.raises(EvaluationError, match=r"\(N, 4\).*\(3,\)"):
        iou_xywh(np.zeros(3), np.zeros(3))
    with pytest.raises(EvaluationError, match="2 and 3 rows"):
        iou_xywh(np.ones((2, 4)), np.ones((3, 4)))


# ---------------------------------------------------------------------------------------
# Curves and one sequence


def test_success_curve_is_strict_and_precision_inclusive():
    ious = np.array([0.5, 0.5, 1.0, 0.0])
    curve = success_curve(ious)
    assert curve[0] == 0.75  # 0.0 is not > 0
    assert curve[10] == 0.25  # threshold 0.5: 0.5 is not > 0.5
    assert curve[9] == 0.75  # threshold 0.45
    assert curve[20] == 0.0  # threshold 1: nothing is > 1
    errors = np.array([0.0, 20.0, 20.5, -1.0])
    prec = precision_curve(errors)
    assert prec[0] == 0.5 and prec[20] == 0.75 and prec[21] == 1.0


def test_hand_made_four_frame_sequence():
    gt = boxes((0, 0, 10, 10), (0, 0, 10, 10), (0, 0, 10, 10), (0, 0, 10, 10))
    pred = boxes((90, 90, 5, 5), (0, 0, 5, 10), (0, 0, 10, 10), (20, 20, 10, 10))
    score = evaluate_sequence(pred, gt, name="four")
    # Frame 0 is overwritten with the ground truth; IoUs 1, 0.5 exactly, 1, 0.
    np.testing.assert_array_equal(score.ious, [1.0, 0.5, 1.0, 0.0])
    np.testing.assert_allclose(score.center_errors, [0.0, 2.5, 0.0, math.hypot(20, 20)])
    expected_success = np.array([0.75] * 10 + [0.5] * 10 + [0.0])  # strict > at 0.5
    np.testing.assert_array_equal(score.success_curve, expected_success)
    assert score.auc == pytest.approx(12.5 / 21, abs=1e-15)
    assert score.success_50 == 0.5
    assert score.precision_20 == 0.75
    assert score.precision_curve[2] == 0.5 and score.precision_curve[3] == 0.75
    assert score.n_frames == 4 and score.name == "four"


def test_identical_and_disjoint_boxes():
    rng = np.random.default_rng(1)
    gt = random_boxes(rng, 30)
    same = evaluate_sequence(gt, gt, name="same")
    assert same.auc == PERFECT_AUC and same.precision_20 == 1.0 and same.success_50 == 1.0
    far = gt + np.array([1000.0, 1000.0, 0.0, 0.0])
    none = evaluate_sequence(far, gt, name="far", replace_first=False)
    assert none.auc == 0.0 and none.precision_20 == 0.0
    # With the toolkit default, frame 1 is the ground truth and succeeds.
    first_only = evaluate_sequence(far, gt, name="far")
    assert first_only.auc == pytest.approx(PERFECT_AUC / 30, abs=1e-15)
    assert first_only.precision_20 == pytest.approx(1 / 30, abs=1e-15)


def test_invalid_ground_truth_rows_follow_otb():
    gt = boxes((0, 0, 10, 10), (np.nan,) * 4, (0, 0, 0, 10), (0, 0, 10, -1), (0, 0, 10, 10))
    pred = boxes(*[(0, 0, 10, 10)] * 5)
    score = evaluate_sequence(pred, gt, name="gaps")
    np.testing.assert_array_equal(score.ious, [1, INVALID_GT_IOU, INVALID_GT_IOU, INVALID_GT_IOU, 1])
    np.testing.assert_array_equal(score.center_errors[1:4], [INVALID_GT_CENTER_ERROR] * 3)
    assert score.success_curve[0] == 2 / 5  # failures at every overlap threshold, denominator 5
    assert np.all(score.precision_curve == 1.0)  # successes at every error threshold


@pytest.mark.parametrize(
    ("rule", "expected_ious", "expected_errors"),
    [
        ("previous", [1.0, 0.5, 0.5, 0.5, 1.0], [0.0, 2.5, 2.5, 2.5, 0.0]),
        ("failure", [1.0, 0.5, 0.0, 0.0, 1.0], [0.0, 2.5, np.inf, np.inf, 0.0]),
    ],
)
def test_invalid_predictions(rule, expected_ious, expected_errors):
    gt = boxes(*[(0, 0, 10, 10)] * 5)
    pred = boxes((0, 0, 10, 10), (0, 0, 5, 10), (np.nan,) * 4, (3, 3, -2, 4), (0, 0, 10, 10))
    score = evaluate_sequence(pred, gt, name="holes", invalid_pred=rule)
    np.testing.assert_array_equal(score.ious, expected_ious)
    np.testing.assert_array_equal(score.center_errors, expected_errors)


def test_invalid_first_prediction_without_replacement_is_a_failure_in_both_rules():
    gt = boxes(*[(0, 0, 10, 10)] * 3)
    pred = boxes((np.nan,) * 4, (np.nan,) * 4, (0, 0, 10, 10))
    for rule in ("previous", "failure"):
        score = evaluate_sequence(pred, gt, name="late", replace_first=False, invalid_pred=rule)
        np.testing.assert_array_equal(score.ious, [0.0, 0.0, 1.0])
        assert score.precision_20 == pytest.approx(1 / 3)


def test_row_count_mismatch_names_both_lengths():
    with pytest.raises(EvaluationError, match=r"'Bolt2'.*results have 3 rows.*ground truth has 4"):
        evaluate_sequence(np.ones((3, 4)), np.ones((4, 4)), name="Bolt2")
    with pytest.raises(EvaluationError, match="no frames"):
        evaluate_sequence(np.ones((0, 4)), np.ones((0, 4)), name="empty")
    with pytest.raises(EvaluationError, match="'previous' or 'failure'"):
        evaluate_sequence(np.ones((1, 4)), np.ones((1, 4)), name="x", invalid_pred="skip")


# ---------------------------------------------------------------------------------------
# Agreement with the independent reference


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("rule", ["previous", "failure"])
def test_agrees_with_reference_on_random_boxes(seed, rule):
    rng = np.random.default_rng(seed)
    n = 300
    gt = random_boxes(rng, n)
    pred = gt + rng.normal(0, 1, (n, 4)) * np.array([15, 15, 8, 8])
    pred[rng.random(n) < 0.05] = np.nan
    pred[rng.random(n) < 0.03, 2] = 0.0
    gt[rng.random(n) < 0.03] = np.nan
    gt[rng.random(n) < 0.02, 3] = -1.0
    for replace_first in (True, False):
        score = evaluate_sequence(pred, gt, name="r", replace_first=replace_first, invalid_pred=rule)
        ious, errors, success, precision = ref_evaluate(pred, gt, replace_first=replace_first, invalid_pred=rule)
        np.testing.assert_allclose(score.ious, ious, rtol=0, atol=1e-12)
        np.testing.assert_allclose(score.center_errors, errors, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(score.success_curve, success)
        np.testing.assert_array_equal(score.precision_curve, precision)
        assert score.auc == pytest.approx(np.mean(success), abs=1e-12)
        assert score.precision_20 == precision[20]


quarter = st.integers(-400, 400).map(lambda v: v / 4)  # exact binary fractions: exact ties stay exact
size = st.integers(-4, 200).map(lambda v: v / 4)
box_rows = st.lists(st.tuples(quarter, quarter, size, size), min_size=1, max_size=12)


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_agrees_with_reference_property(data):
    gt_rows = data.draw(box_rows)
    n = len(gt_rows)
    pred_rows = data.draw(st.lists(st.tuples(quarter, quarter, size, size), min_size=n, max_size=n))
    gt, pred = np.array(gt_rows, float), np.array(pred_rows, float)
    rule = data.draw(st.sampled_from(["previous", "failure"]))
    replace_first = data.draw(st.booleans())
    score = evaluate_sequence(pred, gt, name="h", replace_first=replace_first, invalid_pred=rule)
    ious, errors, success, precision = ref_evaluate(pred, gt, replace_first=replace_first, invalid_pred=rule)
    np.testing.assert_allclose(score.ious, ious, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(score.success_curve, success)
    np.testing.assert_array_equal(score.precision_curve, precision)


@settings(max_examples=100, deadline=None)
@given(rows=st.lists(st.tuples(quarter, quarter, size, size), min_size=2, max_size=2))
def test_iou_is_symmetric_bounded_and_translation_invariant(rows):
    a, b = np.array(rows[:1], float), np.array(rows[1:], float)
    value = iou_xywh(a, b)[0]
    assert value == iou_xywh(b, a)[0]
    assert 0.0 <= value <= 1.0
    shift = np.array([[7.25, -3.5, 0, 0]])
    assert iou_xywh(a + shift, b + shift)[0] == pytest.approx(value, abs=1e-12)


def test_dataset_is_unweighted_mean_over_sequences():
    rng = np.random.default_rng(5)
    pairs = {}
    for name, n in (("short", 10), ("long", 500)):
        gt = random_boxes(rng, n)
        pairs[name] = (gt + rng.normal(0, 6, (n, 4)), gt)
    score = evaluate_dataset(pairs, tracker="T")
    per = [score.sequences[name] for name in pairs]
    np.testing.assert_allclose(score.success_curve, (per[0].success_curve + per[1].success_curve) / 2)
    assert score.auc == pytest.approx((per[0].auc + per[1].auc) / 2, abs=1e-12)
    assert score.precision_20 == pytest.approx((per[0].precision_20 + per[1].precision_20) / 2, abs=1e-12)
    assert list(score.sequences) == ["short", "long"] and score.tracker == "T"
    with pytest.raises(EvaluationError, match="no sequences"):
        evaluate_dataset({})


# ---------------------------------------------------------------------------------------
# OTB files


@pytest.mark.parametrize("separator", [",", "\t", " ", "  ", ", "])
def test_reads_otb_separators_with_one_based_origin(tmp_path, separator):
    path = tmp_path / "groundtruth_rect.txt"
    rows = [(1, 1, 10, 20), (11.5, -3, 7, 8), (100, 200, 30, 40)]
    path.write_text("\n".join(separator.join(str(v) for v in r) for r in rows) + "\n")
    got = read_otb_boxes(path)
    np.testing.assert_array_equal(got, np.array(rows, float) - np.array([1, 1, 0, 0]))
    score = evaluate_result_file(path, path, name="sep")
    assert score.auc == PERFECT_AUC and score.n_frames == 3


@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "utf-16", "utf-16-be", "utf-32"])
def test_reads_box_files_in_the_encodings_windows_writes(tmp_path, encoding):
    """PowerShell 5's ``>`` and Notepad's "Unicode" write UTF-16 with a byte-order mark."""
    path = tmp_path / "result.txt"
    text = "1,2,10,20\r\n3.5,4,7,8\r\n"
    data = text.encode(encoding)
    if encoding == "utf-16-be":
        data = b"\xfe\xff" + data  # Python's utf-16-be writes no mark; BOM-less UTF-16 is not recognised
    path.write_bytes(data)
    np.testing.assert_array_equal(read_otb_boxes(path), [[0, 1, 10, 20], [2.5, 3, 7, 8]])


def test_otb_round_trip_and_mixed_separator_files_score_the_same(tmp_path):
    rng = np.random.default_rng(7)
    gt = np.round(random_boxes(rng, 40))
    pred = gt + rng.normal(0, 4, gt.shape)
    gt_path = tmp_path / "gt.txt"
    gt_path.write_text("".join(f"{x + 1:g}\t{y + 1:g}\t{w:g}\t{h:g}\n" for x, y, w, h in gt))
    pred_path = tmp_path / "pred.txt"
    write_otb_boxes(pred_path, pred)  # comma-separated, 1-based, %.3f
    np.testing.assert_allclose(read_otb_boxes(pred_path), pred, atol=5e-4)
    np.testing.assert_array_equal(read_otb_boxes(gt_path), gt)
    from_files = evaluate_result_file(pred_path, gt_path, name="rt")
    in_memory = evaluate_sequence(np.round(pred, 3), gt, name="rt")
    np.testing.assert_allclose(from_files.ious, in_memory.ious, atol=1e-9)
    assert from_files.auc == in_memory.auc


def test_empty_and_nan_result_rows_count_as_failures(tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,10,10\n1,1,10,10\n1,1,10,10\n1,1,10,10\n")
    res = tmp_path / "res.txt"
    res.write_text("1,1,10,10\n\nnan,nan,nan,nan\n1,1,10,10\n")
    strict = evaluate_result_file(res, gt, name="holes", invalid_pred="failure")
    np.testing.assert_array_equal(strict.ious, [1, 0, 0, 1])
    otb = evaluate_result_file(res, gt, name="holes", invalid_pred="previous")
    np.testing.assert_array_equal(otb.ious, [1, 1, 1, 1])


def test_unparsable_row_names_file_and_line(tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,10,10\n1,1,10,10\n1,1,10,10\n")
    res = tmp_path / "res.txt"
    res.write_text("1,1,10,10\n1,1,10\n1,1,10,10\n")
    with pytest.raises(OTBFormatError, match=r"res\.txt:2: expected 4 numbers"):
        evaluate_result_file(res, gt)
    res.write_text("1,1,10,10\n1,1,10,10\n1,1,ten,10\n")
    with pytest.raises(OTBFormatError, match=r"res\.txt:3:"):
        evaluate_result_file(res, gt)


def test_row_count_mismatch_between_files_names_both_files(tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,10,10\n" * 5)
    res = tmp_path / "res.txt"
    res.write_text("1,1,10,10\n" * 4)
    with pytest.raises(EvaluationError, match=r"res\.txt has 4 rows but the ground truth .*gt\.txt has 5"):
        evaluate_result_file(res, gt, name="S")


def make_otb_root(root: Path) -> dict[str, np.ndarray]:
    """A small OTB layout: single target, multi-target, and an empty extra file (Human4 style)."""
    rng = np.random.default_rng(11)
    truth = {}
    layout = {
        "Alpha": ["groundtruth_rect.txt"],
        "Jog": ["groundtruth_rect.1.txt", "groundtruth_rect.2.txt"],
        "Human": ["groundtruth_rect.1.txt", "groundtruth_rect.2.txt"],
    }
    for folder, files in layout.items():
        (root / folder / "img").mkdir(parents=True)
        for index, file in enumerate(files, start=1):
            if folder == "Human" and index == 1:
                (root / folder / file).write_text("\n")
                continue
            gt = np.round(random_boxes(rng, 12 + index))
            write_otb_boxes(root / folder / file, gt)
            name = folder if len(files) == 1 or folder == "Human" else f"{folder}.{index}"
            truth[name] = gt
    return truth


def test_discover_otb_sequences_uses_got10k_names(tmp_path):
    truth = make_otb_root(tmp_path)
    with pytest.warns(UserWarning, match="empty ground-truth file"):
        found = discover_otb_sequences(tmp_path)
    assert list(found) == ["Alpha", "Human", "Jog.1", "Jog.2"] == sorted(truth)
    assert found["Jog.2"].name == "groundtruth_rect.2.txt"
    assert found["Human"].name == "groundtruth_rect.2.txt"
    with pytest.raises(EvaluationError, match="not a folder"):
        discover_otb_sequences(tmp_path / "nope")
    (tmp_path / "empty_root").mkdir()
    with pytest.raises(EvaluationError, match="no sequence found"):
        discover_otb_sequences(tmp_path / "empty_root")


@pytest.mark.filterwarnings("ignore:.*empty ground-truth file")
def test_results_folder_with_files_and_output_folders(tmp_path):
    truth = make_otb_root(tmp_path / "otb")
    results = tmp_path / "results" / "MyTracker"
    results.mkdir(parents=True)
    write_otb_boxes(results / "Alpha.txt", truth["Alpha"])
    write_otb_boxes(results / "Human.txt", truth["Human"])
    write_otb_boxes(results / "Jog.1.txt", truth["Jog.1"] + np.array([30.0, 0, 0, 0]))
    (results / "Jog.2").mkdir()
    write_otb_boxes(results / "Jog.2" / "Jog.2.txt", truth["Jog.2"])
    score = evaluate_results_dir(tmp_path / "otb", results)
    assert score.tracker == "MyTracker"
    assert list(score.sequences) == ["Alpha", "Human", "Jog.1", "Jog.2"]
    assert score.sequences["Alpha"].auc == PERFECT_AUC
    assert score.sequences["Jog.1"].auc < PERFECT_AUC
    subset = evaluate_results_dir(tmp_path / "otb", results, sequences=["Jog.2"], tracker="T")
    assert list(subset.sequences) == ["Jog.2"] and subset.auc == PERFECT_AUC
    assert find_result_file(results / "Jog.2", name="Jog.2") == results / "Jog.2" / "Jog.2.txt"
    assert find_result_file(results / "Jog.2") == results / "Jog.2" / "Jog.2.txt"  # the folder's own name
    single = evaluate_result_file(results / "Jog.2", tmp_path / "otb" / "Jog" / "groundtruth_rect.2.txt")
    assert single.name == "Jog.2" and single.auc == PERFECT_AUC


@pytest.mark.filterwarnings("ignore:.*empty ground-truth file")
def test_missing_sequences_are_listed_with_expected_paths(tmp_path):
    truth = make_otb_root(tmp_path / "otb")
    results = tmp_path / "res"
    results.mkdir()
    write_otb_boxes(results / "Alpha.txt", truth["Alpha"])
    skipped: list = []
    assert list(load_dataset_pairs(tmp_path / "otb", results, skipped=skipped)) == ["Alpha"]  # what results hold
    assert skipped == ["Human", "Jog.1", "Jog.2"]
    with pytest.raises(EvaluationError) as info:
        load_dataset_pairs(tmp_path / "otb", results, sequences=["Alpha", "Human", "Jog.1", "Jog.2"])
    message = str(info.value)
    assert "no result for 3 of 4 sequence(s)" in message
    for name in ("Human", "Jog.1", "Jog.2"):
        assert f"{name} (expected {results / (name + '.txt')})" in message
    with pytest.raises(EvaluationError, match=r"no ground truth for sequence\(s\) Nope"):
        load_dataset_pairs(tmp_path / "otb", results, sequences=["Alpha", "Nope"])
    with pytest.raises(EvaluationError, match="results folder does not exist"):
        load_dataset_pairs(tmp_path / "otb", tmp_path / "absent")
    (results / "one").mkdir()
    write_otb_boxes(results / "one" / "clip.txt", truth["Alpha"])
    assert find_result_file(results / "one", name="Alpha") == results / "one" / "clip.txt"  # the only .txt
    write_otb_boxes(results / "one" / "other.txt", truth["Alpha"])
    with pytest.raises(EvaluationError, match=r"cannot tell.*Alpha\.txt, one\.txt; it holds 2 \.txt files"):
        find_result_file(results / "one", name="Alpha")
    (results / "none").mkdir()
    with pytest.raises(EvaluationError, match="it holds no .txt file"):
        find_result_file(results / "none")
    with pytest.raises(EvaluationError, match="no such result file"):
        find_result_file(results / "absent.txt")


@pytest.mark.filterwarnings("ignore:.*empty ground-truth file")
def test_dataset_row_count_mismatch_names_both_files(tmp_path):
    truth = make_otb_root(tmp_path / "otb")
    results = tmp_path / "res"
    results.mkdir()
    for name, gt in truth.items():
        write_otb_boxes(results / f"{name}.txt", gt if name != "Jog.1" else gt[:-2])
    with pytest.raises(EvaluationError, match=r"'Jog\.1'.*Jog\.1\.txt has 11 rows.*groundtruth_rect\.1\.txt has 13"):
        load_dataset_pairs(tmp_path / "otb", results)


def test_custom_locator(tmp_path):
    truth = make_otb_root(tmp_path / "otb")
    results = tmp_path / "res"
    (results / "boxes").mkdir(parents=True)
    for name, gt in truth.items():
        write_otb_boxes(results / "boxes" / f"{name.lower()}_otb.txt", gt)
    with pytest.warns(UserWarning):
        score = evaluate_results_dir(
            tmp_path / "otb", results, locate=lambda folder, name: [folder / "boxes" / f"{name.lower()}_otb.txt"]
        )
    assert score.auc == PERFECT_AUC


# ---------------------------------------------------------------------------------------
# Flag quality


def test_flag_quality_hand_made():
    ious = np.array([0.9] * 3 + [0.1] * 6 + [0.8] * 2 + [0.2] * 3 + [0.9] * 2 + [0.0] * 12 + [0.7])
    # Spans: frames 3-8 (6 frames) and 16-27 (12 frames); frames 11-13 are a 3-frame run, too short.
    flags = np.zeros(len(ious), dtype=bool)
    flags[[1, 5, 12, 27]] = True  # 1: false alarm; 5: inside span 1's first 10; 12: short run; 27: span 2 too late
    quality = flag_quality(flags, ious)
    assert (quality.n_frames, quality.n_flagged) == (29, 4)
    assert quality.n_failure_frames == 6 + 3 + 12
    assert quality.n_flagged_failures == 3
    assert quality.n_failure_spans == 2 and quality.n_detected_spans == 1
    assert quality.precision == 3 / 4
    assert quality.recall == 3 / 21
    assert quality.flagged_share == 4 / 29
    assert quality.onset_recall == 1 / 2
    flags[25] = True  # frame 9 of span 2 (0-based offset 9 < 10): detected
    assert flag_quality(flags, ious).onset_recall == 1.0
    flags[25] = False
    flags[26] = True  # offset 10: outside the first 10 frames
    assert flag_quality(flags, ious).onset_recall == 0.5


def test_flag_quality_boundaries_and_undefined_ratios():
    ious = np.array([0.5, 0.49, np.nan, -1.0, 0.6])
    quality = flag_quality(np.array([0, 1, 1, 0, 0]), ious)
    assert quality.n_failure_frames == 3  # 0.5 is not < 0.5; NaN and -1 fail
    assert quality.precision == 1.0 and quality.recall == pytest.approx(2 / 3)
    none_flagged = flag_quality(np.zeros(5, bool), ious)
    assert math.isnan(none_flagged.precision) and none_flagged.recall == 0.0
    perfect = flag_quality(np.array([True, False]), np.array([0.9, 0.8]))
    assert math.isnan(perfect.recall) and math.isnan(perfect.onset_recall) and perfect.precision == 0.0
    assert perfect.to_dict()["recall"] is None


def test_failure_spans_and_short_runs():
    failed = np.array([1, 1, 1, 1, 0, 1, 1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1], bool)
    np.testing.assert_array_equal(failure_spans(failed), [[5, 10], [12, 18]])
    np.testing.assert_array_equal(failure_spans(failed, min_span=1), [[0, 4], [5, 10], [12, 18]])
    assert failure_spans(np.zeros(0, bool)).shape == (0, 2)


def test_flag_quality_errors():
    with pytest.raises(EvaluationError, match="3 flags but 4 IoU"):
        flag_quality(np.zeros(3, bool), np.zeros(4))
    with pytest.raises(EvaluationError, match="booleans or 0/1, got the value 2 at frame 1"):
        flag_quality(np.array([0, 2]), np.zeros(2))


def test_flag_quality_dataset_pools_counts():
    a = (np.array([1, 0, 0, 0, 0, 0], bool), np.array([0.1] * 6))
    b = (np.array([1, 1, 0, 0], bool), np.array([0.9, 0.9, 0.9, 0.9]))
    report = flag_quality_dataset({"A": a, "B": b})
    assert report.sequences["A"].recall == 1 / 6 and math.isnan(report.sequences["B"].recall)
    pooled = report.pooled
    assert (pooled.n_frames, pooled.n_flagged, pooled.n_flagged_failures) == (10, 3, 1)
    assert pooled.precision == 1 / 3 and pooled.recall == 1 / 6 and pooled.onset_recall == 1.0
    assert json.loads(json.dumps(report.to_dict()))["sequences"]["B"]["recall"] is None


def test_flag_quality_reference_on_random_sequences():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = int(rng.integers(1, 200))
        ious = np.repeat(rng.uniform(0, 1, n // 5 + 1), 5)[:n]
        flags = rng.random(n) < 0.2
        quality = flag_quality(flags, ious)
        # Reference: walk the frames once, tracking the current run of failures.
        spans, detected, run_start = 0, 0, None
        for i in range(n + 1):
            fail = i < n and ious[i] < 0.5
            if fail and run_start is None:
                run_start = i
            if not fail and run_start is not None:
                if i - run_start >= 5:
                    spans += 1
                    detected += any(flags[j] for j in range(run_start, min(run_start + 10, i)))
                run_start = None
        assert (quality.n_failure_spans, quality.n_detected_spans) == (spans, detected)
        assert quality.n_failure_frames == sum(v < 0.5 for v in ious)


# ---------------------------------------------------------------------------------------
# Plots and tables


def two_trackers() -> list[DatasetScore]:
    rng = np.random.default_rng(9)
    gt = {name: random_boxes(rng, 60) for name in ("Seq|A", "SeqB")}
    good = evaluate_dataset({k: (v + rng.normal(0, 2, v.shape), v) for k, v in gt.items()}, tracker="good")
    poor = evaluate_dataset({k: (v + rng.normal(0, 15, v.shape), v) for k, v in gt.items()}, tracker="poor")
    return [poor, good]


def test_plots_are_png_of_the_requested_size(tmp_path):
    from PIL import Image

    scores = two_trackers()
    success = plot_success(scores, tmp_path / "success.png")
    precision = plot_precision(scores, tmp_path / "precision.png", figsize=(5, 4), dpi=80)
    with Image.open(success) as image:
        assert image.format == "PNG" and image.size == (640, 480)
    with Image.open(precision) as image:
        assert image.size == (400, 320)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["precision.png", "success.png"]  # no temp files left


def test_plot_otb_names_an_unknown_kind(tmp_path):
    with pytest.raises(ValueError, match="plot kind 'recall' is unknown: expected one of success, precision"):
        plot_otb(two_trackers(), tmp_path / "x.png", kind="recall")
    assert list(tmp_path.iterdir()) == []


def test_markdown_and_json_tables(tmp_path):
    scores = two_trackers()
    flags = {"good": flag_quality_dataset({"Seq|A": (np.zeros(60, bool), scores[1].sequences["Seq|A"].ious)})}
    text = results_markdown(scores, flag_quality=flags)
    good, poor = scores[1], scores[0]
    assert good.auc > poor.auc
    assert f"| 1 | good | {good.auc:.3f} | {good.precision_20:.3f} |" in text
    assert f"| 2 | poor | {poor.auc:.3f} |" in text
    assert "| 2 | 120 | failure | ground truth |" in text
    seq = good.sequences["SeqB"]
    assert f"| SeqB | 60 | {seq.auc:.3f} / {seq.precision_20:.3f} |" in text
    assert "| Seq\\|A | 60 |" in text  # pipes escaped
    assert "continuous areas" in text and "IoU > t (strict)" in text
    pooled = flags["good"].pooled
    assert pooled.n_flagged == 0 and pooled.n_failure_frames > 0
    assert f"| good | n/a | 0.000 | 0.000 | {'n/a' if pooled.n_failure_spans == 0 else '0.000'} |" in text
    assert "| good | Seq\\|A | n/a |" in text and "Failure: IoU < 0.5" in text
    data = results_json(scores, flag_quality=flags)
    assert data["trackers"]["good"]["overall"]["success_score"] == good.auc
    assert data["trackers"]["good"]["rules"] == {"replace_first": True, "invalid_pred": "failure"}
    assert data["trackers"]["poor"]["seq_wise"]["SeqB"]["precision_score"] == poor.sequences["SeqB"].precision_20
    assert len(data["thresholds"]["success_iou"]) == 21 and data["thresholds"]["success_iou"][10] == 0.5
    assert "flag_quality" in data["trackers"]["good"] and "flag_quality" not in data["trackers"]["poor"]
    written = write_report(tmp_path / "report", scores, flag_quality=flags)
    assert json.loads(written["json"].read_text()) == json.loads(json.dumps(data))
    assert written["markdown"].read_text() == text
    assert written["success_plot"].stat().st_size > 0 and written["precision_plot"].stat().st_size > 0
    with pytest.raises(EvaluationError, match="unique"):
        results_markdown([scores[0], scores[0]])


def test_success_thresholds_are_the_otb_21():
    np.testing.assert_allclose(SUCCESS_THRESHOLDS, np.arange(21) * 0.05, atol=1e-15)
    assert SUCCESS_THRESHOLDS[0] == 0.0 and SUCCESS_THRESHOLDS[-1] == 1.0


# ---------------------------------------------------------------------------------------
# Real OTB data


@needs_otb
def test_ground_truth_against_itself_on_real_sequences(tmp_path):
    gt_path = OTB_ROOT / "David" / "groundtruth_rect.txt"
    score = evaluate_result_file(gt_path, gt_path)
    assert score.name == "David" and score.n_frames == 471
    # IoU = 1 everywhere: > t for the 20 thresholds below 1, not for t = 1.
    assert score.auc == 20 / 21
    assert score.precision_20 == 1.0 and score.success_50 == 1.0
    results = tmp_path / "GT"
    results.mkdir()
    for name in ("Jogging.1", "Girl"):
        write_otb_boxes(results / f"{name}.txt", read_otb_boxes(OTB_ROOT / name / "groundtruth_rect.txt"))
    dataset = evaluate_results_dir(OTB_ROOT, results, sequences=["Jogging.1", "Girl"])
    assert dataset.auc == 20 / 21 and dataset.precision_20 == 1.0

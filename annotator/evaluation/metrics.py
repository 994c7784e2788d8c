"""OTB one-pass evaluation (OPE): overlap, centre error, success and precision curves.

The definitions follow the three toolkits the field uses (``docs/design/tracker.md``, "Evaluation metrics"):
the OTB MATLAB toolkit (``calcSeqErrRobust.m``), got10k (``ExperimentOTB``) and
pysot (``OPEBenchmark``). Where they disagree, the choice made here is stated.

Conventions
-----------
Boxes
    0-based ``xywh`` float arrays of shape ``(N, 4)``, one row per frame, as
    returned by :func:`annotator.otb_format.read_otb_boxes`. Every metric here is
    invariant to a common translation, so the origin of the file does not
    change any number as long as results and ground truth share it.
IoU
    **Continuous areas**: ``|A n B| / |A u B|`` with the box covering
    ``[x, x + w) x [y, y + h)``, as got10k ``rect_iou`` and pysot
    ``overlap_ratio``. The OTB MATLAB ``calcRectInt`` uses inclusive pixel
    extents (``right = x + w - 1``, intersection ``+ 1``) but areas ``w * h``;
    the ``-1`` and ``+1`` cancel, so it is the same formula (the tests check
    it against a transcription). got10k adds machine epsilon to the union;
    no epsilon is used here, so identical boxes have an IoU of exactly 1.
Centre error
    Euclidean distance between centres ``(x + (w - 1) / 2, y + (h - 1) / 2)``
    (OTB, got10k ``center_error``, pysot ``convert_bb_to_center``). The
    ``-1/2`` cancels in the difference; the OTB form is kept.
Success curve
    Fraction of frames with IoU **strictly greater** than each of the 21
    thresholds ``0, 0.05, ..., 1``. AUC (the "success score") is the mean of
    the 21 rates. IoU is never > 1, so the last rate is always 0 and a
    perfect tracker scores AUC = 20/21 = 0.952..., exactly as in the toolkits.
Precision curve
    Fraction of frames with centre error ``<=`` each of the thresholds
    ``0, 1, ..., 50`` px; the headline number is precision at 20 px.
Invalid ground truth
    A ground-truth row with a NaN/inf value or ``w <= 0`` or ``h <= 0``
    (OTB marks absent targets this way) gets IoU ``-1``, a failure at every
    success threshold, and centre error ``-1``, a *success* at every
    precision threshold; the denominator stays the full sequence length.
    This is OTB ``calcSeqErrRobust.m`` and pysot ``success_overlap`` (mask
    ``gt[:, 2:] > 0``). OTB MATLAB also masks rows whose 1-based ``x`` or
    ``y`` is ``<= 0``; that would discard valid boxes touching the image
    border, so it is not copied (none of the shared OTB sequences has one).
    got10k does no masking.
Invalid tracker output
    A result row with a NaN/inf value or ``w <= 0`` or ``h <= 0``. With
    ``invalid_pred="failure"`` (the default: got10k and pysot, where NaN
    compares false) it is a failure at every threshold of both curves: IoU 0
    and centre error ``inf``. With ``invalid_pred="previous"`` (OTB
    ``calcSeqErrRobust.m``) it is replaced by the previous frame's (already
    repaired) box; with no earlier valid box it stays a failure.
First frame
    The toolkits overwrite the first result row with the ground truth (the
    tracker was initialised with it): OTB ``rectMat(1,:) = rect_anno(1,:)``,
    got10k ``boxes[0] = anno[0]``. ``replace_first=True`` (default) does the
    same, before invalid outputs are repaired.
Aggregation
    Per-sequence curves, then an unweighted mean over sequences (OTB
    ``perfPlot.m``, got10k ``report``, pysot ``show_result``). The dataset
    AUC is the mean of the mean curve, which equals the mean of the
    per-sequence AUCs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

import numpy as np

from sptpt.boxes import iou_xywh as boxes_iou_xywh

__all__ = [
    "SUCCESS_THRESHOLDS",
    "PRECISION_THRESHOLDS",
    "PRECISION_AT_PX",
    "INVALID_GT_IOU",
    "INVALID_GT_CENTER_ERROR",
    "DEFAULT_INVALID_PRED",
    "InvalidPredRule",
    "EvaluationError",
    "SequenceScore",
    "DatasetScore",
    "iou_xywh",
    "center_error_xywh",
    "valid_boxes_xywh",
    "success_curve",
    "precision_curve",
    "evaluate_sequence",
    "evaluate_dataset",
]


def _readonly(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


#: The 21 overlap thresholds 0:0.05:1 (OTB ``thresholdSetOverlap``, got10k ``linspace(0, 1, 21)``).
SUCCESS_THRESHOLDS: np.ndarray = _readonly(np.linspace(0.0, 1.0, 21))
#: The 51 location-error thresholds 0:50 px (OTB ``thresholdSetError``, got10k ``arange(51)``).
PRECISION_THRESHOLDS: np.ndarray = _readonly(np.arange(51, dtype=np.float64))
#: The location-error threshold of the headline precision number, in pixels.
PRECISION_AT_PX: float = 20.0
#: IoU given to frames whose ground truth is invalid (OTB ``errCoverage = -1``).
INVALID_GT_IOU: float = -1.0
#: Centre error given to frames whose ground truth is invalid (OTB ``errCenter = -1``).
INVALID_GT_CENTER_ERROR: float = -1.0

InvalidPredRule = Literal["previous", "failure"]
#: Default rule for invalid result rows: a NaN or empty row is a failure, as got10k and pysot
#: score it (the issue asks for this); ``"previous"`` is OTB MATLAB's carry-forward.
DEFAULT_INVALID_PRED: InvalidPredRule = "failure"


class EvaluationError(ValueError):
    """Input the evaluator cannot score; the message names the file, sequence or length at fault."""


class MissingInputError(EvaluationError):
    """A result or ground-truth path that does not exist, or is not the kind of path asked for (exit 3)."""


def _as_boxes(boxes: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(boxes, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 4:
        raise EvaluationError(
            f"{name} must be an (N, 4) array of xywh boxes, got shape {array.shape}; "
            "read OTB files with annotator.otb_format.read_otb_boxes"
        )
    return array


def _paired_boxes(a: np.ndarray, b: np.ndarray, function: str) -> tuple[np.ndarray, np.ndarray]:
    """``a`` and ``b`` as (N, 4) arrays of as many rows, which ``function`` pairs row by row."""
    a = _as_boxes(a, "a")
    b = _as_boxes(b, "b")
    if a.shape != b.shape:
        raise EvaluationError(f"{function} pairs boxes row by row: got {len(a)} and {len(b)} rows")
    return a, b


def valid_boxes_xywh(boxes: np.ndarray) -> np.ndarray:
    """Which boxes are usable: every value finite and ``w > 0`` and ``h > 0``.

    Parameters
    ----------
    boxes : (N, 4) array_like
        ``xywh`` boxes.

    Returns
    -------
    valid : (N,) bool ndarray
    """
    boxes = _as_boxes(boxes, "boxes")
    return np.all(np.isfinite(boxes), axis=1) & (boxes[:, 2] > 0) & (boxes[:, 3] > 0)


def iou_xywh(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of paired boxes, with continuous areas.

    The box ``(x, y, w, h)`` covers ``[x, x + w) x [y, y + h)`` (got10k
    ``rect_iou``, pysot ``overlap_ratio``; equal to OTB ``calcRectInt``, see
    the module notes). Areas are taken from the same corner differences as
    the intersection, so identical boxes give exactly 1.

    Parameters
    ----------
    a, b : (N, 4) array_like
        ``xywh`` boxes, paired row by row.

    Returns
    -------
    iou : (N,) float64 ndarray
        In ``[0, 1]``. A box with a non-positive width or height is empty
        (IoU 0); a row holding NaN gives NaN. No invalid-row rule is applied
        here: that is :func:`evaluate_sequence`'s job.

    The arithmetic is :func:`sptpt.boxes.iou_xywh`'s, shared with the tracker; this checks the shapes.
    """
    return boxes_iou_xywh(*_paired_boxes(a, b, "iou_xywh"))


def center_error_xywh(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between the centres of paired boxes, in pixels: an (N,) float64 array.

    ``a`` and ``b`` are (N, 4) ``xywh`` boxes paired row by row, as for :func:`iou_xywh`; a row holding NaN gives
    NaN. Centre ``= (x + (w - 1) / 2, y + (h - 1) / 2)`` as in OTB ``calcSeqErrRobust.m``, got10k
    ``center_error`` and pysot.
    """
    a, b = _paired_boxes(a, b, "center_error_xywh")
    center_a = a[:, :2] + (a[:, 2:] - 1.0) / 2.0
    center_b = b[:, :2] + (b[:, 2:] - 1.0) / 2.0
    return np.hypot(center_a[:, 0] - center_b[:, 0], center_a[:, 1] - center_b[:, 1])


def _as_values(values: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 1 or array.size == 0:
        raise EvaluationError(f"{name} must be a non-empty (N,) array, got shape {array.shape}")
    return array


def success_curve(ious: np.ndarray, thresholds: np.ndarray | None = None) -> np.ndarray:
    """Success rate: the fraction of frames with IoU strictly above each threshold.

    Parameters
    ----------
    ious : (N,) array_like
        Per-frame IoU; ``-1`` or NaN (invalid frames) fail every threshold.
    thresholds : (T,) array_like, optional
        Defaults to :data:`SUCCESS_THRESHOLDS` (21 values, 0:0.05:1).

    Returns
    -------
    rates : (T,) float64 ndarray
        ``mean(ious > t)`` for each threshold ``t``; its mean is the AUC.
    """
    ious = _as_values(ious, "ious")
    thresholds = SUCCESS_THRESHOLDS if thresholds is None else np.asarray(thresholds, dtype=np.float64)
    return np.mean(ious[:, None] > thresholds[None, :], axis=0)


def precision_curve(errors: np.ndarray, thresholds: np.ndarray | None = None) -> np.ndarray:
    """Precision: the fraction of frames with centre error at or below each threshold.

    Parameters
    ----------
    errors : (N,) array_like
        Per-frame centre error in pixels; ``-1`` (invalid ground truth)
        passes every threshold, NaN and ``inf`` fail every threshold.
    thresholds : (T,) array_like, optional
        Defaults to :data:`PRECISION_THRESHOLDS` (0..50 px).

    Returns
    -------
    rates : (T,) float64 ndarray
        ``mean(errors <= t)`` for each threshold ``t``.
    """
    errors = _as_values(errors, "errors")
    thresholds = PRECISION_THRESHOLDS if thresholds is None else np.asarray(thresholds, dtype=np.float64)
    return np.mean(errors[:, None] <= thresholds[None, :], axis=0)


def _curve_array(values: np.ndarray) -> np.ndarray:
    return _readonly(np.array(values, dtype=np.float64))


@dataclass(frozen=True)
class SequenceScore:
    """OPE scores of one tracker on one sequence.

    Attributes
    ----------
    name : str
        Sequence name (``Jogging.1`` style for multi-target sequences).
    n_frames : int
        Number of frames, the denominator of every rate.
    ious : (N,) float64 ndarray
        Per-frame IoU after the first-frame and invalid-output rules;
        :data:`INVALID_GT_IOU` (-1) where the ground truth is invalid.
    center_errors : (N,) float64 ndarray
        Per-frame centre error in pixels; :data:`INVALID_GT_CENTER_ERROR`
        (-1) where the ground truth is invalid, ``inf`` where the result is
        invalid and counts as a failure.
    success_curve : (21,) float64 ndarray
        Success rate at :data:`SUCCESS_THRESHOLDS`.
    precision_curve : (51,) float64 ndarray
        Precision at :data:`PRECISION_THRESHOLDS`.
    auc : float
        Mean of ``success_curve`` (got10k ``success_score``).
    precision_20 : float
        Precision at 20 px (got10k ``precision_score``).
    success_50 : float
        Success rate at IoU threshold 0.5 (got10k ``success_rate``).
    replace_first : bool
        Whether the first result was overwritten with the ground truth.
    invalid_pred : {"previous", "failure"}
        The rule applied to invalid result rows.
    """

    name: str
    n_frames: int
    ious: np.ndarray = field(repr=False)
    center_errors: np.ndarray = field(repr=False)
    success_curve: np.ndarray = field(repr=False)
    precision_curve: np.ndarray = field(repr=False)
    auc: float
    precision_20: float
    success_50: float
    replace_first: bool = True
    invalid_pred: str = DEFAULT_INVALID_PRED

    def to_dict(self, *, per_frame: bool = False) -> dict:
        """JSON-ready dict with got10k's ``performance.json`` key names; optionally per-frame values."""
        out = {
            "n_frames": self.n_frames,
            "success_score": self.auc,
            "precision_score": self.precision_20,
            "success_rate": self.success_50,
            "success_curve": self.success_curve.tolist(),
            "precision_curve": self.precision_curve.tolist(),
        }
        if per_frame:
            out["ious"] = self.ious.tolist()
            out["center_errors"] = [None if not np.isfinite(e) else float(e) for e in self.center_errors]
        return out


def _curve_fields(success: np.ndarray, precision: np.ndarray) -> dict[str, Any]:
    """The curves and their summary figures, as a sequence's and a dataset's scores both hold them."""
    at_20 = np.flatnonzero(PRECISION_THRESHOLDS == PRECISION_AT_PX)[0]
    at_50 = np.flatnonzero(np.isclose(SUCCESS_THRESHOLDS, 0.5))[0]
    return {"success_curve": _curve_array(success), "precision_curve": _curve_array(precision),
            "auc": float(np.mean(success)), "precision_20": float(precision[at_20]),
            "success_50": float(success[at_50])}


def _repair_invalid_predictions(pred: np.ndarray, rule: str) -> tuple[np.ndarray, np.ndarray]:
    """Apply the invalid-output rule; return repaired boxes and the rows that remain failures."""
    valid = valid_boxes_xywh(pred)
    if rule == "failure":
        return pred, ~valid
    # OTB: carry the last valid box forward; before the first valid box there is nothing to carry.
    index = np.where(valid, np.arange(len(pred)), -1)
    last_valid = np.maximum.accumulate(index)
    repaired = pred.copy()
    has_previous = last_valid >= 0
    repaired[has_previous] = pred[last_valid[has_previous]]
    return repaired, ~has_previous


def evaluate_sequence(
    pred: np.ndarray,
    gt: np.ndarray,
    *,
    name: str,
    replace_first: bool = True,
    invalid_pred: InvalidPredRule = DEFAULT_INVALID_PRED,
) -> SequenceScore:
    """Score one tracker on one sequence with the OTB one-pass-evaluation rules.

    Parameters
    ----------
    pred : (N, 4) array_like
        Tracker boxes, ``xywh``, one row per frame including the first.
    gt : (N, 4) array_like
        Ground-truth boxes in the same layout and origin.
    name : str
        Sequence name, used in messages and reports.
    replace_first : bool
        Overwrite the first result with the ground truth, as the toolkits do.
    invalid_pred : {"previous", "failure"}
        Rule for result rows with NaN or a non-positive size: carry the
        previous box forward (OTB) or count a failure (got10k, pysot).
        Defaults to :data:`DEFAULT_INVALID_PRED` (``"failure"``).

    Returns
    -------
    SequenceScore

    Raises
    ------
    EvaluationError
        Wrong shapes, different row counts, or an empty sequence.
    """
    pred = _as_boxes(pred, f"results of sequence {name!r}").copy()
    gt = _as_boxes(gt, f"ground truth of sequence {name!r}")
    if len(pred) != len(gt):
        raise EvaluationError(
            f"sequence {name!r}: the results have {len(pred)} rows but the ground truth has {len(gt)}; "
            "an OTB result file holds exactly one row per ground-truth frame, the first frame included"
        )
    if len(gt) == 0:
        raise EvaluationError(f"sequence {name!r}: the ground truth has no frames; nothing to evaluate")
    if invalid_pred not in ("previous", "failure"):
        raise EvaluationError(f"invalid_pred must be 'previous' or 'failure', got {invalid_pred!r}")

    if replace_first:
        pred[0] = gt[0]
    pred, failed = _repair_invalid_predictions(pred, invalid_pred)
    gt_valid = valid_boxes_xywh(gt)

    ious = np.zeros(len(gt))
    errors = np.full(len(gt), np.inf)
    scored = gt_valid & ~failed
    ious[scored] = iou_xywh(pred[scored], gt[scored])
    errors[scored] = center_error_xywh(pred[scored], gt[scored])
    ious[~gt_valid] = INVALID_GT_IOU
    errors[~gt_valid] = INVALID_GT_CENTER_ERROR

    return SequenceScore(
        name=name,
        n_frames=len(gt),
        ious=_readonly(ious),
        center_errors=_readonly(errors),
        **_curve_fields(success_curve(ious), precision_curve(errors)),
        replace_first=replace_first,
        invalid_pred=invalid_pred,
    )


@dataclass(frozen=True)
class DatasetScore:
    """OPE scores of one tracker over a set of sequences.

    Attributes
    ----------
    tracker : str
        Tracker (or run) name shown in plots and tables.
    sequences : Mapping[str, SequenceScore]
        Per-sequence scores, in evaluation order.
    success_curve : (21,) float64 ndarray
        Unweighted mean of the per-sequence success curves.
    precision_curve : (51,) float64 ndarray
        Unweighted mean of the per-sequence precision curves.
    auc : float
        Mean of ``success_curve`` (= mean of per-sequence AUCs); ranks the success plot.
    precision_20 : float
        Mean precision at 20 px; ranks the precision plot.
    success_50 : float
        Mean success rate at IoU 0.5.
    """

    tracker: str
    sequences: Mapping[str, SequenceScore] = field(repr=False)
    success_curve: np.ndarray = field(repr=False)
    precision_curve: np.ndarray = field(repr=False)
    auc: float
    precision_20: float
    success_50: float

    @classmethod
    def from_sequences(cls, tracker: str, scores: Mapping[str, SequenceScore] | list[SequenceScore]) -> DatasetScore:
        """Aggregate per-sequence scores with an unweighted mean over sequences."""
        if not isinstance(scores, Mapping):
            scores = {score.name: score for score in scores}
        if not scores:
            raise EvaluationError(f"tracker {tracker!r}: no sequences to aggregate")
        success = np.mean([s.success_curve for s in scores.values()], axis=0)
        precision = np.mean([s.precision_curve for s in scores.values()], axis=0)
        return cls(tracker=tracker, sequences=dict(scores), **_curve_fields(success, precision))

    @property
    def rules(self) -> dict:
        """The first-frame and invalid-result rules used, ``"mixed"`` where sequences differ."""
        def one(values: set) -> object:
            return values.pop() if len(values) == 1 else "mixed"

        return {
            "replace_first": one({s.replace_first for s in self.sequences.values()}),
            "invalid_pred": one({s.invalid_pred for s in self.sequences.values()}),
        }

    def to_dict(self) -> dict:
        """JSON-ready dict shaped like got10k's ``performance.json`` entry for one tracker."""
        return {
            "rules": self.rules,
            "overall": {
                "n_sequences": len(self.sequences),
                "n_frames": int(sum(s.n_frames for s in self.sequences.values())),
                "success_score": self.auc,
                "precision_score": self.precision_20,
                "success_rate": self.success_50,
                "success_curve": self.success_curve.tolist(),
                "precision_curve": self.precision_curve.tolist(),
            },
            "seq_wise": {name: score.to_dict() for name, score in self.sequences.items()},
        }


def evaluate_dataset(
    pairs: Mapping[str, tuple[np.ndarray, np.ndarray]],
    *,
    tracker: str = "tracker",
    replace_first: bool = True,
    invalid_pred: InvalidPredRule = DEFAULT_INVALID_PRED,
) -> DatasetScore:
    """Score one tracker on several sequences and average over sequences.

    Parameters
    ----------
    pairs : Mapping[str, tuple[(N, 4) array_like, (N, 4) array_like]]
        Sequence name -> ``(pred, gt)`` boxes (``N`` may differ per sequence).
    tracker : str
        Name shown in plots and tables.
    replace_first, invalid_pred
        As in :func:`evaluate_sequence`.

    Returns
    -------
    DatasetScore
        Curves and scores as unweighted means over sequences.
    """
    if not pairs:
        raise EvaluationError(f"tracker {tracker!r}: no sequences given; pass a mapping name -> (pred, gt)")
    scores = {
        name: evaluate_sequence(pred, gt, name=name, replace_first=replace_first, invalid_pred=invalid_pred)
        for name, (pred, gt) in pairs.items()
    }
    return DatasetScore.from_sequences(tracker, scores)

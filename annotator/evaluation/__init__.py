"""Evaluation against ground truth: OTB one-pass evaluation, flag quality, plots and tables.

Typical use (what ``sptpt-annotate eval`` does)::

    from annotator.evaluation import evaluate_results_dir, write_report

    score = evaluate_results_dir("../shared/otb", "runs/sptpt", tracker="SPTPT")
    write_report("reports/sptpt", [score])

Conventions (IoU with continuous areas, strict ``>`` at 21 thresholds, AUC as
the mean success rate, precision at 20 px, invalid-row rules) are stated in
:mod:`annotator.evaluation.metrics`.
"""

from __future__ import annotations

from annotator.evaluation.dataset import (
    OUTPUT_FOLDER_RESULT_NAMES,
    ResultLocator,
    SequencePair,
    default_result_candidates,
    discover_otb_sequences,
    evaluate_result_file,
    evaluate_results_dir,
    find_result_file,
    load_dataset_pairs,
    load_sequence_pair,
)
from annotator.evaluation.flag_quality import (
    FlagQuality,
    FlagQualityReport,
    failure_spans,
    flag_quality,
    flag_quality_dataset,
)
from annotator.evaluation.metrics import (
    DEFAULT_INVALID_PRED,
    INVALID_GT_CENTER_ERROR,
    INVALID_GT_IOU,
    PRECISION_AT_PX,
    PRECISION_THRESHOLDS,
    SUCCESS_THRESHOLDS,
    DatasetScore,
    EvaluationError,
    InvalidPredRule,
    MissingInputError,
    SequenceScore,
    center_error_xywh,
    evaluate_dataset,
    evaluate_sequence,
    iou_xywh,
    precision_curve,
    success_curve,
    valid_boxes_xywh,
)
from annotator.evaluation.report import (
    PROTOCOL,
    plot_otb,
    plot_precision,
    plot_success,
    results_json,
    results_markdown,
    write_report,
    write_results_json,
    write_results_markdown,
)

__all__ = [
    "DEFAULT_INVALID_PRED",
    "DatasetScore",
    "EvaluationError",
    "FlagQuality",
    "FlagQualityReport",
    "INVALID_GT_CENTER_ERROR",
    "INVALID_GT_IOU",
    "InvalidPredRule",
    "MissingInputError",
    "OUTPUT_FOLDER_RESULT_NAMES",
    "PRECISION_AT_PX",
    "PRECISION_THRESHOLDS",
    "PROTOCOL",
    "ResultLocator",
    "SUCCESS_THRESHOLDS",
    "SequencePair",
    "SequenceScore",
    "center_error_xywh",
    "default_result_candidates",
    "discover_otb_sequences",
    "evaluate_dataset",
    "evaluate_result_file",
    "evaluate_results_dir",
    "evaluate_sequence",
    "failure_spans",
    "find_result_file",
    "flag_quality",
    "flag_quality_dataset",
    "iou_xywh",
    "load_dataset_pairs",
    "load_sequence_pair",
    "plot_otb",
    "plot_precision",
    "plot_success",
    "precision_curve",
    "results_json",
    "results_markdown",
    "success_curve",
    "valid_boxes_xywh",
    "write_report",
    "write_results_json",
    "write_results_markdown",
]

"""How well the review flags point at tracking failures.

Each frame's flag ("a human should look at this frame") is joined with the
frame's IoU against ground truth. A frame is a **failure** when its IoU is
below ``fail_iou`` (0.5 by default), or is not a number, or is the ``-1``
that :func:`~annotator.evaluation.metrics.evaluate_sequence` gives frames
whose ground truth is invalid: NaN and empty rows count as failures, as in
the OTB protocol.

Metrics
-------
precision
    flagged failure frames / flagged frames. NaN when nothing is flagged.
recall
    flagged failure frames / failure frames. NaN when there is no failure.
flagged_share
    flagged frames / all frames (the review workload).
onset_recall
    A **failure span** is a maximal run of consecutive failure frames at
    least ``min_span`` (5) frames long; shorter runs do not count as spans
    (their frames still count in precision and recall). A span is
    **detected** when a flag falls within its first ``onset_window`` (10)
    frames, i.e. on frames ``start .. min(start + onset_window, stop) - 1``;
    a flag before the span or after that window does not count. onset_recall
    is detected spans / spans; NaN when there is no span.

NaN marks an undefined ratio (0 / 0) rather than 0 or 1, so that a sequence
with nothing to find neither rewards nor punishes the flags; JSON writers
turn it into ``null``.

Dataset level
-------------
:func:`flag_quality_dataset` pools the counts over all frames and spans of
all sequences (micro average: a long sequence weighs more) and also keeps the
per-sequence results, from which a per-sequence (macro) view can be read.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Mapping

import numpy as np

from annotator.evaluation.metrics import EvaluationError

__all__ = [
    "FlagQuality",
    "FlagQualityReport",
    "failure_spans",
    "flag_quality",
    "flag_quality_dataset",
]


class _Ratio:
    """A ratio of two of the counts, read like an attribute; NaN when the denominator is 0."""

    def __init__(self, numerator: str, denominator: str, doc: str) -> None:
        self.numerator, self.denominator, self.__doc__ = numerator, denominator, doc

    def __get__(self, counts: object, owner: type | None = None):
        if counts is None:
            return self
        denominator = getattr(counts, self.denominator)
        return float(getattr(counts, self.numerator)) / denominator if denominator > 0 else float("nan")


@dataclass(frozen=True)
class FlagQuality:
    """Flag-quality counts and ratios for one sequence, or pooled over several.

    Attributes
    ----------
    n_frames : int
        Frames scored.
    n_flagged : int
        Frames flagged for review.
    n_failure_frames : int
        Frames with IoU below the failure threshold (or NaN / -1).
    n_flagged_failures : int
        Frames both flagged and failed (true positives).
    n_failure_spans : int
        Failure runs of at least ``min_span`` frames.
    n_detected_spans : int
        Spans with a flag within their first ``onset_window`` frames.
    """

    n_frames: int
    n_flagged: int
    n_failure_frames: int
    n_flagged_failures: int
    n_failure_spans: int
    n_detected_spans: int

    precision = _Ratio("n_flagged_failures", "n_flagged",
                       "Flagged failure frames / flagged frames; NaN when nothing is flagged.")
    recall = _Ratio("n_flagged_failures", "n_failure_frames",
                    "Flagged failure frames / failure frames; NaN when there is no failure.")
    flagged_share = _Ratio("n_flagged", "n_frames", "Flagged frames / frames; NaN for an empty sequence.")
    onset_recall = _Ratio("n_detected_spans", "n_failure_spans",
                          "Detected failure spans / failure spans; NaN when there is no span.")

    def __add__(self, other: FlagQuality) -> FlagQuality:
        if not isinstance(other, FlagQuality):
            return NotImplemented
        return FlagQuality(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})

    def to_dict(self) -> dict:
        """JSON-ready dict of counts and ratios; undefined ratios are ``None``."""
        def clean(value: float) -> float | None:
            return None if np.isnan(value) else value

        return {
            "precision": clean(self.precision),
            "recall": clean(self.recall),
            "flagged_share": clean(self.flagged_share),
            "onset_recall": clean(self.onset_recall),
            "n_frames": self.n_frames,
            "n_flagged": self.n_flagged,
            "n_failure_frames": self.n_failure_frames,
            "n_flagged_failures": self.n_flagged_failures,
            "n_failure_spans": self.n_failure_spans,
            "n_detected_spans": self.n_detected_spans,
        }


def _as_flags(flags: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(flags)
    if array.ndim != 1:
        raise EvaluationError(f"flags of {name} must be an (N,) array, got shape {array.shape}")
    if array.dtype != bool:
        if array.size and not np.all(np.isin(array, (0, 1))):
            frame = int(np.flatnonzero(~np.isin(array, (0, 1)))[0])
            raise EvaluationError(
                f"flags of {name} must be booleans or 0/1, got the value {array[frame].item()!r} at frame {frame}; "
                "pass one True/False per frame"
            )
        array = array.astype(bool)
    return array


def failure_spans(failed: np.ndarray, *, min_span: int = 5) -> np.ndarray:
    """Maximal runs of consecutive ``True`` at least ``min_span`` long.

    Parameters
    ----------
    failed : (N,) bool array_like
        Per-frame failure indicator.
    min_span : int
        Shortest run that counts, in frames.

    Returns
    -------
    spans : (S, 2) int64 ndarray
        ``[start, stop)`` frame indices of each run, in order.
    """
    failed = np.asarray(failed, dtype=bool)
    if min_span < 1:
        raise EvaluationError(f"min_span must be >= 1 frame, got {min_span}")
    padded = np.concatenate(([False], failed, [False])).astype(np.int8)
    edges = np.diff(padded)
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    keep = (stops - starts) >= min_span
    return np.stack([starts[keep], stops[keep]], axis=1).astype(np.int64).reshape(-1, 2)


def flag_quality(
    flags: np.ndarray,
    ious: np.ndarray,
    *,
    fail_iou: float = 0.5,
    min_span: int = 5,
    onset_window: int = 10,
    name: str = "the sequence",
) -> FlagQuality:
    """Join per-frame review flags with per-frame IoU; see the module notes for definitions.

    Parameters
    ----------
    flags : (N,) bool array_like
        ``True`` where the tool flagged the frame for review (0/1 accepted).
    ious : (N,) float array_like
        Per-frame IoU against ground truth, e.g. ``SequenceScore.ious``.
        NaN and negative values (invalid ground truth) count as failures.
    fail_iou : float
        A frame fails when its IoU is below this value.
    min_span : int
        Shortest failure run counted as a span, in frames.
    onset_window : int
        A span is detected when a flag falls within its first this-many frames.
    name : str
        Used in error messages.

    Returns
    -------
    FlagQuality
    """
    flags = _as_flags(flags, name)
    ious = np.asarray(ious, dtype=np.float64)
    if ious.ndim != 1:
        raise EvaluationError(f"ious of {name} must be an (N,) array, got shape {ious.shape}")
    if len(flags) != len(ious):
        raise EvaluationError(
            f"{name}: {len(flags)} flags but {len(ious)} IoU values; the flags file needs one entry per frame"
        )
    if onset_window < 1:
        raise EvaluationError(f"onset_window must be >= 1 frame, got {onset_window}")
    failed = ~(ious >= fail_iou)  # NaN compares false, so it fails
    spans = failure_spans(failed, min_span=min_span)
    detected = sum(bool(flags[start : min(start + onset_window, stop)].any()) for start, stop in spans)
    return FlagQuality(
        n_frames=int(len(flags)),
        n_flagged=int(flags.sum()),
        n_failure_frames=int(failed.sum()),
        n_flagged_failures=int((flags & failed).sum()),
        n_failure_spans=int(len(spans)),
        n_detected_spans=int(detected),
    )


@dataclass(frozen=True)
class FlagQualityReport:
    """Flag quality over a dataset.

    Attributes
    ----------
    pooled : FlagQuality
        Counts summed over all sequences (micro average over frames and spans).
    sequences : Mapping[str, FlagQuality]
        Per-sequence results, in input order.
    fail_iou, min_span, onset_window
        The definitions used (see :func:`flag_quality`).
    """

    pooled: FlagQuality
    sequences: Mapping[str, FlagQuality]
    fail_iou: float = 0.5
    min_span: int = 5
    onset_window: int = 10

    def to_dict(self) -> dict:
        """JSON-ready dict: ``{"definition": {...}, "pooled": {...}, "sequences": {name: {...}}}``."""
        return {
            "definition": {"fail_iou": self.fail_iou, "min_span": self.min_span, "onset_window": self.onset_window},
            "pooled": self.pooled.to_dict(),
            "sequences": {name: quality.to_dict() for name, quality in self.sequences.items()},
        }


def flag_quality_dataset(
    per_sequence: Mapping[str, tuple[np.ndarray, np.ndarray]],
    *,
    fail_iou: float = 0.5,
    min_span: int = 5,
    onset_window: int = 10,
) -> FlagQualityReport:
    """Flag quality per sequence and pooled over sequences.

    Parameters
    ----------
    per_sequence : Mapping[str, tuple[(N,) bool array_like, (N,) float array_like]]
        Sequence name -> ``(flags, ious)``.
    fail_iou, min_span, onset_window
        As in :func:`flag_quality`.

    Returns
    -------
    FlagQualityReport
    """
    if not per_sequence:
        raise EvaluationError("no sequences given; pass a mapping name -> (flags, ious)")
    sequences = {
        name: flag_quality(
            flags, ious, fail_iou=fail_iou, min_span=min_span, onset_window=onset_window, name=f"sequence {name!r}"
        )
        for name, (flags, ious) in per_sequence.items()
    }
    pooled = FlagQuality(0, 0, 0, 0, 0, 0)
    for quality in sequences.values():
        pooled = pooled + quality
    return FlagQualityReport(
        pooled=pooled, sequences=sequences, fail_iou=fail_iou, min_span=min_span, onset_window=onset_window
    )

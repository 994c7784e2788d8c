"""How a segment's forward and backward passes combine into one box per frame, and its flags.

The merge rules (:data:`MERGES`) were compared on ../shared/otb by
``benchmarks/simulated_reviewer.py --merge-study``; flags are recomputed over
whole tracks from each row's stored scores (:func:`reflag`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from annotator.config import RunConfig
from annotator.failure import SIGNALS, FailureModel, load_model, score_track
from annotator.failure.signals import NEUTRAL
from annotator.flagging import flag_p_fail
from sptpt.boxes import iou_xywh

__all__ = ["DEFAULT_MERGE", "MERGES", "NO_SCORING", "PASS_IOU", "PassResult", "filled_signals", "merge_passes", "reflag",
           "track_p_fail"]

#: How a frame between two anchors takes its box from the forward and the backward pass:
#:
#: * ``anchored``: the pass still in its bootstrap stage (its first frames after the human box,
#:   before its subspace models exist) when the other pass is not; otherwise the more confident.
#:   The two stages score on different scales (histogram intersection with the anchor's codes vs.
#:   the logistic of ``RE- - RE+``), so their confidences are not comparable, and a pass that
#:   just left a human box is the one to trust there.
#: * ``confidence``: the more confident pass's box (ties go forward).
#: * ``blend``: the confidence-weighted mean of both boxes.
#: * ``handover``: forward up to the one frame that maximises the summed confidence of
#:   "forward before, backward from", backward after it.
MERGES = ("anchored", "confidence", "blend", "handover")
#: Measured on ../shared/otb by ``benchmarks/simulated_reviewer.py --merge-study`` (RESULTS.md,
#: "Simulated reviewer: merge study"): anchored > confidence ~ handover > blend.
DEFAULT_MERGE = "anchored"

#: ``scoring`` value of rows no tracker scored (``outside`` rows).
NO_SCORING = "none"
#: Track signal holding each row's :attr:`PassResult.pass_iou` (NaN where the row was not merged from two passes).
PASS_IOU = "pass_iou"



@dataclass
class PassResult:
    """One tracker pass over a segment's interior, rows in increasing position order."""

    boxes_xywh: np.ndarray
    confidence: np.ndarray
    log_likelihood: np.ndarray
    accepted: np.ndarray
    scoring: np.ndarray
    seconds: np.ndarray
    #: (n, len(SIGNALS)) failure signals of the pass's rows (annotator.failure.SIGNALS order), NaN where not run.
    signals: np.ndarray | None = None
    #: (n,) IoU of the forward and the backward pass's boxes on a merged row; NaN for a single pass.
    pass_iou: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.signals is None:
            self.signals = np.full((len(self.confidence), len(SIGNALS)), np.nan)
        if self.pass_iou is None:
            self.pass_iou = np.full(len(self.confidence), np.nan)

    @classmethod
    def empty(cls, n: int) -> PassResult:
        return cls(np.full((n, 4), np.nan), np.zeros(n), np.full(n, np.nan), np.zeros(n, bool),
                   np.full(n, NO_SCORING, dtype=object), np.zeros(n))

    def take(self, index) -> PassResult:
        """Copies of the rows at ``index`` (a slice or indices), as a pass of their own (no ``pass_iou``)."""
        return PassResult(*(np.asarray(getattr(self, f))[index].copy() for f in
                            ("boxes_xywh", "confidence", "log_likelihood", "accepted", "scoring", "seconds", "signals")))

def merge_passes(fwd: PassResult, bwd: PassResult | None, method: str = DEFAULT_MERGE) -> PassResult:
    """Combine a forward and a backward pass over the same frames (see :data:`MERGES`).

    ``bwd=None`` returns the forward pass. Per row the result keeps the
    log-likelihood, acceptance and scoring stage of the pass whose box (or
    whose larger weight, for ``blend``) it takes, and that pass's failure
    signals (measured along that pass: "previous frame" is the pass's);
    ``seconds`` is the sum of both, and ``pass_iou`` the IoU of the two
    passes' boxes (the forward-backward check of the failure model's
    ``between_anchors`` section).
    """
    if method not in MERGES:
        raise ValueError(f"merge method {method!r} is not known: choose from {', '.join(MERGES)}")
    if bwd is None:
        return fwd
    n = len(fwd.confidence)
    cf, cb = fwd.confidence, bwd.confidence
    if method == "handover":
        # Forward up to t*, backward from t*: t* maximises sum(cf[:t*]) + sum(cb[t*:]).
        gain = np.concatenate([[0.0], np.cumsum(cf)]) + np.concatenate([np.cumsum(cb[::-1])[::-1], [0.0]])
        switch = int(np.argmax(gain))
        take_fwd = np.arange(n) < switch
    elif method == "anchored":
        fresh_f = np.asarray(fwd.scoring == "bootstrap", dtype=bool)
        fresh_b = np.asarray(bwd.scoring == "bootstrap", dtype=bool)
        take_fwd = np.where(fresh_f & ~fresh_b, True, np.where(fresh_b & ~fresh_f, False, cf >= cb))
    else:
        take_fwd = cf >= cb
    pick = lambda a, b: np.where(take_fwd.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
    out = PassResult(
        boxes_xywh=pick(fwd.boxes_xywh, bwd.boxes_xywh),
        confidence=pick(cf, cb),
        log_likelihood=pick(fwd.log_likelihood, bwd.log_likelihood),
        accepted=pick(fwd.accepted, bwd.accepted),
        scoring=pick(fwd.scoring, bwd.scoring),
        seconds=fwd.seconds + bwd.seconds,
        signals=pick(fwd.signals, bwd.signals),
        # NaN, not 0, where a pass has no box: nothing was compared, so nothing speaks for a loss.
        pass_iou=np.where(np.isfinite(fwd.boxes_xywh).all(axis=1) & np.isfinite(bwd.boxes_xywh).all(axis=1),
                          iou_xywh(fwd.boxes_xywh, bwd.boxes_xywh), np.nan),
    )
    if method == "blend":
        total = cf + cb
        w = np.where(total > 0, cf / np.where(total > 0, total, 1.0), 0.5)
        out.boxes_xywh = w[:, None] * fwd.boxes_xywh + (1 - w[:, None]) * bwd.boxes_xywh
        out.confidence = np.clip(w * cf + (1 - w) * cb, 0.0, 1.0)
        out.signals = np.where((w >= 0.5)[:, None], fwd.signals, bwd.signals)
    return out

def track_p_fail(signals: Mapping[str, np.ndarray], keyframe: np.ndarray, outside: np.ndarray, model: FailureModel,
                 pass_iou: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """``(p_fail, groups)`` of a whole track from its stored signals (see :func:`reflag`)."""
    keyframe, outside = np.asarray(keyframe, bool), np.asarray(outside, bool)
    return score_track(filled_signals(signals), keyframe | outside, outside, model, pass_iou=pass_iou)


def filled_signals(signals: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A track's stored :data:`SIGNALS` with every NaN ("not measured": rows no pass scored; run_iou of a one-run
    tracker; a signal a store was written without, as before it existed) at its neutral value, which for run_iou
    and contrast is NaN itself (the model reads it as its training mean)."""
    n = len(next(iter(signals.values()))) if signals else 0
    return {name: np.nan_to_num(np.asarray(signals.get(name, np.full(n, np.nan)), dtype=np.float64), nan=NEUTRAL[name])
            for name in SIGNALS}


def reflag(signals: Mapping[str, np.ndarray], keyframe: np.ndarray, outside: np.ndarray,
           config: RunConfig, pass_iou: np.ndarray | None = None) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """Failure probabilities and flags of a whole track from its signals: ``(flagged, reasons, p_fail)``.

    Anchors are never flagged and have ``p_fail`` 0; ``outside`` rows are
    flagged with reason ``outside`` (FORMATS.md: absences are recorded in the
    flags file), have no ``p_fail`` (NaN), and neither hold a span open nor
    bridge two flagged stretches. ``pass_iou`` (NaN where a row was not
    merged from two passes) lets the model's ``between_anchors`` section
    correct the rows between two anchors.
    """
    keyframe, outside = np.asarray(keyframe, bool), np.asarray(outside, bool)
    model = load_model(config.failure_model)
    p_fail, groups = track_p_fail(signals, keyframe, outside, model, pass_iou=pass_iou)
    threshold = model.threshold if config.flags.threshold is None else config.flags.threshold
    result = flag_p_fail(p_fail, groups, threshold, config.flags, keyframe=keyframe, outside=outside)
    return result.flagged, result.reasons, p_fail

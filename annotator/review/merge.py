"""How a segment's forward and backward passes combine into one box per frame, and its flags.

The merge rules (:data:`MERGES`) were compared on ../shared/otb by
``benchmarks/simulated_reviewer.py --merge-study``; flags are recomputed over
whole tracks from each row's stored scores (:func:`reflag`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from annotator.config import RunConfig
from annotator.failure import SIGNALS, FailureModel, score_track
from annotator.failure.model import PASS_CHOICE_FEATURES, PASS_OPTIONS, logit
from annotator.failure.signals import NEUTRAL, STAND_IN
from annotator.flagging import flag_p_fail
from annotator.pass_cache import NO_SCORING, PassResult
from annotator.review.segments import Box
from sptpt.boxes import iou_xywh

__all__ = ["DEFAULT_MERGE", "MERGES", "NO_SCORING", "PASS_CHOICE", "PASS_IOU", "PassResult", "filled_signals",
           "merge_passes", "pass_choice_features", "pass_p_fail", "reflag", "track_p_fail"]

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
#: * ``chosen``: as ``anchored`` where the passes agree; where they disagree (IoU below the failure model's
#:   ``pass_choice.disagree_below``), the forward box, the backward box or the interpolation of the two human
#:   boxes, whichever the model's ``pass_choice`` section finds most probably right
#:   (:class:`annotator.failure.model.PassChoice`). Exactly ``anchored`` with a model without the section.
MERGES = ("chosen", "anchored", "confidence", "blend", "handover")
#: Measured on ../shared/otb: ``anchored`` > confidence ~ handover > blend by ``benchmarks/simulated_reviewer.py
#: --merge-study`` (RESULTS.md, "Simulated reviewer: merge study"); ``chosen`` against ``anchored``, held out, by
#: ``benchmarks/pass_choice.py`` (RESULTS.md, "pass-choice").
DEFAULT_MERGE = "chosen"

#: Track signal holding each row's :attr:`PassResult.pass_iou` (NaN where the row was not merged from two passes).
PASS_IOU = "pass_iou"
#: Track signal holding each row's :attr:`PassResult.choice`: the index in
#: :data:`~annotator.failure.model.PASS_OPTIONS` of the box a disagreeing row took (NaN elsewhere).
PASS_CHOICE = "pass_choice"




def merge_passes(fwd: PassResult, bwd: PassResult | None, method: str = DEFAULT_MERGE, *,
                 model: FailureModel | None = None, ends: tuple[Box, Box] | None = None) -> PassResult:
    """Combine a forward and a backward pass over the same frames (see :data:`MERGES`).

    ``model`` and ``ends`` (the human boxes the forward pass starts from and
    the backward pass from) serve the ``chosen`` merge, which without either,
    or with a model without a ``pass_choice`` section, is ``anchored``.
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
    # Only the chosen merge reads the section: every other merge is what its name says, whatever the model holds.
    chooser = model.pass_choice if method == "chosen" and model is not None and ends is not None else None
    if method == "chosen":
        method = "anchored"  # where the passes agree, and throughout without a chooser
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

    def pick(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.where(take_fwd.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)

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
    if chooser is not None:
        assert model is not None and ends is not None  # a chooser comes from the model, given the ends
        _choose_where_passes_disagree(out, fwd, bwd, model, ends)
    return out


def pass_p_fail(result: PassResult, model: FailureModel, *, backward: bool) -> np.ndarray:
    """Each row's failure probability along its own pass, which starts at a human box (a keyframe row).

    ``result``'s rows are in position order; a backward pass is scored in the order it ran.
    """
    rows = result.signals[::-1] if backward else result.signals
    signals = np.vstack([np.full((1, len(SIGNALS)), np.nan), rows])
    keyframe = np.zeros(len(signals), bool)
    keyframe[0] = True
    p_fail, _ = score_track(filled_signals({name: signals[:, k] for k, name in enumerate(SIGNALS)}), keyframe,
                            np.zeros(len(signals), bool), model)
    return p_fail[1:][::-1] if backward else p_fail[1:]


def pass_choice_features(p_forward: np.ndarray, p_backward: np.ndarray, forward_boxes: np.ndarray,
                         backward_boxes: np.ndarray, ends: tuple[Box, Box]) -> tuple[np.ndarray, np.ndarray]:
    """``(features, interpolation)`` of the rows strictly between two human boxes ``ends``.

    ``features`` are :data:`~annotator.failure.model.PASS_CHOICE_FEATURES` per row; ``interpolation`` the
    linear interpolation of the two boxes.
    """
    n = len(p_forward)
    gap = n + 1
    t = np.arange(1, n + 1) / gap
    start, stop = (np.asarray(b, dtype=np.float64) for b in ends)
    interpolation = (1.0 - t)[:, None] * start + t[:, None] * stop
    overlap = lambda a, b: np.nan_to_num(iou_xywh(a, b), nan=0.0)  # noqa: E731 (a missing box overlaps nothing)
    columns = {
        "logit_p_forward": logit(p_forward), "logit_p_backward": logit(p_backward),
        "forward_iou_interpolation": overlap(forward_boxes, interpolation),
        "backward_iou_interpolation": overlap(backward_boxes, interpolation),
        "pass_iou": overlap(forward_boxes, backward_boxes), "position": t, "edge_distance": np.minimum(t, 1.0 - t),
    }
    return np.stack([columns[name] for name in PASS_CHOICE_FEATURES], axis=1), interpolation


def _choose_where_passes_disagree(out: PassResult, fwd: PassResult, bwd: PassResult, model: FailureModel,
                                  ends: tuple[Box, Box]) -> None:
    """The ``chosen`` merge's rows where the passes disagree, written into ``out`` (see :data:`MERGES`)."""
    chooser = model.pass_choice
    assert chooser is not None  # merge_passes calls this only with the model's pass_choice section
    both = np.isfinite(fwd.boxes_xywh).all(axis=1) & np.isfinite(bwd.boxes_xywh).all(axis=1)
    disagree = both & (out.pass_iou < chooser.disagree_below)
    if not disagree.any():
        return
    p_fwd, p_bwd = pass_p_fail(fwd, model, backward=False), pass_p_fail(bwd, model, backward=True)
    features, interpolation = pass_choice_features(p_fwd, p_bwd, fwd.boxes_xywh, bwd.boxes_xywh, ends)
    can_interpolate = len(out.confidence) + 1 <= chooser.max_gap
    rows = np.flatnonzero(disagree)
    picks = chooser.choose(features[rows], np.full(len(rows), can_interpolate))
    forward, backward, _ = range(len(PASS_OPTIONS))
    for row, pick in zip(rows, picks):
        # An interpolated row keeps the other fields of the pass that doubts itself less, so its p_fail is that of
        # a tracked box: no signal measures the interpolation itself. Measured, that ranks these rows' failures
        # worse than the section's own probability would (RESULTS.md, "pass-choice").
        source = fwd if pick == forward or (pick != backward and p_fwd[row] <= p_bwd[row]) else bwd
        out.boxes_xywh[row] = interpolation[row] if pick not in (forward, backward) else source.boxes_xywh[row]
        out.confidence[row], out.log_likelihood[row] = source.confidence[row], source.log_likelihood[row]
        out.accepted[row], out.scoring[row] = source.accepted[row], source.scoring[row]
        out.signals[row] = source.signals[row]
        out.choice[row] = pick

def track_p_fail(signals: Mapping[str, np.ndarray], keyframe: np.ndarray, outside: np.ndarray, model: FailureModel,
                 pass_iou: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """``(p_fail, groups)`` of a whole track from its stored signals (see :func:`reflag`)."""
    keyframe, outside = np.asarray(keyframe, bool), np.asarray(outside, bool)
    return score_track(filled_signals(signals), keyframe | outside, outside, model, pass_iou=pass_iou)


def filled_signals(signals: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A track's stored :data:`SIGNALS` with every NaN ("not measured": rows no pass scored; run_iou of a one-run
    tracker; a signal a store was written without, as before it existed) at its neutral value, which for run_iou,
    run_support and contrast is NaN itself (the model reads it as its training mean); a signal with a
    :data:`~annotator.failure.signals.STAND_IN` takes that signal's (filled) value on the row instead."""
    n = len(next(iter(signals.values()))) if signals else 0
    stored = {name: np.asarray(signals.get(name, np.full(n, np.nan)), dtype=np.float64) for name in SIGNALS}
    filled = {name: np.nan_to_num(values, nan=NEUTRAL[name]) for name, values in stored.items()}
    for name, stand_in in STAND_IN.items():
        filled[name] = np.where(np.isnan(stored[name]), filled[stand_in], stored[name])
    return filled


def reflag(signals: Mapping[str, np.ndarray], keyframe: np.ndarray, outside: np.ndarray,
           config: RunConfig, pass_iou: np.ndarray | None = None, *, model: FailureModel | None = None
           ) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """Failure probabilities and flags of a whole track from its signals: ``(flagged, reasons, p_fail)``.

    Anchors are never flagged and have ``p_fail`` 0; ``outside`` rows are
    flagged with reason ``outside`` (FORMATS.md: absences are recorded in the
    flags file), have no ``p_fail`` (NaN), and neither hold a span open nor
    bridge two flagged stretches. ``pass_iou`` (NaN where a row was not
    merged from two passes) lets the model's ``between_anchors`` section
    correct the rows between two anchors. ``model``: ``config``'s failure
    model, where the caller has it loaded already.
    """
    keyframe, outside = np.asarray(keyframe, bool), np.asarray(outside, bool)
    model = config.load_failure_model() if model is None else model
    p_fail, groups = track_p_fail(signals, keyframe, outside, model, pass_iou=pass_iou)
    threshold = model.threshold if config.flags.threshold is None else config.flags.threshold
    result = flag_p_fail(p_fail, groups, threshold, config.flags, keyframe=keyframe, outside=outside)
    return result.flagged, result.reasons, p_fail

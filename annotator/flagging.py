"""Which frames a human should review: the frames whose failure probability is high, as spans.

A frame is *doubtful* when its failure probability ``p_fail``
(:mod:`annotator.failure`) exceeds a threshold; boxes a person gave
(keyframes) never are. Doubtful frames a few frames apart are merged into one
span, and spans shorter than a minimum are dropped, so the reviewer gets a
handful of stretches rather than a confetti of single frames. Frames where
the object is absent (``outside``) are always flagged, with that reason.

With a review budget the rule is different: the given percentage of each
track's frames, the most doubtful first, is flagged, with no merging (a
person with a fixed amount of time gets exactly that many frames).

Reasons (the ``reason`` column of flags.csv, ``+``-joined)
----------------------------------------------------------
See :data:`REASONS`, the one place they are explained; docs/flags.md and the
report show the same text.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

__all__ = ["KEYFRAME_REASON", "REASONS", "FlagParams", "FlagResult", "SpanFlagger", "budget_flags", "flag_p_fail",
           "keyframe_request", "keyframe_rows", "span_flags", "spans_from_mask", "with_keyframe_request"]

#: Every reason a user can see, with what it means. ``doubt:<group>`` names the group of signals that
#: raised the failure probability most (annotator.failure.model.FEATURE_GROUPS).
REASONS: Mapping[str, str] = {
    "doubt:score": "the tracker's own score is low or fell below its recent level",
    "doubt:candidates": "many candidate boxes scored alike: the tracker cannot tell the object from its surroundings",
    "doubt:motion": "the box jumped or changed size more than the object plausibly moves",
    "doubt:drift": "the box's size or shape drifted from the first frame's, or it is far from the last human box",
    "doubt:flow": "optical flow moved the previous box somewhere else, could not follow its points, or the box "
                  "slid away from them over the last frames",
    "doubt:extent": "the motion around the box disagrees with its size: points just outside it move with it (the "
                    "object reaches past the box), points inside it move with the background (the box holds "
                    "background), or its size changed unlike the object's",
    "doubt:appearance": "the image under the box no longer looks like the object in the first frame, or like the "
                        "object earlier in the track (the shipped model counts this only where one of the tracker's "
                        "runs parts from the box)",
    "doubt:contrast": "the box's colours hardly differ from those around it: it may sit on background",
    "doubt:runs": "the tracker's independent runs put the box in different places: one has likely lost the object",
    "doubt:guide": "the learned tracker beside SPTPT (NanoTrack, in the fused preset) puts the object elsewhere, or "
                   "sees it at another size",
    "doubt:passes": "between two human boxes, the re-tracks forward from the earlier and backward from the later "
                    "one put the box in different places: one has likely lost the object (only with a failure model "
                    "that has a between_anchors section; the shipped one has none)",
    "span": "between two doubtful frames a few frames apart: flagged so the span is reviewed in one go",
    "budget": "among the most doubtful frames of the track (--review-budget)",
    "keyframe": "the track is probably lost on most of its frames: box this frame (one every few frames, and the "
                "last), then re-track, instead of reviewing the track frame by frame",
    "outside": "the object is marked absent from this frame (a correction said so)",
}
#: The reason of the frames a lost track asks a person to box (:func:`with_keyframe_request`).
KEYFRAME_REASON = "keyframe"


@dataclass(frozen=True)
class FlagParams:
    """How failure probabilities become flags (all configurable from the CLI's config file)."""

    threshold: float | None = None
    """Flag frames with ``p_fail`` above this; ``None`` takes the failure model's, chosen when it was fitted for a
    recall of 0.8 and a precision of 0.7 on videos it did not learn from
    (``annotator.failure.fit.choose_threshold``; the shipped model's is the ``threshold`` of its file).
    [ours, benchmarks/RESULTS.md "Failure probability and flags"]"""
    review_budget: float | None = None
    """Percent of each track's frames to flag, the most doubtful first, instead of the threshold. [ours]"""
    merge_gap: int = 5
    """Doubtful frames at most this many frames apart form one span. [ours]"""
    min_span: int = 3
    """Spans shorter than this many frames are not flagged. [ours]"""
    lost_threshold: float | None = 0.6
    """A track whose tracked frames have a mean ``p_fail`` above this is probably lost on most of them: instead of
    its doubtful spans, every ``keyframe_every``-th frame and the last are flagged (reason ``keyframe``) for a person
    to box. Correcting a lost track one doubtful frame at a time costs more than boxing keyframes: the tracker loses
    the object again after each correction and every re-tracked span is looked at again. ``None`` never asks.
    Chosen by leave-one-sequence-out on held-out failure probabilities of ``../shared/otb`` (0.6 in 15 of 17 folds).
    Not with a review budget. [ours, benchmarks/HISTORY.md "keyframe request"]"""
    keyframe_every: int = 10
    """Processed frames between the keyframes a lost track asks for. [ours, benchmarks/RESULTS.md]"""

    def __post_init__(self) -> None:
        checks = [
            (self.threshold is None or 0.0 < self.threshold < 1.0, "threshold", "a probability in (0, 1)"),
            (self.review_budget is None or 0.0 < self.review_budget <= 100.0, "review_budget",
             "a percentage in (0, 100]"),
            (self.merge_gap >= 0, "merge_gap", "an integer >= 0"),
            (self.min_span >= 1, "min_span", "an integer >= 1"),
            (self.lost_threshold is None or 0.0 < self.lost_threshold < 1.0, "lost_threshold",
             "a probability in (0, 1), or null to never ask for keyframes"),
            (self.keyframe_every >= 2, "keyframe_every", "an integer >= 2"),
        ]
        for ok, name, expected in checks:
            if not ok:
                raise ValueError(f"flag parameter {name}={getattr(self, name)!r} is invalid: expected {expected}")

    @property
    def lag(self) -> int:
        """Frames after a doubtful decision until its flag is final (span merging looks this far ahead)."""
        return self.merge_gap + self.min_span


@dataclass(frozen=True)
class FlagResult:
    """Per-frame flags and the reason for each.

    Attributes
    ----------
    flagged : (F,) bool ndarray
    reasons : tuple of str
        ``''`` for unflagged frames, else ``'+'``-joined :data:`REASONS`.
    spans : (S, 2) int64 ndarray
        ``[start, stop)`` positions of flagged spans in the processed frame list.
    """

    flagged: np.ndarray
    reasons: tuple[str, ...]
    spans: np.ndarray


def spans_from_mask(mask: np.ndarray) -> np.ndarray:
    """``[start, stop)`` runs of True in a boolean vector, shape (S, 2)."""
    padded = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return edges.reshape(-1, 2).astype(np.int64)


class SpanFlagger:
    """Turns per-frame doubtful decisions into flags, each final after a bounded lag.

    Span merging and the minimum span length need a few frames of look-ahead:
    a frame's flag is final once ``params.lag`` later frames have been pushed,
    so the overlay can be drawn while tracking with a frame buffer of constant
    size and show exactly the flags of flags.csv. Outside frames are always
    flagged; keyframes never are, and no span merges across one.
    """

    def __init__(self, params: FlagParams | None = None) -> None:
        self.params = FlagParams() if params is None else params
        self.lag = self.params.lag
        self._raw: list[bool] = []
        self._keyframe: list[bool] = []
        self._outside: list[bool] = []
        self._reasons: list[str] = []
        self._emitted = 0

    def push(self, doubtful: bool, reason: str, *, keyframe: bool = False,
             outside: bool = False) -> list[tuple[int, bool, str]]:
        """Add the next frame; return the ``(position, flagged, reason)`` of frames that became final."""
        self._raw.append(bool(doubtful) and not keyframe and not outside)
        self._keyframe.append(bool(keyframe))
        self._outside.append(bool(outside))
        self._reasons.append(reason)
        return self._emit(len(self._raw) - self.lag)

    def finish(self) -> list[tuple[int, bool, str]]:
        """Finalise every remaining frame (the end of the sequence is known)."""
        return self._emit(len(self._raw), at_end=True)

    def _emit(self, until: int, *, at_end: bool = False) -> list[tuple[int, bool, str]]:
        if until <= self._emitted:
            return []
        # Span rules look at most `lag` frames either way; a window of 2 lags
        # before the first undecided frame decides it as the whole prefix would.
        lo = max(0, self._emitted - 2 * self.lag - 1)
        raw = np.array(self._raw[lo:], bool)
        blocked = np.array(self._keyframe[lo:], bool) | np.array(self._outside[lo:], bool)
        # A span still open at the end of the known frames may grow, unless the sequence ended.
        merged, final = _span_rules(raw, blocked, self.params, open_end=not at_end)
        out = []
        for t in range(self._emitted, until):
            if self._outside[t]:
                out.append((t, True, "outside"))
                continue
            flagged = bool(final[t - lo])
            reason = self._reasons[t] if self._raw[t] else ("span" if merged[t - lo] else "")
            out.append((t, flagged, (reason or "span") if flagged else ""))
        self._emitted = until
        return out


def _doubt_reason(group: str) -> str:
    return f"doubt:{group}"


def flag_p_fail(p_fail: np.ndarray, groups, threshold: float, params: FlagParams | None = None, *,
                keyframe: np.ndarray | None = None, outside: np.ndarray | None = None) -> FlagResult:
    """Flags of a whole track from its failure probabilities (the offline form of :class:`SpanFlagger`).

    Parameters
    ----------
    p_fail : (F,) ndarray
        Failure probability per frame (NaN where there is no box).
    groups : sequence of str, length F
        The signal group behind each frame's probability (``doubt:<group>`` reasons).
    threshold : float
        Frames above it are doubtful.
    params : FlagParams, optional
        Span merging; a ``review_budget`` selects :func:`budget_flags` instead.
    keyframe, outside : (F,) bool ndarray, optional
    """
    params = FlagParams() if params is None else params
    p_fail = np.asarray(p_fail, dtype=np.float64)
    n = p_fail.shape[0]
    keyframe = np.zeros(n, bool) if keyframe is None else np.asarray(keyframe, bool)
    outside = np.zeros(n, bool) if outside is None else np.asarray(outside, bool)
    if len(groups) != n or keyframe.shape != (n,) or outside.shape != (n,):
        raise ValueError(f"p_fail, groups, keyframe and outside must have the same length, got {n}, {len(groups)}, "
                         f"{keyframe.shape[0]}, {outside.shape[0]}")
    if params.review_budget is not None:
        return budget_flags(p_fail, groups, params.review_budget, keyframe=keyframe, outside=outside)
    flagger = SpanFlagger(params)
    decided = []
    for t in range(n):
        doubtful = bool(np.isfinite(p_fail[t]) and p_fail[t] > threshold)
        decided += flagger.push(doubtful, _doubt_reason(groups[t]), keyframe=bool(keyframe[t]),
                                outside=bool(outside[t]))
    decided += flagger.finish()
    flagged = np.array([f for _, f, _ in decided], dtype=bool)
    result = FlagResult(flagged=flagged, reasons=tuple(r for _, _, r in decided), spans=spans_from_mask(flagged))
    return with_keyframe_request(result, p_fail, keyframe=keyframe, outside=outside, params=params)


def span_flags(doubtful: np.ndarray, params: FlagParams, *, blocked: np.ndarray | None = None) -> np.ndarray:
    """Which frames of a whole track are flagged, from its doubtful frames: :class:`SpanFlagger`'s spans at once.

    The same flags as :func:`flag_p_fail` with ``p_fail > threshold`` as ``doubtful``, ``blocked`` = keyframes
    (no outside frames, no review budget, no keyframe request): the rules the flagger applies window by window
    (:func:`_span_rules`), applied once to the whole track, without reasons and without a Python loop over
    frames: choosing a threshold (:func:`annotator.failure.fit.choose_threshold`) flags tens of thousands of
    frames at each of ninety thresholds.
    """
    doubtful = np.asarray(doubtful, bool)
    blocked = np.zeros(doubtful.shape[0], bool) if blocked is None else np.asarray(blocked, bool)
    return _span_rules(doubtful & ~blocked, blocked, params)[1]


def _span_rules(raw: np.ndarray, blocked: np.ndarray, params: FlagParams, *, open_end: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(merged, final)`` masks of the span rules on doubtful frames ``raw`` (never ``blocked`` ones).

    ``merged``: ``raw`` with every gap of at most ``merge_gap`` frames between two doubtful frames filled, unless
    it holds a blocked frame (a keyframe or an outside frame). A gap that touches either end of ``raw`` is not
    between two doubtful frames. ``final``: ``merged`` without its spans shorter than ``min_span``; with
    ``open_end``, a span that reaches the end is kept (more frames may lengthen it).
    """
    n = raw.shape[0]
    merged = raw.copy()
    gaps = spans_from_mask(~raw)
    if len(gaps):
        blocked_before = np.concatenate([[0], np.cumsum(blocked)])
        fill = gaps[(gaps[:, 0] > 0) & (gaps[:, 1] < n) & (gaps[:, 1] - gaps[:, 0] <= params.merge_gap)
                    & (blocked_before[gaps[:, 1]] == blocked_before[gaps[:, 0]])]
        merged |= _cover(fill, n)
    spans = spans_from_mask(merged)
    short = spans[:, 1] - spans[:, 0] < params.min_span
    if open_end:
        short &= spans[:, 1] < n
    return merged, _cover(spans[~short], n)


def _cover(spans: np.ndarray, n: int) -> np.ndarray:
    """A length-``n`` mask, True on the ``[start, stop)`` spans (disjoint)."""
    edges = np.zeros(n + 1, np.int64)
    np.add.at(edges, spans[:, 0], 1)
    np.add.at(edges, spans[:, 1], -1)
    return np.cumsum(edges[:-1]) > 0


def budget_flags(p_fail: np.ndarray, groups, percent: float, *, keyframe: np.ndarray,
                 outside: np.ndarray) -> FlagResult:
    """Flag the ``percent`` % most doubtful frames of a track (rounded up), plus every outside frame.

    Keyframes and outside frames are not candidates; ties go to the earlier frame.
    """
    p_fail = np.asarray(p_fail, dtype=np.float64)
    n = p_fail.shape[0]
    candidates = np.flatnonzero(~keyframe & ~outside & np.isfinite(p_fail))
    k = min(len(candidates), int(math.ceil(percent / 100.0 * n - 1e-9)))
    order = candidates[np.lexsort((candidates, -p_fail[candidates]))]
    flagged = np.asarray(outside, bool).copy()
    flagged[order[:k]] = True
    reasons = tuple("outside" if outside[t] else f"budget+{_doubt_reason(groups[t])}" if flagged[t] else ""
                    for t in range(n))
    return FlagResult(flagged=flagged, reasons=reasons, spans=spans_from_mask(flagged))


def keyframe_request(p_fail: np.ndarray, *, keyframe: np.ndarray, outside: np.ndarray,
                     params: FlagParams) -> np.ndarray:
    """Positions a person should box because the track is probably lost (:attr:`FlagParams.lost_threshold`).

    Empty unless the mean ``p_fail`` of the tracked positions (no human box, not absent) exceeds the threshold
    and the track has more positions than ``keyframe_every``.
    Else positions ``every``, ``2 every``, ... and the last, as an interpolation tool asks for keyframes, minus
    those that already hold a human box or an absence.
    """
    p_fail = np.asarray(p_fail, dtype=np.float64)
    keyframe, outside = np.asarray(keyframe, bool), np.asarray(outside, bool)
    n = p_fail.shape[0]
    tracked = ~keyframe & ~outside & np.isfinite(p_fail)
    # A track no longer than the interval would be asked for its last frame alone: it is flagged as usual.
    if (params.lost_threshold is None or n <= params.keyframe_every or not tracked.any()
            or p_fail[tracked].mean() <= params.lost_threshold):
        return np.zeros(0, dtype=np.int64)
    rows = np.unique(np.append(np.arange(params.keyframe_every, n, params.keyframe_every), n - 1))
    return rows[~keyframe[rows] & ~outside[rows]].astype(np.int64)


def with_keyframe_request(result: FlagResult, p_fail: np.ndarray, *, keyframe: np.ndarray, outside: np.ndarray,
                          params: FlagParams) -> FlagResult:
    """``result``, or, for a track that is probably lost, its keyframe request: the requested positions flagged
    with reason ``keyframe`` and absences with ``outside``, nothing else (see :func:`keyframe_request`)."""
    rows = keyframe_request(p_fail, keyframe=keyframe, outside=outside, params=params)
    if rows.size == 0:
        return result
    flagged = np.asarray(outside, bool).copy()
    flagged[rows] = True
    reasons = tuple("outside" if outside[t] else KEYFRAME_REASON if flagged[t] else "" for t in range(len(flagged)))
    return FlagResult(flagged=flagged, reasons=reasons, spans=spans_from_mask(flagged))


def keyframe_rows(reasons) -> list[int]:
    """Positions whose flag is a keyframe request (reason :data:`KEYFRAME_REASON`, alone or ``+``-joined)."""
    return [p for p, reason in enumerate(reasons) if KEYFRAME_REASON in reason.split("+")]

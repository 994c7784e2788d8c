"""Which frames a human should review: the tracker's own doubt, turned into spans.

The starting point is the paper's test: a frame whose best candidate has
``RE- - RE+ <= Phi`` is one the model refuses to learn from. On its own that
test is noisy frame to frame and blind to slow drift, so three additions make
the flags useful to a reviewer:

- a *drop* test against the recent running level of the log-likelihood
  (a robust median over the last accepted frames), which catches the moment
  the tracker slides onto the background even while the score stays positive;
- *hysteresis*: once flagged, a track stays flagged until the score climbs
  back to the running level, because a tracker that lost its target rarely
  finds it again by itself;
- *spans*: flags a few frames apart are merged, and spans shorter than a
  minimum length are dropped, so the reviewer gets a handful of stretches
  rather than a confetti of single frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FlagParams", "FlagResult", "OnlineFlagger", "flag_frames", "spans_from_mask"]


@dataclass(frozen=True)
class FlagParams:
    """Thresholds of the flagging rules (all configurable from the CLI's config file)."""

    accept_threshold: float = 0.0
    """Phi: a subspace-scored frame with log-likelihood <= Phi is flagged ('rejected'). [paper]"""
    margin: float = 2.0
    """Also flag ('low_likelihood') frames the model accepted by less than this: ``Phi < l <= Phi + margin``.
    On ../shared/otb a tracker that has slid onto the background often keeps a small positive score. [ours]"""
    window: int = 100
    """Frames in the running level of the log-likelihood (median of the last trusted frames). [ours]"""
    drop: float = 0.3
    """Flag ('drop') when the log-likelihood falls below ``level * (1 - drop)`` for positive levels. [ours]"""
    recover: float = 0.95
    """Hysteresis: a flagged track clears once the score is back above ``level * recover``. [ours]"""
    min_confidence: float = 0.0
    """Also flag frames whose confidence is below this ('low_confidence'); 0 disables. [ours]"""
    merge_gap: int = 5
    """Flagged frames at most this many frames apart form one span. [ours]"""
    min_span: int = 3
    """Spans shorter than this many frames are not flagged. [ours]"""

    def __post_init__(self) -> None:
        checks = [
            (self.margin >= 0.0, "margin", "a number >= 0"),
            (self.window >= 1, "window", "an integer >= 1"),
            (0.0 <= self.drop <= 1.0, "drop", "a number in [0, 1]"),
            (0.0 <= self.recover <= 1.0, "recover", "a number in [0, 1]"),
            (0.0 <= self.min_confidence <= 1.0, "min_confidence", "a number in [0, 1]"),
            (self.merge_gap >= 0, "merge_gap", "an integer >= 0"),
            (self.min_span >= 1, "min_span", "an integer >= 1"),
        ]
        for ok, name, expected in checks:
            if not ok:
                raise ValueError(f"flag parameter {name}={getattr(self, name)!r} is invalid: expected {expected}")


@dataclass(frozen=True)
class FlagResult:
    """Per-frame flags and the reason for each.

    Attributes
    ----------
    flagged : (F,) bool ndarray
    reasons : tuple of str
        ``''`` for unflagged frames, else ``'+'``-joined reasons among
        ``rejected``, ``low_likelihood``, ``drop``, ``low_confidence``, ``held`` (hysteresis) and
        ``span`` (merged into a span from a gap).
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


class OnlineFlagger:
    """Flags frames as they are tracked, each final after a bounded lag.

    The per-frame rules (Phi, drop, hysteresis, low confidence) are causal;
    span merging and the minimum span length need a few frames of look-ahead.
    A frame's flag is final once ``lag = merge_gap + min_span`` later frames
    have been pushed, so the overlay can be rendered while tracking with a
    frame buffer of constant size, and it shows exactly the flags of
    ``flags.csv``.

    Parameters
    ----------
    params : FlagParams, optional
    """

    def __init__(self, params: FlagParams | None = None) -> None:
        self.params = FlagParams() if params is None else params
        self.lag = self.params.merge_gap + self.params.min_span
        self._raw: list[bool] = []
        self._keyframe: list[bool] = []
        self._reasons: list[list[str]] = []
        self._history: list[float] = []
        self._holding = False
        self._emitted = 0

    def push(self, log_likelihood: float, confidence: float, scoring: str, keyframe: bool = False) -> list[tuple[int, bool, str]]:
        """Add the next frame; return the ``(position, flagged, reason)`` of frames that became final."""
        p = self.params
        reasons: list[str] = []
        if keyframe:
            self._holding = False
        else:
            if p.min_confidence > 0 and confidence < p.min_confidence:
                reasons.append("low_confidence")
            if scoring == "subspace":
                level = float(np.median(self._history[-p.window :])) if self._history else np.nan
                if not np.isfinite(log_likelihood) or log_likelihood <= p.accept_threshold:
                    reasons.append("rejected")
                elif log_likelihood <= p.accept_threshold + p.margin:
                    reasons.append("low_likelihood")
                elif np.isfinite(level) and level > 0 and log_likelihood < level * (1.0 - p.drop):
                    reasons.append("drop")
                if reasons:
                    self._holding = True
                elif self._holding:
                    # With no running level yet there is nothing to climb back to: a good frame clears.
                    if not np.isfinite(level) or log_likelihood >= level * p.recover:
                        self._holding = False
                    else:
                        reasons.append("held")
                # Only frames the tracker trusts define the running level.
                if not reasons and log_likelihood > p.accept_threshold + p.margin:
                    self._history.append(float(log_likelihood))
        self._raw.append(bool(reasons))
        self._keyframe.append(bool(keyframe))
        self._reasons.append(reasons)
        return self._emit(len(self._raw) - self.lag)

    def finish(self) -> list[tuple[int, bool, str]]:
        """Finalise every remaining frame (the end of the sequence is known)."""
        return self._emit(len(self._raw), at_end=True)

    def _emit(self, until: int, *, at_end: bool = False) -> list[tuple[int, bool, str]]:
        if until <= self._emitted:
            return []
        p = self.params
        # Span rules look at most `lag` frames either way; a window of 2 lags
        # before the first undecided frame decides it as the whole prefix would.
        lo = max(0, self._emitted - 2 * self.lag - 1)
        raw = np.array(self._raw[lo:], bool)
        keyframe = np.array(self._keyframe[lo:], bool)
        merged = raw.copy()
        gap_frames: set[int] = set()
        for start, stop in spans_from_mask(~raw):
            # A gap merges only between two flagged frames: it must not touch either end of what is known.
            if start > 0 and stop < raw.shape[0] and stop - start <= p.merge_gap and not keyframe[start:stop].any():
                merged[start:stop] = True
                gap_frames.update(range(lo + start, lo + stop))
        final = merged.copy()
        for start, stop in spans_from_mask(merged):
            # A span still open at the end of the known frames may grow, unless the sequence ended.
            if stop - start < p.min_span and (at_end or stop < raw.shape[0]):
                final[start:stop] = False
        out = []
        for t in range(self._emitted, until):
            flagged = bool(final[t - lo])
            reasons = self._reasons[t] + (["span"] if t in gap_frames else [])
            out.append((t, flagged, "+".join(reasons) if flagged else ""))
        self._emitted = until
        return out


def flag_frames(
    log_likelihood: np.ndarray,
    confidence: np.ndarray,
    scoring: np.ndarray,
    params: FlagParams | None = None,
    *,
    keyframe: np.ndarray | None = None,
) -> FlagResult:
    """Flag every frame of a finished track (the offline form of :class:`OnlineFlagger`).

    Parameters
    ----------
    log_likelihood : (F,) ndarray
        ``RE- - RE+`` per processed frame (bootstrap score before the models exist).
    confidence : (F,) ndarray
        In [0, 1].
    scoring : (F,) array of str
        ``init``, ``bootstrap`` or ``subspace``: the rules that compare with
        Phi and the running level apply to subspace-scored frames only, since
        the bootstrap score is on another scale.
    params : FlagParams, optional
    keyframe : (F,) bool ndarray, optional
        Frames set by a human (or the first frame); never flagged.

    Returns
    -------
    FlagResult
    """
    score = np.asarray(log_likelihood, dtype=np.float64)
    confidence = np.asarray(confidence, dtype=np.float64)
    scoring = np.asarray(scoring)
    n = score.shape[0]
    if confidence.shape != (n,) or scoring.shape != (n,):
        raise ValueError(
            "log_likelihood, confidence and scoring must have the same length, "
            f"got {n}, {confidence.shape[0]}, {scoring.shape[0]}"
        )
    keyframe = np.zeros(n, bool) if keyframe is None else np.asarray(keyframe, bool)
    flagger = OnlineFlagger(params)
    decided = []
    for t in range(n):
        decided += flagger.push(float(score[t]), float(confidence[t]), str(scoring[t]), bool(keyframe[t]))
    decided += flagger.finish()
    flagged = np.array([f for _, f, _ in decided], dtype=bool)
    return FlagResult(flagged=flagged, reasons=tuple(r for _, _, r in decided), spans=spans_from_mask(flagged))

"""Where a track is probably wrong: per-frame signals, the failure probability, and flags from it.

* :mod:`~annotator.failure.signals`: what is measured per frame while (re-)tracking.
* :mod:`~annotator.failure.model`: features of a whole track, and the fitted model
  that turns them into ``p_fail = P(IoU < 0.5)``.

:class:`TrackDoubt` does both frame by frame for the tracking loop, with the flags
of :class:`annotator.flagging.SpanFlagger`; :func:`score_track` does it for a whole
track (re-tracking, evaluation), with the same numbers.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from annotator.failure.model import (
    FEATURE_GROUPS,
    FEATURES,
    LOOKAHEAD,
    FailureModel,
    FailureModelError,
    OnlineFailure,
    feature_matrix,
    load_model,
)
from annotator.failure.signals import SIGNALS, SignalMeter, particle_stats
from annotator.flagging import FlagParams, SpanFlagger

__all__ = [
    "FEATURES",
    "FEATURE_GROUPS",
    "LOOKAHEAD",
    "SIGNALS",
    "FailureModel",
    "FailureModelError",
    "SignalMeter",
    "TrackDoubt",
    "feature_matrix",
    "load_model",
    "particle_stats",
    "score_track",
]


def score_track(signals: Mapping[str, np.ndarray], keyframe: np.ndarray, outside: np.ndarray,
                model: FailureModel, pass_iou: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """``(p_fail, groups)`` of a whole track: 0 where a person gave the box, NaN where the object is absent.

    ``pass_iou``: per row, the IoU of the forward and backward re-tracks' boxes between two anchors (NaN
    elsewhere); the model's ``between_anchors`` section corrects those rows (group ``passes`` where the
    passes' disagreement raised the probability).
    """
    keyframe, outside = np.asarray(keyframe, bool), np.asarray(outside, bool)
    features = feature_matrix(signals, keyframe)
    p_fail = model.p_fail(features) if len(keyframe) else np.zeros(0)
    groups = model.main_group(features) if len(keyframe) else []
    if pass_iou is not None and len(keyframe):
        p_fail, raised = model.with_pass_agreement(p_fail, np.where(keyframe | outside, np.nan, pass_iou))
        groups = ["passes" if r else g for g, r in zip(groups, raised)]
    p_fail = np.where(keyframe, 0.0, p_fail)
    p_fail = np.where(outside, np.nan, p_fail)
    return p_fail, groups


class TrackDoubt:
    """The tracking loop's view of one track: signals in, ``(position, p_fail, flagged, reason)`` out, final after
    ``lag`` frames (the failure model's look-ahead plus span merging's)."""

    def __init__(self, model: FailureModel, params: FlagParams) -> None:
        if params.review_budget is not None:
            raise ValueError("a review budget needs the whole track: flag it with annotator.flagging.budget_flags")
        self.threshold = model.threshold if params.threshold is None else params.threshold
        self._failure = OnlineFailure(model)
        self._spans = SpanFlagger(params)
        self._keyframe: list[bool] = []
        self._p_fail: dict[int, float] = {}
        self.lag = LOOKAHEAD + params.lag

    def push(self, signals: Mapping[str, float], keyframe: bool) -> list[tuple[int, float, bool, str]]:
        self._keyframe.append(bool(keyframe))
        return self._settle(self._failure.push(signals, keyframe))

    def finish(self) -> list[tuple[int, float, bool, str]]:
        decided = self._settle(self._failure.finish())
        return decided + self._collect(self._spans.finish())

    def _settle(self, scored: list[tuple[int, float, str]]) -> list[tuple[int, float, bool, str]]:
        decided = []
        for position, p, group in scored:
            keyframe = self._keyframe[position]
            p = 0.0 if keyframe else p
            self._p_fail[position] = p
            decided += self._collect(self._spans.push(p > self.threshold, f"doubt:{group}", keyframe=keyframe))
        return decided

    def _collect(self, flags: list[tuple[int, bool, str]]) -> list[tuple[int, float, bool, str]]:
        return [(position, self._p_fail.pop(position), flagged, reason) for position, flagged, reason in flags]

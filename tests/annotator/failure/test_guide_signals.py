"""The learned tracker's box as failure signals: ``guide_iou`` and ``guide_scale`` (issue #71)."""

from __future__ import annotations

import math

import numpy as np

from annotator.failure import SIGNALS, SignalMeter
from annotator.failure.model import FEATURE_GROUPS, FEATURES
from annotator.flagging import REASONS
from sptpt_dev.synthetic import make_clip


def _next(meter, frame, box, guide):
    return meter.next(frame, box, log_likelihood=1.0, scoring="subspace", accepted=True, guide_box_xywh=guide)


def test_guide_signals_measure_where_and_how_large_the_learned_tracker_sees_the_object():
    clip = make_clip(4, seed=1)
    box = clip.boxes_xywh[1]
    meter = SignalMeter()
    first = meter.first(clip.frames[0], clip.boxes_xywh[0])
    assert math.isnan(first["guide_iou"]) and math.isnan(first["guide_scale"])  # a given box: nothing to compare
    same = _next(meter, clip.frames[1], box, box)
    assert same["guide_iou"] == 1.0 and same["guide_scale"] == 0.0
    # The learned tracker sees the object twice as wide and high, around the same centre.
    x, y, w, h = box
    larger = _next(meter, clip.frames[2], box, np.array([x - w / 2, y - h / 2, 2 * w, 2 * h]))
    assert np.isclose(larger["guide_scale"], math.log(4.0)) and np.isclose(larger["guide_iou"], 0.25)
    lost = _next(meter, clip.frames[3], box, np.full(4, np.nan))
    assert lost["guide_iou"] == 0.0 and lost["guide_scale"] == 0.0


def test_without_a_learned_tracker_the_guide_signals_are_not_measured():
    clip = make_clip(2, seed=1)
    meter = SignalMeter()
    meter.first(clip.frames[0], clip.boxes_xywh[0])
    signals = _next(meter, clip.frames[1], clip.boxes_xywh[1], None)
    assert math.isnan(signals["guide_iou"]) and math.isnan(signals["guide_scale"])


def test_the_guide_signals_feed_the_model_and_name_their_flags():
    assert {"guide_iou", "guide_scale"} <= set(SIGNALS)
    assert {"guide_iou", "guide_scale", "guide_iou_w5"} <= set(FEATURES)
    assert {FEATURE_GROUPS[name] for name in ("guide_iou", "guide_scale", "guide_iou_w5")} == {"guide"}
    assert "doubt:guide" in REASONS

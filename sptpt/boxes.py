"""The overlap of two boxes (the one IoU of the tracker, the tool and its benchmarks), and the mean of several.

A box ``(x, y, w, h)`` covers ``[x, x + w) x [y, y + h)`` with continuous areas, as got10k ``rect_iou`` and
pysot ``overlap_ratio`` score it (and OTB's ``calcRectInt``, see ``annotator.evaluation.metrics``). It lives here,
in the tracker's library, because the tracker needs it too, and the tool may import the library but not the
other way round.
"""

from __future__ import annotations

import numpy as np


def iou_xywh(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of ``xywh`` boxes on the last axis, broadcast over the rest.

    Pairs of boxes row by row (both ``(N, 4)``), or many boxes against one (``(N, 4)`` and ``(4,)``).
    Areas are taken from the same corner differences as the intersection, so identical boxes give exactly 1.
    A box with a non-positive width or height is empty (IoU 0); a NaN coordinate gives NaN, which each caller
    reads its own way (a failure in evaluation, no overlap in a review).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a_x2, a_y2 = a[..., 0] + a[..., 2], a[..., 1] + a[..., 3]
    b_x2, b_y2 = b[..., 0] + b[..., 2], b[..., 1] + b[..., 3]
    inter_w = np.clip(np.minimum(a_x2, b_x2) - np.maximum(a[..., 0], b[..., 0]), 0.0, None)
    inter_h = np.clip(np.minimum(a_y2, b_y2) - np.maximum(a[..., 1], b[..., 1]), 0.0, None)
    inter = inter_w * inter_h
    area_a = np.clip(a_x2 - a[..., 0], 0.0, None) * np.clip(a_y2 - a[..., 1], 0.0, None)
    area_b = np.clip(b_x2 - b[..., 0], 0.0, None) * np.clip(b_y2 - b[..., 1], 0.0, None)
    union = area_a + area_b - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
    iou = np.clip(iou, 0.0, 1.0)  # rounding can leave 1 + 1 ulp
    return np.where(np.isnan(a).any(axis=-1) | np.isnan(b).any(axis=-1), np.nan, iou)


def mean_box(boxes_xywh) -> np.ndarray:
    """The ``xywh`` box whose centre is the mean of the boxes' centres and whose width and height are the geometric
    means of theirs: sizes combine as ratios (a box twice as large and one half as large average to the same size).

    ``boxes_xywh`` is ``(N, 4)`` with ``N >= 1`` and positive, finite widths and heights (not checked: the tracker
    averages only boxes that overlap); one box is returned as it is. Floating-point sums depend on the order, so a
    caller that needs the same bits for the same set passes the boxes in a fixed order.
    """
    boxes = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)
    if len(boxes) == 1:
        return boxes[0].copy()
    centre = (boxes[:, :2] + boxes[:, 2:] / 2).mean(axis=0)
    size = np.exp(np.log(boxes[:, 2:]).mean(axis=0))
    return np.concatenate([centre - size / 2, size])

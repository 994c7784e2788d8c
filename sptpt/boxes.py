"""Box geometry, once for the tracker and the tool: corners, clipping to the frame, overlap, the mean of several.

A box ``(x, y, w, h)`` covers ``[x, x + w) x [y, y + h)`` with continuous areas, as got10k ``rect_iou`` and
pysot ``overlap_ratio`` score it (and OTB's ``calcRectInt``, see ``annotator.evaluation.metrics``); its corners
``(x0, y0, x1, y1)`` are ``(x, y, x + w, y + h)``. A frame of ``W x H`` pixels covers ``[0, W] x [0, H]``.
Everything lives here, in the tracker's library, because the tracker needs it too, and the tool may import the
library but not the other way round.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["clip_xywh", "clip_xyxy", "iou_xywh", "lies_outside", "mean_box", "xywh_to_xyxy", "xyxy_to_xywh"]


def xywh_to_xyxy(boxes_xywh) -> np.ndarray:
    """Corners ``(x0, y0, x1, y1) = (x, y, x + w, y + h)`` of boxes on the last axis: ``(..., 4)`` float64."""
    boxes = np.asarray(boxes_xywh, dtype=np.float64)
    return np.concatenate([boxes[..., :2], boxes[..., :2] + boxes[..., 2:]], axis=-1)


def xyxy_to_xywh(boxes_xyxy) -> np.ndarray:
    """Boxes ``(x, y, w, h) = (x0, y0, x1 - x0, y1 - y0)`` from corners on the last axis: ``(..., 4)`` float64."""
    corners = np.asarray(boxes_xyxy, dtype=np.float64)
    return np.concatenate([corners[..., :2], corners[..., 2:] - corners[..., :2]], axis=-1)


def clip_xyxy(box_xyxy: Sequence[float] | np.ndarray, width: float, height: float) -> tuple[float, float, float, float]:
    """The corners of one box's intersection with the ``width x height`` frame, as Python floats.

    Empty (nothing of the box inside) when ``x1 <= x0`` or ``y1 <= y0``; a NaN corner stays NaN.
    """
    x0, y0, x1, y1 = (float(v) for v in box_xyxy)
    return max(x0, 0.0), max(y0, 0.0), min(x1, float(width)), min(y1, float(height))


def clip_xywh(box_xywh: Sequence[float] | np.ndarray, width: float, height: float, *,
              decimals: int | None = None) -> tuple[float, float, float, float] | None:
    """One ``xywh`` box clipped to the frame, as Python floats; None when not finite or nothing of it is inside.

    ``decimals`` rounds the clipped corners, then the width and height, to that many decimals (as a file
    writes them), before the emptiness test, so that a box rounded away to nothing is None too.
    """
    if not all(math.isfinite(float(v)) for v in box_xywh):
        return None
    x0, y0, x1, y1 = clip_xyxy(xywh_to_xyxy(box_xywh).tolist(), width, height)
    if decimals is not None:
        x0, y0, x1, y1 = (round(v, decimals) for v in (x0, y0, x1, y1))
    if x1 <= x0 or y1 <= y0:
        return None
    if decimals is None:
        return (x0, y0, x1 - x0, y1 - y0)
    return (x0, y0, round(x1 - x0, decimals), round(y1 - y0, decimals))


def lies_outside(box_xywh: Sequence[float] | np.ndarray, width: float, height: float) -> bool:
    """Whether no part of one ``xywh`` box (with a positive width and height) lies inside the frame."""
    x0, y0, x1, y1 = xywh_to_xyxy(box_xywh).tolist()
    return x0 >= width or y0 >= height or x1 <= 0 or y1 <= 0


def iou_xywh(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Intersection over union of ``xywh`` boxes on the last axis, broadcast over the rest.

    Pairs of boxes row by row (both ``(N, 4)``), or many boxes against one (``(N, 4)`` and ``(4,)``).
    Areas are taken from the same corner differences as the intersection, so identical boxes give exactly 1.
    A box with a non-positive width or height is empty (IoU 0); a NaN coordinate gives NaN, which each caller
    reads its own way (a failure in evaluation, no overlap in a review).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a_x2, a_y2 = np.moveaxis(xywh_to_xyxy(a)[..., 2:], -1, 0)
    b_x2, b_y2 = np.moveaxis(xywh_to_xyxy(b)[..., 2:], -1, 0)
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

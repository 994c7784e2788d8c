"""How far the colours inside a box differ from those around it: the object against its surroundings.

An object stands out from its surroundings however its own look changes; a box that has slid onto
background looks like the background around it. :func:`colour_contrast` measures that as 1 - the
Bhattacharyya coefficient of the HSV colour histograms inside the box and in a ring of the box's own area
around it. Three uses: each run of the ``robust`` preset takes, of its best candidates near the best score, the
one whose box stands out most (``TrackerParams.contrast_candidates``); between independent runs it picks the
reported run (``TrackerParams.run_choice`` ``"contrast"``; with ``"consensus"``, as ``robust`` has it, only
among boxes with as many agreeing boxes, a voter's among them, and a run no other agrees with); and the tool
reads it as a failure signal (``annotator.failure.signals``).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from sptpt.boxes import xywh_to_xyxy

__all__ = ["CONTRAST_PIXELS", "colour_contrast", "most_contrasted", "sampling_step"]

# The ring is the box scaled by sqrt(2) per side, minus the box: as many pixels around the box as in it.
_RING_SCALE = math.sqrt(2.0)
_HSV_BINS = [8, 4, 4]  # hue, saturation, value: hue carries colour, coarse S and V tolerate lighting
_HSV_RANGES = [0, 180, 0, 256, 0, 256]
# 1 - Bhattacharyya between two histograms of 128 bins is biased upwards when they hold few pixels (two samples
# of one colour distribution look different): below this many pixels in the box or the ring the signal is not
# measured. On ../shared/otb the fewest were 181 (Skiing), so the fitted failure model never saw the bias's worst.
_MIN_PIXELS = 100
# A big box is measured on every k-th pixel of every k-th row, k chosen to keep at least this many of the box's
# pixels (128 per bin): the histograms of a regular sample are those of the whole box up to a small sampling error,
# and a call costs at most what a box of 4 x this many pixels costs, however big the box (issue #69: a 500x500 box
# on a 1080p frame took 9 ms a call, and a frame makes some 16 calls). Sampling starts at 65536 pixels (256x256),
# 1.6x the largest box any call saw on OTB's frames (FaceOcc1, 41,000, seeds 0-2), so runs at OTB's sizes keep
# their boxes.
CONTRAST_PIXELS = 16384


def colour_contrast(frame_rgb: np.ndarray, box: np.ndarray) -> float:
    """How far the colours in ``box`` differ from those around it on an RGB frame, in [0, 1].

    Parameters
    ----------
    frame_rgb : numpy.ndarray
        (H, W, 3) uint8 RGB.
    box : numpy.ndarray
        ``(x, y, w, h)``, 0-based pixels.

    Returns
    -------
    float
        0: the box and its ring hold the same colours; 1: no colour in common. NaN where the box or its ring
        has fewer than 100 pixels read in the frame (too few to compare histograms) or the box is not finite.

    Notes
    -----
    A box with 4 x :data:`CONTRAST_PIXELS` pixels or more inside the frame is read on every k-th pixel of every
    k-th row from the ring's top left corner (k = :func:`sampling_step` of its part inside the frame), so that a
    call on an HD frame costs about what a call on a box of that many pixels costs.
    """
    height, width = frame_rgb.shape[:2]
    x, y, w, h = (float(v) for v in box)
    if not all(math.isfinite(v) for v in (x, y, w, h)) or w <= 0 or h <= 0:
        return math.nan
    cx, cy = x + w / 2, y + h / 2
    rx0, ry0 = max(int(round(cx - w * _RING_SCALE / 2)), 0), max(int(round(cy - h * _RING_SCALE / 2)), 0)
    rx1, ry1 = min(int(round(cx + w * _RING_SCALE / 2)), width), min(int(round(cy + h * _RING_SCALE / 2)), height)
    if rx1 - rx0 < 2 or ry1 - ry0 < 2:
        return math.nan
    # The step follows the part of the box inside the frame: a big box mostly off the frame keeps enough pixels,
    # and a huge one (w * h overflowing) is no error.
    step = sampling_step(max(min(x + w, width) - max(x, 0.0), 0.0), max(min(y + h, height) - max(y, 0.0), 0.0))
    crop = np.ascontiguousarray(frame_rgb[ry0:ry1:step, rx0:rx1:step])
    rows, cols = crop.shape[:2]
    x0, y0, x1, y1 = xywh_to_xyxy((x, y, w, h)).tolist()
    # The box's pixels from its first to its last sampled row and column (row ry0 + step * i is sampled).
    bx0, by0 = (_first_sampled(int(round(v)) - r0, step) for v, r0 in ((x0, rx0), (y0, ry0)))
    bx1, by1 = (_first_sampled(int(round(v)) - r0, step) for v, r0 in ((x1, rx0), (y1, ry0)))
    bx1, by1 = min(max(bx1, bx0), cols), min(max(by1, by0), rows)
    box_pixels = max(bx1 - bx0, 0) * max(by1 - by0, 0)
    if box_pixels < _MIN_PIXELS or rows * cols - box_pixels < _MIN_PIXELS:
        return math.nan
    hsv = cv2.cvtColor(crop, cv2.COLOR_RGB2HSV)
    # The ring's histogram is the crop's minus the box's: whole counts, exact in float32, and no masks to build
    # and scan (0.26 -> 0.17 ms a call for an 80x100 box, 2.3 -> 1.3 ms for 255x256, the same figures to the bit).
    inside = cv2.calcHist([hsv[by0:by1, bx0:bx1]], [0, 1, 2], None, _HSV_BINS, _HSV_RANGES).ravel()
    around = cv2.calcHist([hsv], [0, 1, 2], None, _HSV_BINS, _HSV_RANGES).ravel() - inside
    overlap = float(np.sqrt((inside / inside.sum()) * (around / around.sum())).sum())
    return float(np.clip(1.0 - overlap, 0.0, 1.0))


def sampling_step(width: float, height: float) -> int:
    """Every how many pixels :func:`colour_contrast` reads a ``width x height`` box and its ring, in x and in y."""
    return max(1, math.isqrt(int(width * height) // CONTRAST_PIXELS))


def _first_sampled(offset: int, step: int) -> int:
    """The index, among pixels 0, step, 2 * step, ..., of the first at or after ``offset`` (0 for a negative one)."""
    return max(-(-offset // step), 0)


def most_contrasted(frame_rgb: np.ndarray, boxes_xywh, default: int) -> int:
    """Index of the box that stands out most from its surroundings (:func:`colour_contrast`).

    ``default`` (the confident run, for the tracker) keeps it unless another box's contrast is strictly higher;
    a contrast that cannot be measured ranks below every measured one.
    """
    rank = [c if math.isfinite(c) else -math.inf for c in (colour_contrast(frame_rgb, b) for b in boxes_xywh)]
    best = default
    for i, c in enumerate(rank):
        if c > rank[best]:
            best = i
    return best

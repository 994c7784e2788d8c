"""Per-frame signals of tracking failure, measured while tracking (or re-tracking), one frame at a time.

Each signal is a number per processed frame, computed from what is known at
that frame: the tracker's own scores, the box against earlier boxes, and three
checks independent of SPTPT's model, all from OpenCV:

* **flow**: pyramidal Lucas-Kanade "median flow" (Kalal et al., ICPR 2010)
  moves the previous box to this frame from points tracked forward and back;
  ``flow_iou`` is its agreement with the tracker's box, ``flow_fb`` the
  median forward-backward error of the points (a classic failure cue),
  ``flow_kept`` the share of points that survived.
* **appearance**: normalised cross-correlation of the grey patch under the
  box with the first frame's (``ncc_first``) and the previous frame's
  (``ncc_prev``), and with the track's own past (``ncc_memory``: the median
  over the patches of the pass's first frame and of every 10th frame after
  it, up to 10 frames before this one, so that on frames 1-9 it equals
  ``ncc_first``; at most 200, thinned as the pass grows). An object whose look changes as it turns still resembles much
  of its past, and a box that has slid onto background resembles little of
  it; the first frame alone cannot tell the two apart, the previous frame
  alone cannot see a slow slide.
* **contrast**: how far the colours inside the box differ from those of a
  ring around it (``contrast``). An object stands out from its
  surroundings, wherever it goes and however its look changes; a box that
  has slid onto background looks like the background around it. This is the
  cue the appearance checks lack: they fall both when the object changes its
  look and when the box leaves it.
  The measure is :func:`sptpt.contrast.colour_contrast`: ``robust`` also uses
  it to choose, among a run's best candidates, its estimate, and which of its
  runs to report, so there the reported box is already the one of highest
  contrast nearby, and the signal says less than with ``paper`` or ``fast``.

The rest come from the tracker: its log-likelihood and scoring stage, the
gap between its best candidate and the next best ones (a flat posterior
cannot tell the target from its surroundings), the spatial spread of its best
candidates, jumps of position, scale and aspect ratio, and, when it tracks
several independent runs (``robust``), how far they agree: ``run_iou`` with
the run farthest from the box, ``run_support`` with the second nearest (does
another run back the box besides the one it came from?). Runs that put the
box in different places have likely not all kept the object; with three
runs, one lost run lowers ``run_iou`` under a right box, while a box that no
second run backs is likely wrong. (With ``filter_vote`` the box may be the mean
of one run and the correlation-filter tracker that votes with the runs; that
tracker's box is not among the runs' boxes, so ``run_support`` does not count
it: the failure model is fitted on ``robust``'s own boxes, as they are.)

Signals are the raw material; :mod:`annotator.failure.model` turns them into
features (running levels, short windows) and a failure probability. Where a
signal cannot be measured on a frame (the first frame, a box outside the
image) it takes its "nothing wrong" value, documented per name in
:data:`SIGNALS` and :data:`NEUTRAL`, or, for ``run_iou``, ``run_support`` and ``contrast``,
NaN: "not measured". ``run_iou`` and ``run_support`` are NaN for a whole track when the tracker
has one run (``paper``, ``fast``), because "nothing to compare with" is not
"the runs agree"; ``contrast`` is NaN on a box a person gave and where the
box or its ring has too few pixels in the image; a store written before a
signal existed lacks it altogether, and re-tracking reads it as NaN. The
model reads a NaN feature as its training mean, so it neither raises nor
lowers ``p_fail``.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Mapping, TypedDict

import cv2
import numpy as np

from sptpt import colour_contrast
from sptpt.boxes import iou_xywh

__all__ = ["MOTION_SIGNALS", "NEUTRAL", "SIGNALS", "STAND_IN", "MotionMeter", "SignalMeter", "grey_of",
           "particle_stats"]

#: Signal name -> what it measures (and its value where it cannot be measured).
SIGNALS: Mapping[str, str] = {
    "log_likelihood": "the tracker's score RE- - RE+ (bootstrap: intersection with the first frame's codes), "
                      "clipped to [-50, 50]",
    "bootstrap": "1 while the tracker scores by the bootstrap intersection (before its subspaces exist), else 0",
    "accepted": "1 when the frame updated the appearance model, else 0",
    "score_gap": "best candidate's score minus the mean of the best 5%: small when many candidates look alike "
                 "(0 without candidates)",
    "particle_spread": "spread of the best 5% candidates' centres, in box sizes (0 without candidates)",
    "jump": "centre displacement from the previous frame, in box sizes (0 on the first frame)",
    "scale_change": "|log| of the box area ratio to the previous frame (0 on the first frame)",
    "scale_drift": "|log| of the box area ratio to the first frame",
    "aspect_drift": "|log| of the aspect ratio (h/w) ratio to the first frame",
    "flow_iou": "IoU of the tracker's box with the previous box moved by median optical flow (1 when no flow)",
    "flow_fb": "median forward-backward error of the flow points, in box sizes (0 when no flow)",
    "flow_kept": "share of flow points whose forward-backward error was small (1 when no flow)",
    "ncc_first": "normalised cross-correlation of the box's grey patch with the first frame's, in [-1, 1]",
    "ncc_prev": "normalised cross-correlation of the box's grey patch with the previous frame's (1 on the first)",
    "ncc_memory": "median normalised cross-correlation of the box's grey patch with the pass's remembered patches: "
                  "its first frame's and every 10th frame's after it, once at least 10 frames old (at most 200; "
                  "beyond, every other is forgotten and the spacing doubles), in [-1, 1]; on a pass's first "
                  "frame 1 (0 where its box misses the image, as ncc_first); a store that predates the signal reads "
                  "ncc_first in its place",
    "run_iou": "lowest IoU of the box with the boxes of the tracker's independent runs (NaN with one run: "
               "not measured)",
    "run_support": "second highest IoU of the box with the boxes of the tracker's independent runs: how well a "
                   "second run backs it (with two runs, the same as run_iou; NaN with one run: not measured)",
    "contrast": "1 - Bhattacharyya coefficient of the HSV colour histograms inside the box and in a ring of the "
                "box's own area around it, in [0, 1] (NaN, not measured, on a box a person gave and where the box or "
                "the ring has fewer than 100 pixels in the image: too few to compare histograms)",
    "flow_drift": "how far the box's centre moved beyond the median flow of the points in the box, added up as "
                  "a vector over the pass's last 10 frames, in box sizes: a slow slide off the object that no "
                  "single frame shows (0 on a pass's first frame)",
    "flow_scale_drift": "|log| of how much the box's size changed beyond the flow's scale change of its points, "
                        "added up over the pass's last 10 frames (0 on a pass's first frame)",
    "ring_with_box": "share of the flow points on a ring just outside the box (1.3 times its size) that move as "
                     "the box moved rather than with the background (the median flow of a ring at 2.2 times), "
                     "over the pass's last 10 frames: high when the object reaches past the box (NaN, not "
                     "measured, where the box moved as the background did)",
    "box_with_background": "share of the flow points in the box that move with the background rather than as the "
                           "box moved, over the pass's last 10 frames: high when the box holds background (NaN "
                           "where the box moved as the background did)",
    "guide_iou": "IoU of the box with the learned tracker's box (the fused preset's NanoTrack; 0 where it has "
                 "none; NaN without one: not measured)",
    "guide_scale": "log of the learned tracker's box area over the box's: positive when it sees the object larger "
                   "(0 where it has no box; NaN without one: not measured)",
}

#: The signals :class:`MotionMeter` measures from the frames and the boxes alone.
MOTION_SIGNALS: tuple[str, ...] = ("flow_iou", "flow_fb", "flow_kept", "flow_drift", "flow_scale_drift",
                                   "ring_with_box", "box_with_background")

#: Each signal's value where nothing is wrong: a first frame, a box a person gave.
NEUTRAL: Mapping[str, float] = {
    "log_likelihood": 0.0, "bootstrap": 0.0, "accepted": 1.0, "score_gap": 0.0, "particle_spread": 0.0, "jump": 0.0,
    "scale_change": 0.0, "scale_drift": 0.0, "aspect_drift": 0.0, "flow_iou": 1.0, "flow_fb": 0.0, "flow_kept": 1.0,
    "ncc_first": 1.0, "ncc_prev": 1.0, "ncc_memory": 1.0,
    # Not measured: a given box has no runs to compare, and a one-run tracker none at all (module docstring).
    "run_iou": math.nan, "run_support": math.nan,
    # Not measured on a box a person gave (as re-tracking stores its anchors), nor on rows no pass scored.
    "contrast": math.nan,
    "flow_drift": 0.0, "flow_scale_drift": 0.0,
    # Not measured where nothing moves apart from the background (and on a box a person gave).
    "ring_with_box": math.nan, "box_with_background": math.nan,
    # Not measured without a learned tracker beside SPTPT, nor on a box a person gave.
    "guide_iou": math.nan, "guide_scale": math.nan,
}
#: Signals newer than some stores, each with the measured signal a stored row that lacks it reads in its place
#: (``annotator.review.merge.filled_signals``) instead of its neutral value. ``ncc_memory``'s neutral 1, a perfect
#: match with the past, is right for a box a person gave but would clear a tracked row of doubt; ``ncc_first`` is
#: the nearest measure (the two are equal on a pass's first ten frames).
STAND_IN: Mapping[str, str] = {"ncc_memory": "ncc_first"}

_PATCH = 32  # side of the grey patches compared by NCC, px
_GRID = 8  # flow points: an 8x8 grid over the box (corners are too few on small, smooth objects)


class _LKOptions(TypedDict):
    """Lucas-Kanade options for cv2.calcOpticalFlowPyrLK, typed per key so that its stubs' overloads match."""

    winSize: tuple[int, int]
    maxLevel: int
    criteria: tuple[int, int, float]


_LK: _LKOptions = dict(winSize=(15, 15), maxLevel=2,
                       criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
_TOP_SHARE = 0.05
#: ``ncc_memory``: the pass remembers the patch of every this-many-th frame, and compares a frame with remembered
#: patches at least this many frames old (the last few frames are what the box is now, not what the object was).
MEMORY_EVERY = 10
#: ``ncc_memory``: patches remembered at most; when full, every other is forgotten and the spacing doubles, so the
#: memory spans the whole pass in bounded space (200 patches of 32 x 32, and their stacked copy: 3.3 MB).
MEMORY_SIZE = 200
#: Frames of a pass over which the motion signals add up (``flow_drift``, ``flow_scale_drift``) or are averaged.
MOTION_WINDOW = 10
#: The rings of flow points around the previous box, as multiples of its size: just outside it, and the
#: background's (far enough that a box somewhat too small still leaves the object inside it).
NEAR_RING, FAR_RING = 1.3, 2.2
#: The box's move and the background's motion are told apart when they differ by this many box sizes.
SEPARABLE = 0.02
#: A flow point is reliable when its forward-backward error is under this many box sizes.
FB_LIMIT = 0.05


def grey_of(frame_rgb: np.ndarray) -> np.ndarray:
    """The grey image the signals are measured on."""
    return cv2.cvtColor(np.ascontiguousarray(frame_rgb), cv2.COLOR_RGB2GRAY)


def _patch(grey: np.ndarray, box: np.ndarray) -> np.ndarray | None:
    """The box's grey patch resized to 32x32, zero-mean and unit-norm; None if the box misses the image."""
    height, width = grey.shape
    x, y, w, h = box
    x0, y0 = max(int(math.floor(x)), 0), max(int(math.floor(y)), 0)
    x1, y1 = min(int(math.ceil(x + w)), width), min(int(math.ceil(y + h)), height)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    patch = cv2.resize(grey[y0:y1, x0:x1], (_PATCH, _PATCH), interpolation=cv2.INTER_AREA).astype(np.float64)
    patch -= patch.mean()
    norm = np.linalg.norm(patch)
    return patch / norm if norm > 1e-9 else None


def _ncc(a: np.ndarray | None, b: np.ndarray | None) -> float:
    return float(np.clip(np.sum(a * b), -1.0, 1.0)) if a is not None and b is not None else 0.0


def particle_stats(particles_xywh: np.ndarray | None, scores: np.ndarray | None,
                   box: np.ndarray) -> tuple[float, float]:
    """``(score_gap, particle_spread)`` of a frame's candidates (see :data:`SIGNALS`)."""
    if particles_xywh is None or scores is None or len(scores) < 2:
        return 0.0, 0.0
    scores = np.asarray(scores, dtype=np.float64)
    finite = np.isfinite(scores)
    if finite.sum() < 2:
        return 0.0, 0.0
    scores, particles = scores[finite], np.asarray(particles_xywh, dtype=np.float64)[finite]
    k = max(2, int(math.ceil(_TOP_SHARE * len(scores))))
    top = np.argpartition(-scores, k - 1)[:k]
    gap = float(scores.max() - scores[top].mean())
    centres = particles[top, :2] + particles[top, 2:] / 2
    size = math.sqrt(max(box[2] * box[3], 1e-9))
    spread = float(np.sqrt(centres.var(axis=0).sum()) / size)
    return float(np.clip(gap, 0.0, 50.0)), float(min(spread, 10.0))


class _PatchMemory:
    """The patches ``ncc_memory`` compares with: every :data:`MEMORY_EVERY`-th of a pass, once that many frames old.

    :meth:`add` takes every frame's patch in pass order (None where the box missed the image). The first is
    compared with from the next frame on; the patch of frame ``p`` (a multiple of the spacing) from frame
    ``p + MEMORY_EVERY`` on.
    """

    def __init__(self) -> None:
        self._frames = 0  # patches added so far: the next one's position in the pass
        self._every = MEMORY_EVERY
        self._waiting: deque[tuple[int, np.ndarray]] = deque()  # remembered, not yet old enough
        self._kept: list[tuple[int, np.ndarray]] = []
        self._matrix: np.ndarray | None = None  # the kept patches as rows, rebuilt when they change

    def add(self, patch: np.ndarray | None) -> None:
        position = self._frames
        self._frames += 1
        if patch is not None and position % self._every == 0:
            if position == 0:
                self._keep(position, patch)
            else:
                self._waiting.append((position, patch))
        # Patches become comparable once MEMORY_EVERY frames old, as of the next frame (position self._frames).
        while self._waiting and self._waiting[0][0] <= self._frames - MEMORY_EVERY:
            self._keep(*self._waiting.popleft())

    def _keep(self, position: int, patch: np.ndarray) -> None:
        # A loop, not a test: where the patches between were missing, one doubling may forget none.
        while len(self._kept) >= MEMORY_SIZE:
            self._every *= 2
            self._kept = [(p, q) for p, q in self._kept if p % self._every == 0]
            self._matrix = None
        if position % self._every == 0:
            self._kept.append((position, patch))
            self._matrix = None

    def median_ncc(self, patch: np.ndarray | None) -> float:
        """Median NCC of ``patch`` with the kept patches; 0 when either side is missing (as :func:`_ncc`)."""
        if patch is None or not self._kept:
            return 0.0
        if self._matrix is None:
            self._matrix = np.stack([q.ravel() for _, q in self._kept])
        return float(np.clip(np.median(self._matrix @ patch.ravel()), -1.0, 1.0))


class SignalMeter:
    """Measures :data:`SIGNALS` frame by frame along one pass of one track.

    Call :meth:`first` with the frame that holds the given (or corrected) box,
    then :meth:`next` with each following frame in pass order (forward or
    backward: "previous" means the previous frame of the pass).
    """

    def __init__(self) -> None:
        self._first_patch: np.ndarray | None = None
        self._first_box: np.ndarray | None = None
        self._prev_box: np.ndarray | None = None
        self._prev_patch: np.ndarray | None = None
        self._memory = _PatchMemory()
        self._motion = MotionMeter()

    def first(self, frame_rgb: np.ndarray, box_xywh) -> dict[str, float]:
        grey = grey_of(frame_rgb)
        box = np.asarray(box_xywh, dtype=np.float64)
        self._first_box, self._first_patch = box, _patch(grey, box)
        self._prev_box, self._prev_patch = box, self._first_patch
        self._memory = _PatchMemory()
        self._memory.add(self._first_patch)
        self._motion.first(grey, box)
        measured = 1.0 if self._first_patch is not None else 0.0
        return {**NEUTRAL, "ncc_first": measured, "ncc_memory": measured}

    def next(self, frame_rgb: np.ndarray, box_xywh, *, log_likelihood: float, scoring: str, accepted: bool,
             particles_xywh: np.ndarray | None = None, particle_scores: np.ndarray | None = None,
             run_boxes_xywh: np.ndarray | None = None, guide_box_xywh: np.ndarray | None = None
             ) -> dict[str, float]:
        if self._prev_box is None:
            raise RuntimeError("SignalMeter.next() before first(): start the pass with first(frame, box)")
        grey = grey_of(frame_rgb)
        box = np.asarray(box_xywh, dtype=np.float64)
        prev, first = self._prev_box, self._first_box
        assert first is not None  # set with the previous box, by first()
        size = math.sqrt(max(prev[2] * prev[3], 1e-9))
        jump = math.hypot(box[0] + box[2] / 2 - prev[0] - prev[2] / 2, box[1] + box[3] / 2 - prev[1] - prev[3] / 2)
        area = max(box[2] * box[3], 1e-9)
        motion = self._motion.next(grey, box)
        patch = _patch(grey, box)
        gap, spread = particle_stats(particles_xywh, particle_scores, box)
        ll = float(log_likelihood) if np.isfinite(log_likelihood) else -50.0
        # With one run there is nothing to compare (NaN); a run without a box overlaps nothing (0).
        runs = (None if run_boxes_xywh is None
                else np.sort(np.nan_to_num(iou_xywh(np.asarray(run_boxes_xywh), box), nan=0.0))[::-1])
        signals = {
            "log_likelihood": float(np.clip(ll, -50.0, 50.0)),
            "bootstrap": 1.0 if scoring == "bootstrap" else 0.0,
            "accepted": 1.0 if accepted else 0.0,
            "score_gap": gap,
            "particle_spread": spread,
            "jump": float(min(jump / size, 10.0)),
            "scale_change": float(min(abs(math.log(area / max(prev[2] * prev[3], 1e-9))), 5.0)),
            "scale_drift": float(min(abs(math.log(area / max(first[2] * first[3], 1e-9))), 5.0)),
            "aspect_drift": float(min(abs(math.log((box[3] / max(box[2], 1e-9))
                                                   / (first[3] / max(first[2], 1e-9)))), 5.0)),
            **motion,
            "ncc_first": _ncc(patch, self._first_patch),
            "ncc_prev": _ncc(patch, self._prev_patch),
            "ncc_memory": self._memory.median_ncc(patch),
            "run_iou": math.nan if runs is None else float(runs[-1]),
            "run_support": math.nan if runs is None else float(runs[1]),
            "contrast": colour_contrast(frame_rgb, box),
            **_guide_signals(guide_box_xywh, box),
        }
        self._prev_box, self._prev_patch = box, patch
        self._memory.add(patch)
        return signals


def _guide_signals(guide_box: np.ndarray | None, box: np.ndarray) -> dict[str, float]:
    """``guide_iou`` and ``guide_scale`` of ``box`` against the learned tracker's box (see :data:`SIGNALS`)."""
    if guide_box is None:
        return {"guide_iou": math.nan, "guide_scale": math.nan}
    guide = np.asarray(guide_box, dtype=np.float64)
    if not (np.isfinite(guide).all() and guide[2] > 0 and guide[3] > 0):
        return {"guide_iou": 0.0, "guide_scale": 0.0}
    ratio = guide[2] * guide[3] / max(box[2] * box[3], 1e-9)
    return {"guide_iou": float(np.nan_to_num(iou_xywh(guide[None], box)[0], nan=0.0)),
            "guide_scale": float(np.clip(math.log(ratio), -5.0, 5.0))}


def _grid_points(box: np.ndarray, width: int, height: int) -> np.ndarray:
    """``(64, 2)`` points: an 8x8 grid over ``box``, clipped to the image."""
    x, y, w, h = box
    xs = np.clip(x + (np.arange(_GRID) + 0.5) * w / _GRID, 0, width - 1)
    ys = np.clip(y + (np.arange(_GRID) + 0.5) * h / _GRID, 0, height - 1)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def _ring_points(box: np.ndarray, factor: float, count: int) -> np.ndarray:
    """``(count, 2)`` points spaced evenly along the border of ``box`` scaled by ``factor`` about its centre."""
    x, y, w, h = box
    cx, cy, w, h = x + w / 2, y + h / 2, w * factor, h * factor
    s = (np.arange(count) + 0.5) / count * 2 * (w + h)  # arc length along the border, from the top-left corner
    px = np.select([s < w, s < w + h, s < 2 * w + h], [s, w, 2 * w + h - s], 0.0)
    py = np.select([s < w, s < w + h, s < 2 * w + h], [0.0, s - w, h], 2 * (w + h) - s)
    return np.stack([cx - w / 2 + px, cy - h / 2 + py], axis=1)


class MotionMeter:
    """The signals of :data:`MOTION_SIGNALS`: the box against the optical flow, independent of appearance.

    Pyramidal Lucas-Kanade flow of three sets of points of the previous box, tracked forward and back in one
    call: an 8x8 grid over the box (its median flow is the object's motion: ``flow_*``), a ring just outside
    it (:data:`NEAR_RING`) and a ring well outside it (:data:`FAR_RING`, the background's motion). They need
    only the frames and the boxes, so a stored track's can be measured again from its video
    (``benchmarks/motion_signals.py``), bit for bit.
    """

    def __init__(self) -> None:
        self._prev_grey: np.ndarray | None = None
        self._prev_box: np.ndarray | None = None
        self._steps: deque[tuple[float, float, float]] = deque(maxlen=MOTION_WINDOW)
        self._extent: deque[tuple[float, float]] = deque(maxlen=MOTION_WINDOW)

    def first(self, grey: np.ndarray, box: np.ndarray) -> None:
        self._prev_grey, self._prev_box = grey, np.asarray(box, dtype=np.float64)
        self._steps.clear()
        self._extent.clear()

    def next(self, grey: np.ndarray, box: np.ndarray) -> dict[str, float]:
        prev, box = self._prev_box, np.asarray(box, dtype=np.float64)
        assert prev is not None  # first() came before (SignalMeter.next checks it)
        box_move = box[:2] + box[2:] / 2 - prev[:2] - prev[2:] / 2  # the box centre's move
        signals, motion, extent = self._flow(grey, prev, box, box_move)
        if motion is not None:
            # What the box did beyond what the flow says: its centre's move and its size's log change.
            dx, dy, scale = motion
            size, prev_size = math.sqrt(max(box[2] * box[3], 1e-9)), math.sqrt(max(prev[2] * prev[3], 1e-9))
            self._steps.append((float(box_move[0] - dx), float(box_move[1] - dy),
                                math.log(size / prev_size) - math.log(max(scale, 1e-6))))
        self._extent.append(extent)
        steps, extents = np.array(self._steps).reshape(-1, 3), np.array(self._extent).reshape(-1, 2)
        size = math.sqrt(max(box[2] * box[3], 1e-9))
        signals["flow_drift"] = float(min(math.hypot(*steps[:, :2].sum(axis=0)) / size, 10.0))
        signals["flow_scale_drift"] = float(min(abs(steps[:, 2].sum()), 5.0))
        signals["ring_with_box"] = measured_mean(extents[:, 0])
        signals["box_with_background"] = measured_mean(extents[:, 1])
        self._prev_grey, self._prev_box = grey, box
        return signals

    def _flow(self, grey: np.ndarray, prev: np.ndarray, box: np.ndarray, box_move: np.ndarray
              ) -> tuple[dict[str, float], tuple[float, float, float] | None, tuple[float, float]]:
        """``(flow signals, the object's (dx, dy, scale) or None, extent shares)`` of the points of ``prev``."""
        height, width = grey.shape
        x, y, w, h = prev
        no_extent = (math.nan, math.nan)
        if w < 2 or h < 2 or x >= width or y >= height or x + w <= 0 or y + h <= 0:
            return {"flow_iou": 1.0, "flow_fb": 0.0, "flow_kept": 1.0}, None, no_extent
        grid = _grid_points(prev, width, height)
        near, far = (_inside(_ring_points(prev, f, n), width, height) for f, n in ((NEAR_RING, 16), (FAR_RING, 24)))
        points = np.concatenate([grid, near, far]).reshape(-1, 1, 2).astype(np.float32)
        prev_grey = self._prev_grey
        assert prev_grey is not None  # set with the previous box
        # Measured on the window of both images around the points, not on whole frames: the flow's pyramids and
        # their cost follow the object (issue #69). Every figure below is a difference of points, so the window's
        # corner need not be added back.
        x0, y0, x1, y1 = flow_window(points.reshape(-1, 2), width, height)
        points -= np.array([x0, y0], dtype=np.float32)
        prev_grey, grey = prev_grey[y0:y1, x0:x1], grey[y0:y1, x0:x1]
        forward, ok_f, _ = cv2.calcOpticalFlowPyrLK(prev_grey, grey, points, None, **_LK)
        back, ok_b, _ = cv2.calcOpticalFlowPyrLK(grey, prev_grey, forward, None, **_LK)
        ok_all = (ok_f.ravel() == 1) & (ok_b.ravel() == 1)
        fb_all = np.linalg.norm((points - back).reshape(-1, 2), axis=1)
        flows = (forward - points).reshape(-1, 2).astype(np.float64)
        g, n = len(grid), len(near)
        ok, fb = ok_all[:g], fb_all[:g]
        if ok.sum() < 4:
            return {"flow_iou": 0.0, "flow_fb": 1.0, "flow_kept": float(ok.mean())}, None, no_extent
        median_fb = float(np.median(fb[ok]))
        kept = ok & (fb <= median_fb)
        p0 = points[:g].reshape(-1, 2)[kept].astype(np.float64)
        p1 = forward[:g].reshape(-1, 2)[kept].astype(np.float64)
        dx, dy = np.median(p1 - p0, axis=0)
        i, j = np.triu_indices(len(p0), 1)
        d0 = np.linalg.norm(p0[i] - p0[j], axis=1)
        d1 = np.linalg.norm(p1[i] - p1[j], axis=1)
        valid = d0 > 1e-6
        scale = float(np.median(d1[valid] / d0[valid])) if valid.any() else 1.0
        cx, cy = x + w / 2 + dx, y + h / 2 + dy
        moved = np.array([cx - w * scale / 2, cy - h * scale / 2, w * scale, h * scale])
        size = math.sqrt(max(w * h, 1e-9))
        signals = {"flow_iou": float(np.nan_to_num(iou_xywh(moved, box), nan=0.0)),
                   "flow_fb": float(min(median_fb / size, 10.0)), "flow_kept": float(kept.mean())}
        reliable = ok_all & (fb_all <= FB_LIMIT * size)
        return signals, (float(dx), float(dy), scale), _extent_shares(flows, reliable, box_move, g, n, size)


#: How far a point may move and still see, in the flow's window, the same pixels and pyramids as on the whole
#: frame, px: beyond what Lucas-Kanade resolves with these options (its 15 px window at pyramid level 2 spans 32 px).
FLOW_REACH = 64
# What a point's flow reads around it, in full-size pixels: its window, bilinear taps and derivative at level 2
# (9 px of that level, 4 px each: 36) and the two 5-tap pyrDown steps that level is made by (6): 42, rounded up.
_FLOW_MARGIN = FLOW_REACH + 48


def flow_window(points: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)``: the part of a ``width x height`` image the flow of ``(n, 2)`` ``points`` looks at.

    It holds every pixel the flow of a point that moves up to :data:`FLOW_REACH` px reads, on every pyramid level,
    and its corner lies on a multiple of 4, so that the pyramid's levels 1 and 2 sample the same pixels: more image
    changes no point. Against the whole image, the points' coordinates are smaller by the corner and round
    otherwise, which can change where Lucas-Kanade stops: by hundredths of a pixel where it converges, by more on
    points it does not converge on (whose forward-backward error already marks them unreliable).
    """
    finite = points[np.isfinite(points).all(axis=1)]
    if not len(finite):  # a box without coordinates: Lucas-Kanade loses its points, on any image
        return 0, 0, width, height
    low = np.floor(finite.min(axis=0)) - _FLOW_MARGIN
    high = np.ceil(finite.max(axis=0)) + _FLOW_MARGIN + 1
    x0, y0 = (max(int(v) // 4 * 4, 0) for v in low)
    return x0, y0, min(int(high[0]), width), min(int(high[1]), height)


def _inside(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """The points inside the image."""
    keep = (points[:, 0] >= 0) & (points[:, 0] <= width - 1) & (points[:, 1] >= 0) & (points[:, 1] <= height - 1)
    return points[keep]


def _extent_shares(flows: np.ndarray, reliable: np.ndarray, box_move: np.ndarray, grid: int, near: int,
                   size: float) -> tuple[float, float]:
    """``(ring_with_box, box_with_background)`` of one frame; NaN where the box's move and the background's
    cannot be told apart (they differ by less than :data:`SEPARABLE` box sizes) or too few points were tracked.

    Each reliably tracked point is classed by whether its flow is nearer the box's move (the tracker's, not
    the points' median: a box twice too large holds mostly background) or the far ring's median flow: the
    share of the near ring that moves with the box (the object reaches past the box), and the share of the
    box that moves with the background (the box holds background, or is not on the object).
    """
    inner, ring, far = flows[:grid], flows[grid:grid + near], flows[grid + near:]
    ok_inner, ok_ring, ok_far = reliable[:grid], reliable[grid:grid + near], reliable[grid + near:]
    if ok_inner.sum() < 8 or ok_ring.sum() < 4 or ok_far.sum() < 4:
        return math.nan, math.nan
    background = np.median(far[ok_far], axis=0)
    if np.linalg.norm(box_move - background) < SEPARABLE * size:
        return math.nan, math.nan

    def with_box(f: np.ndarray) -> np.ndarray:
        return np.linalg.norm(f - box_move, axis=1) < np.linalg.norm(f - background, axis=1)

    return float(with_box(ring[ok_ring]).mean()), float(1.0 - with_box(inner[ok_inner]).mean())


def measured_mean(values: np.ndarray) -> float:
    """Mean of the measured (not NaN) ``values``, NaN when none is: without numpy's warning on an empty slice."""
    measured = values[~np.isnan(values)]
    return float(measured.mean()) if len(measured) else math.nan

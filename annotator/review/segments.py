"""Anchors and segments: what a set of corrections asks to re-track.

A track's anchors are its keyframe rows (the first-frame box and every human
correction, or ``None`` for an absence); the frames between two consecutive
anchors form a segment, re-tracked when either end is new or changed. See
:mod:`annotator.review.retrack` for the whole procedure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping, cast

import numpy as np

from annotator.tracks import TrackResult
from sptpt.boxes import clip_xyxy, iou_xywh, xywh_to_xyxy

__all__ = ["AnchorChange", "Box", "PreviousTrack", "Segment", "SegmentChange", "box_of", "plan_segments", "same_box"]

Box = tuple[float, float, float, float]


def box_of(values: Iterable[float]) -> Box:
    """A box's four numbers (a row of an ``(N, 4)`` array, a given tuple) as a tuple of Python floats."""
    return cast(Box, tuple(float(v) for v in values))  # four: the length of what was given, a box


@dataclass(frozen=True)
class PreviousTrack:
    """A track as it stands before re-tracking.

    Attributes
    ----------
    track : TrackResult
        Its rows; ``keyframe`` rows are its anchors (an ``outside`` keyframe is
        an absence anchor).
    scoring : (F,) str ndarray
        Scoring stage of each row (``init``, ``bootstrap``, ``subspace`` or
        ``none``), needed to recompute flags; see :func:`scoring_from_accepted`.
    """

    track: TrackResult
    scoring: np.ndarray

    def __post_init__(self) -> None:
        scoring = np.asarray(self.scoring, dtype=object)
        if scoring.shape != (len(self.track),):
            raise ValueError(f"scoring must have shape ({len(self.track)},) like the track, got {scoring.shape}")
        object.__setattr__(self, "scoring", scoring)

    def anchors(self) -> dict[int, Box | None]:
        """``{position: box or None}`` of the keyframe rows."""
        track = self.track
        return {int(p): (None if track.outside[p] else box_of(track.boxes_xywh[p]))
                for p in np.flatnonzero(track.keyframe)}

@dataclass(frozen=True)
class Segment:
    """Frames strictly between anchor ``start`` and ``stop`` (``stop`` = F when no anchor follows).

    ``forward``: track forward from ``start``; ``backward``: also backward from
    ``stop``; neither: every frame is outside. ``set_start``: the anchor row
    ``start`` itself is new and must be written.
    """

    track_id: int
    start: int
    stop: int
    forward: bool
    backward: bool
    set_start: bool

    @property
    def interior(self) -> range:
        return range(self.start + 1, self.stop)

@dataclass(frozen=True)
class SegmentChange:
    """What re-tracking one segment changed, for the report and run.json.

    Attributes
    ----------
    track_id : int
        The segment's track.
    first_frame, last_frame : int
        Source indices of the first re-tracked row (the anchor when it is new) and the last.
    frames : int
        Rows rewritten.
    mean_iou : float
        IoU of the new boxes with the previous ones (NaN rows count as 0); NaN without previous boxes.
    moved : int
        Rows whose new box has IoU < 0.5 with the previous one.
    flagged_before, flagged_after : int
        Flagged rows of the segment before and after.
    """

    track_id: int
    first_frame: int
    last_frame: int
    frames: int
    mean_iou: float
    moved: int
    flagged_before: int
    flagged_after: int

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}

@dataclass(frozen=True)
class AnchorChange:
    """A new or changed anchor.

    Attributes
    ----------
    track_id : int
        The track it anchors.
    position, frame : int
        Its row in the track and its source index.
    box_before : tuple of float or None
        The row's box before (the tracker's or a previous anchor's); None if the object was outside.
    box_after : tuple of float or None
        The person's box; None: the object is absent.
    was_anchor : bool
        The row was an anchor already.
    where : str
        Where the correction came from (``FILE:LINE``).
    """

    track_id: int
    position: int
    frame: int
    box_before: Box | None
    box_after: Box | None
    was_anchor: bool
    where: str

    def to_dict(self) -> dict:
        return {
            "track_id": self.track_id, "frame": self.frame,
            "box_before": None if self.box_before is None else [round(v, 3) for v in self.box_before],
            "box_after": None if self.box_after is None else [round(v, 3) for v in self.box_after],
            "was_anchor": self.was_anchor, "source": self.where,
            "iou": _iou_or_none(self.box_before, self.box_after),
        }

def same_box(a: Box | None, b: Box | None, *, width: float, height: float, tol: float = 2e-3) -> bool:
    """Whether two anchors say the same thing: both absent, or boxes equal after clipping to the frame.

    Clipping and the 1/1000-pixel tolerance make a box read back from the run's
    COCO file (clipped, rounded) the same anchor as the box it was written from.
    """
    if a is None or b is None:
        return a is None and b is None
    # The corners of the part inside the frame, compared as they are (no test for an empty part): two boxes wholly
    # outside are the same only where their corners are.
    clipped_a, clipped_b = (np.array(clip_xyxy(xywh_to_xyxy(box), width, height)) for box in (a, b))
    return bool(np.all(np.abs(clipped_a - clipped_b) <= tol))

def _iou_or_none(a: Box | None, b: Box | None) -> float | None:
    if a is None or b is None or not np.all(np.isfinite(a)) or not np.all(np.isfinite(b)):
        return None
    return round(float(iou_xywh(a, b)), 4)

def plan_segments(track_id: int, anchors: Mapping[int, Box | None], changed: set[int], n_frames: int) -> list[Segment]:
    """The segments of one track to re-track, given its anchors and which of them are new or changed.

    Parameters
    ----------
    anchors : mapping position -> box or None
        All anchors after applying the corrections; must include position 0.
    changed : set of int
        Positions of new or changed anchors (all of them for a first run).
    n_frames : int
        Rows of the track.
    """
    if 0 not in anchors:
        raise ValueError("anchors must include position 0 (the first-frame box)")
    positions = sorted(anchors)
    segments = []
    for k, start in enumerate(positions):
        stop = positions[k + 1] if k + 1 < len(positions) else n_frames
        stop_changed = stop in changed if stop < n_frames else False
        if start not in changed and not stop_changed:
            continue
        present = anchors[start] is not None
        backward = present and stop < n_frames and anchors[stop] is not None
        segments.append(Segment(track_id, start, stop, forward=present, backward=backward,
                                set_start=start in changed))
    return segments

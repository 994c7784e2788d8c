"""What the review-tool exporters (CVAT, Label Studio, MOT, YOLO) share.

* The **processed range**: a Python ``range(start, stop, step)`` of source
  frame indices (``stop`` exclusive, as ``run.json`` records it). Every
  track row must be one of its frames.
* The **review score** shown beside each box: the failure probability
  ``p_fail`` (``1 - confidence``, which is 1 where the object is absent), so a
  reviewer can sort or filter boxes by how likely they are wrong.
* The **review keyframes**: the frames a reviewer should look at, which the
  interpolating tools (CVAT, Label Studio) mark as keyframes.
* **Labels** in order of first appearance over the tracks, the same order
  the COCO exporter numbers its categories in.
* **Fewest keyframes** (:func:`fewest_keyframes`): the interpolating tools
  show only keyframes and draw straight lines between them, so the rows an
  exporter marks as keyframes decide which boxes a reviewer sees.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from annotator.tracks import TrackResult, VideoInfo

#: Name of the per-box score attribute (CVAT ``<attribute name=...>``); "p_fail" once it exists.
REVIEW_SCORE_NAME = "p_fail"
#: Most rows between two keyframes :func:`fewest_keyframes` chooses: bounds its work on a still object.
MAX_KEYFRAME_GAP = 512
#: Decimals the score is written with: finer steps mean nothing to a reviewer sorting boxes.
REVIEW_SCORE_DECIMALS = 3


def review_scores(track: TrackResult) -> np.ndarray:
    """(F,) float64 in [0, 1]: the score written as :data:`REVIEW_SCORE_NAME` for each row of ``track``."""
    return np.round(1.0 - track.confidence, REVIEW_SCORE_DECIMALS)


def check_frame_range(video: VideoInfo, tracks: Sequence[TrackResult], frames: range | None) -> range:
    """The processed range (the whole video when None), checked against the video and the tracks.

    Raises
    ------
    ValueError
        A range outside the video, with no frame, or a track row that is not one of its frames.
    """
    if frames is None:
        frames = range(0, video.frame_count, 1)
    if not isinstance(frames, range):
        raise ValueError(f"frames must be a range(start, stop, step) of source frame indices, got {frames!r}")
    if frames.step < 1 or frames.start < 0 or len(frames) == 0 or frames[-1] >= video.frame_count:
        raise ValueError(
            f"frames={frames!r} must select at least one frame of the {video.frame_count}-frame video "
            f"{video.name!r} with step >= 1 (stop is exclusive, as run.json records it)"
        )
    frames = range(frames.start, frames[-1] + 1, frames.step)  # normalised: stop right after the last frame
    ids = [t.track_id for t in tracks]
    if len(set(ids)) != len(ids):
        raise ValueError(f"track ids must be unique within a video, got {ids}")
    for track in tracks:
        bad = [int(f) for f in track.frame_indices if int(f) not in frames]
        if bad:
            raise ValueError(
                f"track {track.track_id} has frame {bad[0]}, which is not in the processed range "
                f"range({frames.start}, {frames.stop}, {frames.step}); pass the run's start, stop and step"
            )
    return frames


def positions(frames: range, track: TrackResult) -> np.ndarray:
    """(F,) int64: each row's 0-based position in the processed range."""
    return (track.frame_indices - frames.start) // frames.step


def visible(track: TrackResult) -> np.ndarray:
    """(F,) bool: rows with a box to show (not outside, not NaN)."""
    return ~track.outside & np.isfinite(track.boxes_xywh).all(axis=1)


def review_keyframes(track: TrackResult) -> np.ndarray:
    """(F,) bool: the first row, human corrections and the first row of each flagged span."""
    n = len(track)
    keys = track.keyframe.copy()
    if n:
        keys[0] = True
        span_start = track.flagged & ~np.concatenate([[False], track.flagged[:-1]])
        keys |= span_start
    return keys


def fewest_keyframes(t: np.ndarray, written: np.ndarray, exact: np.ndarray, required: np.ndarray,
                     max_error: float) -> np.ndarray:
    """The fewest rows to keep so that linear interpolation between kept rows reproduces every row.

    A tool that interpolates (CVAT, Label Studio) shows, at a row between two
    kept rows ``i < j``, ``written[i] + (written[j] - written[i]) * (t[k] - t[i])
    / (t[j] - t[i])``. The rows returned keep that within ``max_error`` of
    ``exact[k]`` in every column, keep every ``required`` row, and are as few
    as that allows (a shortest path over the rows; ties go to the farther row).

    For a kept row ``i`` the rows ``j`` it may be joined to are those whose
    slope ``(written[j] - written[i]) / (t[j] - t[i])`` lies, in every column,
    inside the cone the rows between them allow; the cone only narrows as
    ``j`` moves on, so the search from ``i`` ends where it closes, or at the
    next required row, which no segment may skip, or :data:`MAX_KEYFRAME_GAP`
    rows on, so that the work follows the object's motion, not the track's
    length (a still object gets a keyframe every that many rows).

    Parameters
    ----------
    t : (n,) float array
        Strictly increasing positions (the tool's frame numbers).
    written : (n, d) float array
        The values as the tool reads them (rounded as written).
    exact : (n, d) float array
        The values to reproduce.
    required : (n,) bool array
        Rows that must be kept; the first and last rows are kept always.
    max_error : float
        Largest difference allowed in any column of any row, in its units.

    Returns
    -------
    (n,) bool array
        The rows to keep.
    """
    n = len(t)
    keep = np.zeros(n, dtype=bool)
    if n == 0:
        return keep
    required = np.asarray(required, dtype=bool).copy()
    required[[0, -1]] = True
    t = np.asarray(t, dtype=np.float64)
    written = np.asarray(written, dtype=np.float64)
    exact = np.asarray(exact, dtype=np.float64)
    next_required = np.empty(n, dtype=np.int64)  # the first required row after each row (n - 1 for the last)
    following = n - 1
    for i in range(n - 1, -1, -1):
        next_required[i] = following
        if required[i]:
            following = i
    cost = np.zeros(n, dtype=np.int64)  # keyframes after row i on the best path from it to the last row
    step = np.zeros(n, dtype=np.int64)
    for i in range(n - 2, -1, -1):
        candidates = _joinable(t, written, exact, i, int(next_required[i]), max_error)
        costs = cost[candidates]
        best = candidates[costs == costs.min()][-1]
        cost[i] = cost[best] + 1
        step[i] = best
    i = 0
    while True:
        keep[i] = True
        if i == n - 1:
            return keep
        i = int(step[i])


def _joinable(t: np.ndarray, written: np.ndarray, exact: np.ndarray, i: int, end: int,
              max_error: float) -> np.ndarray:
    """The rows ``i+1 .. end`` that a straight line from row ``i`` reaches within ``max_error`` of every row between.

    The window grows by doubling until the cone closes, reaches ``end`` or
    :data:`MAX_KEYFRAME_GAP` rows.
    """
    end = min(end, i + MAX_KEYFRAME_GAP)
    window = 32
    while True:
        stop = min(end, i + window)
        span = t[i + 1:stop + 1] - t[i]
        offset = exact[i + 1:stop + 1] - written[i]
        low = np.maximum.accumulate((offset - max_error) / span[:, None], axis=0)
        high = np.minimum.accumulate((offset + max_error) / span[:, None], axis=0)
        slope = (written[i + 1:stop + 1] - written[i]) / span[:, None]
        # Row i+1+m is reached when its slope lies in the cone of the rows before it (i+1 .. i+m).
        fits = np.ones(len(span), dtype=bool)
        fits[1:] = ((low[:-1] <= slope[1:]) & (slope[1:] <= high[:-1])).all(axis=1)
        closed = np.flatnonzero(~(low <= high).all(axis=1))
        if len(closed):
            fits[closed[0] + 1:] = False  # the cone only narrows: no row after it closed is reached
            return np.flatnonzero(fits) + i + 1
        if stop == end:
            return np.flatnonzero(fits) + i + 1
        window *= 2


def labels_in_order(tracks: Sequence[TrackResult]) -> list[str]:
    """Track labels in order of first appearance (the COCO exporter's category order)."""
    names: list[str] = []
    for track in tracks:
        if track.label not in names:
            names.append(track.label)
    return names



def number(value: float, decimals: int = 3) -> str:
    """Shortest decimal text of ``value`` rounded to ``decimals`` (no ``-0``, no trailing zeros)."""
    text = f"{round(float(value), decimals) + 0.0:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text

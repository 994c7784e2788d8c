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
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from annotator.tracks import TrackResult, VideoInfo

#: Name of the per-box score attribute (CVAT ``<attribute name=...>``); "p_fail" once it exists.
REVIEW_SCORE_NAME = "p_fail"
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

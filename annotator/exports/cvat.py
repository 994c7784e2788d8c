"""CVAT for video 1.1 (``cvat.xml``): the tracks as CVAT interpolation tracks, for review in CVAT.

The layout is the one CVAT itself dumps as "CVAT for video 1.1" (its
``dump_as_cvat_interpolation``), so that "Upload annotations" in CVAT and
datumaro's ``cvat`` importer load the file unchanged:

* ``<meta><task>`` holds ``size`` (processed frames), ``mode`` =
  ``interpolation``, ``start_frame``, ``stop_frame`` (the last processed
  frame, inclusive as in CVAT), ``frame_filter`` (``step=N``, empty for
  step 1), the labels with the review-score attribute, ``original_size``
  (the frame size) and ``source`` (the video's file name).
* **Frame numbers are source frame indices**, not positions in the
  processed range: CVAT writes ``abs_frame_id`` in its dumps and converts
  with ``(frame - start_frame) // step`` on upload. So the file lines up with
  a CVAT task created from the same video with the run's start, stop and
  step (or the whole video when those are the defaults); ``start_frame``
  and ``frame_filter`` map a frame back, and the importer checks them.
* One ``<track id label source="auto">`` per track, ids 0.. in the order
  given (CVAT renumbers tracks from 0 on every dump), and one ``<box>`` per
  processed frame of the track with 0-based corners ``xtl ytl xbr ybr``
  (2 decimals, as CVAT dumps), ``occluded`` and ``z_order`` 0.
* ``keyframe="1"`` where CVAT needs it to show the tracker's boxes: CVAT's
  importer keeps only keyframes and interpolates linearly between them, so
  the keyframes are the frames a reviewer should check (the first frame,
  human corrections, the bounds of each flagged span, where the object
  leaves or comes back) and, between those, the fewest frames that keep
  CVAT's interpolation within :data:`MAX_ERROR_PX` of every tracked box
  (see :func:`_keyframes`). The other boxes are written too, with
  ``keyframe="0"``, for readers that keep every box (Datumaro).
* A frame whose object is absent (``outside``) or has no estimate (NaN) is a
  box with ``outside="1"`` at the last known coordinates, as CVAT needs a
  box element to know when an object leaves. A track that ends before the
  processed range does gets one more ``outside="1"`` box at the next
  processed frame, or CVAT would show its last box until the end.
* Every box carries ``<attribute name="confidence">`` (see
  :mod:`annotator.exports.review_tools` for the name and when it changes).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from annotator.atomic import write_text_atomic
from annotator.exports.review_tools import (
    REVIEW_SCORE_DECIMALS,
    REVIEW_SCORE_NAME,
    check_frame_range,
    fewest_keyframes,
    labels_in_order,
    number,
    positions,
    review_keyframes,
    review_scores,
    visible,
)
from annotator.tracks import TrackResult, VideoInfo
from sptpt.boxes import xywh_to_xyxy

__all__ = ["CVAT_VERSION", "MAX_ERROR_PX", "build_cvat_xml", "cvat_keyframes", "write_cvat_xml"]

CVAT_VERSION = "1.1"
_COORD_DECIMALS = 2  # CVAT dumps "{:.2f}"; more would not survive a round trip through CVAT anyway
#: Largest gap, in pixels, between any corner CVAT shows after importing the file and the tracker's box.
MAX_ERROR_PX = 0.5


def _score_attribute_spec() -> list[str]:
    """The ``<attribute>`` declaration of the review score inside a label (CVAT number: min, max, step)."""
    step = number(10.0 ** -REVIEW_SCORE_DECIMALS, REVIEW_SCORE_DECIMALS)
    return [
        "<attribute>",
        f"  <name>{escape(REVIEW_SCORE_NAME)}</name>",
        "  <mutable>True</mutable>",
        "  <input_type>number</input_type>",
        "  <default_value>0</default_value>",
        f"  <values>0\n1\n{step}</values>",
        "</attribute>",
    ]


def _meta(video: VideoInfo, frames: range, labels: list[str]) -> list[str]:
    lines = [
        "<meta>",
        "  <task>",
        "    <id>0</id>",
        f"    <name>{escape(video.name)}</name>",
        f"    <size>{len(frames)}</size>",
        "    <mode>interpolation</mode>",
        "    <overlap>0</overlap>",
        "    <bugtracker></bugtracker>",
        "    <flipped>False</flipped>",
        f"    <start_frame>{frames.start}</start_frame>",
        f"    <stop_frame>{frames[-1]}</stop_frame>",
        f"    <frame_filter>{'' if frames.step == 1 else f'step={frames.step}'}</frame_filter>",
        "    <labels>",
    ]
    for label in labels:
        lines += ["      <label>", f"        <name>{escape(label)}</name>", "        <type>rectangle</type>",
                  "        <attributes>"]
        lines += ["          " + line for line in _score_attribute_spec()]  # the values' newlines stay unindented
        lines += ["        </attributes>", "      </label>"]
    lines += [
        "    </labels>",
        "    <segments>",
        "      <segment>",
        "        <id>0</id>",
        "        <start>0</start>",
        f"        <stop>{len(frames) - 1}</stop>",
        "        <url></url>",
        "      </segment>",
        "    </segments>",
        "    <original_size>",
        f"      <width>{video.width}</width>",
        f"      <height>{video.height}</height>",
        "    </original_size>",
        "  </task>",
        f"  <source>{escape(Path(video.path).name)}</source>",
        "</meta>",
    ]
    return lines


def _box_element(frame: int, box_xywh: np.ndarray, *, outside: bool, occluded: bool, keyframe: bool,
                 score: float | None) -> list[str]:
    x0, y0, x1, y1 = xywh_to_xyxy(box_xywh).tolist()
    attrs = (
        f'frame="{frame}" xtl="{x0:.{_COORD_DECIMALS}f}" ytl="{y0:.{_COORD_DECIMALS}f}" '
        f'xbr="{x1:.{_COORD_DECIMALS}f}" ybr="{y1:.{_COORD_DECIMALS}f}" outside="{int(outside)}" '
        f'occluded="{int(occluded)}" keyframe="{int(keyframe)}" z_order="0"'
    )
    if score is None:
        return [f"<box {attrs}>", "</box>"]
    return [f"<box {attrs}>",
            f'  <attribute name={quoteattr(REVIEW_SCORE_NAME)}>{number(score, REVIEW_SCORE_DECIMALS)}</attribute>',
            "</box>"]


def _track_rows(track: TrackResult, frames: range) -> list[tuple[int, np.ndarray, bool, bool, bool, float]]:
    """Each ``<box>`` of a track: ``(frame, box_xywh, outside, occluded, keyframe, score)``; [] for a track never
    seen."""
    shown = visible(track)
    if not shown.any():
        return []  # no box anywhere: CVAT has nothing to draw, and a track needs coordinates
    # Absent rows reuse the last known box (the next one before the first): CVAT wants coordinates on every box.
    known = np.flatnonzero(shown)
    source_row = np.maximum.accumulate(np.where(shown, np.arange(len(track)), -1))
    source_row[source_row < 0] = known[0]
    keys = _keyframes(track, frames, shown)
    scores = review_scores(track)
    rows = [(int(frame), track.boxes_xywh[source_row[i]], not bool(shown[i]), bool(track.occluded[i] and shown[i]),
             bool(keys[i]), float(scores[i])) for i, frame in enumerate(track.frame_indices)]
    last = int(track.frame_indices[-1])
    if shown[-1] and last != frames[-1]:
        # Without this CVAT would keep showing the last box to the end of the task.
        rows.append((last + frames.step, track.boxes_xywh[source_row[-1]], True, False, True, float(scores[-1])))
    return rows


def _keyframes(track: TrackResult, frames: range, shown: np.ndarray) -> np.ndarray:
    """(F,) bool: the rows written with ``keyframe="1"``, so that CVAT's import shows every box of the track.

    CVAT keeps only keyframes and draws each row between two of them by
    linear interpolation of the corners in frame number; a row after an
    ``outside`` keyframe is outside until the next keyframe, and the last
    keyframe holds to the end. So the keyframes are: the rows a reviewer
    should check (:func:`review_keyframes`) and the last row of each flagged
    span; where the object leaves or comes back; the last row it is seen
    before it leaves (older CVAT holds, newer CVAT interpolates, the box
    before an ``outside`` keyframe); and between those, the fewest rows that
    keep CVAT's interpolation of the corners as written within
    :data:`MAX_ERROR_PX` of the tracker's box (:func:`fewest_keyframes`).
    """
    before = np.concatenate([[False], shown[:-1]])
    after = np.concatenate([shown[1:], [False]])
    flagged_after = np.concatenate([track.flagged[1:], [False]])
    required = review_keyframes(track) | (track.flagged & ~flagged_after) | (shown != before) | (shown & ~after)
    required[0] = True
    keys = required & ~shown  # absent rows: only where the object leaves (or a reviewer should look)
    corners = xywh_to_xyxy(track.boxes_xywh)
    position = positions(frames, track).astype(np.float64)
    run_starts = np.flatnonzero(shown & ~before)
    run_ends = np.flatnonzero(shown & ~after)
    for a, b in zip(run_starts, run_ends):
        exact = corners[a:b + 1]
        written = np.array([float(f"{v:.{_COORD_DECIMALS}f}") for v in exact.ravel()]).reshape(exact.shape)
        keys[a:b + 1] = fewest_keyframes(position[a:b + 1], written, exact, required[a:b + 1], MAX_ERROR_PX)
    return keys

def _corners(box_xywh: np.ndarray) -> list[float]:
    """``xtl, ytl, xbr, ybr`` as written (rounded to the file's decimals)."""
    return [round(v, _COORD_DECIMALS) for v in xywh_to_xyxy(box_xywh).tolist()]


def _track_elements(number_: int, track: TrackResult, frames: range) -> list[str]:
    rows = _track_rows(track, frames)
    if not rows:
        return []
    lines = [f"<track id=\"{number_}\" label={quoteattr(track.label)} source=\"auto\">"]
    for frame, box, outside, occluded, keyframe, score in rows:
        lines += ["  " + s for s in _box_element(frame, box, outside=outside, occluded=occluded, keyframe=keyframe,
                                                 score=score)]
    lines.append("</track>")
    return lines


def cvat_keyframes(video: VideoInfo, tracks: Sequence[TrackResult], *, frames: range | None = None
                   ) -> list[dict[str, object]]:
    """The keyframes :func:`build_cvat_xml` writes, as a record of what a reviewer is given.

    A reviewer's CVAT file holds these keyframes too; only those a person
    changed are corrections (:func:`annotator.review.imports.read_cvat_corrections`).
    The record is kept in ``run.json`` (``review_exports``), since the run's
    tracks, and so its ``cvat.xml``, change with every re-track.

    Returns
    -------
    list of dict
        One ``{"track_id": int, "keyframes": [[frame, xtl, ytl, xbr, ybr] or [frame] (outside), ...]}`` per
        track written, in the file's order; coordinates as written (2 decimals).
    """
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    record = []
    for track in tracks:
        rows = _track_rows(track, frames)
        if rows:
            record.append({"track_id": int(track.track_id),
                           "keyframes": [[frame] if outside else [frame, *_corners(box)]
                                         for frame, box, outside, _, keyframe, _ in rows if keyframe]})
    return record


def build_cvat_xml(video: VideoInfo, tracks: Sequence[TrackResult], *, frames: range | None = None) -> str:
    """The CVAT for video 1.1 XML of one video's tracks (layout in the module docstring).

    Parameters
    ----------
    video : VideoInfo
        Name, path (for ``<source>``) and frame size.
    tracks : sequence of TrackResult
        The run's tracks; ids are written 0.. in this order. A track never
        seen (every row absent or NaN) is left out: CVAT cannot hold a track
        without a box, and the importer skips it the same way.
    frames : range or None
        The processed range ``range(start, stop, step)`` of source frame
        indices (``run.json``'s ``range``); None for the whole video.

    Returns
    -------
    str
        The XML document, ending with a newline.
    """
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    labels = labels_in_order(tracks) or ["object"]
    lines = ['<?xml version="1.0" encoding="utf-8"?>', "<annotations>", f"  <version>{CVAT_VERSION}</version>"]
    lines += ["  " + s for s in _meta(video, frames, labels)]
    for n, track in enumerate(tracks):
        lines += ["  " + s for s in _track_elements(n, track, frames)]
    lines.append("</annotations>")
    return "\n".join(lines) + "\n"


def write_cvat_xml(path: str | os.PathLike, video: VideoInfo, tracks: Sequence[TrackResult], *,
                   frames: range | None = None) -> Path:
    """Write :func:`build_cvat_xml` to ``path`` (e.g. ``<out>/cvat.xml``) atomically; return the path."""
    text = build_cvat_xml(video, tracks, frames=frames)
    write_text_atomic(path, text)
    return Path(path)

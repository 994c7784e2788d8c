"""Reviewers' fixes brought back from CVAT and Label Studio, as :class:`~annotator.corrections.Correction` records.

Both readers return what :func:`annotator.corrections.read_corrections`
returns for a CSV or COCO file (source frame indices, 0-based ``xywh``,
``None`` for an absence, ``where`` = ``FILE:LINE``), so the caller can
dispatch on the file type and hand any of them to
:func:`~annotator.corrections.resolve_corrections`. Problems raise the same
:class:`~annotator.errors.ToolError` (exit code 4, 3 when the file cannot
be read) with a one-line message naming the file.

A reviewer's file holds the run's own keyframes too (first frame, flagged
spans, ...), so only what a person **changed relative to what the tool gave
them** is a correction: a keyframe more than :data:`SAME_BOX_PX` (1 px, the
rounding the tools apply: FiftyOne writes whole pixels) from the
given keyframe at that frame, or hidden or shown where it was not. What was
given is, for Label Studio, the prediction the annotation started from (its
``parent_prediction``, which the export carries); for CVAT, the keyframes of
the ``cvat.xml`` the run wrote (every version is kept in run.json's
``review_exports``; the file is compared with the version it matches best).
So the same file brought back twice adds nothing the second time, although
the run's tracks, and its own keyframes, changed in between. A keyframe at a
frame where the tool gave none (a reviewer added it), or a file with no such
record (a run written before it, an annotation made from scratch), is
compared with the run's current box: a box more than :data:`SAME_BOX_PX`
from it, a box where the run had the object absent, or an absence where the
run had a box.

**CVAT for video 1.1** (the run's ``cvat.xml`` after review, dumped by
CVAT, or exported by FiftyOne as CVATVideoDataset; Datumaro has no such
exporter): boxes with
``keyframe="1"``; ``outside="1"`` marks the object absent from that frame
on. An ``outside`` keyframe just past the processed range (FiftyOne ends
every track so) is skipped with a warning. "CVAT for images" (one
``<image>`` per frame, Datumaro's ``cvat`` format) is refused with a line
that says to export "CVAT for video 1.1". Frames are source indices (CVAT dumps absolute frame
numbers); the file's ``start_frame`` and ``frame_filter`` must match the
run's range, its ``size`` the run's processed frame count and its
``original_size`` the frame size, or it is another task's file. Tracks are
matched to the run's in order (CVAT renumbers them 0.. on every dump) and
must keep their labels.

**Label Studio** (a JSON export of the project holding the run's
``labelstudio.json`` task): the ``videorectangle`` regions of the task's
latest annotation (its predictions when it has none). ``frame`` n is
source frame n - 1; an ``enabled: false`` keyframe shows the box on its
own frame and hides it after, so it is the box at that frame plus an
absence from the next processed frame. Regions are matched to tracks by the
id the exporter gave them (``track-<id>``), else in order.
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Mapping, Sequence, cast
from xml.parsers import expat

import numpy as np

from annotator.corrections import Correction
from annotator.errors import EXIT_VALUE, InputWarning, ToolError
from annotator.exports.labelstudio import labelstudio_region_id
from annotator.exports.review_tools import check_frame_range, visible
from annotator.text_input import read_given_file, read_text
from annotator.tracks import TrackResult, VideoInfo
from annotator.wording import plural
from sptpt.boxes import clip_xywh, xywh_to_xyxy, xyxy_to_xywh

__all__ = ["SAME_BOX_PX", "read_cvat_corrections", "read_labelstudio_corrections"]

#: Largest coordinate change, in pixels, still taken for the run's own box: the tools round what they were given
#: (CVAT to 1/100 px, FiftyOne to whole pixels on each corner, so a width moves by up to 1 px; Label Studio stores
#: percent), and a reviewer who moves a box means more than a pixel.
SAME_BOX_PX = 1.0
#: Room for the float error of a difference of rounded corners (a width of 47 where 47.99 was given).
_SLACK = 1e-6

Box = tuple[float, float, float, float]


def _read_text(path: Path, what: str) -> str:
    return read_given_file(path, what=f"{what} file", expected=f"the file {what} exported")


class _RunTrack:
    """One track of the run, indexed by source frame, to compare a reviewer's boxes with."""

    def __init__(self, track: TrackResult, video: VideoInfo) -> None:
        self.track = track
        self.row = {int(f): i for i, f in enumerate(track.frame_indices)}
        self.video = video

    def clipped_box(self, frame: int) -> Box | None:
        """The run's box at a source frame as the tools show it (clipped), None when absent or not tracked."""
        i = self.row.get(frame)
        if i is None or self.track.outside[i]:
            return None
        return clip_xywh(self.track.boxes_xywh[i], self.video.width, self.video.height)

    def box_changed(self, frame: int, box: Box) -> bool:
        """Whether ``box`` differs from the run's box at ``frame``, as written or as clipped to the image.

        Label Studio always gets the clipped box and CVAT may clip on upload;
        either way an unedited box must not count as a correction.
        """
        for run in (self._raw_box(frame), self.clipped_box(frame)):
            if run is not None and max(abs(a - b) for a, b in zip(run, box)) <= SAME_BOX_PX + _SLACK:
                return False
        return True

    def _raw_box(self, frame: int) -> Box | None:
        i = self.row.get(frame)
        if i is None or self.track.outside[i] or not np.isfinite(self.track.boxes_xywh[i]).all():
            return None
        return cast(Box, tuple(float(v) for v in self.track.boxes_xywh[i]))  # a row of the (N, 4) boxes

    def anchored(self, frame: int, corners: tuple[float, ...] | None) -> bool:
        """Whether the run holds a human anchor at ``frame`` with these corners (None: an absence)."""
        i = self.row.get(frame)
        if i is None or not self.track.keyframe[i]:
            return False
        if corners is None:
            return bool(self.track.outside[i])
        return not self.track.outside[i] and not self.box_changed(frame, tuple(xyxy_to_xywh(corners).tolist()))

    def absence_changed(self, frame: int) -> bool:
        """An absence at ``frame`` is news only where the run shows the object in the image: the exporters hide
        a box that lies wholly outside it, as an absence."""
        return self.clipped_box(frame) is not None


def _int_or(text: str | None, default: int = -1) -> int:
    """``int(text)``, or ``default`` for a missing or malformed number (refused later, with its line)."""
    try:
        return int(text or "")
    except ValueError:
        return default


def _checked_box(values: Sequence[float], where: str, layout: str) -> Box:
    x, y, w, h = values
    if not all(math.isfinite(v) for v in values) or w <= 0 or h <= 0:
        raise ToolError(f"{where}: box {layout} has zero or negative size (w={w:g}, h={h:g}) or is not finite: "
                        "draw the box again, or mark the object absent", EXIT_VALUE)
    return (x, y, w, h)


# --------------------------------------------------------------------------- CVAT


def _parse_xml(path: Path, text: str) -> tuple[ET.Element, dict[int, int]]:
    """The element tree and each element's line (ElementTree keeps none), for ``FILE:LINE`` in messages."""
    builder = ET.TreeBuilder()
    lines: dict[int, int] = {}
    parser = expat.ParserCreate()

    def start(tag: str, attrs: dict[str, str]) -> None:
        lines[id(builder.start(tag, attrs))] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        raise ToolError(f"{path}:{exc.lineno}: not well-formed XML ({expat.ErrorString(exc.code)} at column "
                        f"{exc.offset + 1}): expected the CVAT for video 1.1 XML dumped by CVAT (Export task dataset "
                        "> CVAT for video 1.1)", EXIT_VALUE) from None
    return builder.close(), lines


def _meta_int(task: ET.Element, key: str, where: str) -> int | None:
    text = task.findtext(key)
    if text is None or not text.strip():
        return None
    try:
        return int(text.strip())
    except ValueError:
        raise ToolError(f"{where}: <{key}> must be an integer, got {text.strip()!r}", EXIT_VALUE) from None


_Given = dict[int, dict[int, "tuple[float, ...] | None"]]  # track_id -> frame -> corners, None for outside


def _given_versions(exported: Sequence[Any] | None) -> list[_Given]:
    """run.json's ``review_exports.cvat`` as lookups; versions that do not parse are left out (written by hand)."""
    versions: list[_Given] = []
    for version in exported or []:
        try:
            versions.append({int(t["track_id"]): {int(k[0]): (tuple(float(v) for v in k[1:5]) if len(k) == 5 else None)
                                                  for k in t["keyframes"]} for t in version})
        except (KeyError, TypeError, ValueError, IndexError):
            continue
    return versions


def _same_corners(a: tuple[float, ...] | None, b: tuple[float, ...] | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return max(abs(x - y) for x, y in zip(a, b)) <= SAME_BOX_PX + _SLACK


def _same_as_given(given: tuple[float, ...] | None, box: tuple[float, ...] | None, video: VideoInfo) -> bool:
    """Whether a file's keyframe is the one given, as written or as CVAT clips it to the image on upload."""
    if _same_corners(given, box):
        return True
    if given is None or box is None:
        return False
    clipped = clip_xywh(xyxy_to_xywh(given), video.width, video.height)
    return clipped is not None and _same_corners(tuple(xywh_to_xyxy(clipped).tolist()), box)


def _corners_or_none(box: ET.Element) -> tuple[float, ...] | None:
    if box.get("outside") == "1":
        return None
    try:
        return tuple(float(box.get(k, "")) for k in ("xtl", "ytl", "xbr", "ybr"))
    except ValueError:
        return (math.nan,) * 4  # malformed: matches nothing, refused with its line below


def read_cvat_corrections(path: str | os.PathLike, *, video: VideoInfo, tracks: Sequence[TrackResult],
                          frames: range | None = None, exported: Sequence[Any] | None = None) -> list[Correction]:
    """Read a reviewed CVAT for video 1.1 XML and return its corrections of the run, in file order.

    Parameters
    ----------
    path : path-like
        The XML dumped by CVAT (or the run's ``cvat.xml`` edited by hand).
    video : VideoInfo
        The run's video: its frame size must match ``original_size``.
    tracks : sequence of TrackResult
        The run's tracks, in the order they were exported.
    frames : range or None
        The run's processed range (``run.json``'s ``range``); None for the whole video.
    exported : sequence or None
        The keyframes of each ``cvat.xml`` the run wrote (run.json's
        ``review_exports["cvat"]``, :func:`annotator.exports.cvat.cvat_keyframes`);
        a keyframe the reviewer left as given is no correction. None: compare
        every keyframe with the run's tracks.

    Returns
    -------
    list of Correction
        ``track_id`` is the run's id of the matched track; ``where`` is ``FILE:LINE`` of the ``<box>``.

    Raises
    ------
    ToolError
        Exit code 3 when the file cannot be read; 4 for malformed XML, a file
        of another task (frame count, frame size, start or step), a track
        count or label that does not match the run, or a keyframe off the range.
    """
    path = Path(path)
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    root, lines = _parse_xml(path, _read_text(path, "CVAT"))

    def where(element: ET.Element) -> str:
        return f"{path}:{lines.get(id(element), 1)}"

    _check_cvat_task(root, where, video, frames)
    xml_tracks = root.findall("track")
    tracks = [t for t in tracks if visible(t).any()]  # the exporter leaves out tracks never seen
    if len(xml_tracks) != len(tracks):
        raise ToolError(f"{where(root)}: the file has {len(xml_tracks)} tracks, the run {len(tracks)}: corrections "
                        "can only move, hide or show the run's tracks; delete added tracks or rerun with new "
                        "targets", EXIT_VALUE)
    given = _given_version(exported, xml_tracks, tracks, video)
    past_end: list[str] = []
    corrections: list[Correction] = []
    for element, track in zip(xml_tracks, tracks):
        if element.get("label") != track.label:
            raise ToolError(f"{where(element)}: track {element.get('id')} has label {element.get('label')!r}, the "
                            f"run's track {track.track_id} in that place {track.label!r}: keep the tracks' order and "
                            "labels", EXIT_VALUE)
        corrections += _cvat_track_corrections(element, track, where, video, frames, given, past_end)
    if past_end:
        warnings.warn(f"{past_end[0]}: {plural(len(past_end), 'outside keyframe')} just past the run's last processed "
                      f"frame {frames[-1]} (as FiftyOne ends its tracks) skipped: the tracks end with the range anyway",
                      InputWarning, stacklevel=2)
    return corrections


def _check_cvat_task(root: ET.Element, where, video: VideoInfo, frames: range) -> None:
    """Refuse a file that is not CVAT for video 1.1, or whose task is not the run's (frames, size, start, step)."""
    if root.tag == "annotations" and root.find("track") is None and root.find("image") is not None:
        raise ToolError(f"{where(root.find('image'))}: this is a \"CVAT for images\" file (one <image> per frame, no "
                        "<track>), which loses the tracks: export \"CVAT for video 1.1\" from CVAT (Export task "
                        "dataset) or FiftyOne (CVATVideoDataset) and give that file", EXIT_VALUE)
    meta = root.find("meta")
    if root.tag != "annotations" or meta is None:
        raise ToolError(f"{where(root)}: expected <annotations> with <meta>, the CVAT for video 1.1 layout, got "
                        f"<{root.tag}>", EXIT_VALUE)
    task = meta.find("task")
    if task is None:
        task = meta.find("job")
    if task is None:
        raise ToolError(f"{where(meta)}: <meta> has no <task> or <job>: expected a CVAT for video 1.1 dump",
                        EXIT_VALUE)
    size = _meta_int(task, "size", where(task))
    start = _meta_int(task, "start_frame", where(task))
    width = _meta_int(task, "original_size/width", where(task))
    height = _meta_int(task, "original_size/height", where(task))
    step_text = (task.findtext("frame_filter") or "").strip()
    match = re.fullmatch(r"(?:step\s*=\s*(\d+))?", step_text)
    if match is None:
        raise ToolError(f"{where(task)}: <frame_filter> {step_text!r} is not 'step=N' or empty", EXIT_VALUE)
    step = int(match.group(1) or 1)
    if width is None or height is None:
        raise ToolError(f"{where(task)}: the file has no <original_size> (the frame width and height) in its "
                        "<meta>, so it cannot be checked against the run's video: export the task as \"CVAT for "
                        "video 1.1\", which writes it, or add <original_size><width>"
                        f"{video.width}</width><height>{video.height}</height></original_size> to <task>", EXIT_VALUE)
    found = (f"{size} frames of {width}x{height} from frame {start if start is not None else '?'} every {step}")
    expected = f"{len(frames)} frames of {video.width}x{video.height} from frame {frames.start} every {frames.step}"
    if (size != len(frames) or (width, height) != (video.width, video.height) or step != frames.step
            or (start if start is not None else 0) != frames.start):
        raise ToolError(f"{where(task)}: this CVAT file belongs to another task ({found}); the run processed "
                        f"{expected}: export the annotations of the task created from this run's cvat.xml",
                        EXIT_VALUE)


def _given_version(exported: Sequence[Any] | None, xml_tracks: list[ET.Element], tracks: list[TrackResult],
                   video: VideoInfo) -> _Given | None:
    # The version of the run's cvat.xml this file was made from: the one whose keyframes it keeps the most of,
    # less those it has at a frame where that version had another (on a tie, the latest). The run's own
    # keyframes count for the version they were written in. A reviewer's correction, once applied, is also a
    # keyframe of every later version: a version's mismatch that a later version holds is that correction,
    # already applied, and does not count against it (else a file re-given after its re-track would match the
    # later version as well as its own, and the later version's re-tracked keyframes would become corrections).
    versions = _given_versions(exported)
    if not versions:
        return None
    keyframes = [(track.track_id, _int_or(box.get("frame")), _corners_or_none(box))
                 for element, track in zip(xml_tracks, tracks) for box in element if box.get("keyframe") == "1"]

    def holds(version: _Given, t: int, f: int, c: tuple[float, ...] | None) -> bool:
        return f in version.get(t, {}) and _same_as_given(version[t][f], c, video)

    def score(n: int) -> int:
        version = versions[n]
        held = [(t, f, c) for t, f, c in keyframes if f in version.get(t, {})]
        kept = sum(1 for t, f, c in held if holds(version, t, f, c))
        applied = sum(1 for t, f, c in held if not holds(version, t, f, c)
                      and any(holds(later, t, f, c) for later in versions[n + 1:]))
        return kept - (len(held) - kept - applied)

    return versions[max(reversed(range(len(versions))), key=score)]


def _cvat_track_corrections(element: ET.Element, track: TrackResult, where, video: VideoInfo, frames: range,
                            given: _Given | None, past_end: list[str]) -> list[Correction]:
    """The corrections in one ``<track>`` of the file: its keyframes that differ from what the run gave or holds.
    Outside keyframes just past the range are added to ``past_end`` (skipped, with one warning for the file)."""
    corrections: list[Correction] = []
    run = _RunTrack(track, video)
    # After a new absence, the box where the object shows again ends it and is a correction even when it is
    # the run's box: an absence lasts until the next correction (as in a CSV), so without it the object
    # would stay hidden to the track's end.
    hidden = False
    for box in sorted(element, key=lambda b: _int_or(b.get("frame"))):
        if box.tag != "box":
            raise ToolError(f"{where(box)}: <{box.tag}> in a track: only boxes (rectangles) can correct a "
                            "box track", EXIT_VALUE)
        if box.get("keyframe") != "1":
            continue  # interpolated by CVAT, not set by a person
        try:
            frame = int(box.get("frame", ""))
            corners = [float(box.get(k, "")) for k in ("xtl", "ytl", "xbr", "ybr")]
        except ValueError:
            raise ToolError(f"{where(box)}: a <box> needs an integer frame and numeric xtl, ytl, xbr, ybr, got "
                            f"{dict(box.attrib)!r}", EXIT_VALUE) from None
        if frame not in frames and box.get("outside") == "1" and frames[-1] < frame <= frames[-1] + frames.step:
            past_end.append(where(box))  # ends the track after the range: changes nothing the run holds
            continue
        if frame not in frames:
            raise ToolError(f"{where(box)}: frame {frame} is not one of the run's processed frames (from "
                            f"{frames.start} to {frames[-1]} every {frames.step})", EXIT_VALUE)
        track_given = given.get(track.track_id, {}) if given is not None else {}
        if frame in track_given:
            if (_same_as_given(track_given[frame], _corners_or_none(box), video)
                    and not (hidden and box.get("outside") != "1")):
                continue  # the tool's own keyframe, left as it was (unless it ends a new absence)
            # A keyframe the tool gave, changed by a person; unless the run holds that change as a human anchor
            # already (a correction applied by an earlier re-track, the file given again).
            changed = not run.anchored(frame, _corners_or_none(box))
            if not changed and not hidden:
                continue
        else:
            changed = False  # a keyframe a person added: compared with the run below
        if box.get("outside") == "1":
            if changed or run.absence_changed(frame):
                corrections.append(Correction(frame=frame, box_xywh=None, track_id=track.track_id,
                                              where=where(box)))
                hidden = True
            continue
        x0, y0, x1, y1 = corners
        xywh = _checked_box(xyxy_to_xywh(corners).tolist(), where(box), f"xtl={x0:g} ytl={y0:g} xbr={x1:g} ybr={y1:g}")
        if hidden or changed or run.box_changed(frame, xywh):
            corrections.append(Correction(frame=frame, box_xywh=xywh, track_id=track.track_id, where=where(box)))
        hidden = False
    return corrections


# --------------------------------------------------------------------------- Label Studio


def _json_line(text: str, needle: str) -> int:
    """1-based line of the first occurrence of ``needle`` (JSON gives no positions for nested values)."""
    pos = text.find(needle)
    return text.count("\n", 0, pos) + 1 if pos >= 0 else 1


def _next_processed(frames: range, frame: int) -> int | None:
    """The first processed source frame after ``frame``, None past the range's end."""
    if frame < frames.start:
        return frames.start
    after = frames.start + ((frame - frames.start) // frames.step + 1) * frames.step
    return after if after <= frames[-1] else None


def _keyframe_order(item: Any) -> int:
    """A keyframe's frame number for sorting; a malformed one sorts first and is refused with its line."""
    try:
        return int(item["frame"])
    except (KeyError, TypeError, ValueError):
        return 0


def _rectangles(entry: Any) -> list[dict]:
    results = entry.get("result") if isinstance(entry, dict) else None
    return [r for r in results if isinstance(r, dict) and r.get("type") == "videorectangle"] \
        if isinstance(results, list) else []


def _regions(task: dict) -> tuple[list[dict], str, dict]:
    """The videorectangle results of a task's latest usable annotation, else of its latest prediction; the key
    they came from and their annotation (or prediction)."""
    for key in ("annotations", "completions", "predictions"):
        listed = task.get(key)
        entries = [e for e in listed if isinstance(e, dict) and not e.get("was_cancelled")] \
            if isinstance(listed, list) else []
        for entry in reversed(entries):  # Label Studio lists them oldest first
            result = _rectangles(entry)
            if result:
                return result, key, entry
    return [], "", {}


def _parent_regions(task: dict, annotation: dict) -> list[dict] | None:
    """The regions of the prediction an annotation started from (``parent_prediction``), None when it names none
    that the export holds."""
    parent = annotation.get("parent_prediction")
    if isinstance(parent, dict):  # an id in Label Studio 1.23; some exports may nest the prediction itself
        return _rectangles(parent) or None
    nested = annotation.get("prediction")  # Label Studio's JSON export nests the parent prediction here
    if isinstance(nested, dict) and parent is not None and nested.get("id") == parent:
        return _rectangles(nested) or None
    predictions = task.get("predictions")
    for prediction in predictions if isinstance(predictions, list) else []:
        if isinstance(prediction, dict) and parent is not None and prediction.get("id") == parent:
            return _rectangles(prediction) or None
    return None


class _GivenSequence:
    """The keyframes of a prediction region, and the box Label Studio shows from them at any frame."""

    def __init__(self, sequence: Any, video: VideoInfo) -> None:
        self.video = video
        self.items: list[tuple[int, Box, bool]] = []
        for item in sequence if isinstance(sequence, list) else []:
            try:
                box = self.pixels([float(item[k]) for k in ("x", "y", "width", "height")])
                self.items.append((int(item["frame"]), box, item.get("enabled", True) is not False))
            except (KeyError, TypeError, ValueError):
                continue  # the tool wrote it: a malformed one was edited by hand, and matches nothing
        self.items.sort(key=lambda k: k[0])
        self.at = {frame: (box, enabled) for frame, box, enabled in self.items}

    def pixels(self, pct: Sequence[float]) -> Box:
        w, h = self.video.width, self.video.height
        return (pct[0] * w / 100.0, pct[1] * h / 100.0, pct[2] * w / 100.0, pct[3] * h / 100.0)

    def shown(self, frame: int) -> Box | None:
        """The box shown at a 1-based frame: an ``enabled`` keyframe's box, interpolated linearly towards the
        next keyframe; none after an ``enabled: false`` one or before the first."""
        before = [k for k in self.items if k[0] <= frame]
        if not before:
            return None
        f0, box0, enabled = before[-1]
        if f0 == frame:
            return box0
        if not enabled:
            return None
        after = [k for k in self.items if k[0] > frame]
        if not after:
            return box0
        f1, box1, _ = after[0]
        t = (frame - f0) / (f1 - f0)
        return cast(Box, tuple(a + t * (b - a) for a, b in zip(box0, box1)))  # four pairs: two boxes zipped


def _same_box(a: Box | None, b: Box | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return max(abs(x - y) for x, y in zip(a, b)) <= SAME_BOX_PX + _SLACK


def read_labelstudio_corrections(path: str | os.PathLike, *, video: VideoInfo, tracks: Sequence[TrackResult],
                                 frames: range | None = None) -> list[Correction]:
    """Read a Label Studio JSON export of the run's task and return its corrections of the run.

    Parameters, returns and errors as :func:`read_cvat_corrections`; ``where``
    is ``FILE:LINE`` of the region (or ``FILE: region ID frame N`` when the
    line cannot be found).
    """
    path = Path(path)
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    text = _read_text(path, "Label Studio")
    task, regions, key, entry = _labelstudio_task(path, text, video, frames)
    # What the reviewer was given: the prediction the annotation started from (Label Studio keeps its id).
    parent = _parent_regions(task, entry) if key != "predictions" else None
    matched = _matched_regions(path, regions, tracks)
    given_by_id = {r.get("id"): r for r in parent or [] if isinstance(r.get("id"), str)}
    corrections: list[Correction] = []
    for number_, (region, track) in enumerate(matched):
        region_id = region.get("id")
        line = _json_line(text, json.dumps(region_id)) if region_id is not None else 1
        given_region = given_by_id.get(region_id) if isinstance(region_id, str) and region_id in given_by_id else (
            parent[number_] if parent is not None and len(parent) == len(matched) and not given_by_id else None)
        given = _GivenSequence((given_region.get("value") or {}).get("sequence"), video) \
            if isinstance(given_region, dict) else None
        corrections += _region_corrections(f"{path}:{line}", region, track, given, video, frames)
    return corrections


def _labelstudio_task(path: Path, text: str, video: VideoInfo, frames: range) -> tuple[dict, list, str, Any]:
    """The one task of the export with video rectangles, checked to be this run's: the task, its regions, and
    where they are (``key`` and ``entry`` as :func:`_regions` gives them)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ToolError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg} at column {exc.colno}); expected Label "
                        "Studio's JSON export of the project", EXIT_VALUE) from None
    tasks = data if isinstance(data, list) else [data]
    with_regions = [(t, *_regions(t)) for t in tasks if isinstance(t, dict)]
    with_regions = [(t, r, k, e) for t, r, k, e in with_regions if r]
    if not with_regions:
        raise ToolError(f"{path}:1: no task with video rectangles (results of type 'videorectangle'): expected "
                        "Label Studio's JSON export (not JSON-MIN or CSV) of the project holding this run's "
                        "labelstudio.json", EXIT_VALUE)
    if len(with_regions) > 1:
        names = [str(t.get("id", "?")) for t, _, _, _ in with_regions]
        raise ToolError(f"{path}:1: {len(with_regions)} tasks (ids {', '.join(names)}) have video rectangles; "
                        "corrections apply to one run: export only this run's task", EXIT_VALUE)
    task, regions, key, entry = with_regions[0]
    data = task.get("data")
    info = data.get("sptpt") if isinstance(data, dict) else None
    sptpt_key = '"sptpt"'
    if isinstance(info, dict):
        theirs = (info.get("width"), info.get("height"), info.get("frame_count"), info.get("start"), info.get("step"))
        ours = (video.width, video.height, video.frame_count, frames.start, frames.step)
        stop = info.get("stop")
        if theirs != ours or not isinstance(stop, int) or range(frames.start, stop, frames.step)[-1:] != frames[-1:]:
            raise ToolError(f"{path}:{_json_line(text, sptpt_key)}: this task belongs to another run (video "
                            f"{info.get('video')!r}: {theirs[0]}x{theirs[1]}, {theirs[2]} frames, range "
                            f"{theirs[3]}:{stop}:{theirs[4]}); the run has {video.width}x{video.height}, "
                            f"{video.frame_count} frames, range {frames.start}:{frames.stop}:{frames.step}: export "
                            "the task imported from this run's labelstudio.json", EXIT_VALUE)
    return task, regions, key, entry


def _matched_regions(path: Path, regions: list, tracks: list[TrackResult]) -> list[tuple[dict, TrackResult]]:
    """Each region with the run's track it edits: by the exporter's region id, else in order."""
    by_id = {labelstudio_region_id(t.track_id): t for t in tracks}
    ids = [r.get("id") if isinstance(r.get("id"), str) else None for r in regions]
    if all(i in by_id for i in ids) and len(set(ids)) == len(regions):
        return [(r, by_id[r["id"]]) for r in regions]
    if len(regions) == len(seen := [t for t in tracks if visible(t).any()]):
        return list(zip(regions, seen))  # the exporter leaves out tracks never seen
    raise ToolError(f"{path}:1: {len(regions)} video rectangles, the run has {len(tracks)} tracks, and their ids "
                    f"are not the exporter's ('track-<id>'): corrections can only move, hide or show the run's "
                    "tracks", EXIT_VALUE)


def _region_corrections(where: str, region: dict, track: TrackResult, given: _GivenSequence | None,
                        video: VideoInfo, frames: range) -> list[Correction]:
    """The corrections in one region's keyframes: boxes that differ from what the reviewer was given (or, without
    it, from the run), and new absences."""
    region_id = region.get("id")
    corrections: list[Correction] = []
    value = region.get("value")
    if not isinstance(value, dict):
        raise ToolError(f"{where}: region {region_id!r} has no 'value' object with its keyframes "
                        "('sequence'): expected Label Studio's JSON export of the project", EXIT_VALUE)
    labels = value.get("labels") or []
    if labels and labels != [track.label]:
        raise ToolError(f"{where}: region {region_id!r} has labels {labels}, the run's track "
                        f"{track.track_id} is {track.label!r}: keep the tracks' labels", EXIT_VALUE)
    sequence = value.get("sequence")
    if not isinstance(sequence, list):
        raise ToolError(f"{where}: region {region_id!r} has no 'sequence' list of keyframes", EXIT_VALUE)
    run = _RunTrack(track, video)
    items = sorted(sequence, key=_keyframe_order)
    hidden = False  # a new absence is open: the next keyframe, which shows the object, ends it (see CVAT)
    for n, item in enumerate(items):
        try:
            frame = int(item["frame"]) - 1
            pct = [float(item[k]) for k in ("x", "y", "width", "height")]
        except (KeyError, TypeError, ValueError):
            raise ToolError(f"{where}: keyframe {item!r} of region {region_id!r} needs an integer 'frame' and "
                            "numeric x, y, width, height (percent)", EXIT_VALUE) from None
        if frame < 0:
            raise ToolError(f"{where}: keyframe frame {frame + 1} of region {region_id!r} must be >= 1", EXIT_VALUE)
        xywh = _checked_box((pct[0] * video.width / 100.0, pct[1] * video.height / 100.0,
                             pct[2] * video.width / 100.0, pct[3] * video.height / 100.0), where,
                            f"x={pct[0]:g}% y={pct[1]:g}% width={pct[2]:g}% height={pct[3]:g}%")
        enabled = item.get("enabled", True) is not False
        if given is not None:
            # Changed relative to the prediction: the box differs from what Label Studio showed there.
            was_hidden_after = frame + 1 in given.at and not given.at[frame + 1][1]
            # A keyframe switched back on shows the object after it: its box anchors the re-track from there.
            box_changed = not _same_box(given.shown(frame + 1), xywh) or (enabled and was_hidden_after)
        else:
            box_changed = run.box_changed(frame, xywh)
            was_hidden_after = False
        if hidden or box_changed:
            corrections.append(Correction(frame=frame, box_xywh=xywh, track_id=track.track_id, where=where))
        hidden = False
        if not enabled:
            # Hidden from the next processed frame until the next keyframe.
            after = _next_processed(frames, frame)
            next_key = int(items[n + 1]["frame"]) - 1 if n + 1 < len(items) else None
            news = not was_hidden_after if given is not None else after is not None and run.absence_changed(after)
            if after is not None and (next_key is None or after < next_key) and news:
                corrections.append(Correction(frame=after, box_xywh=None, track_id=track.track_id, where=where))
                hidden = True
    return corrections


def _looks_like_labelstudio(text: str) -> bool:
    try:
        data = json.loads(text)
    except ValueError:
        return False
    if isinstance(data, dict):
        return "data" in data and ("annotations" in data or "predictions" in data)
    return isinstance(data, list)


def read_run_corrections(path: str | os.PathLike, *, video: VideoInfo, tracks: Sequence[TrackResult],
                         frames: range, exported: Mapping[str, Any] | None = None) -> list[Correction]:
    """Corrections from any file a reviewer may bring back, by its content.

    CVAT for video XML and Label Studio exports are compared with the run's
    tracks (only what a person changed is a correction; ``exported`` is
    run.json's ``review_exports``); a CSV or a COCO file holds corrections
    only (:func:`annotator.corrections.read_corrections`).
    """
    from annotator.corrections import read_corrections

    path = Path(path)
    try:
        head = read_text(path)[:4096] if path.is_file() else ""
    except (OSError, UnicodeDecodeError):
        head = ""
    start = head.lstrip()
    if start.startswith("<"):
        return read_cvat_corrections(path, video=video, tracks=tracks, frames=frames,
                                     exported=(exported or {}).get("cvat"))
    if start.startswith("[") or (start.startswith("{") and _looks_like_labelstudio(_read_text(path, "Label Studio"))):
        return read_labelstudio_corrections(path, video=video, tracks=tracks, frames=frames)
    return read_corrections(path)

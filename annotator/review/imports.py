"""Reviewers' fixes brought back from CVAT and Label Studio, as :class:`~annotator.corrections.Correction` records.

Both readers return what :func:`annotator.corrections.read_corrections`
returns for a CSV or COCO file (source frame indices, 0-based ``xywh``,
``None`` for an absence, ``where`` = ``FILE:LINE``), so the caller can
dispatch on the file type and hand any of them to
:func:`~annotator.corrections.resolve_corrections`. Problems raise the same
:class:`~annotator.errors.ToolError` (exit code 4, 3 when the file cannot
be read) with a one-line message naming the file.

A reviewer's file holds the run's own keyframes too (first frame, flagged
spans, ...), so only what **differs from the run** is a correction: a box
more than :data:`SAME_BOX_PX` from the run's box at that frame, a box where
the run had the object absent, or an absence where the run had a box.

**CVAT for video 1.1** (the run's ``cvat.xml`` after review, dumped by
CVAT): boxes with ``keyframe="1"``; ``outside="1"`` marks the object absent
from that frame on. Frames are source indices (CVAT dumps absolute frame
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
import xml.etree.ElementTree as ET
from xml.parsers import expat
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from annotator.corrections import Correction
from annotator.errors import EXIT_INPUT, EXIT_VALUE, ToolError
from annotator.exports._review import check_frame_range, clip_xywh, visible
from annotator.exports.labelstudio import labelstudio_region_id
from annotator.text import TEXT_ENCODINGS, read_text
from annotator.tracks import TrackResult, VideoInfo

__all__ = ["SAME_BOX_PX", "read_cvat_corrections", "read_labelstudio_corrections"]

#: Largest coordinate change, in pixels, still taken for the run's own box: CVAT rounds to 1/100 px
#: and Label Studio stores percent; no reviewer's edit is that small.
SAME_BOX_PX = 0.05

Box = tuple[float, float, float, float]


def _read_text(path: Path, what: str) -> str:
    try:
        return read_text(path)
    except FileNotFoundError:
        raise ToolError(f"{what} file {path} does not exist", EXIT_INPUT) from None
    except IsADirectoryError:
        raise ToolError(f"{what} file {path} is a folder: give the exported file inside it", EXIT_INPUT) from None
    except UnicodeDecodeError:
        raise ToolError(f"{what} file {path} is not text ({TEXT_ENCODINGS}): expected the {what} export", EXIT_VALUE) from None
    except OSError as exc:
        raise ToolError(f"{what} file {path} cannot be read ({exc.strerror})", EXIT_INPUT) from None


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
            if run is not None and max(abs(a - b) for a, b in zip(run, box)) <= SAME_BOX_PX:
                return False
        return True

    def _raw_box(self, frame: int) -> Box | None:
        i = self.row.get(frame)
        if i is None or self.track.outside[i] or not np.isfinite(self.track.boxes_xywh[i]).all():
            return None
        return tuple(float(v) for v in self.track.boxes_xywh[i])

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


def read_cvat_corrections(path: str | os.PathLike, *, video: VideoInfo, tracks: Sequence[TrackResult],
                          frames: range | None = None) -> list[Correction]:
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

    if root.tag != "annotations" or root.find("meta") is None:
        raise ToolError(f"{where(root)}: expected <annotations> with <meta>, the CVAT for video 1.1 layout, got "
                        f"<{root.tag}>", EXIT_VALUE)
    meta = root.find("meta")
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
    found = (f"{size} frames of {width}x{height} from frame {start if start is not None else '?'} every {step}")
    expected = f"{len(frames)} frames of {video.width}x{video.height} from frame {frames.start} every {frames.step}"
    if (size != len(frames) or (width, height) != (video.width, video.height) or step != frames.step
            or (start if start is not None else 0) != frames.start):
        raise ToolError(f"{where(task)}: this CVAT file belongs to another task ({found}); the run processed "
                        f"{expected}: export the annotations of the task created from this run's cvat.xml",
                        EXIT_VALUE)

    xml_tracks = root.findall("track")
    tracks = [t for t in tracks if visible(t).any()]  # the exporter leaves out tracks never seen
    if len(xml_tracks) != len(tracks):
        raise ToolError(f"{where(root)}: the file has {len(xml_tracks)} tracks, the run {len(tracks)}: corrections "
                        "can only move, hide or show the run's tracks; delete added tracks or rerun with new "
                        "targets", EXIT_VALUE)
    corrections: list[Correction] = []
    for element, track in zip(xml_tracks, tracks):
        if element.get("label") != track.label:
            raise ToolError(f"{where(element)}: track {element.get('id')} has label {element.get('label')!r}, the "
                            f"run's track {track.track_id} in that place {track.label!r}: keep the tracks' order and "
                            "labels", EXIT_VALUE)
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
            if frame not in frames:
                raise ToolError(f"{where(box)}: frame {frame} is not one of the run's processed frames (from "
                                f"{frames.start} to {frames[-1]} every {frames.step})", EXIT_VALUE)
            if box.get("outside") == "1":
                if run.absence_changed(frame):
                    corrections.append(Correction(frame=frame, box_xywh=None, track_id=track.track_id,
                                                  where=where(box)))
                    hidden = True
                continue
            x0, y0, x1, y1 = corners
            xywh = _checked_box((x0, y0, x1 - x0, y1 - y0), where(box), f"xtl={x0:g} ytl={y0:g} xbr={x1:g} ybr={y1:g}")
            if hidden or run.box_changed(frame, xywh):
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


def _regions(task: dict) -> tuple[list[dict], str]:
    """The videorectangle results of a task's latest usable annotation, else of its latest prediction."""
    for key in ("annotations", "completions", "predictions"):
        listed = task.get(key)
        entries = [e for e in listed if isinstance(e, dict) and not e.get("was_cancelled")] \
            if isinstance(listed, list) else []
        for entry in reversed(entries):  # Label Studio lists them oldest first
            results = entry.get("result")
            result = [r for r in results if isinstance(r, dict) and r.get("type") == "videorectangle"] \
                if isinstance(results, list) else []
            if result:
                return result, key
    return [], ""


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
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ToolError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg} at column {exc.colno}); expected Label "
                        "Studio's JSON export of the project", EXIT_VALUE) from None
    tasks = data if isinstance(data, list) else [data]
    with_regions = [(t, *_regions(t)) for t in tasks if isinstance(t, dict)]
    with_regions = [(t, r, k) for t, r, k in with_regions if r]
    if not with_regions:
        raise ToolError(f"{path}:1: no task with video rectangles (results of type 'videorectangle'): expected "
                        "Label Studio's JSON export (not JSON-MIN or CSV) of the project holding this run's "
                        "labelstudio.json", EXIT_VALUE)
    if len(with_regions) > 1:
        names = [str(t.get("id", "?")) for t, _, _ in with_regions]
        raise ToolError(f"{path}:1: {len(with_regions)} tasks (ids {', '.join(names)}) have video rectangles; "
                        "corrections apply to one run: export only this run's task", EXIT_VALUE)
    task, regions, _ = with_regions[0]
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

    by_id = {labelstudio_region_id(t.track_id): t for t in tracks}
    ids = [r.get("id") if isinstance(r.get("id"), str) else None for r in regions]
    if all(i in by_id for i in ids) and len(set(ids)) == len(regions):
        matched = [(r, by_id[r["id"]]) for r in regions]
    elif len(regions) == len(seen := [t for t in tracks if visible(t).any()]):
        matched = list(zip(regions, seen))  # the exporter leaves out tracks never seen
    else:
        raise ToolError(f"{path}:1: {len(regions)} video rectangles, the run has {len(tracks)} tracks, and their ids "
                        f"are not the exporter's ('track-<id>'): corrections can only move, hide or show the run's "
                        "tracks", EXIT_VALUE)

    corrections: list[Correction] = []
    for region, track in matched:
        region_id = region.get("id")
        line = _json_line(text, json.dumps(region_id)) if region_id is not None else 1
        value = region.get("value")
        if not isinstance(value, dict):
            raise ToolError(f"{path}:{line}: region {region_id!r} has no 'value' object with its keyframes "
                            "('sequence'): expected Label Studio's JSON export of the project", EXIT_VALUE)
        labels = value.get("labels") or []
        if labels and labels != [track.label]:
            raise ToolError(f"{path}:{line}: region {region_id!r} has labels {labels}, the run's track "
                            f"{track.track_id} is {track.label!r}: keep the tracks' labels", EXIT_VALUE)
        sequence = value.get("sequence")
        if not isinstance(sequence, list):
            raise ToolError(f"{path}:{line}: region {region_id!r} has no 'sequence' list of keyframes", EXIT_VALUE)
        run = _RunTrack(track, video)
        items = sorted(sequence, key=_keyframe_order)
        hidden = False  # a new absence is open: the next keyframe, which shows the object, ends it (see CVAT)
        for n, item in enumerate(items):
            where = f"{path}:{line}"
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
            if hidden or run.box_changed(frame, xywh):
                corrections.append(Correction(frame=frame, box_xywh=xywh, track_id=track.track_id, where=where))
            hidden = False
            if item.get("enabled", True) is False:
                # Hidden from the next processed frame until the next keyframe.
                after = _next_processed(frames, frame)
                next_key = int(items[n + 1]["frame"]) - 1 if n + 1 < len(items) else None
                if after is not None and (next_key is None or after < next_key) and run.absence_changed(after):
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
                         frames: range) -> list[Correction]:
    """Corrections from any file a reviewer may bring back, by its content.

    CVAT for video XML and Label Studio exports are compared with the run's
    tracks (only what differs is a correction); a CSV or a COCO file holds
    corrections only (:func:`annotator.corrections.read_corrections`).
    """
    from annotator.corrections import read_corrections

    path = Path(path)
    try:
        head = read_text(path)[:4096] if path.is_file() else ""
    except (OSError, UnicodeDecodeError):
        head = ""
    start = head.lstrip()
    if start.startswith("<"):
        return read_cvat_corrections(path, video=video, tracks=tracks, frames=frames)
    if start.startswith("[") or (start.startswith("{") and _looks_like_labelstudio(_read_text(path, "Label Studio export"))):
        return read_labelstudio_corrections(path, video=video, tracks=tracks, frames=frames)
    return read_corrections(path)

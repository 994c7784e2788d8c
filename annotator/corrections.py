"""Human corrections: boxes a reviewer set on some frames, read from a CSV or an edited COCO file.

Two formats are accepted (chosen by content: a file whose first non-blank
character is ``{`` is COCO, anything else CSV):

**CSV** ``frame,x,y,w,h[,track_id]``, one correction per row::

    frame,x,y,w,h,track_id        # optional header
    120,310.5,88,42,61,1          # the object is at this box in frame 120
    180,,,,,1                     # ... and absent from frame 180 until the next correction

* ``frame`` is the **source** frame index, 0-based: the ``frame`` column of
  ``flags.csv`` and the COCO image's ``frame_index`` (they differ from the
  row number when ``--start``/``--step`` sub-sample the video).
* ``x,y,w,h`` are 0-based pixels (COCO convention, not OTB's 1-based), ``w``
  and ``h`` > 0. All four empty marks the object absent from that frame until
  the next correction of the track.
* ``track_id`` may be left out (or empty) when the run has one track.
* Blank lines and lines starting with ``#`` are ignored.

**COCO** (e.g. ``annotations.json`` edited in CVAT or by a script): every
annotation whose ``attributes.keyframe`` is ``true`` is a correction. Its frame
is the ``frame_index`` of its image, its track the annotation's ``track_id``
(or ``attributes.track_id``, or ``instance_id``), its box ``bbox``; with
``attributes.outside = true`` it marks the object absent. Annotations without
``keyframe: true`` are ignored: they are the tracker's boxes.

Parsing checks only the file itself; :func:`resolve_corrections` then checks
the corrections against a run (processed frames, track ids, frame size).
Every problem is a :class:`~annotator.errors.ToolError` with exit code 4
(invalid value) whose message starts with ``FILE:LINE:``.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from annotator.box_input import Box, BoxError, parse_box
from annotator.errors import EXIT_VALUE, ToolError
from annotator.text_input import read_given_file
from sptpt.boxes import lies_outside

__all__ = ["Correction", "CSV_HEADER", "read_corrections", "resolve_corrections"]

#: Column names of the CSV format (``track_id`` optional).
CSV_HEADER = ("frame", "x", "y", "w", "h", "track_id")
# Header names accepted for the optional last column.
_TRACK_NAMES = ("track_id", "track", "id")


@dataclass(frozen=True)
class Correction:
    """One corrected frame of one track.

    Attributes
    ----------
    frame : int
        Source frame index, 0-based.
    box_xywh : tuple of 4 floats, or None
        0-based ``x, y, w, h``; None marks the object absent from this frame
        until the track's next correction.
    track_id : int or None
        None when the file does not say (valid only for single-track runs).
    where : str
        ``FILE:LINE`` of the row, for error messages.
    """

    frame: int
    box_xywh: Box | None
    track_id: int | None
    where: str

    @property
    def absent(self) -> bool:
        return self.box_xywh is None


def read_corrections(path: str | os.PathLike) -> list[Correction]:
    """Read a corrections file (CSV or COCO, see the module docstring), in file order.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    list of Correction

    Raises
    ------
    ToolError
        Exit code 3 when the file cannot be read; 4 for a malformed row,
        naming ``FILE:LINE``, the value given and the value expected.
    """
    path = Path(path)
    text = read_given_file(path, what="corrections file",
                           expected="a CSV frame,x,y,w,h[,track_id] or a COCO annotations.json")
    head = text.lstrip()
    if head.startswith("<") or head.startswith("["):
        kind = "a CVAT XML" if head.startswith("<") else "a Label Studio JSON"
        raise ToolError(f"corrections file {path} looks like {kind} export: those are read back into the run they "
                        f"were exported from, with 'sptpt-annotate retrack OUT --corrections {path}'; here give a "
                        "CSV frame,x,y,w,h[,track_id] or a COCO file", EXIT_VALUE)
    if head.startswith("{"):
        corrections = _read_coco(path, text)
        if not corrections:
            raise ToolError(f"corrections file {path} holds no corrected box: mark the annotations you fixed with "
                            "attributes.keyframe = true", EXIT_VALUE)
        return corrections
    corrections = _read_csv(path, text)
    if not corrections:
        raise ToolError(f"corrections file {path} is empty: add a row frame,x,y,w,h[,track_id] for each box you "
                        "fixed", EXIT_VALUE)
    return corrections


# --------------------------------------------------------------------------- CSV


def _integer(text: str, where: str, column: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise ToolError(f"{where}: column {column!r} must be an integer >= {minimum}, got {text!r}",
                        EXIT_VALUE) from None
    if value < minimum:
        raise ToolError(f"{where}: column {column!r} must be an integer >= {minimum}, got {value}", EXIT_VALUE)
    return value


def _box(value: Any, name: str, where: str, absent: str) -> Box:
    """:func:`annotator.box_input.parse_box`, its message behind ``FILE:LINE`` and followed by how to say absent."""
    try:
        return parse_box(value, name=name)
    except BoxError as exc:
        raise ToolError(f"{where}: {exc}; {absent}", EXIT_VALUE) from None


def _is_header(row: list[str]) -> bool:
    return bool(row) and not re.fullmatch(r"[+-]?\d+", row[0].strip())


def _read_csv(path: Path, text: str) -> list[Correction]:
    corrections: list[Correction] = []
    reader = csv.reader(io.StringIO(text))
    seen_data = False
    for row in reader:
        line = reader.line_num
        where = f"{path}:{line}"
        fields = [f.strip() for f in row]
        if not fields or all(not f for f in fields) or fields[0].startswith("#"):
            continue
        if not seen_data and _is_header(fields):
            names = [f.lower() for f in fields]
            if (names[:5] != list(CSV_HEADER[:5]) or len(names) > 6
                    or (len(names) == 6 and names[5] not in _TRACK_NAMES)):
                raise ToolError(f"{where}: expected the header 'frame,x,y,w,h' or 'frame,x,y,w,h,track_id' "
                                f"(or no header), got {','.join(row)!r}", EXIT_VALUE)
            seen_data = True
            continue
        seen_data = True
        if len(fields) not in (5, 6):
            raise ToolError(f"{where}: expected 5 or 6 fields 'frame,x,y,w,h[,track_id]', got {len(fields)} in "
                            f"{','.join(row)!r}", EXIT_VALUE)
        frame = _integer(fields[0], where, "frame", 0)
        coords = fields[1:5]
        if all(not c for c in coords):
            box = None
        elif any(not c for c in coords):
            raise ToolError(f"{where}: x,y,w,h must be four numbers, or all four empty to mark the object absent; "
                            f"got {','.join(fields[1:5])!r}", EXIT_VALUE)
        else:
            box = _box(",".join(coords), "box", where, "leave x,y,w,h all empty to mark the object absent")
        track = None
        if len(fields) == 6 and fields[5]:
            track = _integer(fields[5], where, "track_id", 1)
        corrections.append(Correction(frame=frame, box_xywh=box, track_id=track, where=where))
    return corrections


# --------------------------------------------------------------------------- COCO


def _element_lines(text: str, key: str, count: int) -> list[int] | None:
    """1-based line of each element of the top-level list ``key``, or None when it cannot be located.

    ``json`` gives no positions for nested values, so the list is found by its
    key and decoded element by element with ``raw_decode``; the result is
    only used if it agrees with the parsed document's element count.
    """
    match = re.search(r'"' + re.escape(key) + r'"\s*:\s*\[', text)
    if match is None:
        return None
    decoder = json.JSONDecoder()
    pos, lines = match.end(), []
    try:
        while True:
            while pos < len(text) and text[pos] in " \t\r\n,":
                pos += 1
            if pos >= len(text) or text[pos] == "]":
                break
            lines.append(text.count("\n", 0, pos) + 1)
            _, pos = decoder.raw_decode(text, pos)
    except ValueError:
        return None
    return lines if len(lines) == count else None


def _read_coco(path: Path, text: str) -> list[Correction]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ToolError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg} at column {exc.colno}); expected a COCO "
                        "file such as the run's annotations.json", EXIT_VALUE) from None
    if not isinstance(data, dict) or not isinstance(data.get("annotations"), list) \
            or not isinstance(data.get("images"), list):
        raise ToolError(f"{path}:1: expected a COCO object with 'images' and 'annotations' lists "
                        "(such as the run's annotations.json)", EXIT_VALUE)
    videos = data.get("videos")
    if isinstance(videos, list) and len(videos) > 1:
        raise ToolError(f"{path}:1: holds {len(videos)} videos; corrections apply to one run: keep only the "
                        "run's video in the file", EXIT_VALUE)
    image_lines = _element_lines(text, "images", len(data["images"]))
    frames: dict = {}
    for k, image in enumerate(data["images"]):
        where = f"{path}:{image_lines[k]}" if image_lines else f"{path}: images[{k}]"
        if not isinstance(image, dict) or "id" not in image:
            raise ToolError(f"{where}: an image needs an 'id'", EXIT_VALUE)
        if not isinstance(image["id"], (int, float, str)) or isinstance(image["id"], bool):
            raise ToolError(f"{where}: an image 'id' must be a number or a string, got {image['id']!r}", EXIT_VALUE)
        if "frame_index" in image:
            frames[image["id"]] = image["frame_index"]
    lines = _element_lines(text, "annotations", len(data["annotations"]))
    corrections: list[Correction] = []
    for k, ann in enumerate(data["annotations"]):
        where = f"{path}:{lines[k]}" if lines else f"{path}: annotations[{k}]"
        if not isinstance(ann, dict):
            raise ToolError(f"{where}: an annotation must be a JSON object, got {type(ann).__name__}", EXIT_VALUE)
        attributes = ann.get("attributes") or {}
        if not isinstance(attributes, dict) or attributes.get("keyframe") is not True:
            continue
        if not isinstance(ann.get("image_id"), (int, float, str)) or ann["image_id"] not in frames:
            raise ToolError(f"{where}: annotation {ann.get('id')!r} refers to image {ann.get('image_id')!r}, which is "
                            "not among 'images' or has no 'frame_index' (the source frame index, as in the run's "
                            "annotations.json)", EXIT_VALUE)
        frame = frames[ann["image_id"]]
        if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
            raise ToolError(f"{where}: frame_index of image {ann['image_id']!r} must be an integer >= 0, "
                            f"got {frame!r}", EXIT_VALUE)
        track = _first_present(("track_id", ann), ("track_id", attributes), ("instance_id", ann))
        if track is not None and (isinstance(track, bool) or not isinstance(track, int) or track < 1):
            raise ToolError(f"{where}: track_id must be an integer >= 1, got {track!r}", EXIT_VALUE)
        if attributes.get("outside") is True:
            box = None
        else:
            box = _box(ann.get("bbox"), "bbox", where, "set attributes.outside to true to mark the object absent")
        corrections.append(Correction(frame=frame, box_xywh=box, track_id=track, where=where))
    return corrections


def _first_present(*places: tuple[str, dict]):
    """The value of the first ``(key, mapping)`` whose mapping holds the key, else None."""
    for key, mapping in places:
        if key in mapping:
            return mapping[key]
    return None


# --------------------------------------------------------------------------- against a run


def resolve_corrections(
    corrections: Sequence[Correction],
    *,
    frame_indices: np.ndarray,
    track_ids: Sequence[int],
    width: int,
    height: int,
) -> dict[int, dict[int, tuple[Box | None, str]]]:
    """Check corrections against a run and key them by track and processed-frame position.

    Parameters
    ----------
    corrections : sequence of Correction
    frame_indices : (F,) int ndarray
        Source indices of the run's processed frames, increasing.
    track_ids : sequence of int
        The run's tracks.
    width, height : int
        Frame size; a box must overlap the frame.

    Returns
    -------
    dict
        ``{track_id: {position: (box_xywh or None, where)}}``; ``position``
        is the row of the frame in the run's tracks (0 for the first processed frame).

    Raises
    ------
    ToolError
        Exit code 4, naming ``FILE:LINE``: a frame the run did not process, an
        unknown track id, a missing track id in a multi-track run, a box
        outside the frame, the same frame corrected twice for one track.
    """
    frame_indices = np.asarray(frame_indices, dtype=np.int64)
    ids = [int(t) for t in track_ids]
    position_of: Mapping[int, int] = {int(f): p for p, f in enumerate(frame_indices)}
    resolved: dict[int, dict[int, tuple[Box | None, str]]] = {t: {} for t in ids}
    for c in corrections:
        if c.track_id is None:
            if len(ids) != 1:
                raise ToolError(f"{c.where}: no track_id given, but the run has tracks {', '.join(map(str, ids))}: "
                                "add the track id as the 6th column", EXIT_VALUE)
            track = ids[0]
        elif c.track_id not in resolved:
            raise ToolError(f"{c.where}: unknown track id {c.track_id}: the run has track"
                            f"{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))}", EXIT_VALUE)
        else:
            track = c.track_id
        if c.frame not in position_of:
            raise ToolError(f"{c.where}: frame {c.frame} was not processed by the run ({_describe(frame_indices)}): "
                            "give a source frame index from the 'frame' column of flags.csv", EXIT_VALUE)
        if c.box_xywh is not None:
            if lies_outside(c.box_xywh, width, height):
                x, y, w, h = c.box_xywh
                raise ToolError(f"{c.where}: box {x:g},{y:g},{w:g},{h:g} lies outside the {width}x{height} frame: "
                                "give 0-based pixel coordinates, or leave x,y,w,h empty to mark the object absent",
                                EXIT_VALUE)
        position = position_of[c.frame]
        if position in resolved[track]:
            first = resolved[track][position][1]
            raise ToolError(f"{c.where}: frame {c.frame} of track {track} is corrected twice (also at {first}): "
                            "keep one row per frame and track", EXIT_VALUE)
        resolved[track][position] = (c.box_xywh, c.where)
    return resolved


def _describe(frame_indices: np.ndarray) -> str:
    n = len(frame_indices)
    if n == 0:
        return "no frames"
    if n == 1:
        return f"only frame {int(frame_indices[0])}"
    steps = np.unique(np.diff(frame_indices))
    step = f" every {int(steps[0])}" if len(steps) == 1 and steps[0] > 1 else ""
    return f"frames {int(frame_indices[0])} to {int(frame_indices[-1])}{step}"

"""What CVAT shows after "Upload annotations" of a CVAT for video 1.1 file: its import rule, replayed.

Written from CVAT's own code (cvat-ai/cvat), not from our reader, so that a test of our ``cvat.xml`` sees what a
reviewer sees:

* ``cvat/apps/dataset_manager/formats/cvat.py``, ``load``: a ``<box>`` of a ``<track>`` is kept only when
  ``keyframe == "1"`` (``if shape["keyframe"]: track.shapes.append(...)``); every other box of a track is dropped.
  ``outside`` is ``attrib["outside"] == "1"``.
* ``cvat/apps/dataset_manager/bindings.py``, ``rel_frame_id``: an absolute frame ``f`` of the file becomes the
  task's frame ``(f - start_frame) / step``, refused unless it divides evenly and lies in ``0 .. size - 1``.
* ``cvat/apps/dataset_manager/annotation.py``, ``TrackManager.get_interpolated_shapes``: keyframes sorted by frame;
  between two consecutive keyframes each frame gets ``points0 + (points1 - points0) * (frame - frame0) /
  (frame1 - frame0)`` with the first keyframe's ``outside`` (``copy_shape(shape0, ...)``); older releases hold
  ``points0`` instead when the second keyframe is ``outside`` (``hold_before_outside``). After the last keyframe,
  a shape that is not outside is held to the end of the task. Outside shapes are not shown.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np


def cvat_shown_boxes(path: str | Path, *, hold_before_outside: bool = False) -> list[dict[int, np.ndarray | None]]:
    """Per ``<track>`` of the file, in order: task frame -> the ``xtl, ytl, xbr, ybr`` CVAT shows, None if hidden.

    Every task frame ``0 .. size - 1`` has an entry.
    """
    root = ET.parse(path).getroot()
    task = root.find("meta/task")
    size = int(task.findtext("size"))
    start = int(task.findtext("start_frame") or 0)
    step_text = (task.findtext("frame_filter") or "").strip()
    step = int(step_text.split("=")[1]) if step_text else 1
    shown = []
    for track in root.findall("track"):
        keys = []
        for box in track.findall("box"):
            if box.attrib["keyframe"] != "1":
                continue
            relative, rest = divmod(int(box.attrib["frame"]) - start, step)
            assert rest == 0 and 0 <= relative < size, f"CVAT refuses frame {box.attrib['frame']}"
            points = np.array([float(box.attrib[k]) for k in ("xtl", "ytl", "xbr", "ybr")])
            keys.append((relative, points, box.attrib["outside"] == "1"))
        keys.sort(key=lambda k: k[0])
        boxes: dict[int, np.ndarray | None] = {f: None for f in range(size)}
        for (f0, p0, out0), (f1, p1, out1) in zip(keys[:-1], keys[1:]):
            for frame in range(f0, f1):
                if hold_before_outside and out1:
                    points = p0
                else:
                    points = p0 + (p1 - p0) * ((frame - f0) / (f1 - f0))
                boxes[frame] = None if out0 else points
        if keys:
            f_last, p_last, out_last = keys[-1]
            for frame in range(f_last, size):
                boxes[frame] = None if out_last else p_last
        shown.append(boxes)
    return shown


def cvat_keyframe_count(path: str | Path) -> int:
    """Keyframes in the file (a reviewer's handles)."""
    return sum(box.attrib["keyframe"] == "1" for box in ET.parse(path).getroot().iter("box"))


def cvat_worst_error(path: str | Path, tracks, frames: range, *, hold_before_outside: bool = False) -> float:
    """The largest corner difference, in pixels, between what CVAT shows and the tracks' boxes, over every task frame.

    ``tracks`` are the run's TrackResults in the file's order (tracks never seen are not in the file). A frame
    where CVAT shows a box and the track has none, or the other way round, fails the assertion.
    """
    shown = cvat_shown_boxes(path, hold_before_outside=hold_before_outside)
    seen = [t for t in tracks if (~t.outside & np.isfinite(t.boxes_xywh).all(axis=1)).any()]
    assert len(shown) == len(seen), (len(shown), len(seen))
    worst = 0.0
    for boxes, track in zip(shown, seen):
        rows = {int(f): i for i, f in enumerate(track.frame_indices)}
        for position, frame in enumerate(frames):
            i = rows.get(frame)
            expected = None
            if i is not None and not track.outside[i] and np.isfinite(track.boxes_xywh[i]).all():
                x, y, w, h = track.boxes_xywh[i]
                expected = np.array([x, y, x + w, y + h])
            got = boxes[position]
            assert (got is None) == (expected is None), \
                f"track {track.track_id}, frame {frame}: CVAT shows {got}, the run has {expected}"
            if got is not None:
                worst = max(worst, float(np.abs(got - expected).max()))
    return worst

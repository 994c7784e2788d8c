"""MOTChallenge ground truth (``mot/gt/gt.txt`` and ``mot/gt/labels.txt``), in MOTChallenge's 1-based pixels.

``gt.txt`` has one row per object per frame where the object is present::

    frame,track_id,x,y,w,h,not_ignored,class_id,visibility

* ``frame`` is 1-based: the frame's position in the processed range + 1
  (the image ``img1/000001.jpg`` of a MOT sequence made of the processed
  frames). With ``--start``/``--step`` it differs from the source index:
  source = start + (frame - 1) * step.
* ``track_id`` is ``TrackResult.track_id``.
* ``x, y, w, h``: the box, not clipped (MOTChallenge ground truth keeps
  boxes that leave the image), 3 decimals. ``x, y`` (``bb_left, bb_top``)
  are **1-based**, as MOTChallenge defines them: its evaluation
  (motmetrics' ``loadtxt(fmt="mot15-2D")``) subtracts 1, so a
  0-based box ``x`` is written ``x + 1``. CVAT's "MOT 1.1" importer and
  Datumaro's ``mot_seq`` take ``x, y`` as written, with no shift: in CVAT
  review with ``cvat.xml`` instead, which CVAT reads to the pixel.
  ``origin=0`` writes 0-based pixels for a tool that wants them.
* ``not_ignored`` is 1; ``class_id`` indexes ``labels.txt`` from 1 (datumaro
  reads ``class_id - 1``); ``visibility`` is 1, or 0 for an occluded box
  (datumaro's ``1 - occluded``).
* No row where the object is absent (``outside``) or has no estimate (NaN):
  MOT has no absent box; the flags file records absences.

Rows are sorted by frame, then track id. ``labels.txt`` holds one label a
line in order of first appearance over the tracks.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from annotator.atomic import write_text_atomic
from annotator.exports.review_tools import check_frame_range, labels_in_order, number, positions, visible
from annotator.tracks import TrackResult, VideoInfo

__all__ = ["build_mot_gt", "write_mot"]


def build_mot_gt(video: VideoInfo, tracks: Sequence[TrackResult], *, frames: range | None = None,
                 origin: int = 1) -> tuple[str, str]:
    """The text of ``gt.txt`` and ``labels.txt`` (layout in the module docstring).

    Parameters
    ----------
    video : VideoInfo
    tracks : sequence of TrackResult
        Written with their own ids as ``track_id``; their labels numbered for ``class_id``.
    frames : range or None
        The processed range of source frame indices, whose positions are MOT's frame numbers; None for the
        whole video.
    origin : {1, 0}
        Pixel origin of ``x, y``: 1 as MOTChallenge (the default), 0 for tools that read them unshifted.
    """
    if origin not in (0, 1):
        raise ValueError(f"origin must be 1 (MOTChallenge) or 0 (unshifted), got {origin!r}")
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    labels = labels_in_order(tracks) or ["object"]
    class_id = {label: n for n, label in enumerate(labels, start=1)}
    rows = []
    for track in tracks:
        shown = visible(track)
        for i, position in enumerate(positions(frames, track)):
            if not shown[i]:
                continue
            x, y, w, h = track.boxes_xywh[i]
            rows.append((int(position) + 1, track.track_id, x + origin, y + origin, w, h, class_id[track.label],
                         0 if track.occluded[i] else 1))
    rows.sort(key=lambda r: (r[0], r[1]))
    gt = "".join(f"{f},{t},{number(x)},{number(y)},{number(w)},{number(h)},1,{c},{v}\n"
                 for f, t, x, y, w, h, c, v in rows)
    return gt, "".join(f"{label}\n" for label in labels)


def write_mot(out_dir: str | os.PathLike, video: VideoInfo, tracks: Sequence[TrackResult], *,
              frames: range | None = None, origin: int = 1) -> list[Path]:
    """Write ``out_dir/gt/gt.txt`` and ``out_dir/gt/labels.txt`` atomically; return their paths.

    ``out_dir`` is the sequence folder (``<out>/mot``); keywords as :func:`build_mot_gt`.
    """
    gt, labels = build_mot_gt(video, tracks, frames=frames, origin=origin)
    gt_dir = Path(out_dir) / "gt"
    gt_dir.mkdir(parents=True, exist_ok=True)
    written = [gt_dir / "gt.txt", gt_dir / "labels.txt"]
    write_text_atomic(written[0], gt)
    write_text_atomic(written[1], labels)
    return written

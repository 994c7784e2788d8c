"""Label Studio video object tracking tasks (``labelstudio.json``): one ``videorectangle`` region per track.

Import the file into a project whose labeling config is the one written
beside it, ``labelstudio_config.xml`` (:func:`build_labelstudio_config`: the
``<Labels>`` of the run, the ``<Video>`` with the video's frame rate, which
Label Studio needs to map its frame numbers to time, and the
``<VideoRectangle>``).

The file is a list with one task: ``data.video`` (the URL given with
``--media-url``, else the video's path, which a Label Studio server cannot
play: see ``docs/review-tools.md``),
``data.sptpt`` (the video's name, size, frame count and fps and the
processed range, which the importer checks), and the tracks as
``predictions`` (pre-annotations a reviewer accepts and edits).

Each region's ``value`` holds ``framesCount`` (the video's decoded frame
count), ``duration`` (frames / fps, seconds), ``labels`` and a ``sequence``
of keyframes ``{frame, x, y, width, height, rotation, enabled, time}``:

* ``frame`` is 1-based in the **source video** (source index + 1), because
  Label Studio plays the whole video file, whatever range was processed;
  ``time = frame / fps`` as Label Studio writes it. Frames outside the
  processed range are simply not keyframes.
* ``x, y, width, height`` are percent of the frame size, of the box clipped
  to the image; ``rotation`` 0.
* Label Studio shows a box from an ``enabled`` keyframe until the next
  keyframe, interpolating linearly, and shows an ``enabled: false`` keyframe
  at its own frame only (``isInLifespan``). So an absence is an ``enabled:
  false`` keyframe on the last frame the object is seen, and an ``enabled``
  keyframe where it comes back; absent frames have no keyframe.

Which rows become keyframes: the first frame the object is seen, human
corrections, the start of each flagged span and the first frame after it,
where the object leaves and comes back, the last processed frame of the
track (``enabled: false`` when the track ends before the range does), and,
between those, as few extra frames as keep Label Studio's linear
interpolation within ``max_error_px`` of the tracker's box on every
processed frame (Ramer-Douglas-Peucker on the four coordinates). Inside a
flagged span no extra keyframes are added: a reviewer redraws it anyway.
"""

from __future__ import annotations

import json
import os
from typing import Any, Sequence
from xml.sax.saxutils import quoteattr

import numpy as np

from annotator.atomic import write_text_atomic
from annotator.exports.review_tools import check_frame_range, labels_in_order, number, review_keyframes
from annotator.tracks import TrackResult, VideoInfo
from sptpt.boxes import clip_xywh

__all__ = ["LS_FROM_NAME", "LS_TO_NAME", "LS_LABELS_NAME", "LS_MODEL_VERSION", "build_labelstudio_config",
           "build_labelstudio_tasks", "media_url_for", "write_labelstudio", "labelstudio_region_id"]

#: ``name`` of the ``<VideoRectangle>`` and of the ``<Video>`` tag in the labeling config.
LS_FROM_NAME = "box"
LS_TO_NAME = "video"
#: ``name`` of the ``<Labels>`` tag.
LS_LABELS_NAME = "videoLabels"
LS_MODEL_VERSION = "sptpt-annotate"
_PERCENT_DECIMALS = 6  # 1e-6 % of a 4K frame is 4e-5 px: the round trip through percent stays exact enough


def labelstudio_region_id(track_id: int) -> str:
    """Region id of a track; Label Studio keeps it when a reviewer accepts and edits a prediction."""
    return f"track-{int(track_id)}"


def _simplify(frames: np.ndarray, boxes: np.ndarray, first: int, last: int, max_error_px: float,
              out: set[int]) -> None:
    """Add to ``out`` the rows between ``first`` and ``last`` that keep linear interpolation within tolerance."""
    stack = [(first, last)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        t = (frames[a + 1:b] - frames[a]) / (frames[b] - frames[a])
        guess = boxes[a] + t[:, None] * (boxes[b] - boxes[a])
        error = np.abs(guess - boxes[a + 1:b]).max(axis=1)
        worst = int(np.argmax(error))
        if error[worst] > max_error_px:
            k = a + 1 + worst
            out.add(k)
            stack += [(a, k), (k, b)]


def _sequence(track: TrackResult, video: VideoInfo, frames: range, max_error_px: float) -> list[dict]:
    n = len(track)
    clipped = [None if track.outside[i] else clip_xywh(track.boxes_xywh[i], video.width, video.height)
               for i in range(n)]
    shown = np.array([c is not None for c in clipped], dtype=bool)
    if not shown.any():
        return []
    boxes = np.array([c if c is not None else (np.nan,) * 4 for c in clipped], dtype=np.float64)
    before = np.concatenate([[False], shown[:-1]])
    after = np.concatenate([shown[1:], [False]])
    flagged_before = np.concatenate([[False], track.flagged[:-1]])
    leaves = shown & ~after & (np.arange(n) < n - 1)
    ends_early = int(track.frame_indices[-1]) != frames[-1]
    if ends_early:
        leaves[-1] = shown[-1]
    keys = review_keyframes(track) | (flagged_before & ~track.flagged) | (shown & ~before) | leaves
    keys[-1] = True
    keys &= shown
    rows = set(np.flatnonzero(keys).tolist())
    # Extra keyframes only inside unflagged stretches where the object is seen throughout.
    ordered = sorted(rows)
    for a, b in zip(ordered[:-1], ordered[1:]):
        if shown[a:b + 1].all() and not track.flagged[a + 1:b].any():
            _simplify(track.frame_indices.astype(np.float64), boxes, a, b, max_error_px, rows)
    sequence = []
    for i in sorted(rows):
        frame = int(track.frame_indices[i]) + 1
        x, y, w, h = boxes[i]
        sequence.append({
            "frame": frame,
            "x": round(100.0 * x / video.width, _PERCENT_DECIMALS),
            "y": round(100.0 * y / video.height, _PERCENT_DECIMALS),
            "width": round(100.0 * w / video.width, _PERCENT_DECIMALS),
            "height": round(100.0 * h / video.height, _PERCENT_DECIMALS),
            "rotation": 0,
            "enabled": not bool(leaves[i]),
            "time": round(frame / video.fps, 6),
        })
    return sequence


def media_url_for(media_url: str | None, video_path: str) -> str | None:
    """``data.video`` for ``--media-url``: the URL as given, or with the video's file name appended when it ends
    with ``/`` or ``=`` (a folder, or ``/data/local-files/?d=videos/``, shared by a batch's videos)."""
    if media_url is None:
        return None
    return media_url + os.path.basename(video_path) if media_url.endswith(("/", "=")) else media_url


def build_labelstudio_config(video: VideoInfo, tracks: Sequence[TrackResult]) -> str:
    """The labeling config of a Label Studio project for :func:`build_labelstudio_tasks` (``labelstudio_config.xml``).

    ``<Labels>`` lists the run's labels (in the COCO exporter's order),
    ``<Video framerate>`` is the video's frame rate (Label Studio turns time
    into frame numbers with it: a wrong one shifts every box), and the
    ``<VideoRectangle>`` and ``<Video>`` names are those the task's regions use.

    Returns
    -------
    str
        The XML, ending with a newline; paste it into the project's
        Settings > Labeling Interface > Code, or send it as ``label_config``.
    """
    labels = labels_in_order(list(tracks)) or ["object"]
    lines = ["<View>", f'  <Labels name="{LS_LABELS_NAME}" toName="{LS_TO_NAME}" allowEmpty="true">']
    lines += [f"    <Label value={quoteattr(label)}/>" for label in labels]
    lines += ["  </Labels>",
              f'  <Video name="{LS_TO_NAME}" value="$video" framerate="{number(video.fps, 6)}"/>',
              f'  <VideoRectangle name="{LS_FROM_NAME}" toName="{LS_TO_NAME}"/>',
              "</View>"]
    return "\n".join(lines) + "\n"


def build_labelstudio_tasks(video: VideoInfo, tracks: Sequence[TrackResult], *, frames: range | None = None,
                            video_url: str | None = None, max_error_px: float = 2.0) -> list[dict[str, Any]]:
    """The Label Studio task list of one video (layout in the module docstring).

    Parameters
    ----------
    video : VideoInfo
    tracks : sequence of TrackResult
        One region each, with the id :func:`labelstudio_region_id` gives.
    frames : range or None
        The processed range of source frame indices; None for the whole video.
    video_url : str or None
        ``data.video``: where Label Studio finds the video (a URL or
        ``/data/local-files/?d=...``); None writes ``video.path``.
    max_error_px : float
        Largest gap, in pixels, between Label Studio's interpolation and the
        tracker's box on any unflagged processed frame; smaller adds keyframes.

    Returns
    -------
    list of dict
        One task; plain Python types, ready for ``json.dump``.
    """
    if not (max_error_px > 0):
        raise ValueError(f"max_error_px must be > 0 pixels, got {max_error_px!r}")
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    results = []
    for track in tracks:
        sequence = _sequence(track, video, frames, max_error_px)
        if not sequence:
            continue  # never seen: Label Studio cannot hold a region without a box
        results.append({
            "id": labelstudio_region_id(track.track_id),
            "type": "videorectangle",
            "from_name": LS_FROM_NAME,
            "to_name": LS_TO_NAME,
            "origin": "prediction",
            "value": {
                "framesCount": video.frame_count,
                "duration": round(video.frame_count / video.fps, 6),
                "sequence": sequence,
                "labels": [track.label],
            },
        })
    return [{
        "data": {
            "video": video.path if video_url is None else str(video_url),
            "sptpt": {
                "video": video.name, "width": video.width, "height": video.height, "fps": video.fps,
                "frame_count": video.frame_count, "start": frames.start, "stop": frames.stop, "step": frames.step,
            },
        },
        "predictions": [{"model_version": LS_MODEL_VERSION, "result": results}],
    }]


def write_labelstudio(path: str | os.PathLike, video: VideoInfo, tracks: Sequence[TrackResult], *,
                      frames: range | None = None, video_url: str | None = None,
                      max_error_px: float = 2.0, config_path: str | os.PathLike | None = None) -> list[dict[str, Any]]:
    """Write :func:`build_labelstudio_tasks` to ``path`` (``<out>/labelstudio.json``) atomically; return the tasks.

    With ``config_path``, the labeling config (:func:`build_labelstudio_config`) is written there too.
    """
    tasks = build_labelstudio_tasks(video, tracks, frames=frames, video_url=video_url, max_error_px=max_error_px)
    if config_path is not None:
        write_text_atomic(config_path, build_labelstudio_config(video, tracks))
    write_text_atomic(path, json.dumps(tasks, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    return tasks

"""YOLO detection labels (``yolo/labels/<frame>.txt``, ``yolo/data.yaml``, ``yolo/frames.txt``).

* One label file per processed frame, named like the COCO exporter's image
  ``file_name`` stem. For a video: the source frame index, 6 digits
  (``000042.txt``), which is what ``ffmpeg -i VIDEO -fps_mode passthrough
  -start_number 0 yolo/images/%06d.jpg`` names the decoded frames (without
  passthrough, ffmpeg duplicates or drops frames of a variable frame rate
  video). For an image folder: the image's own stem (``0001.txt`` for
  ``0001.jpg``), so the labels pair with the user's images; if two images
  share a stem, the index names. YOLO trainers find ``labels/000042.txt``
  for ``images/000042.jpg``.
* A row ``class cx cy w h`` per object present in the frame: class 0.. in
  order of first appearance of the labels over the tracks (``names``),
  centre and size normalised by the frame size, after clipping the box to
  the image, 6 decimals. A frame with no box has an empty file: YOLO reads
  it as a background image, which it is.
* Absent (``outside``), NaN and wholly off-image boxes get no row.
* ``frames.txt`` lists the processed frames' images (``./images/000042.jpg``)
  and ``data.yaml`` points ``train`` and ``val`` at it, so that with
  ``--step`` the frames that were not tracked, which ffmpeg also extracts,
  are not taken for background. ``data.yaml`` has no ``path``: Ultralytics
  then resolves the lists relative to the folder holding ``data.yaml``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

from annotator.atomic import write_text_atomic
from annotator.exports.review_tools import check_frame_range, labels_in_order, number
from annotator.tracks import TrackResult, VideoInfo
from sptpt.boxes import clip_xywh

__all__ = ["yolo_frame_stem", "build_yolo_labels", "write_yolo"]

_DECIMALS = 6  # normalised units: 1e-6 of a 4K frame is far below a pixel


def yolo_frame_stem(frame_index: int) -> str:
    """File stem of a video's frame: the COCO exporter's image name without folder and extension."""
    return f"{int(frame_index):06d}"


def _image_names(video: VideoInfo, frames: Sequence[int]) -> dict[int, str] | None:
    """For an image folder, each frame's own image name (``0001.jpg``), so labels pair with the user's images.

    None for a video, or when two images share a stem (``0001.jpg`` and ``0001.png``): a label file
    cannot tell them apart, and the index names are used instead.
    """
    if video.frame_files is None:
        return None
    names = {int(f): Path(video.frame_files[int(f)]).name for f in frames}
    stems = [Path(name).stem for name in names.values()]
    return names if len(set(stems)) == len(stems) else None


def build_yolo_labels(video: VideoInfo, tracks: Sequence[TrackResult], *,
                      frames: range | None = None) -> tuple[dict[str, str], list[str]]:
    """``({stem: label file text}, names)`` for every processed frame (layout in the module docstring)."""
    texts, names = _label_texts(video, tracks, frames)
    return _by_stem(texts, _image_names(video, list(texts))), names


def _label_texts(video: VideoInfo, tracks: Sequence[TrackResult],
                 frames: range | None) -> tuple[dict[int, str], list[str]]:
    """``({source frame: label file text}, names)`` for every processed frame."""
    tracks = list(tracks)
    frames = check_frame_range(video, tracks, frames)
    names = labels_in_order(tracks) or ["object"]
    class_of = {label: n for n, label in enumerate(names)}
    rows: dict[int, list[str]] = {int(f): [] for f in frames}
    for track in tracks:
        for i, frame in enumerate(track.frame_indices):
            if track.outside[i]:
                continue
            box = clip_xywh(track.boxes_xywh[i], video.width, video.height)
            if box is None:
                continue
            x, y, w, h = box
            values = ((x + w / 2) / video.width, (y + h / 2) / video.height, w / video.width, h / video.height)
            rows[int(frame)].append(f"{class_of[track.label]} " + " ".join(number(v, _DECIMALS) for v in values))
    return {f: "".join(r + "\n" for r in lines) for f, lines in rows.items()}, names


def _by_stem(texts: dict[int, str], images: dict[int, str] | None) -> dict[str, str]:
    """The label texts keyed by file stem: the image's own (image folders), else the frame index's."""
    stem = (lambda f: Path(images[f]).stem) if images is not None else yolo_frame_stem
    return {stem(f): text for f, text in texts.items()}


def write_yolo(out_dir: str | os.PathLike, video: VideoInfo, tracks: Sequence[TrackResult], *,
               frames: range | None = None) -> list[Path]:
    """Write the label files, ``frames.txt`` and ``data.yaml`` under ``out_dir`` (``<out>/yolo``), each atomically.

    Returns
    -------
    list of Path
        ``data.yaml``, ``frames.txt``, then the label files in frame order.
    """
    labels, names = build_yolo_labels(video, tracks, frames=frames)
    images = _image_names(video, list(check_frame_range(video, list(tracks), frames)))
    if images is not None:
        image_files = list(images.values())
        assert video.frame_files is not None  # the names are the frame files'
        folder = json.dumps(Path(video.frame_files[0]).parent.as_posix(), ensure_ascii=False)
        how = f"# Copy or link the sequence's images ({folder}, as named in frames.txt) into images/ here\n"
    else:
        image_files = [f"{stem}.jpg" for stem in labels]
        how = ("# Copy the sequence's images into images/ here, named by frame index (000000.jpg, ...): two of them "
               "share a name stem\n" if video.frame_files is not None else
               "# Extract the frames with: ffmpeg -i VIDEO -fps_mode passthrough -start_number 0 images/%06d.jpg "
               "(from this folder; ffmpeg before 5.1: -vsync passthrough)\n")
    out_dir = Path(out_dir)
    (out_dir / "labels").mkdir(parents=True, exist_ok=True)
    written = [out_dir / "data.yaml", out_dir / "frames.txt"]
    for stem, text in labels.items():
        path = out_dir / "labels" / f"{stem}.txt"
        write_text_atomic(path, text)
        written.append(path)
    write_text_atomic(written[1], "".join(f"./images/{name}\n" for name in image_files))
    # JSON strings are valid YAML scalars: quoting through json keeps any label name safe.
    names_yaml = "".join(f"  {n}: {json.dumps(name, ensure_ascii=False)}\n" for n, name in enumerate(names))
    data_yaml = (
        f"# YOLO dataset of {json.dumps(video.name, ensure_ascii=False)} written by sptpt-annotate.\n"
        + how +
        "train: frames.txt\n"
        "val: frames.txt\n"
        f"nc: {len(names)}\n"
        f"names:\n{names_yaml}"
    )
    write_text_atomic(written[0], data_yaml)
    return written

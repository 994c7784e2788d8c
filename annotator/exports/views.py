"""Every file export is a view of track stores: ``write_exports(out_dir, store, formats)`` for one run,
``write_dataset_exports(out_dir, stores, formats)`` for a batch's merged files.

Each format is a function from the :class:`~annotator.track_store.RunStore` (or
the stores of a batch's items) to its files, nothing else: no tracking, no
reading of other exports. The main command, ``retrack`` and batch all write
exports through here, so a format added to :data:`FILE_EXPORTS` appears
everywhere at once.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

from annotator.atomic import write_text_atomic
from annotator.exports.coco import build_coco, merge_coco, save_coco, write_coco
from annotator.exports.cvat import cvat_keyframes, write_cvat_xml
from annotator.exports.flags import write_flags_csv
from annotator.exports.labelstudio import build_labelstudio_tasks, media_url_for, write_labelstudio
from annotator.exports.mot import write_mot
from annotator.exports.otb import write_otb_results
from annotator.exports.yolo import write_yolo
from annotator.output_files import (
    COCO_NAME,
    CVAT_NAME,
    FLAGS_NAME,
    LABELSTUDIO_CONFIG,
    LABELSTUDIO_NAME,
    MOT_FOLDER,
    YOLO_FOLDER,
)
from annotator.track_store import RunStore

__all__ = ["DATASET_EXPORTS", "ExportOptions", "FILE_EXPORTS", "LABELSTUDIO_CONFIG", "REVIEW_EXPORTS_KEPT",
           "record_review_exports", "write_dataset_exports", "write_exports"]

#: How many versions of the run's cvat.xml keyframes run.json keeps (one per re-track that changed them): a
#: reviewer's file is compared with the version it was made from, which may predate the last few re-tracks.
REVIEW_EXPORTS_KEPT = 50



@dataclass(frozen=True)
class ExportOptions:
    """What a view needs beyond the store; kept in run.json so that a re-track writes the same."""

    #: ``data.video`` of the Label Studio task (``--media-url``; a trailing ``/`` or ``=`` gets the video's file
    #: name); None writes the video's path.
    media_url: str | None = None


def _otb(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return write_otb_results(out_dir, store.video.name, store.tracks)


def _coco(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    write_coco(out_dir / COCO_NAME, store.video, store.tracks)
    return [out_dir / COCO_NAME]


def _flags(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    write_flags_csv(out_dir / FLAGS_NAME, store.tracks)
    return [out_dir / FLAGS_NAME]


def _frames(store: RunStore) -> range:
    return range(store.start, store.stop, store.step)


def _cvat(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return [write_cvat_xml(out_dir / CVAT_NAME, store.video, store.tracks, frames=_frames(store))]


def _mot(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return write_mot(out_dir / MOT_FOLDER, store.video, store.tracks, frames=_frames(store))


def _labelstudio(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    write_labelstudio(out_dir / LABELSTUDIO_NAME, store.video, store.tracks, frames=_frames(store),
                      video_url=media_url_for(options.media_url, store.video.path),
                      config_path=out_dir / LABELSTUDIO_CONFIG)
    return [out_dir / LABELSTUDIO_NAME, out_dir / LABELSTUDIO_CONFIG]


def _yolo(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return write_yolo(out_dir / YOLO_FOLDER, store.video, store.tracks, frames=_frames(store))


#: ``--formats`` value -> view writing its files into a folder and returning their paths.
FILE_EXPORTS: Mapping[str, Callable[[Path, RunStore, ExportOptions], list[Path]]] = {
    "otb": _otb,
    "coco": _coco,
    "flags": _flags,
    "cvat": _cvat,
    "mot": _mot,
    "labelstudio": _labelstudio,
    "yolo": _yolo,
}


def write_exports(out_dir: str | os.PathLike, store: RunStore, formats: Sequence[str],
                  options: ExportOptions | None = None) -> dict[str, list[Path]]:
    """Write the file exports among ``formats`` (others, such as ``overlay``, are skipped) into ``out_dir``."""
    out_dir = Path(out_dir)
    options = options or ExportOptions()
    return {name: FILE_EXPORTS[name](out_dir, store, options) for name in formats if name in FILE_EXPORTS}


def _dataset_coco(out_dir: Path, stores: Sequence[RunStore], options: ExportOptions) -> list[Path]:
    """All items' tracks as one COCO file, ids renumbered to be unique across videos."""
    if stores:
        merged = merge_coco([build_coco(store.video, store.tracks) for store in stores])
        merged["info"]["description"] = f"sptpt-annotate boxes for {len(merged['videos'])} videos"
    else:
        merged = {"info": {"description": "sptpt-annotate boxes for 0 videos", "contributor": "sptpt-annotate",
                           "bbox_format": "xywh, 0-based pixels"},
                  "licenses": [], "categories": [], "videos": [], "images": [], "tracks": [], "annotations": []}
    save_coco(out_dir / COCO_NAME, merged)
    return [out_dir / COCO_NAME]


def _dataset_labelstudio(out_dir: Path, stores: Sequence[RunStore], options: ExportOptions) -> list[Path]:
    """One Label Studio task list for the whole batch: every item's task, in the stores' order."""
    tasks = [task for store in stores for task in build_labelstudio_tasks(
        store.video, store.tracks, frames=_frames(store), video_url=media_url_for(options.media_url, store.video.path))]
    write_text_atomic(out_dir / LABELSTUDIO_NAME,
                      json.dumps(tasks, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    return [out_dir / LABELSTUDIO_NAME]


#: ``--formats`` value -> view of several runs' stores (a batch's items, each video named for its item) as one
#: file; the other formats are one file per video and stay in the items' folders.
DATASET_EXPORTS: Mapping[str, Callable[[Path, Sequence[RunStore], ExportOptions], list[Path]]] = {
    "coco": _dataset_coco,
    "labelstudio": _dataset_labelstudio,
}


def write_dataset_exports(out_dir: str | os.PathLike, stores: Sequence[RunStore], formats: Sequence[str],
                          options: ExportOptions | None = None) -> dict[str, list[Path]]:
    """Write the merged exports among ``formats`` of several runs' ``stores`` into ``out_dir``."""
    out_dir = Path(out_dir)
    options = options or ExportOptions()
    return {name: DATASET_EXPORTS[name](out_dir, stores, options) for name in formats if name in DATASET_EXPORTS}


def record_review_exports(previous: Mapping | None, store: RunStore, formats: Sequence[str]) -> dict | None:
    """run.json's ``review_exports``: the keyframes of every ``cvat.xml`` the run wrote, oldest first.

    A reviewer's CVAT file carries the keyframes it was given; only those a
    person changed are corrections, and the run's own keyframes change with
    each re-track, so each version is kept (a new one only when it differs
    from the last, at most :data:`REVIEW_EXPORTS_KEPT`). Label Studio needs no
    record: its export carries the prediction each annotation started from.

    Returns
    -------
    dict or None
        ``{"cvat": [version, ...]}`` (see :func:`annotator.exports.cvat.cvat_keyframes`), or ``previous`` as it
        was when this run writes no ``cvat.xml``.
    """
    record = dict(previous or {})
    if "cvat" not in formats:
        return record or None
    versions = list(record.get("cvat") or [])
    latest = json.loads(json.dumps(cvat_keyframes(store.video, store.tracks, frames=_frames(store))))
    if not versions or versions[-1] != latest:
        versions.append(latest)
    record["cvat"] = versions[-REVIEW_EXPORTS_KEPT:]
    return record

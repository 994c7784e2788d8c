"""Every file export is a view of the run's track store: ``write_exports(out_dir, store, formats)``.

Each format is a function from the :class:`~annotator.store.RunStore` to its
files, nothing else: no tracking, no reading of other exports. The main
command, ``retrack`` and batch all write exports through here, so a format
added to :data:`FILE_EXPORTS` appears everywhere at once.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

from annotator.exports.coco import write_coco
from annotator.exports.cvat import cvat_keyframes, write_cvat_xml
from annotator.exports.flags import write_flags_csv
from annotator.exports.labelstudio import media_url_for, write_labelstudio
from annotator.exports.mot import write_mot
from annotator.exports.otb import write_otb_results
from annotator.exports.yolo import write_yolo
from annotator.store import RunStore

__all__ = ["ExportOptions", "FILE_EXPORTS", "LABELSTUDIO_CONFIG", "REVIEW_EXPORTS_KEPT", "record_review_exports",
           "write_exports"]

#: How many versions of the run's cvat.xml keyframes run.json keeps (one per re-track that changed them): a
#: reviewer's file is compared with the version it was made from, which may predate the last few re-tracks.
REVIEW_EXPORTS_KEPT = 50

#: The Label Studio labeling config written beside ``labelstudio.json``.
LABELSTUDIO_CONFIG = "labelstudio_config.xml"


@dataclass(frozen=True)
class ExportOptions:
    """What a view needs beyond the store; kept in run.json so that a re-track writes the same."""

    #: ``data.video`` of the Label Studio task (``--media-url``; a trailing ``/`` or ``=`` gets the video's file
    #: name); None writes the video's path.
    media_url: str | None = None


def _otb(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return write_otb_results(out_dir, store.video.name, store.tracks)


def _coco(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    write_coco(out_dir / "annotations.json", store.video, store.tracks)
    return [out_dir / "annotations.json"]


def _flags(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    write_flags_csv(out_dir / "flags.csv", store.tracks)
    return [out_dir / "flags.csv"]


def _frames(store: RunStore) -> range:
    return range(store.start, store.stop, store.step)


def _cvat(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return [write_cvat_xml(out_dir / "cvat.xml", store.video, store.tracks, frames=_frames(store))]


def _mot(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return write_mot(out_dir / "mot", store.video, store.tracks, frames=_frames(store))


def _labelstudio(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    write_labelstudio(out_dir / "labelstudio.json", store.video, store.tracks, frames=_frames(store),
                      video_url=media_url_for(options.media_url, store.video.path),
                      config_path=out_dir / LABELSTUDIO_CONFIG)
    return [out_dir / "labelstudio.json", out_dir / LABELSTUDIO_CONFIG]


def _yolo(out_dir: Path, store: RunStore, options: ExportOptions) -> list[Path]:
    return write_yolo(out_dir / "yolo", store.video, store.tracks, frames=_frames(store))


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

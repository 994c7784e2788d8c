"""Every file export is a view of the run's track store: ``write_exports(out_dir, store, formats)``.

Each format is a function from the :class:`~annotator.store.RunStore` to its
files, nothing else: no tracking, no reading of other exports. The main
command, ``retrack`` and batch all write exports through here, so a format
added to :data:`FILE_EXPORTS` appears everywhere at once.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Mapping, Sequence

from annotator.exports.coco import write_coco
from annotator.exports.cvat import write_cvat_xml
from annotator.exports.flags import write_flags_csv
from annotator.exports.labelstudio import write_labelstudio
from annotator.exports.mot import write_mot
from annotator.exports.otb import write_otb_results
from annotator.exports.yolo import write_yolo
from annotator.store import RunStore

__all__ = ["FILE_EXPORTS", "write_exports"]


def _otb(out_dir: Path, store: RunStore) -> list[Path]:
    return write_otb_results(out_dir, store.video.name, store.tracks)


def _coco(out_dir: Path, store: RunStore) -> list[Path]:
    write_coco(out_dir / "annotations.json", store.video, store.tracks)
    return [out_dir / "annotations.json"]


def _flags(out_dir: Path, store: RunStore) -> list[Path]:
    write_flags_csv(out_dir / "flags.csv", store.tracks)
    return [out_dir / "flags.csv"]


def _frames(store: RunStore) -> range:
    return range(store.start, store.stop, store.step)


def _cvat(out_dir: Path, store: RunStore) -> list[Path]:
    return [write_cvat_xml(out_dir / "cvat.xml", store.video, store.tracks, frames=_frames(store))]


def _mot(out_dir: Path, store: RunStore) -> list[Path]:
    return write_mot(out_dir / "mot", store.video, store.tracks, frames=_frames(store))


def _labelstudio(out_dir: Path, store: RunStore) -> list[Path]:
    write_labelstudio(out_dir / "labelstudio.json", store.video, store.tracks, frames=_frames(store))
    return [out_dir / "labelstudio.json"]


def _yolo(out_dir: Path, store: RunStore) -> list[Path]:
    return write_yolo(out_dir / "yolo", store.video, store.tracks, frames=_frames(store))


#: ``--formats`` value -> view writing its files into a folder and returning their paths.
FILE_EXPORTS: Mapping[str, Callable[[Path, RunStore], list[Path]]] = {
    "otb": _otb,
    "coco": _coco,
    "flags": _flags,
    "cvat": _cvat,
    "mot": _mot,
    "labelstudio": _labelstudio,
    "yolo": _yolo,
}


def write_exports(out_dir: str | os.PathLike, store: RunStore, formats: Sequence[str]) -> dict[str, list[Path]]:
    """Write the file exports among ``formats`` (others, such as ``overlay``, are skipped) into ``out_dir``."""
    out_dir = Path(out_dir)
    return {name: FILE_EXPORTS[name](out_dir, store) for name in formats if name in FILE_EXPORTS}

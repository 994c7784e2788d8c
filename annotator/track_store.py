"""The track store: one lossless file per output folder that every export and every re-track reads.

A run's results live here and only here; OTB, COCO, flags, the overlay and
the report are views written from it (:mod:`annotator.views`) and never
parsed back. ``retrack``, batch and ``eval`` read this file and ``run.json``.

Format
------
``tracks.npz``: a NumPy ``.npz`` archive (a zip of ``.npy`` arrays), written
without pickles and read with ``allow_pickle=False``. Chosen because it is
exact for float64 (raw IEEE bytes, NaN payloads included), fast (100,000
frames load in milliseconds), readable without this tool
(``numpy.load("tracks.npz")``, or any zip reader plus the documented ``.npy``
header), and needs nothing beyond NumPy. CSV or JSON would need a decimal
round trip for every float; Parquet or HDF5 a heavy dependency.

Members::

    header                     () str   JSON: format, schema_version, video, range, tracks
    t<id>.frame_index          (F,) int64    source frame index, 0-based
    t<id>.box_xywh             (F, 4) float64 0-based pixels; NaN rows where there is no box
    t<id>.confidence           (F,) float64
    t<id>.log_likelihood       (F,) float64
    t<id>.accepted             (F,) bool
    t<id>.flagged              (F,) bool
    t<id>.reason               (F,) str
    t<id>.keyframe             (F,) bool
    t<id>.keyframe_source      (F,) str    "given", "FILE:LINE" of a correction, "" on other rows
    t<id>.outside              (F,) bool
    t<id>.occluded             (F,) bool
    t<id>.scoring              (F,) str    init | bootstrap | subspace | none
    t<id>.seconds              (F,) float64
    t<id>.signal.<name>        (F,) float64  further per-frame numbers, by name

``header`` holds ``{"format": "sptpt-annotate track store", "schema_version": 1,
"video": {path, name, width, height, fps, frame_count, frame_files}, "range":
{start, stop, step}, "tracks": [{"track_id", "label", "signals": [...]}, ...]}``.
``frame_files`` (image folders: each frame's image path, see
:class:`~annotator.tracks.VideoInfo`; null for videos) may be missing from
stores written before it existed and reads as null. A reader refuses a schema
version it does not know rather than guess.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from annotator.atomic import atomic_path
from annotator.output_files import STORE_NAME
from annotator.tracks import TrackResult, VideoInfo

__all__ = ["SCHEMA_VERSION", "STORE_FORMAT", "STORE_NAME", "RunStore", "StoreError", "read_store", "write_store"]

STORE_FORMAT = "sptpt-annotate track store"
SCHEMA_VERSION = 1

_COLUMNS = ("frame_index", "box_xywh", "confidence", "log_likelihood", "accepted", "flagged", "reason", "keyframe",
            "keyframe_source", "outside", "occluded", "scoring", "seconds")


class StoreError(ValueError):
    """A track store that cannot be read; the message names the file and says how to recover."""


@dataclass(frozen=True)
class RunStore:
    """Everything a run knows per frame, and the source it was computed on.

    Attributes
    ----------
    video : VideoInfo
        The source (its ``name`` names the OTB files and the COCO video).
    start, stop, step : int
        The processed range of source frame indices, ``range(start, stop, step)``
        (``stop`` is exclusive and clipped to the source).
    tracks : tuple of TrackResult
        One per object. A run's tracks cover the same processed frames;
        :func:`annotator.review.load_run` checks that before re-tracking.
    """

    video: VideoInfo
    start: int
    stop: int
    step: int
    tracks: tuple[TrackResult, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "tracks", tuple(self.tracks))
        for key in ("start", "stop", "step"):
            object.__setattr__(self, key, int(getattr(self, key)))
        if self.start < 0 or self.step < 1 or self.stop < self.start:
            raise ValueError(f"RunStore range must satisfy 0 <= start <= stop and step >= 1, "
                             f"got start={self.start} stop={self.stop} step={self.step}")
        ids = [t.track_id for t in self.tracks]
        if len(set(ids)) != len(ids):
            raise ValueError(f"RunStore track ids must be unique, got {ids}")

    @property
    def frame_indices(self) -> np.ndarray:
        """(F,) int64: the processed source frames (those of the first track; a run's tracks share them)."""
        return self.tracks[0].frame_indices if self.tracks else np.zeros(0, dtype=np.int64)

    def track(self, track_id: int) -> TrackResult:
        for t in self.tracks:
            if t.track_id == track_id:
                return t
        raise KeyError(f"no track {track_id} in this run; it has tracks {[t.track_id for t in self.tracks]}")


def _header(store: RunStore) -> dict:
    v = store.video
    return {
        "format": STORE_FORMAT,
        "schema_version": SCHEMA_VERSION,
        "video": {"path": v.path, "name": v.name, "width": v.width, "height": v.height, "fps": v.fps,
                  "frame_count": v.frame_count,
                  "frame_files": None if v.frame_files is None else list(v.frame_files)},
        "range": {"start": store.start, "stop": store.stop, "step": store.step},
        "tracks": [{"track_id": t.track_id, "label": t.label, "signals": sorted(t.signals)} for t in store.tracks],
    }


def _text_array(values: Sequence[str]) -> np.ndarray:
    # Fixed-width unicode (never dtype=object, which would need a pickle); width >= 1 so empty columns load.
    width = max([1, *(len(v) for v in values)])
    return np.asarray(list(values), dtype=f"<U{width}")


def write_store(path: str | os.PathLike, store: RunStore) -> Path:
    """Write ``store`` to ``path`` atomically (the old file or the complete new one, never half)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {"header": np.asarray(json.dumps(_header(store), sort_keys=True))}
    for t in store.tracks:
        p = f"t{t.track_id}."
        arrays.update({
            p + "frame_index": t.frame_indices, p + "box_xywh": t.boxes_xywh, p + "confidence": t.confidence,
            p + "log_likelihood": t.log_likelihood, p + "accepted": t.accepted, p + "flagged": t.flagged,
            p + "reason": _text_array(t.reasons), p + "keyframe": t.keyframe,
            p + "keyframe_source": _text_array(t.keyframe_source), p + "outside": t.outside,
            p + "occluded": t.occluded, p + "scoring": _text_array(t.scoring), p + "seconds": t.seconds,
        })
        for name, values in t.signals.items():
            arrays[f"{p}signal.{name}"] = values
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)  # type: ignore[arg-type]  # array names, never allow_pickle
            handle.flush()
            os.fsync(handle.fileno())
    return path


def read_store(path: str | os.PathLike) -> RunStore:
    """Read a track store written by :func:`write_store`.

    Parameters
    ----------
    path : str or path-like
        A run's ``tracks.npz``.

    Returns
    -------
    RunStore
        The video, the frame range and every track with its per-frame values.

    Raises
    ------
    StoreError
        The file is missing, truncated or damaged, of an unknown schema
        version, or does not describe valid tracks; the message names the file.

    Examples
    --------
    >>> from annotator import annotate, read_store
    >>> _ = annotate("samples/clip.mp4", (136, 129, 48, 40), out_dir="clip_out", stop=3, formats=("otb",),
    ...              show_progress=False)
    >>> store = read_store("clip_out/tracks.npz")
    >>> store.track(1).boxes_xywh.shape
    (3, 4)
    """
    path = Path(path)
    redo = "re-run the annotation with --force to rebuild it"
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except FileNotFoundError:
        raise StoreError(f"{path} does not exist: the folder holds no track store; {redo}") from None
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, KeyError) as exc:
        raise StoreError(f"{path} is truncated or damaged ({type(exc).__name__}: {exc}); {redo}") from None
    try:
        header = json.loads(str(arrays["header"][()]))
    except (KeyError, ValueError, TypeError, IndexError):
        raise StoreError(f"{path} has no readable header: it is not a {STORE_FORMAT}; {redo}") from None
    if not isinstance(header, dict) or header.get("format") != STORE_FORMAT:
        raise StoreError(f"{path} is not a {STORE_FORMAT} (format "
                         f"{header.get('format') if isinstance(header, dict) else None!r}); {redo}")
    version = header.get("schema_version")
    if version != SCHEMA_VERSION:
        raise StoreError(f"{path} has schema version {version!r}, this sptpt-annotate reads version "
                         f"{SCHEMA_VERSION}: use the version that wrote it, or {redo}")
    try:
        v, r = header["video"], header["range"]
        video = VideoInfo(path=v["path"], name=v["name"], width=v["width"], height=v["height"], fps=v["fps"],
                          frame_count=v["frame_count"], frame_files=v.get("frame_files"))  # optional: older stores
        tracks = []
        for entry in header["tracks"]:
            tid = int(entry["track_id"])
            p = f"t{tid}."
            col = {name: arrays[p + name] for name in _COLUMNS}
            tracks.append(TrackResult(
                track_id=tid, label=str(entry["label"]), frame_indices=col["frame_index"],
                boxes_xywh=col["box_xywh"], confidence=col["confidence"], log_likelihood=col["log_likelihood"],
                accepted=col["accepted"], flagged=col["flagged"], reasons=tuple(str(s) for s in col["reason"]),
                keyframe=col["keyframe"], keyframe_source=tuple(str(s) for s in col["keyframe_source"]),
                outside=col["outside"], occluded=col["occluded"], scoring=tuple(str(s) for s in col["scoring"]),
                seconds=col["seconds"],
                signals={name: arrays[f"{p}signal.{name}"] for name in entry.get("signals", [])},
            ))
        return RunStore(video=video, start=r["start"], stop=r["stop"], step=r["step"], tracks=tuple(tracks))
    except (KeyError, TypeError, ValueError) as exc:
        raise StoreError(f"{path} does not describe valid tracks ({type(exc).__name__}: {exc}); {redo}") from None

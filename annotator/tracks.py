"""Track records: what the exporters, the renderer and the report read.

One :class:`TrackResult` per tracked object holds one row per processed frame
as a struct of arrays (the supervision ``Detections`` layout), validated once
in ``__post_init__`` so that no exporter has to re-check shapes. Boxes are
0-based ``xywh`` floats; only the OTB writer shifts them to 1-based.

The tracking loop builds a record frame by frame with :class:`TrackRecorder`
and calls :meth:`TrackRecorder.to_result` at the end, or after a
:class:`~annotator.frame_sources.DecodeError` to keep what was computed.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from array import array
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar, Mapping, Protocol, Sequence, TypeVar

import numpy as np

if TYPE_CHECKING:
    class DataclassInstance(Protocol):
        """What dataclasses.fields and dataclasses.replace accept: an instance of a dataclass."""

        __dataclass_fields__: ClassVar[dict[str, Any]]

__all__ = ["SCORING_STAGES", "KEYFRAME_GIVEN", "SpanThumbnail", "Target", "VideoInfo", "TrackResult", "TrackRecorder",
           "select_rows"]

#: How the tracker scored a row: the first frame (``init``), before both subspace models exist
#: (``bootstrap``), with them (``subspace``), or not at all (``none``: an absence anchor and its span).
SCORING_STAGES = ("init", "bootstrap", "subspace", "none")
#: ``keyframe_source`` of the first-frame box the user gave on the command line or in a manifest.
KEYFRAME_GIVEN = "given"


@dataclass(frozen=True)
class Target:
    """One object to label.

    Attributes
    ----------
    box_xywh : tuple of float
        Its first-frame box, ``x, y, w, h`` in 0-based pixels.
    track_id : int
        The id of its track in every output.
    label : str
        Its class name in the exports.
    """

    box_xywh: tuple[float, float, float, float]
    track_id: int
    label: str = "object"


@dataclass(frozen=True)
class SpanThumbnail:
    """A small JPEG of an overlay frame, for the review report.

    Attributes
    ----------
    track_id : int
        The track whose flagged span it shows.
    position, frame_index : int
        The frame's row in the track and its source index.
    jpeg_base64 : str
        The JPEG, base64-encoded for an ``<img src="data:...">``.
    """

    track_id: int
    position: int
    frame_index: int
    jpeg_base64: str


@dataclass(frozen=True)
class VideoInfo:
    """The source a set of tracks was computed on.

    Attributes
    ----------
    path : str
        The video file or image folder as given.
    name : str
        Sequence name: file stem, folder name, or OTB sequence name.
    width, height : int
        Frame size in pixels.
    fps : float
        Frames per second (nominal for videos, 30 by default for image folders).
    frame_count : int
        Frames of the whole source as decoded, not only the processed ones.
    frame_files : tuple of str, length frame_count, optional
        Image folders only: each source frame's image file, relative to the
        parent of the sequence folder (the folder ``name`` comes from), with
        ``/`` separators, e.g. ``Coke/img/0001.jpg``; None for videos.
        Exporters name images with it without touching the files.
    """

    path: str
    name: str
    width: int
    height: int
    fps: float
    frame_count: int
    frame_files: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", str(self.path))
        for key in ("width", "height", "frame_count"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"VideoInfo.{key} must be a positive integer, got {value!r}")
            object.__setattr__(self, key, int(value))
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"VideoInfo.fps must be a positive number of frames per second, got {self.fps!r}")
        object.__setattr__(self, "fps", float(self.fps))
        if not self.name or any(c in self.name for c in "/\\\0"):
            raise ValueError(f"VideoInfo.name must be a non-empty file-name-safe string, got {self.name!r}")
        if self.frame_files is not None:
            files = tuple(self.frame_files)
            if len(files) != self.frame_count or not all(isinstance(f, str) and f for f in files):
                raise ValueError(f"VideoInfo.frame_files must be {self.frame_count} non-empty strings (one per source "
                                 f"frame) or None, got {len(files)} entries")
            object.__setattr__(self, "frame_files", files)


def _frozen(values: np.ndarray) -> np.ndarray:
    """A read-only copy: a TrackResult is shared by exporters and must not change under them."""
    values = np.array(values, copy=True)
    values.setflags(write=False)
    return values


Rows = TypeVar("Rows", bound="DataclassInstance")


def select_rows(record: Rows, picked: np.ndarray) -> Rows:
    """A struct-of-arrays dataclass with only the rows ``picked`` (indices, in that order).

    Every array field is indexed, every tuple field picked item by item and every mapping's arrays indexed; the
    other fields (a track's id and label) are kept. The copy is built by the class, so it is validated as any is.
    """
    def rows(value):
        if isinstance(value, np.ndarray):
            return value[picked]
        if isinstance(value, tuple):
            return tuple(value[i] for i in picked)
        if isinstance(value, Mapping):
            return {key: values[picked] for key, values in value.items()}
        return value

    return dataclasses.replace(record, **{f.name: rows(getattr(record, f.name)) for f in dataclasses.fields(record)})


@dataclass(frozen=True)
class TrackResult:
    """All processed frames of one tracked object, as a struct of arrays.

    Row ``i`` of every array describes source frame ``frame_indices[i]``.

    Attributes
    ----------
    track_id : int
        Identity of the object, >= 1, unique within a video.
    label : str
        Category name, e.g. ``"object"``, ``"car"``.
    frame_indices : (F,) int64 ndarray
        Source indices of the processed frames, strictly increasing, >= 0.
    boxes_xywh : (F, 4) float64 ndarray
        0-based ``x, y, w, h`` in pixels; NaN rows are allowed for frames
        without an estimate (exporters write or skip them as their format demands).
    confidence : (F,) float64 ndarray
        In [0, 1]; 0.5 is the tracker's acceptance threshold.
    log_likelihood : (F,) float64 ndarray
        The tracker's ``RE- - RE+`` score (may be +-inf or NaN on the first frame).
    accepted : (F,) bool ndarray
        Whether the frame updated the appearance model.
    flagged : (F,) bool ndarray
        Whether a human should review the frame.
    reasons : tuple of str, length F
        Why a frame is flagged; ``""`` exactly when it is not flagged.
    keyframe : (F,) bool ndarray
        First frame and human corrections: boxes a person gave, not the tracker.
    outside : (F,) bool ndarray
        The object is judged absent; such frames must be flagged (FORMATS.md
        asks for absences to be recorded in the flags file).
    seconds : (F,) float64 ndarray
        Tracking time per frame, >= 0 (got10k ``times/`` file).
    occluded : (F,) bool ndarray, optional
        Occlusion judgement, exported as a COCO/CVAT attribute; all False by
        default (the tracker does not estimate it).
    scoring : tuple of str, length F, optional
        The tracker's scoring stage per row (:data:`SCORING_STAGES`); flags
        are recomputed from it after a re-track. By default ``init`` on
        keyframes, ``none`` on outside rows and ``subspace`` elsewhere.
    keyframe_source : tuple of str, length F, optional
        Who gave each keyframe's box: :data:`KEYFRAME_GIVEN` for the
        first-frame box, ``FILE:LINE`` of a correction; ``""`` exactly on
        rows that are not keyframes. By default ``given`` on keyframes.
    signals : mapping of str to (F,) float64 ndarray, optional
        Further per-frame numbers (failure-probability signals), by name;
        stored and exported as they are.
    """

    track_id: int
    label: str
    frame_indices: np.ndarray
    boxes_xywh: np.ndarray
    confidence: np.ndarray
    log_likelihood: np.ndarray
    accepted: np.ndarray
    flagged: np.ndarray
    reasons: tuple[str, ...]
    keyframe: np.ndarray
    outside: np.ndarray
    seconds: np.ndarray
    # Optional when built: None asks for the default, which __post_init__ puts in its place, so a track's
    # attribute is never None. The annotations are the attributes'; the type system cannot say "None in, array
    # out" of a dataclass field.
    occluded: np.ndarray = field(default=None)  # type: ignore[arg-type]
    scoring: tuple[str, ...] = field(default=None)  # type: ignore[arg-type]
    keyframe_source: tuple[str, ...] = field(default=None)  # type: ignore[arg-type]
    signals: Mapping[str, np.ndarray] = field(default=None)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        name = f"TrackResult(track_id={self.track_id!r})"
        self._check_identity(name)
        self._check_rows(name)
        self._check_flags(name)
        self._check_stages(name)
        self._check_signals(name)

    def _check_identity(self, name: str) -> None:
        if isinstance(self.track_id, bool) or not isinstance(self.track_id, (int, np.integer)) or self.track_id < 1:
            raise ValueError(f"{name}: track_id must be an integer >= 1, got {self.track_id!r}")
        object.__setattr__(self, "track_id", int(self.track_id))
        if not isinstance(self.label, str) or not self.label.strip():
            raise ValueError(f"{name}: label must be a non-empty category name such as 'object', got {self.label!r}")

    def _check_rows(self, name: str) -> None:
        """Frame indices, boxes and per-row numbers: the arrays every other column is checked against."""
        indices = np.asarray(self.frame_indices)
        if indices.ndim != 1 or (indices.size and not np.issubdtype(indices.dtype, np.integer)):
            raise ValueError(f"{name}: frame_indices must be a (F,) integer array, got {indices.dtype} {indices.shape}")
        indices = indices.astype(np.int64)
        n = indices.shape[0]
        if n and (indices[0] < 0 or np.any(np.diff(indices) <= 0)):
            raise ValueError(
                f"{name}: frame_indices must be >= 0 and strictly increasing (one row per processed frame), "
                f"got {indices[:8].tolist()}{'...' if n > 8 else ''}"
            )
        object.__setattr__(self, "frame_indices", _frozen(indices))

        boxes = np.asarray(self.boxes_xywh, dtype=np.float64)
        if boxes.shape != (n, 4):
            raise ValueError(f"{name}: boxes_xywh must have shape ({n}, 4) to match frame_indices, got {boxes.shape}")
        finite = np.isfinite(boxes).all(axis=1)
        if np.any(boxes[finite, 2:] < 0):
            raise ValueError(f"{name}: boxes_xywh widths and heights must be >= 0 (layout x, y, w, h)")
        object.__setattr__(self, "boxes_xywh", _frozen(boxes))

        for key, dtype in (("confidence", np.float64), ("log_likelihood", np.float64), ("seconds", np.float64)):
            values = np.asarray(getattr(self, key), dtype=dtype)
            if values.shape != (n,):
                raise ValueError(f"{name}: {key} must have shape ({n},) to match frame_indices, got {values.shape}")
            object.__setattr__(self, key, _frozen(values))
        if np.any(~((self.confidence >= 0.0) & (self.confidence <= 1.0))):
            bad = self.confidence[~((self.confidence >= 0.0) & (self.confidence <= 1.0))][0]
            raise ValueError(f"{name}: confidence must lie in [0, 1] (no NaN), got {bad:g}")
        if np.any(~(self.seconds >= 0.0)):
            raise ValueError(f"{name}: seconds must be >= 0 (time spent on each frame)")

    def _check_flags(self, name: str) -> None:
        n, indices = len(self.frame_indices), self.frame_indices
        if self.occluded is None:
            object.__setattr__(self, "occluded", np.zeros(n, dtype=bool))
        for key in ("accepted", "flagged", "keyframe", "outside", "occluded"):
            values = np.asarray(getattr(self, key))
            if values.shape != (n,) or not (values.dtype == bool or n == 0):
                raise ValueError(f"{name}: {key} must be a ({n},) bool array, got {values.dtype} {values.shape}")
            object.__setattr__(self, key, _frozen(values.astype(bool)))

        reasons = tuple(self.reasons)
        if len(reasons) != n or not all(isinstance(r, str) for r in reasons):
            raise ValueError(f"{name}: reasons must be {n} strings (one per frame), got {len(reasons)}")
        for i, (flag, reason) in enumerate(zip(self.flagged, reasons)):
            if bool(flag) != bool(reason):
                raise ValueError(
                    f"{name}: frame {indices[i]} has flagged={bool(flag)} and reason {reason!r}; "
                    f"a flagged frame needs a reason and an unflagged one the empty string"
                )
            if "\n" in reason or "\r" in reason:
                raise ValueError(f"{name}: frame {indices[i]} reason {reason!r} must be one line")
        object.__setattr__(self, "reasons", reasons)
        absent = np.flatnonzero(self.outside & ~self.flagged)
        if absent.size:
            raise ValueError(
                f"{name}: frame {indices[absent[0]]} is outside (object absent) but not flagged; "
                f"flag it with a reason such as 'object absent' so the flags file records the absence"
            )

    def _check_stages(self, name: str) -> None:
        """Scoring stages and keyframe sources, with their defaults."""
        n, indices = len(self.frame_indices), self.frame_indices
        if self.scoring is None:
            default = np.where(self.keyframe & ~self.outside, "init", np.where(self.outside, "none", "subspace"))
            object.__setattr__(self, "scoring", tuple(str(v) for v in default))
        scoring = tuple(str(v) for v in self.scoring)
        if len(scoring) != n or not set(scoring) <= set(SCORING_STAGES):
            bad = sorted(set(scoring) - set(SCORING_STAGES))
            raise ValueError(f"{name}: scoring must be {n} values from {SCORING_STAGES}, got {len(scoring)} "
                             f"values{' including ' + repr(bad[0]) if bad else ''}")
        object.__setattr__(self, "scoring", scoring)

        if self.keyframe_source is None:
            object.__setattr__(self, "keyframe_source", tuple(KEYFRAME_GIVEN if k else "" for k in self.keyframe))
        sources = tuple(self.keyframe_source)
        if len(sources) != n or not all(isinstance(v, str) for v in sources):
            raise ValueError(f"{name}: keyframe_source must be {n} strings (one per frame), got {len(sources)}")
        for i, (key, source) in enumerate(zip(self.keyframe, sources)):
            if bool(key) != bool(source):
                raise ValueError(f"{name}: frame {indices[i]} has keyframe={bool(key)} and keyframe_source "
                                 f"{source!r}; a keyframe names who gave its box and other rows the empty string")
        object.__setattr__(self, "keyframe_source", sources)

    def _check_signals(self, name: str) -> None:
        n = len(self.frame_indices)
        signals = {}
        for key, values in dict(self.signals or {}).items():
            if not isinstance(key, str) or not key.isidentifier():
                raise ValueError(f"{name}: signal names must be identifiers such as 'p_fail', got {key!r}")
            values = np.asarray(values, dtype=np.float64)
            if values.shape != (n,):
                raise ValueError(f"{name}: signal {key!r} must have shape ({n},) to match frame_indices, "
                                 f"got {values.shape}")
            signals[key] = _frozen(values)
        object.__setattr__(self, "signals", MappingProxyType(signals))

    def __len__(self) -> int:
        return int(self.frame_indices.shape[0])

    @property
    def needs_review(self) -> np.ndarray:
        """(F,) bool: the ``needs_review`` attribute of the exports (same as ``flagged``)."""
        return self.flagged

    @property
    def p_fail(self) -> np.ndarray:
        """(F,) float64: failure probability ``P(IoU < 0.5)`` per frame, NaN where the object is absent.

        The ``p_fail`` signal when the track carries it (:mod:`annotator.failure`), else ``1 - confidence``
        (tracks built without failure signals, such as hand-made ones in tests).
        """
        stored = (self.signals or {}).get("p_fail")
        p_fail = np.array(stored if stored is not None else 1.0 - self.confidence, dtype=np.float64)
        p_fail[self.outside] = np.nan
        return p_fail

    def up_to(self, last_frame_index: int) -> TrackResult:
        """The rows whose source index is <= ``last_frame_index`` (e.g. a DecodeError's last good frame)."""
        keep = self.frame_indices <= last_frame_index
        return self.select(keep)

    def select(self, mask: np.ndarray) -> TrackResult:
        """The rows where ``mask`` (an (F,) bool array) is True."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (len(self),):
            raise ValueError(f"mask must have shape ({len(self)},), got {mask.shape}")
        return select_rows(self, np.flatnonzero(mask))

    def equals(self, other: TrackResult) -> bool:
        """Whether two tracks hold the same rows bit for bit (NaN equals NaN; a lossless round trip)."""
        def same(a: np.ndarray, b: np.ndarray) -> bool:
            return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()

        arrays = ("frame_indices", "boxes_xywh", "confidence", "log_likelihood", "accepted", "flagged", "keyframe",
                  "outside", "seconds", "occluded")
        return (self.track_id == other.track_id and self.label == other.label
                and all(same(getattr(self, k), getattr(other, k)) for k in arrays)
                and (self.reasons, self.scoring, self.keyframe_source)
                == (other.reasons, other.scoring, other.keyframe_source)
                and self.signals.keys() == other.signals.keys()
                and all(same(v, other.signals[k]) for k, v in self.signals.items()))


#: TrackRecorder's numeric columns and their ``array`` type codes (boxes flat, four per row); bools as bytes.
_NUMBER_COLUMNS = {"frame_indices": "q", "boxes_xywh": "d", "confidence": "d", "log_likelihood": "d",
                   "accepted": "b", "flagged": "b", "keyframe": "b", "outside": "b", "seconds": "d", "occluded": "b"}
_TEXT_COLUMNS = ("reasons", "scoring", "keyframe_source")


class TrackRecorder:
    """Collects one track frame by frame; :meth:`to_result` freezes it into a :class:`TrackResult`.

    Example
    -------
    >>> rec = TrackRecorder(track_id=1, label="object")            # doctest: +SKIP
    >>> for index, frame in source:                                 # doctest: +SKIP
    ...     result = tracker.update(frame)
    ...     rec.append(index, result.box_xywh, confidence=result.confidence,
    ...                log_likelihood=result.log_likelihood, accepted=result.accepted,
    ...                seconds=elapsed)
    >>> track = rec.to_result()                                     # doctest: +SKIP
    """

    def __init__(self, track_id: int = 1, label: str = "object") -> None:
        self.track_id = track_id
        self.label = label
        # One typed column per field, not a tuple of Python objects per row: a run keeps every row until it
        # ends, and a checkpoint pickles them all every CHECKPOINT_EVERY frames, so a row's size is what a long
        # video pays (about 0.3 KiB a row here against 1.2 KiB as tuples and lists of floats; issue #69).
        self._numbers: dict[str, array[Any]] = {name: array(code) for name, code in _NUMBER_COLUMNS.items()}
        self._texts: dict[str, list[str]] = {name: [] for name in _TEXT_COLUMNS}
        self._signals: dict[str, array[float]] = {}

    def __len__(self) -> int:
        return len(self._numbers["frame_indices"])

    def __setstate__(self, state: dict) -> None:
        """Read a recorder pickled as rows of tuples (checkpoints written before the columns) as columns."""
        if "_rows" not in state:
            self.__dict__.update(state)
            return
        self.__init__(state["track_id"], state["label"])  # type: ignore[misc]
        for row in state["_rows"]:
            self._add_row(*row)
        self._signals = {name: array("d", values) for name, values in state["_signals"].items()}

    def append(
        self,
        frame_index: int,
        box_xywh: Sequence[float] | np.ndarray,
        *,
        confidence: float,
        log_likelihood: float,
        accepted: bool,
        seconds: float,
        flagged: bool = False,
        reason: str = "",
        keyframe: bool = False,
        outside: bool = False,
        occluded: bool = False,
        scoring: str | None = None,
        keyframe_source: str | None = None,
        signals: Mapping[str, float] | None = None,
    ) -> None:
        """Add one processed frame. Validation happens in :meth:`to_result`.

        ``scoring`` and ``keyframe_source`` default as in :class:`TrackResult`;
        ``signals`` must name the same signals on every row (missing ones are NaN).
        """
        n = len(self)
        for name, value in (signals or {}).items():
            column = self._signals.setdefault(name, array("d", [math.nan]) * n)
            column.append(float(value))
        if scoring is None:
            scoring = "none" if outside else "init" if keyframe else "subspace"
        if keyframe_source is None:
            keyframe_source = KEYFRAME_GIVEN if keyframe else ""
        self._add_row(frame_index, box_xywh, confidence, log_likelihood, accepted, flagged, reason, keyframe,
                      outside, seconds, occluded, scoring, keyframe_source)
        for column in self._signals.values():
            if len(column) < n + 1:
                column.append(math.nan)

    def _add_row(self, frame_index, box_xywh, confidence, log_likelihood, accepted, flagged, reason, keyframe,
                 outside, seconds, occluded, scoring, keyframe_source) -> None:
        numbers, texts = self._numbers, self._texts
        numbers["frame_indices"].append(int(frame_index))
        numbers["boxes_xywh"].extend(np.asarray(box_xywh, dtype=np.float64).reshape(4).tolist())
        numbers["confidence"].append(float(confidence))
        numbers["log_likelihood"].append(float(log_likelihood))
        numbers["accepted"].append(bool(accepted))
        numbers["flagged"].append(bool(flagged))
        texts["reasons"].append(sys.intern(str(reason)))
        numbers["keyframe"].append(bool(keyframe))
        numbers["outside"].append(bool(outside))
        numbers["seconds"].append(float(seconds))
        numbers["occluded"].append(bool(occluded))
        texts["scoring"].append(sys.intern(str(scoring)))
        texts["keyframe_source"].append(sys.intern(str(keyframe_source)))

    def set_flag(self, position: int, flagged: bool, reason: str) -> None:
        """Set the flag of the row at ``position`` (0-based in append order) once it is final.

        The tracking loop decides a frame's flag a few frames after it was
        tracked (:class:`annotator.failure.TrackDoubt`), and reports it by that position.
        """
        self._numbers["flagged"][position] = bool(flagged)
        self._texts["reasons"][position] = sys.intern(str(reason))

    def set_failure(self, position: int, p_fail: float) -> None:
        """Record the row's failure probability: signal ``p_fail``, and confidence ``1 - p_fail``."""
        self._numbers["confidence"][position] = 1.0 - float(p_fail)
        self._signals.setdefault("p_fail", array("d", [math.nan]) * len(self))[position] = float(p_fail)

    def to_result(self) -> TrackResult:
        numbers, texts = self._numbers, self._texts
        return TrackResult(
            track_id=self.track_id,
            label=self.label,
            frame_indices=np.array(numbers["frame_indices"], dtype=np.int64),
            boxes_xywh=np.array(numbers["boxes_xywh"], dtype=np.float64).reshape(-1, 4),
            confidence=np.array(numbers["confidence"], dtype=np.float64),
            log_likelihood=np.array(numbers["log_likelihood"], dtype=np.float64),
            accepted=np.array(numbers["accepted"], dtype=bool),
            flagged=np.array(numbers["flagged"], dtype=bool),
            reasons=tuple(texts["reasons"]),
            keyframe=np.array(numbers["keyframe"], dtype=bool),
            outside=np.array(numbers["outside"], dtype=bool),
            seconds=np.array(numbers["seconds"], dtype=np.float64),
            occluded=np.array(numbers["occluded"], dtype=bool),
            scoring=tuple(texts["scoring"]),
            keyframe_source=tuple(texts["keyframe_source"]),
            signals={name: np.array(values, dtype=np.float64) for name, values in self._signals.items()},
        )

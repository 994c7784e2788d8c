"""The tracker passes a run keeps for its next re-track (``passes.npz``).

A pass depends only on its anchor (:mod:`annotator.review.retrack`): when a
correction ``C`` splits the segment ``A .. B``, the forward pass from ``A``
and the backward pass from ``B`` give, up to ``C``, the rows they gave
before. The track store holds merged rows only, so without the passes
themselves every re-track ran those two again: about half of its tracking.
The run folder therefore keeps each pass that starts at a current anchor,
keyed as :class:`~annotator.review.passes.SegmentRun` looks them up (track,
anchor position, direction, anchor box): the main command writes the forward
pass from the first frame, each re-track the passes it ran or kept.

The file is a cache: one that is missing, damaged, or made for another input,
tracker configuration or tool version is ignored (the passes are run again),
never an error. Its arrays are plain numbers and fixed-width text (no pickles).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from annotator.atomic import atomic_path
from annotator.failure import SIGNALS
from annotator.output_files import PASSES_NAME
from annotator.tracks import TrackResult
from annotator.version import __version__

__all__ = ["NO_SCORING", "PASSES_NAME", "CachedPass", "PassKey", "PassResult", "first_pass", "keep_anchored",
           "pass_fingerprint", "pass_key", "read_pass_cache", "write_pass_cache"]

#: ``scoring`` value of rows no tracker scored (``outside`` rows).
NO_SCORING = "none"


@dataclass
class PassResult:
    """One tracker pass over a segment's interior, rows in increasing position order.

    Attributes
    ----------
    boxes_xywh : numpy.ndarray
        (n, 4) boxes, 0-based pixels.
    confidence, log_likelihood : numpy.ndarray
        (n,) the tracker's confidence and its likelihood of each box.
    accepted : numpy.ndarray
        (n,) bool: the tracker's model updated on the row.
    scoring : numpy.ndarray
        (n,) the scoring stage of each row.
    seconds : numpy.ndarray
        (n,) the tracker's wall time per row.
    signals, pass_iou, choice : numpy.ndarray
        As the comments at the fields say.
    """

    boxes_xywh: np.ndarray
    confidence: np.ndarray
    log_likelihood: np.ndarray
    accepted: np.ndarray
    scoring: np.ndarray
    seconds: np.ndarray
    # The last three are optional when built: None asks for the NaN default, which __post_init__ puts in its
    # place, so a pass's attribute is never None (the type system cannot say "None in, array out" of a field).
    #: (n, len(SIGNALS)) failure signals of the pass's rows (annotator.failure.SIGNALS order), NaN where not run.
    signals: np.ndarray = None  # type: ignore[assignment]
    #: (n,) IoU of the forward and the backward pass's boxes on a merged row; NaN for a single pass.
    pass_iou: np.ndarray = None  # type: ignore[assignment]
    #: (n,) index in PASS_OPTIONS of the box the ``chosen`` merge took where the passes disagreed; NaN elsewhere.
    choice: np.ndarray = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.signals is None:
            self.signals = np.full((len(self.confidence), len(SIGNALS)), np.nan)
        if self.pass_iou is None:
            self.pass_iou = np.full(len(self.confidence), np.nan)
        if self.choice is None:
            self.choice = np.full(len(self.confidence), np.nan)

    @classmethod
    def empty(cls, n: int) -> PassResult:
        return cls(np.full((n, 4), np.nan), np.zeros(n), np.full(n, np.nan), np.zeros(n, bool),
                   np.full(n, NO_SCORING, dtype=object), np.zeros(n))

    def take(self, index) -> PassResult:
        """Copies of the rows at ``index`` (a slice or indices), as a pass of their own (no ``pass_iou``)."""
        return PassResult(*(np.asarray(getattr(self, f))[index].copy() for f in
                            ("boxes_xywh", "confidence", "log_likelihood", "accepted", "scoring", "seconds",
                             "signals")))


#: File name of the kept passes in a run folder.

#: (track_id, anchor position, direction 0 forward / 1 backward, anchor box x, y, w, h)
PassKey = tuple


@dataclass
class CachedPass:
    """A pass as it was run: rows in pass order (backward passes: nearest the anchor first)."""

    rows: PassResult
    init_log_likelihood: float
    init_seconds: float


def pass_key(track_id: int, position: int, direction: int, box: Iterable[float]) -> PassKey:
    """The key of the pass of ``track_id`` from its anchor at ``position`` (0 forward, 1 backward) with ``box``."""
    return (int(track_id), int(position), int(direction), tuple(float(v) for v in box))


def keep_anchored(cache: Mapping[PassKey, CachedPass], tracks: Iterable[TrackResult]) -> dict[PassKey, CachedPass]:
    """The passes that start at an anchor of ``tracks`` as it is now, each cut to its segment.

    A replaced box's passes can never be used again. Anchors are only added or replaced, never removed, so a
    segment only ever shrinks: a forward pass needs no row past the next anchor, a backward pass none before the
    previous one (without the cut, a review from the start to the end kept every earlier, longer pass).
    """
    kept: dict[PassKey, CachedPass] = {}
    for t in tracks:
        anchors = np.flatnonzero(t.keyframe)  # absences too: a segment ends there
        boxes = {int(p): tuple(float(v) for v in t.boxes_xywh[p]) for p in anchors if not t.outside[p]}
        for k, cached in cache.items():
            track_id, position, direction, box = k
            if track_id != t.track_id or boxes.get(position) != box:
                continue
            if direction == 0:
                later = anchors[anchors > position]
                room = (int(later[0]) if len(later) else len(t)) - position - 1
            else:
                earlier = anchors[anchors < position]
                room = position - (int(earlier[-1]) if len(earlier) else -1) - 1
            n = len(cached.rows.confidence)
            rows = cached.rows if n <= room else cached.rows.take(slice(0, room))
            kept[k] = CachedPass(rows, cached.init_log_likelihood, cached.init_seconds)
    return kept


def pass_fingerprint(config: Mapping[str, Any], content_hash: str | None, frame_range: Mapping[str, int]) -> str:
    """What the passes of a run depend on besides their anchors: tracker configuration and seed, the input's
    bytes and range, the failure signals measured, and the code that computes them (:func:`code_identity`)."""
    what = {"config": config, "input": content_hash, "range": dict(frame_range), "signals": list(SIGNALS),
            "code": code_identity()}
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()


#: Modules besides the ``sptpt`` package whose code decides a pass's rows: decoding, the failure signals measured
#: along a pass, how a pass runs and is seeded.
_PASS_MODULES = ("annotator.frame_sources", "annotator.failure.signals", "annotator.review.passes",
                 "annotator.pipeline")


@functools.lru_cache(maxsize=1)
def code_identity() -> dict[str, str]:
    """The code a pass's rows come from: a digest of the tracker's and those modules' sources, and the versions
    of the libraries under them (NumPy's random streams, numba, OpenCV's optical flow, ffmpeg's decoding).

    The tool's version number alone is not enough: it does not change with every change of the tracker.
    """
    import cv2
    import imageio_ffmpeg
    import numba

    import sptpt

    digest = hashlib.sha256()
    package = Path(sptpt.__file__).parent
    files = [(f"sptpt/{f.relative_to(package).as_posix()}", f) for f in sorted(package.rglob("*.py"))]
    # Modules of this package, read from their source files, not imported: the cache sits below the engine and
    # the re-track code whose sources it digests (tests/test_layers.py).
    tool = Path(__file__).parent
    files += [(name, tool.joinpath(*name.split(".")[1:]).with_suffix(".py")) for name in _PASS_MODULES]
    for name, file in files:
        digest.update(name.encode() + b"\0" + file.read_bytes() + b"\0")
    try:
        ffmpeg = imageio_ffmpeg.get_ffmpeg_version()
    except Exception:  # noqa: BLE001 - no ffmpeg to ask: image folders still decode; the exe's path stands in
        ffmpeg = "unknown"
    return {"tool": __version__, "sources": digest.hexdigest(), "numpy": np.__version__, "numba": numba.__version__,
            "opencv": cv2.__version__, "ffmpeg": ffmpeg}


def first_pass(track: TrackResult, tracker_confidence: np.ndarray) -> tuple[PassKey, CachedPass]:
    """The main command's track as the forward pass from its first frame, which a re-track would run again.

    ``tracker_confidence`` is the tracker's own confidence per row (the track's ``confidence`` is ``1 - p_fail``).
    """
    rows = PassResult(
        boxes_xywh=np.array(track.boxes_xywh[1:], dtype=np.float64),
        confidence=np.array(tracker_confidence[1:], dtype=np.float64),
        log_likelihood=np.array(track.log_likelihood[1:], dtype=np.float64),
        accepted=np.array(track.accepted[1:], dtype=bool),
        scoring=np.array(track.scoring[1:], dtype=object),
        seconds=np.array(track.seconds[1:], dtype=np.float64),
        signals=np.column_stack([np.asarray(track.signals[name], dtype=np.float64)[1:] for name in SIGNALS])
        if len(track) > 1 else np.zeros((0, len(SIGNALS))),
    )
    key = pass_key(track.track_id, 0, 0, track.boxes_xywh[0])
    return key, CachedPass(rows, float(track.log_likelihood[0]), float(track.seconds[0]))


def write_pass_cache(path: str | os.PathLike, cache: Mapping[PassKey, CachedPass], fingerprint: str) -> Path:
    """Write ``cache`` to ``path`` atomically."""
    path = Path(path)
    keys = list(cache)
    passes = [cache[k] for k in keys]
    rows = [p.rows for p in passes]

    def stacked(field: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        parts = [np.asarray(getattr(r, field), dtype=dtype).reshape(-1, *shape) for r in rows]
        return np.concatenate(parts) if parts else np.zeros((0, *shape), dtype=dtype)

    scoring = [str(s) for r in rows for s in r.scoring]
    arrays = {
        "header": np.asarray(json.dumps({"fingerprint": fingerprint, "signals": list(SIGNALS)})),
        "key": np.array([[k[0], k[1], k[2], *k[3]] for k in keys], dtype=np.float64).reshape(-1, 7),
        "init": np.array([[p.init_log_likelihood, p.init_seconds] for p in passes], dtype=np.float64).reshape(-1, 2),
        "length": np.array([len(r.confidence) for r in rows], dtype=np.int64),
        "box_xywh": stacked("boxes_xywh", (4,), np.float64),
        "confidence": stacked("confidence", (), np.float64),
        "log_likelihood": stacked("log_likelihood", (), np.float64),
        "accepted": stacked("accepted", (), bool),
        "scoring": np.asarray(scoring, dtype=f"<U{max([1, *map(len, scoring)])}"),
        "seconds": stacked("seconds", (), np.float64),
        "signals": stacked("signals", (len(SIGNALS),), np.float64),
    }
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)  # type: ignore[arg-type]  # array names, never allow_pickle
    return path


def read_pass_cache(path: str | os.PathLike, fingerprint: str) -> dict[PassKey, CachedPass]:
    """The passes kept in ``path`` if it was written for ``fingerprint``; else (missing, damaged, foreign) none."""
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            if header.get("fingerprint") != fingerprint or header.get("signals") != list(SIGNALS):
                return {}
            arrays = {name: data[name] for name in ("key", "init", "length", "box_xywh", "confidence",
                                                     "log_likelihood", "accepted", "scoring", "seconds", "signals")}
    except Exception:  # noqa: BLE001 - any unreadable cache is only a cache miss: the passes run again
        return {}
    lengths = arrays["length"]
    total = int(lengths.sum()) if len(lengths) else 0
    if not (len(arrays["key"]) == len(arrays["init"]) == len(lengths)
            and all(len(arrays[n]) == total for n in ("box_xywh", "confidence", "log_likelihood", "accepted",
                                                      "scoring", "seconds", "signals"))):
        return {}
    cache: dict[PassKey, CachedPass] = {}
    offset = 0
    for key, init, n in zip(arrays["key"], arrays["init"], lengths):
        part = slice(offset, offset + int(n))
        offset += int(n)
        rows = PassResult(arrays["box_xywh"][part].copy(), arrays["confidence"][part].copy(),
                          arrays["log_likelihood"][part].copy(), arrays["accepted"][part].copy(),
                          arrays["scoring"][part].astype(object), arrays["seconds"][part].copy(),
                          arrays["signals"][part].copy())
        cache[pass_key(key[0], key[1], key[2], key[3:])] = CachedPass(rows, float(init[0]), float(init[1]))
    return cache

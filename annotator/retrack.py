"""Re-tracking from human anchors: only the spans a correction affects, forward and backward.

A track's *anchors* are the frames a human set: the first-frame box and every
correction. An anchor holds a box, or ``None`` for "the object is absent
from here until the next anchor". Tracking never overwrites an anchor; only
a later correction of the same frame replaces it. An absence anchor is a
keyframe that is still flagged (reason ``outside``): every absence is
recorded in the flags file (FORMATS.md), and ``TrackResult`` requires it.

Between two consecutive anchors ``A < B`` lies a *segment*. A segment is
re-tracked when ``A`` or ``B`` is a new or changed anchor; every other
segment keeps its previous rows untouched. A re-tracked segment:

* ``A`` present, ``B`` present: the tracker is initialised on ``A`` with the
  human box and run forward over ``A+1 .. B-1``, and initialised on ``B`` and
  run backward (frames in reverse order) over ``B-1 .. A+1``. Each frame then
  takes a box from the two passes (:data:`MERGES`; by default the pass that
  is still near its own human box, else the more confident one).
* ``A`` present, no ``B`` (end of the track) or ``B`` absent: forward only.
* ``A`` absent: every frame up to ``B`` is ``outside`` (no box, flagged
  ``outside``, no COCO annotation, a ``nan`` OTB row).

Seeds: each pass has its own generator, derived from the run seed, the track
id, the anchor's source frame index and the direction, so a re-track is
reproducible and independent of which other segments were re-tracked. The
forward pass from the first processed frame uses the run's own track seed
(:func:`annotator.pipeline.seed_for_track`), so it reproduces the original
run's rows exactly. A pass thus depends only on its anchor: when a new
anchor ``C`` splits ``A .. B``, the forward pass from the unchanged ``A`` over
``A .. C`` gives the rows it gave before, and the backward pass from ``C``
meets it there (and the forward pass from ``C`` meets the one from ``B``).
Re-running the unchanged side costs time but changes nothing;
``pass_cache`` skips it when a caller keeps the passes (the simulated
reviewer does; the command line does not, as the folder stores merged rows
only).

Frames: passes read frames through a :class:`FrameProvider`, one ordered
sweep over the union of the segments' frames. Forward passes stream. A
backward pass keeps its segment's frames in a buffer until it reaches ``B``
when the segment has at most ``max_buffer_frames`` frames; a longer segment
is run backward afterwards in chunks of that size, each read again from the
provider (for a video that means decoding again from the start of the file
for every chunk, so a span of L frames costs about L / chunk extra decodes
of the video head: the price of memory that does not grow with the span;
spans between corrections are usually short, and the command line sizes
the chunk from a byte budget, ``annotator.review.BUFFER_BYTES``).

Flags are recomputed over whole tracks with :func:`annotator.flagging.flag_frames`
(anchors are never flagged; ``outside`` frames are flagged ``outside``), from
each row's stored log-likelihood, confidence and scoring stage.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Iterator, Mapping, Protocol, Sequence

import numpy as np

from annotator.config import RunConfig
from annotator.flagging import flag_frames
from annotator.pipeline import seed_for_track
from annotator.tracks import KEYFRAME_GIVEN, TrackResult
from sptpt.params import TrackerParams
from sptpt.tracker import Tracker

__all__ = [
    "ArrayFrames",
    "DEFAULT_MERGE",
    "FrameProvider",
    "MERGES",
    "PassResult",
    "PreviousTrack",
    "RetrackResult",
    "Segment",
    "SegmentChange",
    "merge_passes",
    "pass_seed",
    "plan_segments",
    "reflag",
    "retrack_tracks",
    "scoring_from_accepted",
    "same_box",
]

Box = tuple[float, float, float, float]

#: How a frame between two anchors takes its box from the forward and the backward pass:
#:
#: * ``anchored``: the pass still in its bootstrap stage (its first frames after the human box,
#:   before its subspace models exist) when the other pass is not; otherwise the more confident.
#:   The two stages score on different scales (histogram intersection with the anchor's codes vs.
#:   the logistic of ``RE- - RE+``), so their confidences are not comparable, and a pass that
#:   just left a human box is the one to trust there.
#: * ``confidence``: the more confident pass's box (ties go forward).
#: * ``blend``: the confidence-weighted mean of both boxes.
#: * ``handover``: forward up to the one frame that maximises the summed confidence of
#:   "forward before, backward from", backward after it.
MERGES = ("anchored", "confidence", "blend", "handover")
#: Measured on ../shared/otb by ``benchmarks/simulated_reviewer.py --merge-study`` (RESULTS.md,
#: "Simulated reviewer: merge study"): anchored > confidence ~ handover > blend.
DEFAULT_MERGE = "anchored"

#: ``scoring`` value of rows no tracker scored (``outside`` rows).
NO_SCORING = "none"
#: Frames a backward pass may hold in memory before it falls back to re-reading in chunks.
DEFAULT_MAX_BUFFER_FRAMES = 512


class FrameProvider(Protocol):
    """Frames by processed-frame position (row of the tracks), read in increasing order."""

    def frames(self, lo: int, hi: int) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(position, (H, W, 3) uint8 RGB)`` for positions ``lo .. hi-1`` in order."""
        ...


class ArrayFrames:
    """A :class:`FrameProvider` over frames held in memory (tests, benchmarks).

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8 ndarray
        Frame ``k`` is processed position ``k``.
    """

    def __init__(self, frames: Sequence[np.ndarray]) -> None:
        self._frames = frames

    def __len__(self) -> int:
        return len(self._frames)

    def frames(self, lo: int, hi: int) -> Iterator[tuple[int, np.ndarray]]:
        for position in range(lo, hi):
            yield position, self._frames[position]


@dataclass(frozen=True)
class PreviousTrack:
    """A track as it stands before re-tracking.

    Attributes
    ----------
    track : TrackResult
        Its rows; ``keyframe`` rows are its anchors (an ``outside`` keyframe is
        an absence anchor).
    scoring : (F,) str ndarray
        Scoring stage of each row (``init``, ``bootstrap``, ``subspace`` or
        ``none``), needed to recompute flags; see :func:`scoring_from_accepted`.
    """

    track: TrackResult
    scoring: np.ndarray

    def __post_init__(self) -> None:
        scoring = np.asarray(self.scoring, dtype=object)
        if scoring.shape != (len(self.track),):
            raise ValueError(f"scoring must have shape ({len(self.track)},) like the track, got {scoring.shape}")
        object.__setattr__(self, "scoring", scoring)

    def anchors(self) -> dict[int, Box | None]:
        """``{position: box or None}`` of the keyframe rows."""
        track = self.track
        return {int(p): (None if track.outside[p] else tuple(float(v) for v in track.boxes_xywh[p]))
                for p in np.flatnonzero(track.keyframe)}


@dataclass(frozen=True)
class Segment:
    """Frames strictly between anchor ``start`` and ``stop`` (``stop`` = F when no anchor follows).

    ``forward``: track forward from ``start``; ``backward``: also backward from
    ``stop``; neither: every frame is outside. ``set_start``: the anchor row
    ``start`` itself is new and must be written.
    """

    track_id: int
    start: int
    stop: int
    forward: bool
    backward: bool
    set_start: bool

    @property
    def interior(self) -> range:
        return range(self.start + 1, self.stop)


@dataclass
class PassResult:
    """One tracker pass over a segment's interior, rows in increasing position order."""

    boxes_xywh: np.ndarray
    confidence: np.ndarray
    log_likelihood: np.ndarray
    accepted: np.ndarray
    scoring: np.ndarray
    seconds: np.ndarray

    @classmethod
    def empty(cls, n: int) -> PassResult:
        return cls(np.full((n, 4), np.nan), np.zeros(n), np.full(n, np.nan), np.zeros(n, bool),
                   np.full(n, NO_SCORING, dtype=object), np.zeros(n))


@dataclass(frozen=True)
class SegmentChange:
    """What re-tracking one segment changed, for the report and run.json."""

    track_id: int
    first_frame: int  # source index of the first re-tracked row (the anchor when it is new)
    last_frame: int
    frames: int  # rows rewritten
    mean_iou: float  # IoU of the new boxes with the previous ones (NaN rows count as 0); NaN without previous
    moved: int  # rows whose new box has IoU < 0.5 with the previous one
    flagged_before: int
    flagged_after: int

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class AnchorChange:
    """A new or changed anchor."""

    track_id: int
    position: int
    frame: int
    box_before: Box | None  # the row's box before (tracker's or previous anchor's); None if it was outside
    box_after: Box | None  # None: absent
    was_anchor: bool
    where: str

    def to_dict(self) -> dict:
        return {
            "track_id": self.track_id, "frame": self.frame,
            "box_before": None if self.box_before is None else [round(v, 3) for v in self.box_before],
            "box_after": None if self.box_after is None else [round(v, 3) for v in self.box_after],
            "was_anchor": self.was_anchor, "source": self.where,
            "iou": _iou_or_none(self.box_before, self.box_after),
        }


@dataclass
class RetrackResult:
    """New tracks, their scoring stages, and what changed."""

    tracks: list[TrackResult]
    scoring: dict[int, np.ndarray]
    anchors: list[AnchorChange]
    segments: list[SegmentChange]
    frames_tracked: int  # tracker calls (init and update) over all passes
    seconds: float
    #: The raw passes of each re-tracked segment, ``(track_id, start, stop) -> (forward, backward or None)``,
    #: for comparing merge methods without tracking again (benchmarks).
    passes: dict[tuple[int, int, int], tuple[PassResult, PassResult | None]] = field(default_factory=dict)

    @property
    def changed(self) -> bool:
        return bool(self.anchors)


# --------------------------------------------------------------------------- small pieces


def pass_seed(seed: int, track_id: int, anchor_frame: int, direction: int, *, first: bool = False) -> np.random.Generator:
    """Generator of one pass: from the run seed, track id, anchor source frame and direction (0 fwd, 1 back).

    The forward pass from the first processed frame (``first=True``) uses the
    run's track seed, as the original run did.
    """
    if first and direction == 0:
        return seed_for_track(seed, track_id)
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(track_id), int(anchor_frame), int(direction)]))


def same_box(a: Box | None, b: Box | None, *, width: int, height: int, tol: float = 2e-3) -> bool:
    """Whether two anchors say the same thing: both absent, or boxes equal after clipping to the frame.

    Clipping and the 1/1000-pixel tolerance make a box read back from the run's
    COCO file (clipped, rounded) the same anchor as the box it was written from.
    """
    if a is None or b is None:
        return a is None and b is None

    def clip(box):
        x, y, w, h = box
        return np.array([max(x, 0.0), max(y, 0.0), min(x + w, width), min(y + h, height)])

    return bool(np.all(np.abs(clip(a) - clip(b)) <= tol))


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise IoU of (N, 4) xywh boxes; 0 where either is NaN."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    x0 = np.maximum(a[:, 0], b[:, 0])
    y0 = np.maximum(a[:, 1], b[:, 1])
    x1 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y1 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    union = a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = inter / union
    return np.where(np.isfinite(iou), iou, 0.0)


def _iou_or_none(a: Box | None, b: Box | None) -> float | None:
    if a is None or b is None or not np.all(np.isfinite(a)) or not np.all(np.isfinite(b)):
        return None
    return round(float(_iou(np.array(a), np.array(b))[0]), 4)


def scoring_from_accepted(accepted: np.ndarray, keyframe: np.ndarray, outside: np.ndarray, params: TrackerParams) -> np.ndarray:
    """Scoring stage of each row of a track tracked forward from its keyframes, from ``accepted`` alone.

    :class:`sptpt.tracker.Tracker` scores with the subspace models once both
    exist: the positive one after ``update_every - 1`` accepted frames, the
    negative one at the first accepted frame from frame ``update_every`` of
    the pass on. Replaying that schedule from the ``accepted`` column gives
    the exact stage of every row of a forward run (as the main command
    writes), which flags need and ``flags.csv`` does not store.

    Returns
    -------
    (F,) object ndarray of str
    """
    accepted = np.asarray(accepted, bool)
    keyframe = np.asarray(keyframe, bool)
    outside = np.asarray(outside, bool)
    scoring = np.empty(len(accepted), dtype=object)
    u = params.update_every
    buffer, positive, negative, frame_number = 1, False, False, 1
    for t in range(len(accepted)):
        if outside[t]:
            scoring[t] = NO_SCORING
            continue
        if keyframe[t]:
            scoring[t] = "init"
            buffer, positive, negative, frame_number = 1, False, False, 1
            continue
        frame_number += 1
        scoring[t] = "subspace" if positive and negative else "bootstrap"
        if accepted[t]:
            buffer += 1
            if buffer == u:
                positive, buffer = True, 0
            if frame_number >= u:
                negative = True
    return scoring


def plan_segments(track_id: int, anchors: Mapping[int, Box | None], changed: set[int], n_frames: int) -> list[Segment]:
    """The segments of one track to re-track, given its anchors and which of them are new or changed.

    Parameters
    ----------
    anchors : mapping position -> box or None
        All anchors after applying the corrections; must include position 0.
    changed : set of int
        Positions of new or changed anchors (all of them for a first run).
    n_frames : int
        Rows of the track.
    """
    if 0 not in anchors:
        raise ValueError("anchors must include position 0 (the first-frame box)")
    positions = sorted(anchors)
    segments = []
    for k, start in enumerate(positions):
        stop = positions[k + 1] if k + 1 < len(positions) else n_frames
        stop_changed = stop in changed if stop < n_frames else False
        if start not in changed and not stop_changed:
            continue
        present = anchors[start] is not None
        backward = present and stop < n_frames and anchors[stop] is not None
        segments.append(Segment(track_id, start, stop, forward=present, backward=backward,
                                set_start=start in changed))
    return segments


def merge_passes(fwd: PassResult, bwd: PassResult | None, method: str = DEFAULT_MERGE) -> PassResult:
    """Combine a forward and a backward pass over the same frames (see :data:`MERGES`).

    ``bwd=None`` returns the forward pass. Per row the result keeps the
    log-likelihood, acceptance and scoring stage of the pass whose box (or
    whose larger weight, for ``blend``) it takes; ``seconds`` is the sum of both.
    """
    if method not in MERGES:
        raise ValueError(f"merge method {method!r} is not known: choose from {', '.join(MERGES)}")
    if bwd is None:
        return fwd
    n = len(fwd.confidence)
    cf, cb = fwd.confidence, bwd.confidence
    if method == "handover":
        # Forward up to t*, backward from t*: t* maximises sum(cf[:t*]) + sum(cb[t*:]).
        gain = np.concatenate([[0.0], np.cumsum(cf)]) + np.concatenate([np.cumsum(cb[::-1])[::-1], [0.0]])
        switch = int(np.argmax(gain))
        take_fwd = np.arange(n) < switch
    elif method == "anchored":
        fresh_f = np.asarray(fwd.scoring == "bootstrap", dtype=bool)
        fresh_b = np.asarray(bwd.scoring == "bootstrap", dtype=bool)
        take_fwd = np.where(fresh_f & ~fresh_b, True, np.where(fresh_b & ~fresh_f, False, cf >= cb))
    else:
        take_fwd = cf >= cb
    pick = lambda a, b: np.where(take_fwd.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
    out = PassResult(
        boxes_xywh=pick(fwd.boxes_xywh, bwd.boxes_xywh),
        confidence=pick(cf, cb),
        log_likelihood=pick(fwd.log_likelihood, bwd.log_likelihood),
        accepted=pick(fwd.accepted, bwd.accepted),
        scoring=pick(fwd.scoring, bwd.scoring),
        seconds=fwd.seconds + bwd.seconds,
    )
    if method == "blend":
        total = cf + cb
        w = np.where(total > 0, cf / np.where(total > 0, total, 1.0), 0.5)
        out.boxes_xywh = w[:, None] * fwd.boxes_xywh + (1 - w[:, None]) * bwd.boxes_xywh
        out.confidence = np.clip(w * cf + (1 - w) * cb, 0.0, 1.0)
    return out


def reflag(log_likelihood: np.ndarray, confidence: np.ndarray, scoring: np.ndarray, keyframe: np.ndarray,
           outside: np.ndarray, config: RunConfig) -> tuple[np.ndarray, tuple[str, ...]]:
    """Flags of a whole track: :func:`flag_frames` with anchors and ``outside`` rows exempt, then absences flagged.

    ``outside`` rows are passed to the flagger as keyframes: they have no
    tracker score, must not hold a span open, and must not bridge two flagged
    stretches; afterwards they are flagged with reason ``outside`` (FORMATS.md:
    absences are recorded in the flags file), human-marked absences included.
    """
    outside = np.asarray(outside, bool)
    result = flag_frames(log_likelihood, confidence, np.asarray(scoring, dtype=str), config.flags,
                         keyframe=np.asarray(keyframe, bool) | outside)
    flagged = result.flagged | outside
    reasons = tuple("outside" if outside[i] else r for i, r in enumerate(result.reasons))
    return flagged, reasons


# --------------------------------------------------------------------------- the passes


@dataclass
class _CachedPass:
    """A pass as it was run: rows in pass order (backward passes: nearest the anchor first)."""

    rows: PassResult
    init_log_likelihood: float
    init_seconds: float


def _take(result: PassResult, index) -> PassResult:
    return PassResult(*(np.asarray(getattr(result, f))[index].copy() for f in
                        ("boxes_xywh", "confidence", "log_likelihood", "accepted", "scoring", "seconds")))


class _SegmentRun:
    """Runs the passes of one segment while frames stream by (or takes them from a pass cache)."""

    def __init__(self, segment: Segment, box_start: Box | None, box_stop: Box | None, frame_indices: np.ndarray,
                 params: TrackerParams, seed: int, max_buffer: int, cache: dict | None) -> None:
        self.segment = segment
        self.box_start, self.box_stop = box_start, box_stop
        self.frame_indices = frame_indices
        self.params, self.seed = params, seed
        self.cache = cache
        n = len(segment.interior)
        self.fwd = PassResult.empty(n)
        self.bwd = PassResult.empty(n) if segment.backward else None
        self.start_row: tuple | None = None  # (log-likelihood, seconds) of the forward pass's init on the anchor
        self.calls = 0
        self.fwd_todo, self.bwd_todo = segment.forward, segment.backward
        if cache is not None:
            self._from_cache(n)
        # The backward pass buffers its frames only when the segment is short enough.
        self.buffered = self.bwd_todo and n <= max_buffer
        self.deferred = self.bwd_todo and not self.buffered
        self._buffer: list[np.ndarray] = []
        self._tracker: Tracker | None = None

    def _key(self, direction: int) -> tuple:
        s = self.segment
        position, box = (s.start, self.box_start) if direction == 0 else (s.stop, self.box_stop)
        return (s.track_id, position, direction, tuple(float(v) for v in box))

    def _from_cache(self, n: int) -> None:
        # A pass is deterministic (its seed depends only on the anchor), so a longer run of it
        # already made holds this segment's rows as its first n rows.
        if self.fwd_todo:
            hit = self.cache.get(self._key(0))
            if hit is not None and len(hit.rows.confidence) >= n:
                self.fwd = _take(hit.rows, slice(0, n))
                self.start_row = (hit.init_log_likelihood, hit.init_seconds)
                self.fwd_todo = False
        if self.bwd_todo:
            hit = self.cache.get(self._key(1))
            if hit is not None and len(hit.rows.confidence) >= n:
                self.bwd = _take(hit.rows, slice(n - 1, None, -1) if n else slice(0, 0))
                self.bwd_todo = False

    def _remember(self, direction: int, rows: PassResult, init: tuple[float, float]) -> None:
        if self.cache is None:
            return
        key = self._key(direction)
        known = self.cache.get(key)
        if known is None or len(known.rows.confidence) < len(rows.confidence):
            ordered = rows if direction == 0 else _take(rows, slice(None, None, -1))
            self.cache[key] = _CachedPass(ordered, *init)

    @property
    def planned(self) -> int:
        """Tracker calls this segment will make."""
        n = len(self.segment.interior)
        return (1 + n if self.fwd_todo else 0) + (1 + n if self.bwd_todo else 0)

    @property
    def needed(self) -> tuple[int, int] | None:
        """``[lo, hi)`` of positions this segment reads in the main sweep."""
        s = self.segment
        if self.fwd_todo:
            return s.start, (s.stop + 1 if self.buffered else s.stop)
        if self.buffered:
            return s.start + 1, s.stop + 1
        return None

    def _tracker_for(self, position: int, direction: int) -> Tracker:
        first = position == 0
        rng = pass_seed(self.seed, self.segment.track_id, int(self.frame_indices[position]), direction, first=first)
        return Tracker(self.params, seed=rng)

    def feed(self, position: int, frame: np.ndarray) -> None:
        s = self.segment
        if position == s.start and self.fwd_todo:
            self._tracker = self._tracker_for(position, 0)
            tic = time.perf_counter()
            result = self._tracker.init(frame, self.box_start)
            self.start_row = (result.log_likelihood, time.perf_counter() - tic)
            self.calls += 1
        elif s.start < position < s.stop:
            if self.fwd_todo:
                tic = time.perf_counter()
                result = self._tracker.update(frame)
                self._store(self.fwd, position - s.start - 1, result, time.perf_counter() - tic)
            if self.buffered:
                self._buffer.append(frame)
        if position == s.stop - 1 and self.fwd_todo:
            self._tracker = None
            self.fwd_todo = False
            self._remember(0, self.fwd, self.start_row)
        if position == s.stop and self.buffered:
            self._backward(frame, reversed(self._buffer), s.stop - 1)
            self._buffer = []
            self.buffered = False

    def run_deferred(self, provider: FrameProvider, chunk: int) -> None:
        """The backward pass of a long segment: chunks of ``chunk`` frames, last chunk first."""
        s = self.segment
        hi = s.stop + 1
        tracker = None
        while hi > s.start + 1:
            lo = max(s.start + 1, hi - chunk)
            frames = [f for _, f in provider.frames(lo, hi)]
            if tracker is None:
                tracker = self._backward(frames[-1], reversed(frames[:-1]), hi - 2, remember=False)
            else:
                self._backward_continue(tracker, reversed(frames), hi - 1)
            hi = lo
        self.deferred = False
        self._remember(1, self.bwd, (float("nan"), 0.0))

    def _backward(self, anchor_frame: np.ndarray, frames, first_position: int, *, remember: bool = True) -> Tracker:
        tracker = self._tracker_for(self.segment.stop, 1)
        tracker.init(anchor_frame, self.box_stop)
        self.calls += 1
        self._backward_continue(tracker, frames, first_position)
        if remember:
            self._remember(1, self.bwd, (float("nan"), 0.0))
        return tracker

    def _backward_continue(self, tracker: Tracker, frames, first_position: int) -> None:
        position = first_position
        for frame in frames:
            tic = time.perf_counter()
            result = tracker.update(frame)
            self._store(self.bwd, position - self.segment.start - 1, result, time.perf_counter() - tic)
            position -= 1

    def _store(self, target: PassResult, row: int, result, seconds: float) -> None:
        target.boxes_xywh[row] = result.box_xywh
        target.confidence[row] = result.confidence
        target.log_likelihood[row] = result.log_likelihood
        target.accepted[row] = result.accepted
        target.scoring[row] = result.scoring
        target.seconds[row] = seconds
        self.calls += 1


def _merge_intervals(intervals: list[tuple[int, int]]) -> list[tuple[int, int]]:
    merged: list[list[int]] = []
    for lo, hi in sorted(intervals):
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    return [(lo, hi) for lo, hi in merged]


def retrack_tracks(
    frames: FrameProvider,
    frame_indices: np.ndarray,
    anchors: Mapping[int, Mapping[int, Box | None | tuple[Box | None, str]]],
    config: RunConfig,
    *,
    previous: Mapping[int, PreviousTrack] | None = None,
    labels: Mapping[int, str] | None = None,
    width: int | None = None,
    height: int | None = None,
    merge: str = DEFAULT_MERGE,
    max_buffer_frames: int = DEFAULT_MAX_BUFFER_FRAMES,
    progress: Callable[[int, int], None] | None = None,
    pass_cache: dict | None = None,
) -> RetrackResult:
    """Apply anchors to tracks and re-track exactly the segments they affect.

    Parameters
    ----------
    frames : FrameProvider
        The processed frames by position.
    frame_indices : (F,) int ndarray
        Source index of each processed position (for seeds and reports).
    anchors : mapping track_id -> {position: box or None, or (box or None, where)}
        Corrections (0-based ``xywh``; None = absent from here to the next
        anchor). With ``previous``, they are merged into each track's existing
        anchors, replacing those at the same positions. Without ``previous``
        every track is tracked from scratch and needs an anchor at position 0.
    config : RunConfig
        Tracker parameters, flag thresholds and seed (the run's).
    previous : mapping track_id -> PreviousTrack, optional
        The tracks before the corrections; segments no new anchor touches keep
        these rows. Tracks not named in ``anchors`` are kept as they are.
    labels : mapping track_id -> str, optional
        Labels of tracks without ``previous`` (default ``"object"``).
    width, height : int, optional
        Frame size, to decide whether a correction equals an existing anchor
        after clipping; defaults to an unbounded frame.
    merge : str
        How frames between two anchors combine the passes (:data:`MERGES`).
    max_buffer_frames : int
        Longest segment whose backward pass is buffered in one go (see module docstring).
    progress : callable, optional
        ``progress(done, total)`` with the tracker calls (init and update)
        made so far and planned in all, after each frame read.
    pass_cache : dict, optional
        Passes already run, kept across calls by a caller that re-tracks the
        same frames with the same config again and again (the simulated
        reviewer): a pass is deterministic given its anchor, so a segment
        whose pass from an unchanged anchor was run before, over at least as
        many frames, reuses its rows instead of tracking again. Start with
        ``{}``; the results are identical with or without it.

    Returns
    -------
    RetrackResult
    """
    if merge not in MERGES:
        raise ValueError(f"merge={merge!r} is not known: choose from {', '.join(MERGES)}")
    if max_buffer_frames < 1:
        raise ValueError(f"max_buffer_frames must be >= 1, got {max_buffer_frames}")
    started = time.perf_counter()
    frame_indices = np.asarray(frame_indices, dtype=np.int64)
    n = len(frame_indices)
    previous = dict(previous or {})
    width = np.inf if width is None else width
    height = np.inf if height is None else height
    track_ids = list(dict.fromkeys([*previous, *anchors]))

    runs: list[_SegmentRun] = []
    plans: dict[int, tuple[dict, list[Segment]]] = {}
    anchor_changes: list[AnchorChange] = []
    for tid in track_ids:
        given = {int(p): (v if isinstance(v, tuple) and len(v) == 2 and not _is_number(v[0]) else (v, ""))
                 for p, v in (anchors.get(tid) or {}).items()}
        for p in given:
            if not 0 <= p < n:
                raise ValueError(f"track {tid}: anchor position {p} is outside the {n} processed frames")
        if tid in previous:
            prev = previous[tid]
            if len(prev.track) != n:
                raise ValueError(f"track {tid} has {len(prev.track)} rows but {n} frame indices were given")
            current = prev.anchors()
            changed = set()
            for p, (box, where) in sorted(given.items()):
                box = None if box is None else tuple(float(v) for v in box)
                if p in current and same_box(current[p], box, width=width, height=height):
                    continue
                before = None if prev.track.outside[p] else tuple(float(v) for v in prev.track.boxes_xywh[p])
                anchor_changes.append(AnchorChange(tid, p, int(frame_indices[p]), before, box, p in current, where))
                current[p] = box
                changed.add(p)
        else:
            if 0 not in given:
                raise ValueError(f"track {tid} has no previous rows and no anchor at position 0 to start from")
            current = {p: (None if b is None else tuple(float(v) for v in b)) for p, (b, _) in given.items()}
            changed = set(current)
            anchor_changes.extend(AnchorChange(tid, p, int(frame_indices[p]), None, current[p], False, given[p][1])
                                  for p in sorted(changed))
        segments = plan_segments(tid, current, changed, n)
        plans[tid] = (current, segments)
        for seg in segments:
            box_stop = current.get(seg.stop) if seg.stop < n else None
            runs.append(_SegmentRun(seg, current[seg.start], box_stop, frame_indices, config.tracker, config.seed,
                                    max_buffer_frames, pass_cache))

    # One ordered sweep over the frames any pass needs.
    spans = [(r.needed, r) for r in runs if r.needed is not None]  # fixed before the sweep changes them
    intervals = _merge_intervals([span for span, _ in spans])
    by_start = sorted(spans, key=lambda item: item[0][0])
    active: list[tuple[tuple[int, int], _SegmentRun]] = []
    nxt = 0
    planned = sum(r.planned for r in runs)
    for lo, hi in intervals:
        for position, frame in frames.frames(lo, hi):
            while nxt < len(by_start) and by_start[nxt][0][0] <= position:
                active.append(by_start[nxt])
                nxt += 1
            for _, run in active:
                run.feed(position, frame)
            active = [(span, r) for span, r in active if span[1] > position + 1]
            if progress is not None:
                progress(sum(r.calls for r in runs), planned)
    for run in runs:
        if run.deferred:
            run.run_deferred(frames, max_buffer_frames)
            if progress is not None:
                progress(sum(r.calls for r in runs), planned)

    # Assemble the new rows.
    results: list[TrackResult] = []
    scorings: dict[int, np.ndarray] = {}
    changes: list[SegmentChange] = []
    runs_by_track: dict[int, list[_SegmentRun]] = {}
    for run in runs:
        runs_by_track.setdefault(run.segment.track_id, []).append(run)
    for tid in track_ids:
        current, segments = plans[tid]
        prev = previous.get(tid)
        if prev is not None:
            t = prev.track
            boxes, conf, ll = t.boxes_xywh.copy(), t.confidence.copy(), t.log_likelihood.copy()
            accepted, seconds = t.accepted.copy(), t.seconds.copy()
            keyframe, outside, occluded = t.keyframe.copy(), t.outside.copy(), t.occluded.copy()
            scoring = prev.scoring.copy()
            sources = list(t.keyframe_source)
            label = t.label
        else:
            boxes, conf, ll = np.full((n, 4), np.nan), np.zeros(n), np.full(n, np.nan)
            accepted, seconds = np.zeros(n, bool), np.zeros(n)
            keyframe, outside, occluded = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
            scoring = np.full(n, NO_SCORING, dtype=object)
            sources = [""] * n
            label = (labels or {}).get(tid, "object")
        for change in anchor_changes:
            if change.track_id == tid:
                sources[change.position] = change.where or KEYFRAME_GIVEN
        rewritten: list[tuple[int, int]] = []
        for run in runs_by_track.get(tid, []):
            seg = run.segment
            lo = seg.start if seg.set_start else seg.start + 1
            rewritten.append((lo, seg.stop))
            if seg.set_start:
                box = current[seg.start]
                keyframe[seg.start] = True
                occluded[seg.start] = False
                if box is None:
                    boxes[seg.start], conf[seg.start], ll[seg.start] = np.nan, 0.0, np.nan
                    accepted[seg.start], seconds[seg.start] = False, 0.0
                    outside[seg.start], scoring[seg.start] = True, NO_SCORING
                else:
                    loglik, secs = run.start_row
                    boxes[seg.start], conf[seg.start], ll[seg.start] = box, 1.0, loglik
                    accepted[seg.start], seconds[seg.start] = True, secs
                    outside[seg.start], scoring[seg.start] = False, "init"
            rows = slice(seg.start + 1, seg.stop)
            keyframe[rows] = False
            sources[seg.start + 1:seg.stop] = [""] * (seg.stop - seg.start - 1)
            occluded[rows] = False
            if seg.forward:
                merged = merge_passes(run.fwd, run.bwd, merge)
                boxes[rows], conf[rows], ll[rows] = merged.boxes_xywh, merged.confidence, merged.log_likelihood
                accepted[rows], scoring[rows], seconds[rows] = merged.accepted, merged.scoring, merged.seconds
                outside[rows] = False
            else:
                boxes[rows], conf[rows], ll[rows] = np.nan, 0.0, np.nan
                accepted[rows], scoring[rows], seconds[rows] = False, NO_SCORING, 0.0
                outside[rows] = True
        # Anchors set without a segment of their own cannot occur: every changed anchor starts one.
        flagged, reasons = reflag(ll, conf, scoring, keyframe, outside, config)
        track = TrackResult(
            track_id=tid, label=label, frame_indices=frame_indices, boxes_xywh=boxes, confidence=conf,
            log_likelihood=ll, accepted=accepted, flagged=flagged, reasons=reasons, keyframe=keyframe,
            outside=outside, seconds=seconds, occluded=occluded, scoring=tuple(str(v) for v in scoring),
            keyframe_source=tuple(sources),
        )
        results.append(track)
        scorings[tid] = scoring
        for lo, hi in rewritten:
            if hi <= lo:
                continue
            if prev is not None:
                iou = _iou(prev.track.boxes_xywh[lo:hi], boxes[lo:hi])
                both_outside = prev.track.outside[lo:hi] & outside[lo:hi]
                iou = np.where(both_outside, 1.0, iou)
                mean_iou, moved = float(iou.mean()), int((iou < 0.5).sum())
                before = int(prev.track.flagged[lo:hi].sum())
            else:
                mean_iou, moved, before = float("nan"), 0, 0
            changes.append(SegmentChange(tid, int(frame_indices[lo]), int(frame_indices[hi - 1]), hi - lo,
                                         round(mean_iou, 4) if np.isfinite(mean_iou) else mean_iou, moved, before,
                                         int(flagged[lo:hi].sum())))
    return RetrackResult(tracks=results, scoring=scorings, anchors=anchor_changes,
                         segments=sorted(changes, key=lambda c: (c.first_frame, c.track_id)),
                         frames_tracked=sum(r.calls for r in runs), seconds=time.perf_counter() - started,
                         passes={(r.segment.track_id, r.segment.start, r.segment.stop): (r.fwd, r.bwd)
                                 for r in runs if r.segment.forward})


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating))

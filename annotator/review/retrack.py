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
``pass_cache`` skips it when a caller keeps the passes: the command line
keeps them in the run folder (:mod:`annotator.pass_cache`), the
simulated reviewer in memory.

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

Failure probabilities and flags are recomputed over whole tracks
(:func:`annotator.review.merge.reflag`) from each row's failure signals: the
stored ones for kept rows, those of the chosen pass for re-tracked rows
(anchors are never flagged; ``outside`` frames are flagged ``outside``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from annotator.config import RunConfig
from annotator.failure import SIGNALS
from annotator.review.merge import (
    DEFAULT_MERGE,
    MERGES,
    NO_SCORING,
    PASS_CHOICE,
    PASS_IOU,
    PassResult,
    merge_passes,
    reflag,
)
from annotator.review.passes import DEFAULT_MAX_BUFFER_FRAMES, FrameProvider, SegmentRun
from annotator.review.segments import (
    AnchorChange,
    Box,
    PreviousTrack,
    SegmentChange,
    box_of,
    plan_segments,
    same_box,
)
from annotator.tracks import KEYFRAME_GIVEN, TrackResult
from sptpt import compile_kernels
from sptpt.boxes import iou_xywh

__all__ = ["RetrackResult", "retrack_tracks"]


@dataclass
class RetrackResult:
    """New tracks, their scoring stages, and what changed.

    Attributes
    ----------
    tracks : list of TrackResult
        Every track after the re-track, in the run's order.
    scoring : dict of int to numpy.ndarray
        Per track id, each row's scoring stage.
    anchors : list of AnchorChange
        The anchors the corrections added or changed.
    segments : list of SegmentChange
        What re-tracking each segment changed.
    frames_tracked : int
        Tracker calls (init and update) over all passes.
    seconds : float
        Wall time of the re-track.
    passes : dict
        The raw passes of each re-tracked segment, ``(track_id, start, stop) -> (forward, backward or None)``, for
        comparing merge methods without tracking again (benchmarks).
    """

    tracks: list[TrackResult]
    scoring: dict[int, np.ndarray]
    anchors: list[AnchorChange]
    segments: list[SegmentChange]
    frames_tracked: int
    seconds: float
    passes: dict[tuple[int, int, int], tuple[PassResult, PassResult | None]] = field(default_factory=dict)

    @property
    def changed(self) -> bool:
        return bool(self.anchors)

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
    previous = dict(previous or {})
    # No size given: nothing is clipped.
    clip_width: float = np.inf if width is None else width
    clip_height: float = np.inf if height is None else height
    track_ids = list(dict.fromkeys([*previous, *anchors]))

    plans, runs, anchor_changes = _plan_runs(track_ids, anchors, previous, frame_indices, config, clip_width,
                                             clip_height, max_buffer_frames, pass_cache)
    _run_passes(frames, runs, max_buffer_frames, progress)
    results, scorings, changes = _assemble_tracks(track_ids, plans, runs, anchor_changes, previous, labels or {},
                                                  frame_indices, config, merge)
    return RetrackResult(tracks=results, scoring=scorings, anchors=anchor_changes,
                         segments=sorted(changes, key=lambda c: (c.first_frame, c.track_id)),
                         frames_tracked=sum(r.calls for r in runs), seconds=time.perf_counter() - started,
                         passes={(r.segment.track_id, r.segment.start, r.segment.stop): (r.fwd, r.bwd)
                                 for r in runs if r.segment.forward})


def _plan_runs(track_ids: list[int], anchors: Mapping, previous: dict[int, PreviousTrack], frame_indices: np.ndarray,
               config: RunConfig, width: float, height: float, max_buffer_frames: int, pass_cache: dict | None,
               ) -> tuple[dict[int, dict[int, Box | None]], list[SegmentRun], list[AnchorChange]]:
    """Each track's anchors in force, the segment runs their changes need, and the changes themselves."""
    n = len(frame_indices)
    runs: list[SegmentRun] = []
    plans: dict[int, dict[int, Box | None]] = {}
    anchor_changes: list[AnchorChange] = []
    for tid in track_ids:
        current, changed, track_changes = _anchors_in_force(tid, anchors.get(tid) or {}, previous.get(tid),
                                                            frame_indices, width, height)
        anchor_changes += track_changes
        plans[tid] = current
        for seg in plan_segments(tid, current, changed, n):
            box_stop = current.get(seg.stop) if seg.stop < n else None
            runs.append(SegmentRun(seg, current[seg.start], box_stop, frame_indices, config.tracker, config.seed,
                                   max_buffer_frames, pass_cache))
    return plans, runs, anchor_changes


def _assemble_tracks(track_ids: list[int], plans: dict[int, dict[int, Box | None]], runs: list[SegmentRun],
                     anchor_changes: list[AnchorChange], previous: dict[int, PreviousTrack], labels: Mapping[int, str],
                     frame_indices: np.ndarray, config: RunConfig, merge: str,
                     ) -> tuple[list[TrackResult], dict[int, np.ndarray], list[SegmentChange]]:
    """The new tracks: the previous rows with the re-tracked segments written over them, flagged again."""
    n = len(frame_indices)
    model = config.load_failure_model()
    results: list[TrackResult] = []
    scorings: dict[int, np.ndarray] = {}
    changes: list[SegmentChange] = []
    for tid in track_ids:
        prev = previous.get(tid)
        columns = _Columns.of(prev, n) if prev is not None else _Columns.empty(n, labels.get(tid, "object"))
        for change in anchor_changes:
            if change.track_id == tid:
                columns.sources[change.position] = change.where or KEYFRAME_GIVEN
        track_runs = [run for run in runs if run.segment.track_id == tid]
        for run in track_runs:
            columns.rewrite(run, plans[tid], merge, model)
        # Anchors set without a segment of their own cannot occur: every changed anchor starts one.
        track = columns.track(tid, frame_indices, config, model)
        results.append(track)
        scorings[tid] = columns.scoring
        changes += _segment_changes(tid, track_runs, prev, columns, track.flagged, frame_indices)
    return results, scorings, changes


def _anchors_in_force(tid: int, given_anchors: Mapping, prev: PreviousTrack | None, frame_indices: np.ndarray,
                      width: float, height: float) -> tuple[dict[int, Box | None], set[int], list[AnchorChange]]:
    """A track's anchors once ``given_anchors`` are applied, the positions that changed, and the changes."""
    n = len(frame_indices)
    given = {int(p): (v if isinstance(v, tuple) and len(v) == 2 and not _is_number(v[0]) else (v, ""))
             for p, v in given_anchors.items()}
    for p in given:
        if not 0 <= p < n:
            raise ValueError(f"track {tid}: anchor position {p} is outside the {n} processed frames")
    if prev is None:
        if 0 not in given:
            raise ValueError(f"track {tid} has no previous rows and no anchor at position 0 to start from")
        current = {p: (None if b is None else box_of(b)) for p, (b, _) in given.items()}
        return current, set(current), [AnchorChange(tid, p, int(frame_indices[p]), None, current[p], False,
                                                    given[p][1]) for p in sorted(current)]
    if len(prev.track) != n:
        raise ValueError(f"track {tid} has {len(prev.track)} rows but {n} frame indices were given")
    current = prev.anchors()
    changed: set[int] = set()
    changes: list[AnchorChange] = []
    for p, (box, where) in sorted(given.items()):
        box = None if box is None else box_of(box)
        if p in current and same_box(current[p], box, width=width, height=height):
            continue
        before = None if prev.track.outside[p] else box_of(prev.track.boxes_xywh[p])
        changes.append(AnchorChange(tid, p, int(frame_indices[p]), before, box, p in current, where))
        current[p] = box
        changed.add(p)
    return current, changed, changes


def _run_passes(frames: FrameProvider, runs: list[SegmentRun], max_buffer_frames: int,
                progress: Callable[[int, int], None] | None) -> None:
    """Every segment's passes, in one ordered sweep over the frames any of them needs, then the deferred ones."""
    spans = [(r.needed, r) for r in runs if r.needed is not None]  # fixed before the sweep changes them
    if spans:
        compile_kernels(wait=False)  # as in annotator.pipeline.track_source
    by_start = sorted(spans, key=lambda item: item[0][0])
    active: list[tuple[tuple[int, int], SegmentRun]] = []
    nxt = 0
    planned = sum(r.planned for r in runs)
    for lo, hi in _merge_intervals([span for span, _ in spans]):
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


@dataclass
class _Columns:
    """A track's per-row columns while its re-tracked segments are written into them."""

    label: str
    boxes: np.ndarray
    conf: np.ndarray
    ll: np.ndarray
    accepted: np.ndarray
    seconds: np.ndarray
    keyframe: np.ndarray
    outside: np.ndarray
    occluded: np.ndarray
    scoring: np.ndarray
    sources: list[str]
    signals: np.ndarray  # (n, len(SIGNALS))
    pass_iou: np.ndarray
    choice: np.ndarray

    @classmethod
    def of(cls, prev: PreviousTrack, n: int) -> _Columns:
        """Copies of the previous track's rows: what segments no new anchor touches keep."""
        t = prev.track
        return cls(
            label=t.label, boxes=t.boxes_xywh.copy(), conf=t.confidence.copy(), ll=t.log_likelihood.copy(),
            accepted=t.accepted.copy(), seconds=t.seconds.copy(), keyframe=t.keyframe.copy(),
            outside=t.outside.copy(), occluded=t.occluded.copy(), scoring=prev.scoring.copy(),
            sources=list(t.keyframe_source),
            signals=np.stack([np.asarray(t.signals.get(name, np.full(n, np.nan)), dtype=np.float64)
                              for name in SIGNALS], axis=1),
            pass_iou=np.array(t.signals.get(PASS_IOU, np.full(n, np.nan)), dtype=np.float64),
            choice=np.array(t.signals.get(PASS_CHOICE, np.full(n, np.nan)), dtype=np.float64))

    @classmethod
    def empty(cls, n: int, label: str) -> _Columns:
        """A track tracked from scratch: every row is written by a segment."""
        return cls(
            label=label, boxes=np.full((n, 4), np.nan), conf=np.zeros(n), ll=np.full(n, np.nan),
            accepted=np.zeros(n, bool), seconds=np.zeros(n), keyframe=np.zeros(n, bool), outside=np.zeros(n, bool),
            occluded=np.zeros(n, bool), scoring=np.full(n, NO_SCORING, dtype=object), sources=[""] * n,
            signals=np.full((n, len(SIGNALS)), np.nan), pass_iou=np.full(n, np.nan), choice=np.full(n, np.nan))

    def rewrite(self, run: SegmentRun, current: Mapping[int, Box | None], merge: str, model) -> None:
        """Write a re-tracked segment: its start anchor's row when it sets one, and its interior."""
        seg = run.segment
        if seg.set_start:
            self._anchor_row(seg.start, current[seg.start], run.start_row)
        rows = slice(seg.start + 1, seg.stop)
        self.keyframe[rows] = False
        self.sources[seg.start + 1:seg.stop] = [""] * (seg.stop - seg.start - 1)
        self.occluded[rows] = False
        if seg.forward:
            ends = None
            if run.bwd is not None:
                box_start, box_stop = current[seg.start], current.get(seg.stop)
                assert box_start is not None and box_stop is not None  # a backward pass runs between two boxes
                ends = (box_start, box_stop)
            merged = merge_passes(run.fwd, run.bwd, merge, model=model, ends=ends)
            self.boxes[rows], self.conf[rows] = merged.boxes_xywh, merged.confidence
            self.ll[rows], self.accepted[rows] = merged.log_likelihood, merged.accepted
            self.scoring[rows], self.seconds[rows] = merged.scoring, merged.seconds
            self.signals[rows] = merged.signals
            self.pass_iou[rows], self.choice[rows] = merged.pass_iou, merged.choice
            self.outside[rows] = False
        else:
            self.boxes[rows], self.conf[rows], self.ll[rows] = np.nan, 0.0, np.nan
            self.accepted[rows], self.scoring[rows], self.seconds[rows] = False, NO_SCORING, 0.0
            self.signals[rows] = np.nan
            self.pass_iou[rows] = self.choice[rows] = np.nan
            self.outside[rows] = True

    def _anchor_row(self, position: int, box: Box | None, start_row: tuple[float, float] | None) -> None:
        self.keyframe[position] = True
        self.occluded[position] = False
        self.signals[position] = np.nan  # a person's box: nothing measured, nothing doubtful
        self.pass_iou[position] = self.choice[position] = np.nan
        if box is None:
            self.boxes[position], self.conf[position], self.ll[position] = np.nan, 0.0, np.nan
            self.accepted[position], self.seconds[position] = False, 0.0
            self.outside[position], self.scoring[position] = True, NO_SCORING
        else:
            assert start_row is not None  # a box anchor starts a forward pass, which sets its row
            loglik, secs = start_row
            self.boxes[position], self.conf[position], self.ll[position] = box, 1.0, loglik
            self.accepted[position], self.seconds[position] = True, secs
            self.outside[position], self.scoring[position] = False, "init"

    def track(self, tid: int, frame_indices: np.ndarray, config: RunConfig, model) -> TrackResult:
        """The track of these rows, flagged again from their signals."""
        by_name = {name: self.signals[:, k] for k, name in enumerate(SIGNALS)}
        flagged, reasons, p_fail = reflag(by_name, self.keyframe, self.outside, config, pass_iou=self.pass_iou,
                                          model=model)
        conf = np.where(self.outside, 0.0, 1.0 - np.nan_to_num(p_fail, nan=1.0))
        # Only a track with rows merged from two passes carries the column: a run nobody corrected keeps its files.
        passes = {PASS_IOU: self.pass_iou} if np.any(~np.isnan(self.pass_iou)) else {}
        if np.any(~np.isnan(self.choice)):
            passes[PASS_CHOICE] = self.choice
        return TrackResult(
            track_id=tid, label=self.label, frame_indices=frame_indices, boxes_xywh=self.boxes, confidence=conf,
            log_likelihood=self.ll, accepted=self.accepted, flagged=flagged, reasons=reasons, keyframe=self.keyframe,
            outside=self.outside, seconds=self.seconds, occluded=self.occluded,
            scoring=tuple(str(v) for v in self.scoring), keyframe_source=tuple(self.sources),
            signals={**by_name, "p_fail": p_fail, **passes},
        )


def _segment_changes(tid: int, runs: list[SegmentRun], prev: PreviousTrack | None, columns: _Columns,
                     flagged: np.ndarray, frame_indices: np.ndarray) -> list[SegmentChange]:
    """What each re-tracked segment of a track changed: boxes moved and flags before and after."""
    changes = []
    for run in runs:
        seg = run.segment
        lo, hi = (seg.start if seg.set_start else seg.start + 1), seg.stop
        if hi <= lo:
            continue
        if prev is not None:
            # A missing box overlaps nothing.
            iou = np.nan_to_num(iou_xywh(prev.track.boxes_xywh[lo:hi], columns.boxes[lo:hi]), nan=0.0)
            both_outside = prev.track.outside[lo:hi] & columns.outside[lo:hi]
            iou = np.where(both_outside, 1.0, iou)
            mean_iou, moved = float(iou.mean()), int((iou < 0.5).sum())
            before = int(prev.track.flagged[lo:hi].sum())
        else:
            mean_iou, moved, before = float("nan"), 0, 0
        changes.append(SegmentChange(tid, int(frame_indices[lo]), int(frame_indices[hi - 1]), hi - lo,
                                     round(mean_iou, 4) if np.isfinite(mean_iou) else mean_iou, moved, before,
                                     int(flagged[lo:hi].sum())))
    return changes


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating))


def _merge_intervals(intervals: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Overlapping or touching ``[lo, hi)`` intervals joined, in increasing order."""
    merged: list[list[int]] = []
    for lo, hi in sorted(intervals):
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    return [(lo, hi) for lo, hi in merged]

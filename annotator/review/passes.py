"""The tracker passes of a re-track: forward and backward from anchors, over frames read in one sweep.

Each pass has its own generator (:func:`pass_seed`), so a pass depends only on
its anchor and a re-track is reproducible. Frames come from a
:class:`FrameProvider`; a long backward pass is re-read in chunks (see
:mod:`annotator.review.retrack`).
"""

from __future__ import annotations

import time
from typing import Iterator, Protocol, Sequence

import numpy as np

from annotator.failure import SIGNALS, SignalMeter
from annotator.kmeans_child import DICTIONARY_KMEANS
from annotator.nanotrack import guide_for
from annotator.pass_cache import CachedPass, PassKey, PassResult, pass_key
from annotator.pipeline import FramesAhead, seed_for_track
from annotator.review.segments import Box, Segment
from sptpt import Tracker, TrackerParams

__all__ = ["DEFAULT_MAX_BUFFER_FRAMES", "ArrayFrames", "FrameProvider", "SegmentRun", "pass_seed"]

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

def pass_seed(seed: int, track_id: int, anchor_frame: int, direction: int, *,
              first: bool = False) -> np.random.Generator:
    """Generator of one pass: from the run seed, track id, anchor source frame and direction (0 fwd, 1 back).

    The forward pass from the first processed frame (``first=True``) uses the
    run's track seed, as the original run did.
    """
    if first and direction == 0:
        return seed_for_track(seed, track_id)
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(track_id), int(anchor_frame), int(direction)]))


# --------------------------------------------------------------------------- the passes


class SegmentRun:
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
        # (log-likelihood, seconds) of the forward pass's init on the anchor
        self.start_row: tuple[float, float] | None = None
        self.calls = 0
        self.fwd_todo, self.bwd_todo = segment.forward, segment.backward
        if cache is not None:
            self._from_cache(cache, n)
        # The backward pass buffers its frames only when the segment is short enough.
        self.buffered = self.bwd_todo and n <= max_buffer
        self.deferred = self.bwd_todo and not self.buffered
        self._buffer: list[np.ndarray] = []
        self._forward: tuple[FramesAhead, SignalMeter] | None = None  # the forward pass's frames in flight

    def _key(self, direction: int) -> PassKey:
        s = self.segment
        position, box = (s.start, self.box_start) if direction == 0 else (s.stop, self.box_stop)
        assert box is not None  # a pass starts from a box (plan_segments: no pass from an absence)
        return pass_key(s.track_id, position, direction, box)

    def _from_cache(self, cache: dict, n: int) -> None:
        # A pass is deterministic (its seed depends only on the anchor), so a longer run of it
        # already made holds this segment's rows as its first n rows.
        if self.fwd_todo:
            hit = cache.get(self._key(0))
            if hit is not None and len(hit.rows.confidence) >= n:
                self.fwd = hit.rows.take(slice(0, n))
                self.start_row = (hit.init_log_likelihood, hit.init_seconds)
                self.fwd_todo = False
        if self.bwd_todo:
            hit = cache.get(self._key(1))
            if hit is not None and len(hit.rows.confidence) >= n:
                self.bwd = hit.rows.take(slice(n - 1, None, -1) if n else slice(0, 0))
                self.bwd_todo = False

    def _remember(self, direction: int, rows: PassResult, init: tuple[float, float]) -> None:
        if self.cache is None:
            return
        key = self._key(direction)
        known = self.cache.get(key)
        if known is None or len(known.rows.confidence) < len(rows.confidence):
            ordered = rows if direction == 0 else rows.take(slice(None, None, -1))
            self.cache[key] = CachedPass(ordered, *init)

    @property
    def _forward_in_flight(self) -> tuple[FramesAhead, SignalMeter]:
        # Frames come in order, so one after the anchor finds the pass the anchor's frame started.
        assert self._forward is not None
        return self._forward

    @property
    def _backward_rows(self) -> PassResult:
        # Asked for by the backward pass only, which a segment has when it has these rows.
        assert self.bwd is not None
        return self.bwd

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
        return Tracker(self.params, seed=rng, guide=guide_for(self.params), kmeans=DICTIONARY_KMEANS)

    def feed(self, position: int, frame: np.ndarray) -> None:
        s = self.segment
        if position == s.start and self.fwd_todo:
            tracker = self._tracker_for(position, 0)
            tic = time.perf_counter()
            result = tracker.init(frame, self.box_start)
            self.start_row = (result.log_likelihood, time.perf_counter() - tic)
            meter = SignalMeter()
            meter.first(frame, self.box_start)
            self.calls += 1
            # Frames go to the tracker ahead of the rows stored (Tracker.submit: the same rows, sooner).
            self._forward = FramesAhead({0: tracker}), meter
        elif s.start < position < s.stop:
            if self.fwd_todo:
                ahead, meter = self._forward_in_flight
                ahead.add(position, frame)
                self._store_settled(self.fwd, ahead, meter)
            if self.buffered:
                self._buffer.append(frame)
        if position == s.stop - 1 and self.fwd_todo:
            self._store_settled(self.fwd, *self._forward_in_flight, final=True)
            self._forward = None
            self.fwd_todo = False
            assert self.start_row is not None  # set with the forward pass, on the anchor's frame
            self._remember(0, self.fwd, self.start_row)
        if position == s.stop and self.buffered:
            self._backward(frame, reversed(self._buffer), s.stop - 1)
            self._buffer = []
            self.buffered = False

    def run_deferred(self, provider: FrameProvider, chunk: int) -> None:
        """The backward pass of a long segment: chunks of ``chunk`` frames, last chunk first."""
        s = self.segment
        hi = s.stop + 1
        backward = None
        while hi > s.start + 1:
            lo = max(s.start + 1, hi - chunk)
            frames = [f for _, f in provider.frames(lo, hi)]
            if backward is None:
                backward = self._backward(frames[-1], reversed(frames[:-1]), hi - 2, remember=False)
            else:
                self._backward_continue(*backward, reversed(frames), hi - 1)
            hi = lo
        self.deferred = False
        self._remember(1, self._backward_rows, (float("nan"), 0.0))

    def _backward(self, anchor_frame: np.ndarray, frames, first_position: int, *,
                  remember: bool = True) -> tuple[Tracker, SignalMeter]:
        tracker = self._tracker_for(self.segment.stop, 1)
        tracker.init(anchor_frame, self.box_stop)
        meter = SignalMeter()
        meter.first(anchor_frame, self.box_stop)
        self.calls += 1
        self._backward_continue(tracker, meter, frames, first_position)
        if remember:
            self._remember(1, self._backward_rows, (float("nan"), 0.0))
        return tracker, meter

    def _backward_continue(self, tracker: Tracker, meter: SignalMeter, frames, first_position: int) -> None:
        ahead = FramesAhead({0: tracker})
        for offset, frame in enumerate(frames):
            ahead.add(first_position - offset, frame)
            self._store_settled(self._backward_rows, ahead, meter)
        self._store_settled(self._backward_rows, ahead, meter, final=True)

    def _store_settled(self, target: PassResult, ahead: FramesAhead, meter: SignalMeter, *,
                       final: bool = False) -> None:
        for position, frame, results, seconds in ahead.settled(final=final):
            self._store(target, position - self.segment.start - 1, results[0], seconds[0], meter, frame)

    def _store(self, target: PassResult, row: int, result, seconds: float, meter: SignalMeter,
               frame: np.ndarray) -> None:
        target.boxes_xywh[row] = result.box_xywh
        target.confidence[row] = result.confidence
        target.log_likelihood[row] = result.log_likelihood
        target.accepted[row] = result.accepted
        target.scoring[row] = result.scoring
        target.seconds[row] = seconds
        signals = meter.next(frame, result.box_xywh, log_likelihood=result.log_likelihood, scoring=result.scoring,
                             accepted=result.accepted, particles_xywh=result.particles_xywh,
                             particle_scores=result.particle_scores, run_boxes_xywh=result.run_boxes_xywh,
                             guide_box_xywh=result.guide_box_xywh)
        target.signals[row] = [signals[name] for name in SIGNALS]
        self.calls += 1

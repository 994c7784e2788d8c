"""One video in, annotations out: the tracking loop behind ``sptpt-annotate VIDEO --box ...``.

Frames are decoded once and streamed: each frame is tracked for every
target, its failure signals are measured (:class:`~annotator.failure.SignalMeter`),
its failure probability and flag are decided by a
:class:`~annotator.failure.TrackDoubt` a few frames later, and the overlay
frame is drawn and encoded as soon as they are final. With a review budget,
which frames are flagged is known only at the end: the overlay then shows
each box's failure probability but no review marks. Memory therefore depends on the frame size and the flag
look-ahead, never on the video's length. If decoding fails part-way, every
frame tracked so far is still written, validly.
"""

from __future__ import annotations

import base64
import collections
import contextlib
import dataclasses
import signal
import threading
import time
from array import array
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from annotator.allocator import release_freed_memory
from annotator.checkpoint import CHECKPOINT_EVERY, Checkpoint, write_checkpoint
from annotator.config import RunConfig
from annotator.errors import EXIT_INPUT, ToolError
from annotator.failure import SignalMeter, TrackDoubt, score_track
from annotator.flagging import FlagParams, FlagResult, flag_p_fail, spans_from_mask, with_keyframe_request
from annotator.frame_sources import DecodeError, FrameSource
from annotator.kmeans_child import DICTIONARY_KMEANS
from annotator.nanotrack import guide_for
from annotator.progress import Progress
from annotator.render import OverlayItem, OverlayRenderer, OverlayWriter, i420_to_rgb, items_from_tracks, rgb_to_i420
from annotator.tracks import KEYFRAME_GIVEN, SpanThumbnail, Target, TrackRecorder, TrackResult, VideoInfo
from sptpt import FrameResult, Tracker, compile_kernels

__all__ = ["FRAMES_AHEAD", "FrameLoopEnd", "FrameMark", "FramesAhead", "HeldFrames", "OverlaySink",
           "TrackRecords", "TrackingRun", "WorstFrameThumbnails", "final_flags", "render_tracks",
           "seed_for_track", "track_frame", "track_frames", "track_source"]

THUMBNAIL_WIDTH = 200


class WorstFrameThumbnails:
    """One thumbnail per flagged span: its frame with the highest ``p_fail``, captured as overlay frames stream by.

    Frames are given in order, each with its final flag; a span is over at its
    track's first unflagged frame (or at :meth:`finish`). Per open span only
    the worst frame so far is kept, already shrunk to thumbnail size, so
    memory is one small image per track. Equal maxima keep the first frame,
    and a span without a finite ``p_fail`` (object absent throughout) keeps its
    first frame: the same choice as :func:`annotator.run_report.flagged_spans`.
    The first frame of a span is not captured too: the report's frame-range
    link already seeks there, and a span's first frames are often still
    right (spans merge and lead up to the failure).
    """

    def __init__(self) -> None:
        self.thumbnails: list[SpanThumbnail] = []
        self._open: dict[int, tuple[float, int, int, np.ndarray]] = {}  # track -> (p_fail, position, frame, small)

    def add(self, track_id: int, position: int, frame_index: int, *, flagged: bool, p_fail: float,
            drawn: np.ndarray) -> None:
        """Take the next overlay frame ``drawn`` ((H, W, 3) uint8 RGB) of a track."""
        if not flagged:
            self._close(track_id)
            return
        score = float(p_fail) if np.isfinite(p_fail) else -np.inf
        current = self._open.get(track_id)
        if current is None or score > current[0]:
            self._open[track_id] = (score, position, frame_index, _shrink(drawn))

    def finish(self) -> list[SpanThumbnail]:
        """Close every open span (the frames ended); return all thumbnails, in the order their spans ended."""
        for track_id in list(self._open):
            self._close(track_id)
        return self.thumbnails

    def _close(self, track_id: int) -> None:
        current = self._open.pop(track_id, None)
        if current is not None:
            _, position, frame_index, small = current
            self.thumbnails.append(SpanThumbnail(track_id, position, frame_index, _jpeg_base64(small)))


@dataclass
class TrackingRun:
    """What one pass over a source produced.

    Attributes
    ----------
    video : VideoInfo
        The source.
    tracks : list of TrackResult
        One per target, a row per processed frame.
    frames_processed : int
        Frames tracked (fewer than selected after a decode error or an interruption).
    seconds_tracking, seconds_total : float
        Wall time in the trackers, and in all.
    decode_error : DecodeError or None
        Where decoding stopped, if it did.
    interrupted : bool
        Ctrl-C stopped the run; the frames before it are kept.
    thumbnails : list of SpanThumbnail
        Each flagged span's worst overlay frame, for the report.
    overlay_path : Path or None
        The overlay video, when one was rendered.
    tracker_confidence : dict of int to numpy.ndarray
        The tracker's own confidence per row, by track id (the tracks' ``confidence`` is ``1 - p_fail``): with
        the tracks, the forward pass from the first frame that a re-track would otherwise run again.
    """

    video: VideoInfo
    tracks: list[TrackResult]
    frames_processed: int
    seconds_tracking: float
    seconds_total: float
    decode_error: DecodeError | None = None
    interrupted: bool = False
    thumbnails: list[SpanThumbnail] = field(default_factory=list)
    overlay_path: Path | None = None
    tracker_confidence: dict[int, np.ndarray] = field(default_factory=dict)


class _NothingTracked(Exception):
    """No frame of the range could be decoded; aborts the overlay writer, which then leaves no file."""

    def __init__(self, end) -> None:
        super().__init__()
        self.end = end


@contextlib.contextmanager
def _deferred_interrupt():
    """Turn the first Ctrl-C into a request to stop after the frames in flight; a second one stops at once.

    A KeyboardInterrupt raised at an arbitrary point (half-way through
    recording a frame for several tracks, or while encoding) would leave the
    run's records inconsistent; the flag is checked between frames instead.
    Signal handlers can only be set in the main thread; elsewhere Ctrl-C
    keeps its default behaviour.
    """
    state = {"requested": False}
    if threading.current_thread() is not threading.main_thread():
        yield state
        return
    previous = signal.getsignal(signal.SIGINT)

    def request_stop(signum, frame):
        if state["requested"]:
            signal.signal(signal.SIGINT, previous)
            raise KeyboardInterrupt
        state["requested"] = True

    signal.signal(signal.SIGINT, request_stop)
    try:
        yield state
    finally:
        signal.signal(signal.SIGINT, previous)


def seed_for_track(seed: int, track_id: int) -> np.random.Generator:
    """The random generator of track ``track_id`` in a run with ``seed``: derived from both, so tracks are
    independent.

    Parameters
    ----------
    seed : int
        The run's seed (``--seed``).
    track_id : int
        The track's id (1 for the first box).

    Returns
    -------
    numpy.random.Generator
        The generator the tool gives that track's :class:`sptpt.Tracker` as its ``seed``.
    """
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(track_id)]))


def _shrink(frame_rgb: np.ndarray) -> np.ndarray:
    """The frame at thumbnail width (a new array: the caller may reuse its frame buffer)."""
    height, width = frame_rgb.shape[:2]
    scale = THUMBNAIL_WIDTH / width
    return cv2.resize(frame_rgb, (THUMBNAIL_WIDTH, max(1, int(round(height * scale)))), interpolation=cv2.INTER_AREA)


def _jpeg_base64(small_rgb: np.ndarray) -> str:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(small_rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])
    return base64.b64encode(data.tobytes()).decode("ascii") if ok else ""


def track_frame(trackers: dict[int, Tracker], targets: Sequence[Target], frame: np.ndarray, *,
                first: bool) -> tuple[dict[int, FrameResult], dict[int, float]]:
    """The tracking stage: every target's tracker on one frame.

    Parameters
    ----------
    trackers : dict of int to Tracker
        By track id; started on the first frame (``first=True``) with the targets' boxes.
    targets : sequence of Target
    frame : (H, W, 3) uint8 ndarray
        RGB.
    first : bool
        The source's first selected frame: the trackers are started on it.

    Returns
    -------
    results : dict of int to FrameResult
        By track id, in the targets' order.
    seconds : dict of int to float
        Each tracker's wall time on the frame.
    """
    results: dict[int, FrameResult] = {}
    seconds: dict[int, float] = {}
    for target in targets:
        tid = target.track_id
        tic = time.perf_counter()
        if first:
            results[tid] = trackers[tid].init(frame, target.box_xywh)
        else:
            # Details always: the candidates' scores are a failure signal.
            results[tid] = trackers[tid].update(frame, details=True)
        seconds[tid] = time.perf_counter() - tic
    if first:  # every tracker has its dictionary: the k-means child's memory is not kept while tracking
        DICTIONARY_KMEANS.close()
    return results, seconds


@dataclass(frozen=True)
class FrameMark:
    """A frame's final doubt for one track: the online flag (made even with a review budget) and ``p_fail``."""

    flagged: bool
    reason: str
    p_fail: float


class TrackRecords:
    """The measuring and flagging stage: each tracked frame's failure signals, row, ``p_fail`` and flag.

    Every track's signals are measured by a :class:`~annotator.failure.SignalMeter`, its row recorded by a
    :class:`~annotator.tracks.TrackRecorder`, and its ``p_fail`` and flag decided by a
    :class:`~annotator.failure.TrackDoubt` a few frames later. With a review budget the online flags are only a
    way to get ``p_fail`` frame by frame: the rows get no flag (the budget flags them at the end), but
    :meth:`take_marks` still gives the online ones.

    Parameters
    ----------
    targets : sequence of Target
    model
        The failure model (:func:`annotator.failure.load_model`).
    flags : FlagParams
        The online flagging's threshold, merge gap and minimum span.
    budget : bool
        Flags are made by review budget at the end.
    keep_marks : bool
        Keep each decided frame's :class:`FrameMark` until :meth:`take_marks` takes it (for an overlay).
    """

    def __init__(self, targets: Sequence[Target], model, flags: FlagParams, *, budget: bool,
                 keep_marks: bool) -> None:
        self.budget, self.keep_marks = budget, keep_marks
        self._order = [t.track_id for t in targets]
        self._recorders = {t.track_id: TrackRecorder(t.track_id, t.label) for t in targets}
        self._meters = {t.track_id: SignalMeter() for t in targets}
        self._flaggers = {t.track_id: TrackDoubt(model, flags) for t in targets}
        self._confidence: dict[int, array[float]] = {t.track_id: array("d") for t in targets}
        self._marks: dict[int, dict[int, FrameMark]] = {t.track_id: {} for t in targets}

    def add(self, frame_index: int, frame: np.ndarray, results: dict[int, FrameResult],
            seconds: dict[int, float]) -> None:
        """Record one tracked frame (frames in order), with the trackers' ``results`` and ``seconds`` by track id."""
        for tid, result in results.items():
            first = result.scoring == "init"
            if first:
                signals = self._meters[tid].first(frame, result.box_xywh)
            else:
                signals = self._meters[tid].next(
                    frame, result.box_xywh, log_likelihood=result.log_likelihood, scoring=result.scoring,
                    accepted=result.accepted, particles_xywh=result.particles_xywh,
                    particle_scores=result.particle_scores, run_boxes_xywh=result.run_boxes_xywh,
                    guide_box_xywh=result.guide_box_xywh)
            self._confidence[tid].append(result.confidence)
            self._recorders[tid].append(
                frame_index, result.box_xywh, confidence=result.confidence, log_likelihood=result.log_likelihood,
                accepted=result.accepted, seconds=seconds[tid], keyframe=first, scoring=result.scoring,
                keyframe_source=KEYFRAME_GIVEN if first else "", signals=signals)
            self._settle(tid, self._flaggers[tid].push(signals, keyframe=first))

    def stop_marking(self) -> None:
        """Keep no more marks (a resumed run draws its overlay from the finished tracks), and drop those kept."""
        self.keep_marks = False
        for marks in self._marks.values():
            marks.clear()

    def finish(self) -> None:
        """Decide the frames the flaggers still hold (the frames ended)."""
        for tid, flagger in self._flaggers.items():
            self._settle(tid, flagger.finish())

    def take_marks(self, position: int, *, final: bool = False) -> dict[int, FrameMark] | None:
        """The marks of the frame at ``position`` by track id, removed from the stage; None while a track's is
        not decided yet, unless ``final`` (after :meth:`finish`), where an undecided one reads unflagged, 0."""
        if not final and not all(position in self._marks[tid] for tid in self._order):
            return None
        return {tid: self._marks[tid].pop(position, FrameMark(False, "", 0.0)) for tid in self._order}

    def tracks(self) -> list[TrackResult]:
        """Each track's rows so far, in the targets' order (flags as decided online)."""
        return [self._recorders[tid].to_result() for tid in self._order]

    def tracker_confidence(self) -> dict[int, np.ndarray]:
        """(F,) float64 by track id: the tracker's own confidence of each row."""
        return {tid: np.asarray(values, dtype=np.float64) for tid, values in self._confidence.items()}

    def _settle(self, tid: int, decided: list[tuple[int, float, bool, str]]) -> None:
        for position, p_fail, flagged, reason in decided:
            self._recorders[tid].set_failure(position, p_fail)
            self._recorders[tid].set_flag(position, flagged and not self.budget, reason if not self.budget else "")
            if self.keep_marks:
                self._marks[tid][position] = FrameMark(flagged, reason, p_fail)


class OverlaySink:
    """The overlay stage: draws each frame's items, encodes it, and keeps each flagged span's worst frame.

    What a first run streams while it tracks and a re-track renders from the tracks it wrote: one way of drawing,
    encoding and choosing thumbnails for both.

    Parameters
    ----------
    writer : OverlayWriter
        The open video the drawn frames go to, in order.
    renderer : OverlayRenderer, optional
        How items are drawn; the default style by default.
    """

    def __init__(self, writer: OverlayWriter, renderer: OverlayRenderer | None = None) -> None:
        self.writer = writer
        self.renderer = OverlayRenderer() if renderer is None else renderer
        self._thumbnails = WorstFrameThumbnails()

    def write(self, position: int, frame_index: int, frame: np.ndarray, items: Sequence[OverlayItem],
              marks: dict[int, FrameMark]) -> None:
        """Draw ``items`` on ``frame`` ((H, W, 3) uint8 RGB) and encode it; ``marks`` (final, by track id) say
        which tracks' flagged spans it belongs to."""
        drawn = self.renderer.annotate(frame, items)
        self.writer.write(drawn)
        for tid, mark in marks.items():
            self._thumbnails.add(tid, position, frame_index, flagged=mark.flagged, p_fail=mark.p_fail, drawn=drawn)

    def finish(self) -> list[SpanThumbnail]:
        """The frames ended: every flagged span's thumbnail, in the order the spans ended."""
        return self._thumbnails.finish()


def render_tracks(sink: OverlaySink, frames, frame_indices: np.ndarray, tracks: Sequence[TrackResult],
                  progress: Progress | None = None) -> list[SpanThumbnail]:
    """Draw finished ``tracks`` into ``sink``: boxes, labels, keyframes and review marks, no particles.

    ``frames`` yields ``(position, frame)`` in order, position ``k`` being source frame ``frame_indices[k]``.
    Returns the flagged spans' thumbnails.
    """
    for position, frame in frames:
        index = int(frame_indices[position])
        marks = {t.track_id: FrameMark(bool(t.flagged[position]), "", float(t.p_fail[position])) for t in tracks}
        sink.write(position, index, frame, items_from_tracks(tracks, index), marks)
        if progress is not None:
            progress.advance()
    return sink.finish()


class HeldFrames:
    """Tracked frames held until their marks are final (a few frames later), then drawn into the overlay in order.

    With a review budget the boxes show ``p_fail`` but no review mark: which frames the budget flags is known only
    at the end.

    A frame is held in YUV 4:2:0 (:func:`~annotator.render.rgb_to_i420`), the format the overlay is encoded in:
    at 1920x1080 about ten frames wait at once, and each takes 3 MiB instead of RGB's 6 (issue #69). It is drawn
    on its RGB again, so what is drawn goes through 4:2:0 once, in the encoder, and the picture under it twice.
    """

    def __init__(self, records: TrackRecords, sink: OverlaySink) -> None:
        self.records, self.sink = records, sink
        # (position, frame_index, the frame's I420 planes, its (height, width), {track: FrameResult})
        self._held: collections.deque = collections.deque()

    def add(self, position: int, frame_index: int, frame: np.ndarray, results: dict[int, FrameResult]) -> None:
        self._held.append((position, frame_index, rgb_to_i420(frame), frame.shape[:2], results))
        self.drain()

    def drain(self, *, final: bool = False) -> None:
        """Draw every held frame whose marks are final; with ``final`` (the records finished), all of them."""
        while self._held:
            position, frame_index, planes, (height, width), results = self._held[0]
            marks = self.records.take_marks(position, final=final)
            if marks is None:
                return
            self._held.popleft()
            frame = i420_to_rgb(planes, width, height)
            # The live run's only keyframe is the user's first-frame box; corrections come in a re-track.
            items = [OverlayItem.from_frame_result(
                result, track_id=tid, flagged=marks[tid].flagged and not self.records.budget,
                confidence=1.0 - marks[tid].p_fail, keyframe_source=KEYFRAME_GIVEN if result.scoring == "init" else "")
                for tid, result in results.items()]
            self.sink.write(position, frame_index, frame, items, marks)


@dataclass
class FrameLoopEnd:
    """How :func:`track_frames` ended."""

    frames_tracked: int
    seconds_tracking: float
    decode_error: DecodeError | None = None
    interrupted: bool = False


#: Frames the tracking stage keeps submitted beyond the one it waits for: a run that finished its part of a frame
#: goes on with the next ones instead of waiting for the slowest run (:meth:`sptpt.tracker.Tracker.submit`).
FRAMES_AHEAD = 2


class FramesAhead:
    """The tracking stage with frames in flight: each frame goes to every tracker as soon as it is decoded, and its
    results are taken once every tracker has them, in frame order, ``ahead`` frames behind the newest.

    Frames are submitted (:meth:`~sptpt.tracker.Tracker.submit`), so their results are what
    :meth:`~sptpt.tracker.Tracker.update` would give, to the bit; a frame tracked otherwise (the first, which
    starts the trackers) joins the queue with :meth:`add_tracked`. A frame's seconds are the time the caller spent
    in the trackers' ``submit`` and ``collect`` for it, split evenly among the trackers: their runs work at the
    same time as each other and as the caller's own work, so what each tracker alone took is not measured, and
    the sum over frames is the time the caller waited on tracking.

    Parameters
    ----------
    trackers : dict of int to Tracker
        By track id, in the order the results are to come.
    ahead : int
        Frames in flight beyond the one waited for.
    """

    def __init__(self, trackers: dict[int, Tracker], ahead: int = FRAMES_AHEAD) -> None:
        self.trackers, self.ahead = trackers, ahead
        # (frame_index, frame, results by track id or None while submitted, seconds so far)
        self._in_flight: collections.deque = collections.deque()

    def __len__(self) -> int:
        return len(self._in_flight)

    def add(self, frame_index: int, frame: np.ndarray) -> None:
        """Submit ``frame`` (RGB; not written into until it is taken) to every tracker."""
        tic = time.perf_counter()
        for tracker in self.trackers.values():
            tracker.submit(frame, details=True)  # details always: the candidates' scores are a failure signal
        self._in_flight.append((frame_index, frame, None, time.perf_counter() - tic))

    def add_tracked(self, frame_index: int, frame: np.ndarray, results: dict[int, FrameResult],
                    seconds: dict[int, float]) -> None:
        """Queue a frame already tracked (its results and seconds by track id), after those in flight."""
        self._in_flight.append((frame_index, frame, results, seconds))

    def settled(self, *, final: bool = False):
        """Take the oldest frames while more than ``ahead`` are in flight (with ``final``, all of them): yields
        ``(frame_index, frame, results, seconds)``, results and seconds by track id."""
        while self._in_flight and (final or len(self._in_flight) > self.ahead):
            frame_index, frame, results, seconds = self._in_flight[0]
            if results is None:
                tic = time.perf_counter()
                results = {tid: tracker.collect() for tid, tracker in self.trackers.items()}
                share = (seconds + time.perf_counter() - tic) / len(self.trackers)
                seconds = {tid: share for tid in self.trackers}
            self._in_flight.popleft()
            yield frame_index, frame, results, seconds

    def discard(self) -> None:
        """Drop the frames in flight, once the trackers have stopped working on them (an interrupted loop)."""
        self._in_flight.clear()
        for tracker in self.trackers.values():
            tracker.discard()


def track_frames(source, targets: Sequence[Target], trackers: dict[int, Tracker], follow_up, *,
                 stop_requested=lambda: False, ahead: int = FRAMES_AHEAD, resumed: FrameLoopEnd | None = None,
                 checkpoint=None, checkpoint_every: int = 0) -> FrameLoopEnd:
    """The frame loop: track each frame (:class:`FramesAhead`), then hand it to ``follow_up`` on a thread of its
    own.

    ``follow_up(position, frame_index, frame, results, seconds)`` runs in frame order on one thread while the next
    frames are tracked: the follow-up (failure signals, flags, overlay drawing and encoding: 3-4 ms a frame) fills
    time the trackers leave a core idle. One thread, fed in frame order, so every signal, flag and overlay frame
    is what it would be if the loop did it all in turn. At most two frames wait behind, so an error there stops
    tracking soon; the first error is the one raised.

    ``source`` yields ``(frame_index, frame)``; a :class:`~annotator.frame_sources.DecodeError` from it ends the loop,
    as do ``stop_requested()`` (checked between frames) and a Ctrl-C outside the main thread; every frame tracked
    so far is kept (after a Ctrl-C, those in flight are dropped).

    ``resumed`` (a run going on from a checkpoint) holds the frames tracked before, and ``source`` then yields the
    frames after them; ``trackers`` are already started. With ``checkpoint``, every ``checkpoint_every`` frames
    the loop waits until no frame is in flight and every follow-up is done, then calls ``checkpoint(end,
    frame_index)`` with the last frame's source index: the trackers and the follow-up's state are then those of
    exactly ``end.frames_tracked`` frames.
    """
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="sptpt-follow-up") as pool:
        submitted: collections.deque = collections.deque()
        in_flight = FramesAhead({t.track_id: trackers[t.track_id] for t in targets}, ahead)
        try:
            end = _track_and_submit(iter(source), targets, in_flight, follow_up, pool, submitted, stop_requested,
                                    resumed, checkpoint, checkpoint_every)
            wait(submitted)  # every frame is followed up before the caller finishes the flags
            while submitted:
                submitted.popleft().result()
            return end
        except BaseException:
            # The trackers' frames in flight are waited for and dropped, as are the follow-ups queued behind the
            # error (they would run on the state it left); the one running is waited for, its own error ignored.
            in_flight.discard()
            for future in submitted:
                future.cancel()
            wait(submitted)
            raise


def _track_and_submit(frames, targets: Sequence[Target], in_flight: FramesAhead, follow_up,
                      pool: ThreadPoolExecutor, submitted: collections.deque, stop_requested,
                      resumed: FrameLoopEnd | None, checkpoint, checkpoint_every: int) -> FrameLoopEnd:
    end = FrameLoopEnd(frames_tracked=0, seconds_tracking=0.0) if resumed is None else \
        FrameLoopEnd(frames_tracked=resumed.frames_tracked, seconds_tracking=resumed.seconds_tracking)
    taken_from_source = end.frames_tracked

    def follow(frame_index, frame, results, seconds) -> None:
        end.seconds_tracking += sum(seconds.values())
        submitted.append(pool.submit(follow_up, end.frames_tracked, frame_index, frame, results, seconds))
        end.frames_tracked += 1
        while len(submitted) > 2 or (submitted and submitted[0].done()):
            submitted[0].result()  # raises the follow-up's error; removed only once it is done
            submitted.popleft()

    try:
        while not stop_requested():
            try:
                frame_index, frame = next(frames)
            except StopIteration:
                break
            except DecodeError as exc:
                end.decode_error = exc
                break
            if end.frames_tracked == 0 and not len(in_flight):
                in_flight.add_tracked(frame_index, frame, *track_frame(in_flight.trackers, targets, frame,
                                                                       first=True))
                release_freed_memory()  # the start's temporaries (k-means, the learned tracker's start)
            else:
                in_flight.add(frame_index, frame)
            taken_from_source += 1
            for taken in in_flight.settled():
                follow(*taken)
            if checkpoint is not None and taken_from_source % checkpoint_every == 0:
                for taken in in_flight.settled(final=True):  # nothing in flight: the trackers are idle
                    follow(*taken)
                while submitted:  # every frame measured and flagged
                    submitted.popleft().result()
                checkpoint(end, frame_index)
                release_freed_memory()
        else:
            end.interrupted = True
        for taken in in_flight.settled(final=True):  # the frames decoded before the loop ended
            follow(*taken)
    except KeyboardInterrupt:
        # Ctrl-C outside the main thread, or a second one while waiting: keep every frame followed up so far
        # (a frame half-tracked or in flight is dropped).
        in_flight.discard()
        end.interrupted = True
    return end


def track_source(
    source: FrameSource,
    targets: Sequence[Target],
    config: RunConfig,
    *,
    overlay_path: Path | None = None,
    progress: Progress | None = None,
    checkpoints: tuple[Path, dict] | None = None,
    resume: Checkpoint | None = None,
) -> TrackingRun:
    """Track every target through the source's selected frames.

    The stages: :func:`track_frames` (with :class:`FramesAhead`) feeds each frame to :class:`TrackRecords`, and,
    with an overlay, through :class:`HeldFrames` to an :class:`OverlaySink`; the flags are then finished by
    :func:`final_flags`.

    Parameters
    ----------
    source : FrameSource
        The decoded frames; its first selected frame holds the targets' boxes.
    targets : sequence of Target
    config : RunConfig
    overlay_path : Path, optional
        Where to stream the overlay video; ``None`` renders nothing.
    progress : Progress, optional
    checkpoints : (Path, dict), optional
        The output folder to write a :class:`~annotator.checkpoint.Checkpoint` into every
        :data:`~annotator.checkpoint.CHECKPOINT_EVERY` frames, and the run's key
        (:func:`~annotator.checkpoint.run_key`); None writes none.
    resume : Checkpoint, optional
        Go on from this checkpoint of the same run: its frames are decoded and skipped, the trackers and
        records it holds track the rest. The overlay is then drawn from the finished tracks after tracking
        (:func:`render_tracks`, as a re-track draws it), since the interrupted run's stream is gone.

    Returns
    -------
    TrackingRun
        On a decode error part-way, the frames before it, with the error in
        ``decode_error``; the overlay then also ends there.
    """
    started = time.perf_counter()
    # On a fresh machine: the kernels the trackers' first frame compiles last are compiled meanwhile on the other
    # core (nothing happens once numba's cache holds them).
    compile_kernels(wait=False)
    model = config.load_failure_model()
    if resume is None:
        trackers = {t.track_id: Tracker(config.tracker, seed=seed_for_track(config.seed, t.track_id),
                                        guide=guide_for(config.tracker), kmeans=DICTIONARY_KMEANS) for t in targets}
        online = FlagParams(threshold=config.flags.threshold, merge_gap=config.flags.merge_gap,
                            min_span=config.flags.min_span)
        records = TrackRecords(targets, model, online, budget=config.flags.review_budget is not None,
                               keep_marks=overlay_path is not None)
    else:
        trackers, records = resume.trackers, resume.records
        records.stop_marking()  # the overlay is drawn from the finished tracks
    loop = _FrameLoop(source, targets, trackers, records, progress, checkpoints, resume)
    with _deferred_interrupt() as stop_request:
        if overlay_path is not None and resume is None:
            end, thumbnails = _track_with_overlay(loop, source, overlay_path, stop_request)
        else:
            end, thumbnails = loop.run(None, stop_request), []
    tracks = final_flags(records.tracks(), config.flags, model)
    if overlay_path is not None and resume is not None and end.frames_tracked:
        thumbnails = _render_overlay(source, tracks, overlay_path, progress)
    if progress is not None:
        progress.close()
    return TrackingRun(
        video=VideoInfo(path=str(source.path), name=source.name, width=source.width, height=source.height,
                        fps=source.fps, frame_count=source.frame_count,
                        frame_files=getattr(source, "frame_files", None)),  # image folders only
        tracks=tracks,
        frames_processed=end.frames_tracked,
        seconds_tracking=end.seconds_tracking,
        seconds_total=time.perf_counter() - started,
        decode_error=end.decode_error,
        interrupted=end.interrupted,
        thumbnails=thumbnails,
        overlay_path=overlay_path,
        tracker_confidence=records.tracker_confidence(),
    )


def _track_with_overlay(loop: _FrameLoop, source, overlay_path: Path,
                        stop_request) -> tuple[FrameLoopEnd, list[SpanThumbnail]]:
    try:
        with OverlayWriter(overlay_path, fps=source.fps, width=source.width, height=source.height) as writer:
            sink = OverlaySink(writer)
            held = HeldFrames(loop.records, sink)
            end = loop.run(held, stop_request)
            if end.frames_tracked == 0:
                # Not even the first frame decoded: discard the empty video (an MP4 needs a frame) and let the
                # caller report the unreadable input.
                raise _NothingTracked(end)
            held.drain(final=True)
            return end, sink.finish()
    except _NothingTracked as nothing:
        return nothing.end, []


def _render_overlay(source, tracks: Sequence[TrackResult], overlay_path: Path, progress) -> list[SpanThumbnail]:
    """The overlay of a resumed run, drawn from its finished tracks over the frames they hold."""
    indices = tracks[0].frame_indices
    frames = ((position, frame) for position, (_, frame) in zip(range(len(indices)), source))
    with OverlayWriter(overlay_path, fps=source.fps, width=source.width, height=source.height) as writer:
        return render_tracks(OverlaySink(writer), frames, indices, tracks)


class _FrameLoop:
    """The frame loop with its follow-up (records each frame, holds it for the overlay, advances the bar), and
    the checkpoints of its state."""

    def __init__(self, source, targets: Sequence[Target], trackers: dict[int, Tracker], records: TrackRecords,
                 progress, checkpoints: tuple[Path, dict] | None, resume: Checkpoint | None) -> None:
        self.source, self.targets, self.trackers, self.records = source, targets, trackers, records
        self.progress, self.checkpoints, self.resume = progress, checkpoints, resume

    def run(self, held: HeldFrames | None, stop_request) -> FrameLoopEnd:
        records, progress = self.records, self.progress

        def follow_up(position, frame_index, frame, results, seconds) -> None:
            records.add(frame_index, frame, results, seconds)
            if held is not None:
                held.add(position, frame_index, frame, results)
            if progress is not None:
                progress.advance()

        frames, resumed = self.source, None
        if self.resume is not None:
            last = self.resume.last_index
            frames = _skipped_to(self.source, last, self.trackers.values())  # decoded and skipped up to it
            resumed = FrameLoopEnd(frames_tracked=self.resume.frames_tracked,
                                   seconds_tracking=self.resume.seconds_tracking)
            if progress is not None:
                progress.advance(self.resume.frames_tracked)
        end = track_frames(frames, self.targets, self.trackers, follow_up,
                           stop_requested=lambda: stop_request["requested"], resumed=resumed,
                           checkpoint=self._checkpoint if self.checkpoints is not None else None,
                           checkpoint_every=CHECKPOINT_EVERY)
        records.finish()
        return end

    def _checkpoint(self, end: FrameLoopEnd, frame_index: int) -> None:
        assert self.checkpoints is not None  # run() passes this method only when there are checkpoints
        folder, key = self.checkpoints
        write_checkpoint(folder, Checkpoint(
            key=key, frames_tracked=end.frames_tracked, last_index=int(frame_index),
            seconds_tracking=end.seconds_tracking, trackers=self.trackers, records=self.records))


def _skipped_to(source, last: int, trackers) -> Iterator[tuple[int, np.ndarray]]:
    """The frames of ``source`` after frame index ``last``; those before it go to the guides of resumed trackers
    (a NanoTrack guide is brought back by its frames: :meth:`annotator.nanotrack.NanoTrackGuide.catch_up`).

    The checkpoint's run key names the input, so these refusals mean the video now decodes to other frames than
    when the checkpoint was written (a damaged or re-encoded file under the same name)."""
    behind = [t.guide for t in trackers if t.guide is not None and getattr(t.guide, "behind", False)]
    reached = False  # whether the source got as far as the checkpoint's frame
    for index, frame in source:
        reached = reached or index >= last
        if index > last:
            if any(guide.behind for guide in behind):
                raise ToolError(f"{source.path}: the checkpoint's learned tracker saw more frames before frame "
                                f"{last + 1} than the video now has ({index}): it changed since the run; start "
                                "again with --force", EXIT_INPUT)
            behind = []
            yield index, frame
        else:
            for guide in behind:
                if guide.behind:
                    guide.catch_up(frame)
    if not reached:
        raise ToolError(f"{source.path}: the video ends before frame {last}, where the checkpoint stopped: it "
                        "changed since the run; start again with --force", EXIT_INPUT)


def final_flags(tracks: Sequence[TrackResult], params: FlagParams, model) -> list[TrackResult]:
    """The flagging stage that needs whole tracks: by review budget when ``params`` has one, else the online
    flags, with a keyframe request where a track is probably lost."""
    if params.review_budget is not None:
        return [_budget_flags(track, params, model) for track in tracks]
    return [_with_keyframe_request(track, params) for track in tracks]


def _with_keyframe_request(track: TrackResult, params: FlagParams) -> TrackResult:
    """The track, or, when it is probably lost, flagged for keyframes instead (see
    :func:`annotator.flagging.with_keyframe_request`). Needs the whole track, so it comes after the overlay, whose
    review marks stay those of the doubtful frames."""
    current = FlagResult(flagged=track.flagged, reasons=track.reasons, spans=spans_from_mask(track.flagged))
    result = with_keyframe_request(current, track.p_fail, keyframe=track.keyframe, outside=track.outside,
                                   params=params)
    if result is current:
        return track
    return dataclasses.replace(track, flagged=result.flagged, reasons=result.reasons)


def _budget_flags(track: TrackResult, params: FlagParams, model) -> TrackResult:
    """The track flagged by review budget: its most doubtful frames (see :func:`annotator.flagging.budget_flags`)."""
    p_fail, groups = score_track(track.signals, track.keyframe, track.outside, model)
    result = flag_p_fail(p_fail, groups, 0.5, params, keyframe=track.keyframe, outside=track.outside)
    return dataclasses.replace(track, flagged=result.flagged, reasons=result.reasons)

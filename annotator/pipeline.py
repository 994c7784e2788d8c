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
import dataclasses
import collections
import contextlib
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from annotator.config import RunConfig
from annotator.failure import SignalMeter, TrackDoubt, load_model, score_track
from annotator.flagging import FlagParams, FlagResult, flag_p_fail, spans_from_mask, with_keyframe_request
from annotator.frames import DecodeError, FrameSource
from annotator.progress import Progress
from annotator.render import OverlayItem, OverlayRenderer, OverlayWriter
from annotator.tracks import KEYFRAME_GIVEN, TrackRecorder, TrackResult, VideoInfo
from sptpt.results import FrameResult
from sptpt.tracker import Tracker

__all__ = ["Target", "TrackingRun", "SpanThumbnail", "WorstFrameThumbnails", "track_source", "seed_for_track"]

THUMBNAIL_WIDTH = 200


@dataclass(frozen=True)
class Target:
    """One object to label: its first-frame box (0-based ``xywh``), track id and label."""

    box_xywh: tuple[float, float, float, float]
    track_id: int
    label: str = "object"


@dataclass(frozen=True)
class SpanThumbnail:
    """A small JPEG of an overlay frame, for the review report."""

    track_id: int
    position: int
    frame_index: int
    jpeg_base64: str


class WorstFrameThumbnails:
    """One thumbnail per flagged span: its frame with the highest ``p_fail``, captured as overlay frames stream by.

    Frames are given in order, each with its final flag; a span is over at its
    track's first unflagged frame (or at :meth:`finish`). Per open span only
    the worst frame so far is kept, already shrunk to thumbnail size, so
    memory is one small image per track. Equal maxima keep the first frame,
    and a span without a finite ``p_fail`` (object absent throughout) keeps its
    first frame: the same choice as :func:`annotator.report.flagged_spans`.
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
    """What one pass over a source produced."""

    video: VideoInfo
    tracks: list[TrackResult]
    frames_processed: int
    seconds_tracking: float
    seconds_total: float
    decode_error: DecodeError | None = None
    interrupted: bool = False
    thumbnails: list[SpanThumbnail] = field(default_factory=list)
    overlay_path: Path | None = None
    #: The tracker's own confidence per row, by track id (the tracks' ``confidence`` is ``1 - p_fail``): with the
    #: tracks, the forward pass from the first frame that a re-track would otherwise run again.
    tracker_confidence: dict[int, np.ndarray] = field(default_factory=dict)


class _NothingTracked(Exception):
    """No frame of the range could be decoded; aborts the overlay writer, which then leaves no file."""


@contextlib.contextmanager
def _deferred_interrupt():
    """Turn the first Ctrl-C into a request to stop after the current frame; a second one stops at once.

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
    """Each track's generator derives from the run seed and its id, so tracks are independent."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(track_id)]))


def _shrink(frame_rgb: np.ndarray) -> np.ndarray:
    """The frame at thumbnail width (a new array: the caller may reuse its frame buffer)."""
    height, width = frame_rgb.shape[:2]
    scale = THUMBNAIL_WIDTH / width
    return cv2.resize(frame_rgb, (THUMBNAIL_WIDTH, max(1, int(round(height * scale)))), interpolation=cv2.INTER_AREA)


def _jpeg_base64(small_rgb: np.ndarray) -> str:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(small_rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])
    return base64.b64encode(data.tobytes()).decode("ascii") if ok else ""



def track_source(
    source: FrameSource,
    targets: Sequence[Target],
    config: RunConfig,
    *,
    overlay_path: Path | None = None,
    progress: Progress | None = None,
) -> TrackingRun:
    """Track every target through the source's selected frames.

    Parameters
    ----------
    source : FrameSource
        The decoded frames; its first selected frame holds the targets' boxes.
    targets : sequence of Target
    config : RunConfig
    overlay_path : Path, optional
        Where to stream the overlay video; ``None`` renders nothing.
    progress : Progress, optional

    Returns
    -------
    TrackingRun
        On a decode error part-way, the frames before it, with the error in
        ``decode_error``; the overlay then also ends there.
    """
    started = time.perf_counter()
    render = overlay_path is not None
    trackers = {t.track_id: Tracker(config.tracker, seed=seed_for_track(config.seed, t.track_id)) for t in targets}
    recorders = {t.track_id: TrackRecorder(t.track_id, t.label) for t in targets}
    tracker_confidence: dict[int, list[float]] = {t.track_id: [] for t in targets}
    model = load_model(config.failure_model)
    budget = config.flags.review_budget is not None
    # In budget mode the online flags are only a way to get p_fail frame by frame; flags are made at the end.
    online = FlagParams(threshold=config.flags.threshold, merge_gap=config.flags.merge_gap,
                        min_span=config.flags.min_span)
    flaggers = {t.track_id: TrackDoubt(model, online) for t in targets}
    meters = {t.track_id: SignalMeter() for t in targets}
    p_fails: dict[int, dict[int, float]] = {t.track_id: {} for t in targets}
    flags: dict[int, dict[int, tuple[bool, str]]] = {t.track_id: {} for t in targets}
    pending: collections.deque = collections.deque()  # (position, frame_index, frame, {track: FrameResult})
    renderer = OverlayRenderer() if render else None
    thumbnails = WorstFrameThumbnails()
    tracking_seconds = 0.0
    decode_error: DecodeError | None = None
    interrupted = False
    info = VideoInfo(path=str(source.path), name=source.name, width=source.width, height=source.height,
                     fps=source.fps, frame_count=source.frame_count,
                     frame_files=getattr(source, "frame_files", None))  # image folders only

    def drain(writer: OverlayWriter | None, *, final: bool = False) -> None:
        while pending:
            position = pending[0][0]
            if not all(position in flags[tid] for tid in flags):
                if not final:
                    return
            _, frame_index, frame, results = pending.popleft()
            items = []
            frame_p_fail: dict[int, float] = {}
            for tid, result in results.items():
                flagged, _ = flags[tid].get(position, (False, ""))
                p_fail = frame_p_fail[tid] = p_fails[tid].pop(position, 0.0)
                # The live run's only keyframe is the user's first-frame box; corrections come in a re-track.
                items.append(OverlayItem.from_frame_result(
                    result, track_id=tid, flagged=flagged and not budget, confidence=1.0 - p_fail,
                    keyframe_source=KEYFRAME_GIVEN if result.scoring == "init" else ""))
            drawn = renderer.annotate(frame, items)
            writer.write(drawn)
            # Flags and p_fail of this frame are final here, so each span's worst frame is known when it ends.
            for tid in results:
                thumbnails.add(tid, position, frame_index, flagged=flags[tid].get(position, (False, ""))[0],
                               p_fail=frame_p_fail[tid], drawn=drawn)

    def settle(tid: int, decided: list[tuple[int, float, bool, str]]) -> None:
        """Store the failure probabilities and flags the flagger has made final."""
        for pos, p_fail, flagged, reason in decided:
            recorders[tid].set_failure(pos, p_fail)
            recorders[tid].set_flag(pos, flagged and not budget, reason if not budget else "")
            flags[tid][pos] = (flagged, reason)
            if render:
                p_fails[tid][pos] = p_fail

    def record(frame_index: int, frame: np.ndarray, tid: int, result: FrameResult, seconds: float) -> None:
        first = result.scoring == "init"
        if first:
            signals = meters[tid].first(frame, result.box_xywh)
        else:
            signals = meters[tid].next(frame, result.box_xywh, log_likelihood=result.log_likelihood,
                                       scoring=result.scoring, accepted=result.accepted,
                                       particles_xywh=result.particles_xywh, particle_scores=result.particle_scores,
                                       run_boxes_xywh=result.run_boxes_xywh)
        tracker_confidence[tid].append(result.confidence)
        recorders[tid].append(
            frame_index, result.box_xywh, confidence=result.confidence, log_likelihood=result.log_likelihood,
            accepted=result.accepted, seconds=seconds, keyframe=first, scoring=result.scoring,
            keyframe_source=KEYFRAME_GIVEN if first else "", signals=signals)
        settle(tid, flaggers[tid].push(signals, keyframe=first))

    def after_update(position: int, frame_index: int, frame: np.ndarray, results: dict[int, FrameResult],
                     times: dict[int, float], writer: OverlayWriter | None) -> None:
        """A tracked frame's signals, flags and overlay, in frame order on the one follow-up thread."""
        for tid, result in results.items():
            record(frame_index, frame, tid, result, times[tid])
        if writer is not None:
            pending.append((position, frame_index, frame, results))
            drain(writer)
        if progress is not None:
            progress.advance()

    def run(writer: OverlayWriter | None) -> int:
        # The follow-up of frame t (failure signals, flags, overlay drawing and encoding: 3-4 ms a frame) runs on
        # a thread of its own while frame t + 1 is tracked: the tracker's kernels keep both cores busy, but between
        # them it leaves one idle for several ms a frame, and the follow-up fills that time. One thread, fed in
        # frame order, so every signal, flag and overlay frame is what it was when the loop did it all in turn.
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="sptpt-follow-up") as follow_up:
            submitted: collections.deque = collections.deque()
            try:
                return track_frames(writer, follow_up, submitted)
            except BaseException:
                # The first error is the one raised: the follow-ups queued behind it are dropped (they would run on
                # the state it left), and the one running is waited for, its own error ignored.
                for future in submitted:
                    future.cancel()
                wait(submitted)
                raise

    def track_frames(writer: OverlayWriter | None, follow_up: ThreadPoolExecutor, submitted: collections.deque) -> int:
        nonlocal tracking_seconds, decode_error, interrupted
        position = -1
        frames = iter(source)
        while True:
            if stop_request["requested"]:
                interrupted = True
                break
            try:
                frame_index, frame = next(frames)
                results: dict[int, FrameResult] = {}
                times: dict[int, float] = {}
                for target in targets:
                    tid = target.track_id
                    tic = time.perf_counter()
                    if position == -1:
                        results[tid] = trackers[tid].init(frame, target.box_xywh)
                    else:
                        # Details always: the candidates' scores are a failure signal.
                        results[tid] = trackers[tid].update(frame, details=True)
                    times[tid] = time.perf_counter() - tic
            except StopIteration:
                break
            except DecodeError as exc:
                decode_error = exc
                break
            except KeyboardInterrupt:
                # Ctrl-C outside the main thread: keep every frame finished so far (a half-tracked frame is dropped).
                interrupted = True
                break
            position += 1
            tracking_seconds += sum(times.values())
            submitted.append(follow_up.submit(after_update, position, frame_index, frame, results, times, writer))
            try:
                # At most two frames behind: an error there stops tracking soon, and few frames wait in memory.
                while len(submitted) > 2 or (submitted and submitted[0].done()):
                    submitted[0].result()  # raises the follow-up's error; removed only once it is done
                    submitted.popleft()
            except KeyboardInterrupt:
                # A second Ctrl-C while waiting: keep every frame tracked so far, as during tracking.
                interrupted = True
                break
        wait(submitted)  # every frame is followed up before the flags are finished
        while submitted:
            submitted.popleft().result()
        for tid, flagger in flaggers.items():
            settle(tid, flagger.finish())
        if writer is not None:
            drain(writer, final=True)
            thumbnails.finish()
        return position + 1

    with _deferred_interrupt() as stop_request:
        if render:
            try:
                with OverlayWriter(overlay_path, fps=source.fps, width=source.width, height=source.height) as writer:
                    processed = run(writer)
                    if processed == 0:
                        # Not even the first frame decoded: discard the empty video (an MP4 needs a frame)
                        # and let the caller report the unreadable input.
                        raise _NothingTracked
            except _NothingTracked:
                processed = 0
        else:
            processed = run(None)
    if progress is not None:
        progress.close()
    tracks = [recorders[t.track_id].to_result() for t in targets]
    if budget:
        tracks = [_budget_flags(track, config.flags, model) for track in tracks]
    else:
        tracks = [_with_keyframe_request(track, config.flags) for track in tracks]
    return TrackingRun(
        video=info,
        tracks=tracks,
        frames_processed=processed,
        seconds_tracking=tracking_seconds,
        seconds_total=time.perf_counter() - started,
        decode_error=decode_error,
        interrupted=interrupted,
        thumbnails=thumbnails.thumbnails,
        overlay_path=overlay_path if render else None,
        tracker_confidence={tid: np.asarray(values, dtype=np.float64) for tid, values in tracker_confidence.items()},
    )


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

"""The stages ``track_source`` is made of, each alone, on synthetic frames and scripted tracker answers.

The whole pipeline runs end to end in tests/annotator/test_pipeline.py; here each stage gets the inputs it takes and no
more: the frame loop a list of frames and a recording follow-up, the records scripted tracker results, the overlay
sink a writer that keeps the frames it is given.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from _paths import DATA

from annotator.failure import load_model
from annotator.flagging import FlagParams
from annotator.frame_sources import DecodeError
from annotator.pipeline import (
    FrameMark,
    HeldFrames,
    OverlaySink,
    Target,
    TrackRecords,
    render_tracks,
    track_frame,
    track_frames,
)
from annotator.render import i420_to_rgb, rgb_to_i420
from sptpt.results import FrameResult

SCORE_ONLY_MODEL = DATA / "score_only_failure_model.json"
TARGETS = [Target((8.0, 8.0, 16.0, 16.0), track_id=1), Target((30.0, 20.0, 12.0, 12.0), track_id=2, label="b")]
H, W = 48, 64
LOST = range(6, 14)  # positions where track 1's scripted tracker rejects every candidate


def frame(k: int) -> np.ndarray:
    """A textured frame, different for each ``k`` (the value of its top-left pixel is ``k``)."""
    rng = np.random.default_rng(k)
    image = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    image[0, 0] = k
    return image


def scripted_result(track_id: int, position: int) -> FrameResult:
    """What a tracker could answer: the box drifts 1 px right per frame; track 1 is lost on ``LOST``."""
    box = np.asarray(TARGETS[track_id - 1].box_xywh) + [position, 0.0, 0.0, 0.0]
    if position == 0:
        return FrameResult(box_xywh=box, log_likelihood=10.0, confidence=1.0, accepted=True, scoring="init")
    lost = track_id == 1 and position in LOST
    return FrameResult(box_xywh=box, log_likelihood=-1.0 if lost else 10.0, confidence=0.1 if lost else 0.9,
                       accepted=not lost, scoring="subspace")


class ScriptedTracker:
    def __init__(self, track_id: int, calls: list) -> None:
        self.track_id, self.calls, self.position = track_id, calls, 0
        self.pending: list = []

    def init(self, image, box_xywh):
        self.calls.append((self.track_id, "init", int(image[0, 0, 0]), tuple(box_xywh)))
        return scripted_result(self.track_id, 0)

    def update(self, image, *, details=False):
        self.position += 1
        self.calls.append((self.track_id, "update", int(image[0, 0, 0]), details))
        return scripted_result(self.track_id, self.position)

    # Frames in flight, as the real tracker's: results in submission order.
    def submit(self, image, *, details=False):
        self.pending.append(self.update(image, details=details))
        self.calls[-1] = (self.track_id, "submit") + self.calls[-1][2:]

    def collect(self):
        self.calls.append((self.track_id, "collect"))
        return self.pending.pop(0)

    def discard(self):
        self.calls.append((self.track_id, "discard", len(self.pending)))
        self.pending.clear()


def scripted_trackers(calls: list) -> dict[int, ScriptedTracker]:
    return {t.track_id: ScriptedTracker(t.track_id, calls) for t in TARGETS}


class KeptFrames:
    """Stands in for an OverlayWriter: keeps what it is given."""

    def __init__(self) -> None:
        self.frames: list[np.ndarray] = []

    def write(self, image: np.ndarray) -> None:
        self.frames.append(image.copy())


def new_records(*, budget: bool = False, keep_marks: bool = True) -> TrackRecords:
    return TrackRecords(TARGETS, load_model(SCORE_ONLY_MODEL), FlagParams(merge_gap=2, min_span=2), budget=budget,
                        keep_marks=keep_marks)


def recorded(n: int, *, budget: bool = False) -> TrackRecords:
    records = new_records(budget=budget)
    for position in range(n):
        records.add(100 + position, frame(position), {t.track_id: scripted_result(t.track_id, position)
                                                      for t in TARGETS}, {1: 0.01, 2: 0.02})
    return records


# --------------------------------------------------------------------------- tracking


def test_track_frame_starts_each_tracker_on_the_first_frame_then_asks_for_details():
    calls: list = []
    trackers = scripted_trackers(calls)
    results, seconds = track_frame(trackers, TARGETS, frame(3), first=True)
    assert list(results) == [1, 2] and list(seconds) == [1, 2] and all(s >= 0 for s in seconds.values())
    assert [r.scoring for r in results.values()] == ["init", "init"]
    track_frame(trackers, TARGETS, frame(4), first=False)
    assert calls == [(1, "init", 3, TARGETS[0].box_xywh), (2, "init", 3, TARGETS[1].box_xywh),
                     (1, "update", 4, True), (2, "update", 4, True)]


def follow_ups_of(source, **kwargs):
    seen: list = []
    end = track_frames(source, TARGETS, scripted_trackers([]),
                       lambda position, index, image, results, seconds: seen.append(
                           (position, index, int(image[0, 0, 0]), sorted(results))), **kwargs)
    return end, seen


def test_track_frames_follows_every_frame_up_once_in_order():
    end, seen = follow_ups_of([(10 + k, frame(k)) for k in range(7)])
    assert seen == [(k, 10 + k, k, [1, 2]) for k in range(7)]
    assert end.frames_tracked == 7 and end.decode_error is None and not end.interrupted
    assert end.seconds_tracking >= 0


@pytest.mark.parametrize("ahead", [0, 2])
def test_track_frames_submits_frames_ahead_of_the_one_it_waits_for(ahead):
    """Each tracker gets frame k + ahead before frame k's result is collected, and never more in flight."""
    calls: list = []
    seen: list = []
    track_frames([(k, frame(k)) for k in range(6)], TARGETS, scripted_trackers(calls),
                 lambda position, *rest: seen.append(position), ahead=ahead)
    assert seen == list(range(6))
    one = [call[1:3] for call in calls if call[0] == 1]
    assert one[0] == ("init", 0)
    # Frames 1..5 submitted in order, each collected once, in order; the last ones after the source ended.
    expected = [("submit", k) for k in range(1, ahead + 1)]
    for k in range(ahead + 1, 6):
        expected += [("submit", k), ("collect",)]
    expected += [("collect",)] * ahead
    assert one[1:] == expected
    in_flight = max(sum(c[0] == "submit" for c in one[1:i]) - sum(c[0] == "collect" for c in one[1:i])
                    for i in range(1, len(one) + 1))
    assert in_flight == ahead + 1 if ahead else in_flight == 1


def test_track_frames_with_real_trackers_gives_update_s_results_to_the_bit():
    """Two targets, each tracked by three runs and the voter, two frames ahead on two kernel threads."""
    import dataclasses

    import numba

    from sptpt.params import get_preset
    from sptpt.tracker import Tracker
    from sptpt_dev.synthetic import make_clip

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread here: no run goes ahead")
    clip = make_clip(8, size=(96, 72), object_size=(24, 20), seed=2)
    targets = [Target(tuple(clip.boxes_xywh[0]), track_id=1), Target((60.0, 40.0, 20.0, 20.0), track_id=2)]
    params = dataclasses.replace(get_preset("fast"), n_particles=40, n_negatives=10, independent_runs=3,
                                 run_choice="consensus", filter_vote=True)
    new = lambda: {t.track_id: Tracker(params, seed=t.track_id) for t in targets}  # noqa: E731
    previous = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        seen: list = []
        track_frames(list(enumerate(clip.frames)), targets, new(),
                     lambda position, index, image, results, seconds: seen.append(results))
        in_step = new()
        expected = [{t.track_id: in_step[t.track_id].init(clip.frames[0], t.box_xywh) for t in targets}]
        expected += [{tid: tracker.update(frame, details=True) for tid, tracker in in_step.items()}
                     for frame in clip.frames[1:]]
    finally:
        numba.set_num_threads(previous)
    assert len(seen) == len(expected) == 8
    for got, want in zip(seen, expected):
        assert list(got) == [1, 2]
        for tid in (1, 2):
            np.testing.assert_array_equal(got[tid].box_xywh, want[tid].box_xywh)
            assert got[tid].log_likelihood == want[tid].log_likelihood
            if want[tid].particle_scores is not None:
                np.testing.assert_array_equal(got[tid].particle_scores, want[tid].particle_scores)


def test_track_frames_drops_the_frames_in_flight_on_ctrl_c_and_keeps_those_before():
    def source():
        for k in range(5):
            yield k, frame(k)
        raise KeyboardInterrupt  # as a Ctrl-C reaches a loop outside the main thread

    calls: list = []
    seen: list = []
    end = track_frames(source(), TARGETS, scripted_trackers(calls), lambda position, *rest: seen.append(position))
    assert end.interrupted and seen == [0, 1, 2] and end.frames_tracked == 3  # 3 and 4 were in flight
    assert (1, "discard", 2) in calls and (2, "discard", 2) in calls


def test_track_frames_keeps_the_frames_before_a_decode_error():
    def source():
        for k in range(3):
            yield 10 + k, frame(k)
        raise DecodeError("clip.mp4", 12, "broken packet")

    end, seen = follow_ups_of(source())
    assert [s[0] for s in seen] == [0, 1, 2] and end.frames_tracked == 3
    assert end.decode_error is not None and end.decode_error.last_good_index == 12 and not end.interrupted


def test_track_frames_stops_between_frames_when_asked():
    asked = iter([False, False, True])
    end, seen = follow_ups_of([(k, frame(k)) for k in range(5)], stop_requested=lambda: next(asked))
    assert end.interrupted and end.frames_tracked == 2 and [s[0] for s in seen] == [0, 1]


def test_track_frames_raises_the_first_follow_up_error():
    def failing(position, *args):
        if position == 2:
            raise RuntimeError("follow-up failed at 2")

    with pytest.raises(RuntimeError, match="at 2"):
        track_frames([(k, frame(k)) for k in range(20)], TARGETS, scripted_trackers([]), failing)


def test_track_frames_gives_freed_memory_back_after_the_first_frame_and_after_each_checkpoint(monkeypatch):
    """What the start and a checkpoint free is no frame's working set (annotator.allocator): the loop trims the
    heap right after those points, and at no other frame."""
    events: list = []  # the trackers' calls, the follow-ups' positions, the checkpoints and the trims, in order
    monkeypatch.setattr("annotator.pipeline.release_freed_memory", lambda: events.append("trim"))
    track_frames([(k, frame(k)) for k in range(7)], TARGETS, scripted_trackers(events),
                 lambda position, *rest: events.append(position),
                 checkpoint=lambda end, index: events.append(f"checkpoint {end.frames_tracked}"), checkpoint_every=3)
    # Both trackers started on frame 0, then the trim, before frame 1 is submitted to either.
    assert [event[1] for event in events[:2]] == ["init", "init"] and events[2] == "trim"
    assert events.count("trim") == 3
    assert events[events.index("checkpoint 3") + 1] == "trim" and events[events.index("checkpoint 6") + 1] == "trim"


# --------------------------------------------------------------------------- measuring and flagging


def test_records_hold_a_row_per_frame_and_flag_the_lost_frames():
    records = recorded(20)
    records.finish()
    one, two = records.tracks()
    assert len(one) == len(two) == 20 and one.frame_indices.tolist() == list(range(100, 120))
    np.testing.assert_array_equal(one.boxes_xywh[:, 0], 8.0 + np.arange(20))
    assert one.keyframe.tolist() == [True] + [False] * 19
    assert set(np.flatnonzero(one.flagged)) <= set(LOST) and one.flagged.any()
    assert not two.flagged.any()
    assert records.tracker_confidence()[1][LOST.start] == pytest.approx(0.1)


def test_records_decide_the_marks_a_few_frames_late_and_give_each_once():
    records = recorded(20)
    assert records.take_marks(19) is None  # not decided before the frames after it are seen
    records.finish()
    one, _ = records.tracks()
    marks = [records.take_marks(position) for position in range(20)]
    assert [m[1].flagged for m in marks] == one.flagged.tolist()
    np.testing.assert_allclose([m[1].p_fail for m in marks], one.p_fail)
    assert records.take_marks(0, final=True) == {1: FrameMark(False, "", 0.0), 2: FrameMark(False, "", 0.0)}


def test_records_with_a_review_budget_leave_rows_unflagged_but_give_the_online_marks():
    online, budget = recorded(20), recorded(20, budget=True)
    online.finish()
    budget.finish()
    assert not budget.tracks()[0].flagged.any()
    np.testing.assert_array_equal(budget.tracks()[0].p_fail, online.tracks()[0].p_fail)
    assert [budget.take_marks(p)[1].flagged for p in range(20)] == online.tracks()[0].flagged.tolist()


# --------------------------------------------------------------------------- the overlay


def test_overlay_sink_writes_each_frame_and_keeps_the_worst_frame_of_a_span():
    kept = KeptFrames()
    sink = OverlaySink(kept)
    p_fail = [0.1, 0.7, 0.9, 0.8, 0.2]
    for position, value in enumerate(p_fail):
        sink.write(position, 50 + position, frame(position), [], {1: FrameMark(0 < position < 4, "", value)})
    thumbnails = sink.finish()
    assert len(kept.frames) == 5 and all(f.shape == (H, W, 3) for f in kept.frames)
    assert [(t.track_id, t.position, t.frame_index) for t in thumbnails] == [(1, 2, 52)]


class DecidedUpTo:
    """Stands in for TrackRecords: the marks of positions below ``decided`` are final."""

    budget = False

    def __init__(self) -> None:
        self.decided = 0

    def take_marks(self, position, *, final=False):
        if position >= self.decided and not final:
            return None
        return {1: FrameMark(False, "", 0.25), 2: FrameMark(False, "", 0.5)}


def test_held_frames_reach_the_overlay_in_order_once_their_marks_are_final():
    records, kept = DecidedUpTo(), KeptFrames()
    held = HeldFrames(records, OverlaySink(kept))
    for position in range(4):
        held.add(position, position, frame(position), {t.track_id: scripted_result(t.track_id, position)
                                                       for t in TARGETS})
    assert kept.frames == []
    records.decided = 2
    held.drain()
    assert len(kept.frames) == 2
    held.drain(final=True)
    assert len(kept.frames) == 4


def test_held_frames_wait_in_yuv420_and_are_drawn_on_their_rgb_again():
    """A held frame takes half an RGB frame's memory (issue #69); what is drawn is its 4:2:0 round trip, odd
    sizes included."""
    records, kept = DecidedUpTo(), KeptFrames()
    held = HeldFrames(records, OverlaySink(kept))  # no items, no flag: nothing is drawn
    rng = np.random.default_rng(5)
    odd = cv2.resize(rng.integers(0, 256, (8, 9, 3)).astype(np.uint8), (W + 1, H + 1))
    held.add(0, 0, odd, {})
    (planes_held,) = [entry[2] for entry in held._held]
    assert planes_held.nbytes * 2 <= odd.nbytes + 3 * (W + H + 3)
    held.drain(final=True)
    np.testing.assert_array_equal(kept.frames[0], i420_to_rgb(rgb_to_i420(odd), W + 1, H + 1))


def test_streamed_and_rerendered_overlays_choose_the_same_thumbnails():
    """A first run's overlay (streamed while tracking) and a re-track's (drawn from the finished tracks) show
    different boxes (particles only live), but the same spans and so the same worst frames."""
    records, streamed = new_records(), KeptFrames()
    live = OverlaySink(streamed)
    held = HeldFrames(records, live)
    for position in range(20):
        results = {t.track_id: scripted_result(t.track_id, position) for t in TARGETS}
        records.add(100 + position, frame(position), results, {1: 0.0, 2: 0.0})
        held.add(position, 100 + position, frame(position), results)
    records.finish()
    held.drain(final=True)
    rerendered = KeptFrames()
    again = render_tracks(OverlaySink(rerendered), ((p, frame(p)) for p in range(20)), list(range(100, 120)),
                          records.tracks())
    live_thumbnails = live.finish()
    assert live_thumbnails and len(streamed.frames) == len(rerendered.frames) == 20
    assert [(t.track_id, t.position, t.frame_index) for t in again] == \
        [(t.track_id, t.position, t.frame_index) for t in live_thumbnails]

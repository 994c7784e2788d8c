"""Frames submitted ahead (``Tracker.submit`` and ``collect``): the same results as ``update``, to the bit, with each
run going on to the next frame as soon as its own part of a frame is done."""

from __future__ import annotations

import copy
import dataclasses
import pickle
import threading
import time
from concurrent.futures import wait

import numba
import numpy as np
import pytest
from _numba_threads import numba_threads
from threadpoolctl import threadpool_info

import sptpt.tracker as tracker_module
from sptpt.params import get_preset
from sptpt.results import FrameResult
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip

needs_two_threads = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2,
                                       reason="numba has one thread here: no run can go ahead")


@pytest.fixture(scope="module")
def clip():
    return make_clip(12, seed=4)


def three_runs_and_the_voter():
    """robust's choice (three runs, consensus with the correlation-filter voter) at a test's cost."""
    return dataclasses.replace(get_preset("fast"), independent_runs=3, run_choice="consensus", filter_vote=True)


def by_update(clip, params, seed=7):
    tracker = Tracker(params, seed=seed)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    return [tracker.update(frame, details=k % 2 == 0) for k, frame in enumerate(clip.frames[1:])]


def by_submit(clip, params, ahead, seed=7):
    tracker = Tracker(params, seed=seed)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    results = []
    for k, frame in enumerate(clip.frames[1:]):
        tracker.submit(frame, details=k % 2 == 0)
        while tracker.submitted > ahead:
            results.append(tracker.collect())
    while tracker.submitted:
        results.append(tracker.collect())
    return results


def numbered(clip, n: int) -> list[np.ndarray]:
    """Copies of frames 1..n whose first pixel holds the frame's number (for scripted runs to read)."""
    frames = [clip.frames[k].copy() for k in range(1, n + 1)]
    for k, frame in enumerate(frames, start=1):
        frame[0, 0, 0] = k
    return frames


def scripted_runs(clip, monkeypatch, act) -> Tracker:
    """A started tracker of three runs whose update only calls ``act(run index, frame number)`` (the frames of
    :func:`numbered`) and answers a fixed box."""
    tracker = Tracker(dataclasses.replace(get_preset("fast"), independent_runs=3), seed=1)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])

    def update(self, frame, *, details, share=1.0, guide_box=None):
        act(tracker._runs.index(self), int(frame[0, 0, 0]))
        return FrameResult(box_xywh=np.array([10.0, 10.0, 20.0, 20.0]), log_likelihood=1.0, confidence=0.5,
                           accepted=True, scoring="subspace")

    monkeypatch.setattr(tracker_module._Run, "update", update)
    return tracker


def assert_same(expected: list[FrameResult], got: list[FrameResult]) -> None:
    assert len(expected) == len(got)
    for a, b in zip(expected, got):
        np.testing.assert_array_equal(a.box_xywh, b.box_xywh)
        np.testing.assert_array_equal(a.run_boxes_xywh, b.run_boxes_xywh)
        assert (a.log_likelihood, a.confidence, a.accepted, a.scoring) == (b.log_likelihood, b.confidence,
                                                                           b.accepted, b.scoring)
        if a.particle_scores is None:
            assert b.particle_scores is None
        else:
            np.testing.assert_array_equal(a.particle_scores, b.particle_scores)
            np.testing.assert_array_equal(a.superpixel_labels, b.superpixel_labels)


@needs_two_threads
@pytest.mark.parametrize("ahead", [1, 3])
def test_frames_submitted_ahead_give_update_s_results_to_the_bit(clip, ahead):
    params = three_runs_and_the_voter()
    with numba_threads(2):
        expected = by_update(clip, params)
        assert_same(expected, by_submit(clip, params, ahead))


@pytest.mark.parametrize("threads, easy_after", [(1, 0), (2, 2)])
def test_where_runs_cannot_go_ahead_submit_tracks_at_once_with_the_same_results(clip, monkeypatch, threads,
                                                                                   easy_after):
    """One kernel thread (a one-core batch worker), or easy frames, whose share waits on the last consensus."""
    if threads > numba.config.NUMBA_NUM_THREADS:
        pytest.skip("numba has one thread here")
    params = dataclasses.replace(three_runs_and_the_voter(), easy_after=easy_after, easy_share=0.5)
    with numba_threads(threads):
        expected = by_update(clip, params)
        monkeypatch.setattr(tracker_module.InOrder, "submit", lambda *args: pytest.fail("a run went ahead"))
        assert_same(expected, by_submit(clip, params, 2))


@needs_two_threads
def test_a_run_goes_on_to_the_next_frame_while_another_still_tracks_this_one(clip, monkeypatch):
    """Run 1 finishes frame 1 only once run 0 has started frame 2: with the runs waiting for each other every frame,
    it would wait in vain."""
    started: dict[tuple[int, int], threading.Event] = {}
    lock = threading.Lock()

    def event(run: int, frame: int) -> threading.Event:
        with lock:
            return started.setdefault((run, frame), threading.Event())

    def act(run: int, k: int) -> None:
        event(run, k).set()
        if (run, k) == (1, 1) and not event(0, 2).wait(10):
            raise AssertionError("run 0 did not go on to frame 2")

    tracker = scripted_runs(clip, monkeypatch, act)
    frames = numbered(clip, 3)
    with numba_threads(2):
        for frame in frames:
            tracker.submit(frame)
        assert tracker.submitted == 3
        results = [tracker.collect() for _ in frames]
    assert tracker.submitted == 0 and all(r.accepted for r in results)


@needs_two_threads
def test_a_run_s_error_reaches_collect_and_drops_the_frames_after_it(clip, monkeypatch):
    real_update = tracker_module._Run.update

    def update(self, frame, *, details, share=1.0):
        if int(frame[0, 0, 0]) == 2 and tracker._runs.index(self) == 2:
            raise FloatingPointError("run 2 failed on frame 2")
        return real_update(self, frame, details=details, share=share)

    tracker = Tracker(three_runs_and_the_voter(), seed=1)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    monkeypatch.setattr(tracker_module._Run, "update", update)
    frames = numbered(clip, 4)
    with numba_threads(2):
        for frame in frames:
            tracker.submit(frame)
        assert tracker.collect().box_xywh.shape == (4,)
        with pytest.raises(FloatingPointError, match="frame 2"):
            tracker.collect()
    assert tracker.submitted == 0
    tracker.init(clip.frames[0], clip.boxes_xywh[0])  # started again, it tracks on
    assert tracker.update(clip.frames[1]).box_xywh.shape == (4,)


def test_calls_out_of_turn_are_refused_and_discard_drops_what_is_in_flight(clip):
    tracker = Tracker(three_runs_and_the_voter(), seed=2)
    with pytest.raises(RuntimeError, match="submit\\(frame\\) first"):
        tracker.collect()
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    with pytest.raises(ValueError, match="same size"):
        tracker.submit(clip.frames[1][:-4])
    assert tracker.submitted == 0
    tracker.submit(clip.frames[1])
    tracker.submit(clip.frames[2])
    for call in (lambda: tracker.update(clip.frames[3]), lambda: tracker.init(clip.frames[0], clip.boxes_xywh[0]),
                 lambda: tracker.inspect(clip.frames[2])):
        with pytest.raises(RuntimeError, match="2 submitted frame\\(s\\) not collected"):
            call()
    tracker.discard()
    assert tracker.submitted == 0
    tracker.init(clip.frames[0], clip.boxes_xywh[0])  # started again (its runs' random streams go on)
    assert tracker.update(clip.frames[1]).box_xywh.shape == (4,)


def blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_blas_stays_on_one_thread_until_the_last_holder_lets_go():
    """Frames in flight hold the limit until their runs are done; a second holder (another tracker's) must not lift
    it; the last holder lifts it from whichever thread it lets go on."""
    before = blas_threads()
    hold = tracker_module._BlasOnOneThread()
    hold.acquire()
    hold.acquire()
    assert all(n == 1 for n in blas_threads())
    hold.release()
    assert all(n == 1 for n in blas_threads())
    thread = threading.Thread(target=hold.release)  # as a run's lane lets go of a frame's hold
    thread.start()
    thread.join()
    assert blas_threads() == before


@needs_two_threads
def test_a_tracker_dropped_with_frames_in_flight_gives_blas_its_threads_back(clip):
    before = blas_threads()
    tracker = Tracker(three_runs_and_the_voter(), seed=3)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    with numba_threads(2):
        tracker.submit(clip.frames[1])
        tracker.submit(clip.frames[2])
    futures = [future for entry in tracker._submitted for future in entry.futures]
    del tracker  # never collected
    wait(futures)
    for _ in range(100):  # the last task's done-callback runs just after its future is done
        if blas_threads() == before:
            break
        time.sleep(0.01)
    assert blas_threads() == before


def test_a_tracker_is_copied_with_nothing_in_flight_and_refuses_while_frames_are(clip):
    tracker = Tracker(three_runs_and_the_voter(), seed=4)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    twin = copy.deepcopy(tracker)
    again = pickle.loads(pickle.dumps(tracker))
    boxes = [t.update(clip.frames[1]).box_xywh for t in (tracker, twin, again)]
    np.testing.assert_array_equal(boxes[0], boxes[1])
    np.testing.assert_array_equal(boxes[0], boxes[2])
    with numba_threads(2):
        tracker.submit(clip.frames[2])
        with pytest.raises(RuntimeError, match="copying\\(\\) with 1 submitted frame"):
            copy.deepcopy(tracker)
        tracker.collect()


def test_a_lane_is_idle_when_its_last_call_s_future_is_done():
    """A tracker is copied (a run's checkpoint) right after its frames are collected: its lanes must be idle by
    then, not a moment later when their thread gets round to the empty queue. The lane's thread is slowed down
    wherever it takes the lane's lock, so that the waiter runs first whenever it can."""
    from sptpt._kernels import InOrder

    class SlowInLaneThread:
        def __init__(self) -> None:
            self._lock = threading.Lock()

        def __enter__(self):
            if threading.current_thread() is not threading.main_thread():
                time.sleep(0.002)
            self._lock.acquire()

        def __exit__(self, *exc) -> None:
            self._lock.release()

    lane = InOrder()
    lane._lock = SlowInLaneThread()
    for k in range(20):
        future = lane.submit(lambda k=k: k)
        assert future.result() == k
        pickle.dumps(lane)  # refused while the lane still has calls to make


@needs_two_threads
def test_discard_cancels_what_the_runs_have_not_started(clip, monkeypatch):
    calls = []
    tracker = scripted_runs(clip, monkeypatch, lambda run, k: calls.append(k) or time.sleep(0.2))
    frames = numbered(clip, 4)
    with numba_threads(2):
        for frame in frames:
            tracker.submit(frame)
        for _ in range(100):  # until every run is inside its first frame
            if len(calls) == 3:
                break
            time.sleep(0.01)
        tracker.discard()
    assert tracker.submitted == 0
    assert sorted(calls) == [1, 1, 1]  # each run's first frame had started; the three later ones never ran


@needs_two_threads
def test_an_interrupted_submit_leaves_nothing_running_unseen(clip, monkeypatch):
    """A Ctrl-C part-way through submit: the runs that got the frame are waited for, collect says the frame is
    incomplete, and BLAS gets its threads back."""
    before = blas_threads()
    tracker = Tracker(three_runs_and_the_voter(), seed=5)
    tracker.init(clip.frames[0], clip.boxes_xywh[0])
    real_submit = tracker_module.InOrder.submit
    made = []

    def submit(lane, call):
        if len(made) == 2:
            raise KeyboardInterrupt
        made.append(lane)
        return real_submit(lane, call)

    monkeypatch.setattr(tracker_module.InOrder, "submit", submit)
    with numba_threads(2):
        with pytest.raises(KeyboardInterrupt):
            tracker.submit(clip.frames[1])
        assert tracker.submitted == 1
        with pytest.raises(RuntimeError, match="interrupted before every run had this frame"):
            tracker.collect()
    assert tracker.submitted == 0
    for _ in range(100):
        if blas_threads() == before:
            break
        time.sleep(0.01)
    assert blas_threads() == before

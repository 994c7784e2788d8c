"""The thread pool under the batch kernels and the tracker's parallel stages."""

from __future__ import annotations

import pickle
import threading
import time

import numpy as np
import pytest

from sptpt._kernels import InOrder, map_on_threads, on_own_threads, run_in_chunks


def test_every_item_is_done_once_whatever_the_chunk_count() -> None:
    for n_threads in (1, 2, 3, 7, 50):
        done = np.zeros(10, dtype=int)

        def work(start: int, stop: int, done: np.ndarray = done) -> None:
            done[start:stop] += 1

        run_in_chunks(work, 10, n_threads)
        np.testing.assert_array_equal(done, np.ones(10, dtype=int))


def test_an_error_is_raised_once_no_block_is_running_and_stops_the_rest() -> None:
    running = []
    started = []
    lock = threading.Lock()

    def work(start: int, stop: int) -> None:
        with lock:
            running.append(start)
            started.append(start)
        time.sleep(0.01)
        with lock:
            running.remove(start)
        if start == 0:
            raise ValueError("first block failed")

    with pytest.raises(ValueError, match="first block failed"):
        run_in_chunks(work, 1000, 2)
    assert running == []  # nothing still writes once the caller sees the error
    assert len(started) < 1000 and 0 in started  # the blocks after the error were not started


def test_blocks_are_contiguous_disjoint_and_cover_every_item() -> None:
    for n_items in (1, 2, 3, 129, 1000):
        blocks = []
        lock = threading.Lock()

        def work(start: int, stop: int, blocks: list = blocks, lock: threading.Lock = lock) -> None:
            with lock:
                blocks.append((start, stop))

        run_in_chunks(work, n_items, 2)
        blocks.sort()
        assert blocks[0][0] == 0 and blocks[-1][1] == n_items, (n_items, blocks)
        assert all(a[1] == b[0] for a, b in zip(blocks, blocks[1:]))
        assert all(stop > start for start, stop in blocks)


def test_an_error_in_a_pool_thread_reaches_the_caller() -> None:
    pool_started = threading.Event()
    failed_on = []

    def work(start: int, stop: int) -> None:
        if threading.current_thread() is threading.main_thread():
            # Hold the calling thread's first block until a pool thread has taken one, so that one fails there.
            assert pool_started.wait(timeout=30)
            return
        pool_started.set()
        failed_on.append(threading.current_thread().name)
        raise RuntimeError("pool block failed")

    with pytest.raises(RuntimeError, match="pool block failed"):
        run_in_chunks(work, 100, 2)
    assert failed_on and failed_on[0].startswith("sptpt-kernel")


def test_map_on_threads_returns_the_results_in_item_order_from_both_threads() -> None:
    names = map_on_threads(lambda item: (item, threading.current_thread().name), range(6), 2)
    assert [item for item, _ in names] == list(range(6))
    assert map_on_threads(lambda item: item * item, [3, 1, 2], 1) == [9, 1, 4]
    assert map_on_threads(lambda item: item, [], 2) == []


def test_on_own_threads_runs_every_call_at_once_and_keeps_the_item_order() -> None:
    # More calls than this machine may have cores: each waits for all the others, so the test fails (the
    # barrier breaks) unless every call has a thread of its own at the same time.
    items = list(range(5))
    barrier = threading.Barrier(len(items), timeout=10)

    def call(item: int) -> tuple[int, str]:
        barrier.wait()
        return item * item, threading.current_thread().name

    results = on_own_threads(call, items)
    assert [value for value, _ in results] == [item * item for item in items]
    assert len({name for _, name in results}) == len(items)
    assert results[0][1] == threading.current_thread().name  # the first call on the caller's thread
    assert on_own_threads(lambda item: item + 1, [4]) == [5]
    assert on_own_threads(lambda item: item, []) == []


def test_on_own_threads_raises_once_every_call_has_stopped() -> None:
    finished = []

    def call(item: int) -> int:
        if item == 0:
            raise RuntimeError("first call failed")
        time.sleep(0.05)
        finished.append(item)
        return item

    with pytest.raises(RuntimeError, match="first call failed"):
        on_own_threads(call, [0, 1, 2])
    assert sorted(finished) == [1, 2]  # no call still running when the error reached the caller
    with pytest.raises(ValueError, match="a later call failed"):
        on_own_threads(lambda item: (_ for _ in ()).throw(ValueError("a later call failed")) if item else item,
                       [0, 1])


def test_in_order_makes_its_calls_one_after_another_in_submission_order_while_the_caller_goes_on() -> None:
    lane = InOrder()
    release = threading.Event()
    running: list[int] = []
    done: list[int] = []

    def call(item: int) -> int:
        running.append(item)
        assert len(running) - len(done) == 1, "two calls of one lane at once"
        if item == 0:
            assert release.wait(10)  # the caller submits the rest meanwhile: submit never waits
        done.append(item)
        return item * 10

    futures = [lane.submit(lambda item=item: call(item)) for item in range(5)]
    assert not futures[0].done()
    release.set()
    assert [future.result(timeout=10) for future in futures] == [0, 10, 20, 30, 40]
    assert done == list(range(5))


def test_in_order_hands_a_call_s_error_to_its_future_and_goes_on_with_the_next() -> None:
    lane = InOrder()
    failing = lane.submit(lambda: (_ for _ in ()).throw(ValueError("call 0 failed")))
    after = lane.submit(lambda: "next")
    with pytest.raises(ValueError, match="call 0 failed"):
        failing.result(timeout=10)
    assert after.result(timeout=10) == "next"
    # Idle again: a later call starts a new thread's turn.
    assert lane.submit(lambda: 7).result(timeout=10) == 7


def test_in_order_fails_its_calls_when_no_thread_can_make_them_and_works_again_after(monkeypatch) -> None:
    import sptpt._kernels as kernels

    class NoThreads:
        def submit(self, *args):
            raise RuntimeError("cannot schedule new futures after interpreter shutdown")

    lane = InOrder()
    monkeypatch.setattr(kernels, "_own_pool", lambda: NoThreads())
    with pytest.raises(RuntimeError, match="interpreter shutdown"):
        lane.submit(lambda: 1)
    monkeypatch.undo()
    assert lane.submit(lambda: 2).result(timeout=10) == 2  # not left waiting for a thread that never came


def test_in_order_after_a_fork_fails_what_the_parent_s_thread_would_have_made() -> None:
    lane = InOrder()
    release = threading.Event()
    running = lane.submit(lambda: release.wait(10))
    queued = lane.submit(lambda: "never")
    time.sleep(0.05)
    with pytest.raises(TypeError, match="while it has calls"):
        pickle.dumps(lane)
    lane._forget()  # what the fork hook does in the child
    for future in (running, queued):
        with pytest.raises(RuntimeError, match="forked"):
            future.result(timeout=1)
    release.set()
    assert pickle.loads(pickle.dumps(lane)).submit(lambda: 3).result(timeout=10) == 3

"""Private numba kernels: tight loops only, no validation and no defaults (see the public wrappers).

The batch kernels are serial ``nogil`` loops over an item range ``start:stop``
writing into a preallocated output; :func:`run_in_chunks` runs contiguous
blocks of a batch on threads (:func:`map_on_threads` runs a few independent
Python calls there; :func:`on_own_threads` runs each on a thread of its own,
for the tracker's runs, and :class:`InOrder` runs calls one after another on them, for a run that goes ahead of
the others). numba's ``parallel=True`` (``prange``) would do
the same, but its parallel lowering added about 2 s of compilation per kernel
on a fresh install (``cue_features``: 3.9 s parallel, 1.6 s serial), most of
the quick start's first run, for no speed gain on these embarrassingly
parallel batches.
"""

from __future__ import annotations

import collections
import os
import threading
import weakref
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

import numba

__all__ = ["InOrder", "map_on_threads", "on_own_threads", "run_in_chunks"]

#: numba's settings (``numba.config``), read when used: numba sets them at import time, from the environment,
#: so they are invisible to the type checker.
_NUMBA_CONFIG: Any = numba.config
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()
# Threads of :func:`on_own_threads`, apart from the kernel pool: a call there may itself run kernels in chunks.
# The executor starts a thread only when none of its own is idle. Calls that themselves call on_own_threads until
# all of its threads are busy would wait on each other for ever; the tracker's runs never nest (inside a run
# numba has one thread, so its stages run on the caller's thread).
_OWN: ThreadPoolExecutor | None = None
_OWN_MAX = 64
# Every InOrder, for the fork hook (weakly: a dropped tracker's lanes go with it).
_LANES: weakref.WeakSet = weakref.WeakSet()


def _forget_pool() -> None:
    # A forked child inherits the pool objects but not their threads; it would wait forever on them (nor the
    # lock's state, if another thread held it at the fork).
    global _POOL, _POOL_LOCK, _OWN
    _POOL = None
    _OWN = None
    _POOL_LOCK = threading.Lock()
    for lane in list(_LANES):  # their threads are gone too: the calls queued there will never run
        lane._forget()


os.register_at_fork(after_in_child=_forget_pool)


def _pool() -> ThreadPoolExecutor:
    """The process's kernel thread pool, created on first use (once, also when two threads ask at once)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            # As many workers as numba would start threads; a smaller thread
            # count (numba.set_num_threads) simply uses fewer of them.
            _POOL = ThreadPoolExecutor(max_workers=max(1, _NUMBA_CONFIG.NUMBA_NUM_THREADS - 1),
                                       thread_name_prefix="sptpt-kernel")
        return _POOL


def run_in_chunks(kernel, n_items: int, n_threads: int, *args) -> None:
    """Call ``kernel(*args, start, stop)`` on contiguous blocks covering ``range(n_items)``, on ``n_threads`` threads.

    The calling thread and pool threads take blocks in turn until none is left
    (guided scheduling: each block is a share of what remains, at least one
    item), so a thread that finishes early takes more instead
    of waiting: with one fixed range per thread, the two threads of a frame's
    LASSO finished about 3 ms apart on Deer. The kernel must release the GIL
    for most of its work (a ``nogil=True`` numba kernel, or NumPy and BLAS
    calls on large arrays) and write only to items ``start:stop`` of its
    outputs, so the result does not depend on the blocks or the threads.
    ``n_threads`` is clipped to ``[1, n_items]``. The first exception of a
    block is raised once every thread has stopped.
    """
    n_threads = max(1, min(n_threads, n_items))
    if n_threads == 1:
        kernel(*args, 0, n_items)
        return
    pool = _pool()
    lock = threading.Lock()
    taken = [0]
    failed = threading.Event()

    def take_blocks() -> None:
        while not failed.is_set():
            with lock:
                start = taken[0]
                if start >= n_items:
                    return
                stop = min(n_items, start + max(1, (n_items - start) // (2 * n_threads)))
                taken[0] = stop
            try:
                kernel(*args, start, stop)
            except BaseException:
                failed.set()  # the other threads stop after their current block
                raise

    futures = [pool.submit(take_blocks) for _ in range(n_threads - 1)]
    try:
        take_blocks()
    finally:
        # Also when this thread raised: no block may still be writing once the caller goes on.
        wait(futures)
    for future in futures:
        future.result()


def map_on_threads(function, items, n_threads: int) -> list:
    """``[function(item) for item in items]``, the calls made on ``n_threads`` kernel threads (one item a block).

    For a few independent calls whose work is mostly NumPy or BLAS (GIL released): each result is computed
    exactly as it would be alone.
    """
    items = list(items)
    results: list = [None] * len(items)

    def call_range(start: int, stop: int) -> None:
        for index in range(start, stop):
            results[index] = function(items[index])

    run_in_chunks(call_range, len(items), n_threads)
    return results


def on_own_threads(function, items) -> list:
    """``[function(item) for item in items]``, every call on a thread of its own at the same time (the first on the
    calling thread), however many cores there are.

    For a few independent calls that alternate kernels (GIL released) with serial Python work: with more calls
    than cores the operating system shares the cores among them, so one call's serial work overlaps the others'
    kernels instead of leaving a core idle. Each result is computed exactly as it would be alone.
    """
    items = list(items)
    if len(items) <= 1:
        return [function(item) for item in items]
    pool = _own_pool()
    futures = [pool.submit(function, item) for item in items[1:]]
    try:
        first = function(items[0])
    finally:
        wait(futures)  # also when the first call raised: none may still be running once the caller goes on
    return [first] + [future.result() for future in futures]


def _own_pool() -> ThreadPoolExecutor:
    """The threads of :func:`on_own_threads` and :class:`InOrder`, created on first use."""
    global _OWN
    with _POOL_LOCK:
        if _OWN is None:
            _OWN = ThreadPoolExecutor(max_workers=_OWN_MAX, thread_name_prefix="sptpt-own")
        return _OWN


class InOrder:
    """Calls made one after another in the order they were submitted, each on a thread of :func:`on_own_threads`'
    pool while the caller goes on.

    For a run of the tracker that may go ahead of the others: its frames must be tracked in turn, but need not
    wait for the other runs. Holds a thread only while it has calls to make (none of its own when idle), so a
    tracker that is dropped leaves no thread behind.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._queue: collections.deque = collections.deque()  # (future, call) not started yet
        self._busy = False
        self._running: Future | None = None  # the call being made (for the fork hook)
        _LANES.add(self)

    def submit(self, call) -> Future:
        """``call()`` after every call submitted before it; its future holds its result or its exception."""
        future: Future = Future()
        with self._lock:
            self._queue.append((future, call))
            if self._busy:
                return future  # the thread making the calls before it takes it next
            self._busy = True
        try:
            _own_pool().submit(self._drain)
        except BaseException as exc:  # no thread to make the calls (interpreter shutting down, interrupted)
            self._fail_queued(exc)
            raise
        return future

    def __getstate__(self) -> dict:
        # A copy (of a tracker, say) gets a lane of its own, idle; calls in progress cannot be copied.
        with self._lock:
            if self._busy:
                raise TypeError("cannot copy a lane while it has calls to make")
        return {}

    def __setstate__(self, state: dict) -> None:
        type(self).__init__(self)

    def _forget(self) -> None:
        """In a forked child: the parent's thread making these calls is not there."""
        self._lock = threading.Lock()
        lost = RuntimeError("the process forked while this call waited or ran: it will never finish here")
        running, self._running = self._running, None
        if running is not None and not running.done():
            running.set_exception(lost)
        self._fail_queued(lost)

    def _fail_queued(self, exc: BaseException) -> None:
        with self._lock:
            queued, self._queue, self._busy = self._queue, collections.deque(), False
        for future, _ in queued:
            if future.set_running_or_notify_cancel():
                future.set_exception(exc)

    def _drain(self) -> None:
        while True:
            with self._lock:
                if not self._queue:
                    self._busy = False
                    return
                future, call = self._queue.popleft()
                if not future.set_running_or_notify_cancel():
                    continue
                self._running = future
            failed: BaseException | None = None
            try:
                result = call()
            except BaseException as exc:  # handed to whoever waits on the future
                failed = exc
            # Idle before the last call's future is done: whoever waited on it may copy the lane at once.
            with self._lock:
                self._running = None
                idle = not self._queue
                if idle:
                    self._busy = False
            if failed is not None:
                future.set_exception(failed)
            else:
                future.set_result(result)
            if idle:
                return

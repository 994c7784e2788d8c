"""Where items are sent to run: local worker processes or a Dask cluster, and the loop that collects outcomes.

Workers
    ``workers=N``: a :class:`concurrent.futures.ProcessPoolExecutor` of N
    processes started by a fork server (``spawn`` where there is none; never
    plain fork: numba's OpenMP/workqueue thread pools are not fork-safe, and
    the parent may have run the tracker before), numba threads per worker
    ``cores // N``. See :func:`worker_context`. ``scheduler=ADDRESS``:
    a running Dask distributed cluster; its workers must see the inputs and
    ``OUT`` at the same paths and have this package installed. Run one item
    at a time per Dask worker process (``dask worker --nthreads 1
    --nworkers N``): items in one process are serialised by a lock, since
    numba's parallel kernels are not safe to enter from two threads.

Worker deaths
    A worker process that dies (out of memory, killed) is replaced and its
    items retried once; an item in flight when a worker dies twice fails
    with that reason. On a Dask cluster the scheduler does the retrying.

When the main process dies
    Local workers and their fork server stop within moments of the batch's
    main process, whatever ends it (``kill -9`` included): no orphan keeps
    tracking, writing or holding memory and cores that a rerun needs. Each
    worker watches a pipe whose write end only the main process holds and
    exits at its end of file (see
    :func:`annotator.batch.workers._exit_when_main_process_dies`); the fork
    server, whose "alive" pipe the workers hold, then sees its end of file
    and exits too, as does multiprocessing's resource tracker. On a Dask
    cluster the workers belong to the cluster: when the client disconnects
    the scheduler releases the run's items, and one already running on a
    worker runs to its end there.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing as mp
import os
import queue as queue_module
import time
import uuid
from pathlib import Path
from typing import Any, cast

from annotator.batch.outputs import write_failures
from annotator.batch.plan import ItemJob, PlannedItem
from annotator.batch.workers import ItemOutcome, dask_run_item, pool_initializer, pool_run_item
from annotator.errors import EXIT_INTERNAL, EXIT_VALUE, ToolError
from annotator.progress import BatchProgress

_MAX_WORKER_DEATHS = 2  # an item in flight when this many workers died fails


def default_workers() -> int:
    """Cores this process may run on (``sched_getaffinity``), else ``os.cpu_count()``."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)



def threads_per_worker(n_workers: int) -> int:
    """numba threads for each of ``n_workers`` local workers: the cores shared out, within NUMBA_NUM_THREADS."""
    import numba

    # numba.config sets its settings at import time, unseen by the type checker.
    return max(1, min(default_workers() // n_workers, cast(Any, numba.config).NUMBA_NUM_THREADS))



def worker_context() -> Any:
    """``forkserver`` with the worker module preloaded where the platform has it, else ``spawn``.

    Never plain ``fork``: the parent may have run numba's parallel kernels
    (OpenMP or workqueue threads, which do not survive a fork). The fork
    server is a fresh interpreter that only imports the tool (numba's thread
    pool is not started by importing), so forking workers from it is safe,
    and starts two workers in about 0.4 s instead of 1.0-1.5 s with spawn on
    the 2-core development machine.
    """
    if "forkserver" in mp.get_all_start_methods():
        context = mp.get_context("forkserver")
        context.set_forkserver_preload(["annotator.batch.workers"])
        return context
    return mp.get_context("spawn")  # pragma: no cover - Windows


class _PoolBackend:
    """Local worker processes (forkserver or spawn), rebuilt if one dies."""

    name = "processes"

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._context = worker_context()
        self._start()

    def _start(self) -> None:
        self.events = self._context.Queue()
        # Only this process holds the write end; each worker gets a copy of the read end and exits at its EOF.
        self._main_alive_reader, self._main_alive_writer = self._context.Pipe(duplex=False)
        self.pool = cf.ProcessPoolExecutor(self.workers, mp_context=self._context, initializer=pool_initializer,
                                           initargs=(self.events, self._main_alive_reader))

    def submit(self, job: ItemJob, priority: int = 0) -> cf.Future:
        return self.pool.submit(pool_run_item, job)

    def is_worker_death(self, exc: BaseException) -> bool:
        return isinstance(exc, cf.process.BrokenProcessPool)

    def restart(self) -> None:
        self._drop(cancel=True)
        self._start()

    def drain(self, timeout: float) -> list[tuple]:
        events = []
        try:
            events.append(self.events.get(timeout=timeout))
            while True:
                events.append(self.events.get_nowait())
        except (queue_module.Empty, OSError, EOFError, ValueError):
            pass
        return events

    def _drop(self, *, cancel: bool) -> None:
        processes = list(getattr(self.pool, "_processes", {}).values())
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)
        if cancel:
            for process in processes:
                with contextlib.suppress(Exception):
                    process.kill()
            for process in processes:
                with contextlib.suppress(Exception):
                    process.join(5)
        with contextlib.suppress(Exception):
            self.events.close()
            self.events.cancel_join_thread()
        # After the shutdown above: closing earlier would end workers still finishing their items.
        self._main_alive_writer.close()
        self._main_alive_reader.close()

    def close(self, *, cancel: bool = False) -> None:
        self._drop(cancel=cancel)


def check_scheduler_address(address: str) -> None:
    """Refuse an address Dask cannot parse before a Client exists: a half-built Client prints a traceback
    from its destructor and holds the process for seconds."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        if scheme in ("tcp", "tls", "ws", "wss"):
            parse_host_port(location)
    except ValueError as exc:
        raise ToolError(f"--scheduler {address!r} is not a Dask scheduler address ({exc}): give e.g. "
                        "tcp://10.0.0.5:8786, or leave out --scheduler to use local processes", EXIT_VALUE) from None


class _DaskBackend:
    """An existing Dask distributed cluster."""

    name = "dask"

    def __init__(self, address: str) -> None:
        from distributed import Client, Queue  # present: run_batch checked the extra first
        try:
            self.client = Client(address, timeout="15s", set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ToolError(f"--scheduler {address}: cannot connect to a Dask scheduler ({exc}); start one "
                            "(`dask scheduler`, `dask worker ADDRESS`) or leave out --scheduler to use local "
                            "processes", EXIT_VALUE) from None
        self.queue_name = f"sptpt-batch-{uuid.uuid4().hex}"
        self.events = Queue(self.queue_name, client=self.client)
        self._token = uuid.uuid4().hex[:8]
        self._futures: list[Any] = []

    def submit(self, job: ItemJob, priority: int = 0) -> Any:
        future = self.client.submit(dask_run_item, job, self.queue_name, pure=False, priority=priority, retries=0,
                                    key=f"sptpt-item-{job.item_id}-{self._token}")
        self._futures.append(future)
        return future

    def is_worker_death(self, exc: BaseException) -> bool:
        return False  # the scheduler already retries on other workers, then raises KilledWorker

    def restart(self) -> None:  # pragma: no cover - never asked for
        pass

    def drain(self, timeout: float) -> list[tuple]:
        try:
            events = self.events.get(batch=True)
        except Exception:  # noqa: BLE001 - progress only
            events = []
        if not events:
            time.sleep(timeout)
        return [tuple(e) for e in events]

    def close(self, *, cancel: bool = False) -> None:
        with contextlib.suppress(Exception):
            if cancel:
                self.client.cancel(self._futures)
            self.client.close()


def execute_items(todo: list[PlannedItem], outcomes: dict[str, ItemOutcome], progress: BatchProgress, out_dir: Path,
             planned: list[PlannedItem], *, scheduler: str | None, workers: int) -> None:
    """Submit every item, collect outcomes as they come, replace a broken process pool."""
    backend: _PoolBackend | _DaskBackend = _DaskBackend(scheduler) if scheduler else _PoolBackend(workers)
    deaths: dict[str, int] = {}  # item id -> worker deaths while it was running
    attempts: dict[str, int] = {}  # item id -> resubmissions after a pool broke
    started: set[str] = set()  # items whose "start" event came from the current pool

    def note(events: list[tuple]) -> None:
        for event in events:
            if event and event[0] == "start":
                started.add(event[1])
            progress.event(event)

    try:
        pending: dict[Any, PlannedItem] = {}
        for rank, plan in enumerate(todo):
            pending[backend.submit(plan.job, priority=len(todo) - rank)] = plan
        while pending:
            note(backend.drain(0.1))
            finished = [h for h in pending if h.done()]
            if any(_is_death(backend, h) for h in finished):
                note(backend.drain(0.2))  # late "start" events say which items were running
            requeue: list[PlannedItem] = []
            for handle in finished:
                plan = pending.pop(handle)
                item_id = plan.item.id
                try:
                    outcome = handle.result()
                except KeyboardInterrupt:
                    raise
                except BaseException as exc:  # noqa: BLE001 - every other failure is this item's
                    outcome = _worker_failure(backend, exc, item_id, started, deaths, attempts)
                    if outcome is None:
                        requeue.append(plan)
                        continue
                outcomes[item_id] = outcome
                progress.item_finished(item_id, outcome)
                if outcome.status != "done":
                    write_failures(out_dir, planned, outcomes)
            if requeue:
                # Every future of a broken pool fails: rebuild it and resubmit what has not finished.
                requeue += list(pending.values())
                pending.clear()
                started.clear()
                backend.restart()
                for rank, plan in enumerate(sorted(requeue, key=lambda p: -p.estimate)):
                    pending[backend.submit(plan.job, priority=len(requeue) - rank)] = plan
    except KeyboardInterrupt:
        backend.close(cancel=True)
        raise
    backend.close()


def _is_death(backend: Any, handle: Any) -> bool:
    try:
        exc = handle.exception(timeout=0)
    except BaseException:  # noqa: BLE001 - cancelled or interrupted: not a death
        return False
    return exc is not None and backend.is_worker_death(exc)


def _worker_failure(backend: Any, exc: BaseException, item_id: str, started: set[str], deaths: dict[str, int],
                    attempts: dict[str, int]) -> ItemOutcome | None:
    """The outcome of an item whose future raised; None to run it again (its worker died, not yet too often)."""
    if backend.is_worker_death(exc):
        if item_id in started:
            deaths[item_id] = deaths.get(item_id, 0) + 1
        attempts[item_id] = attempts.get(item_id, 0) + 1
        if deaths.get(item_id, 0) < _MAX_WORKER_DEATHS and attempts[item_id] <= 2 * _MAX_WORKER_DEATHS:
            return None
        return ItemOutcome(item_id, "failed", EXIT_INTERNAL, (
            f"the worker process died {max(deaths.get(item_id, 0), 1)} times while running this item (killed, or "
            "out of memory): run it alone, with fewer --workers, or with a shorter range"))
    return ItemOutcome(item_id, "failed", EXIT_INTERNAL, (
        f"the worker could not run this item ({type(exc).__name__}: {exc}): check the workers and rerun to retry it"))

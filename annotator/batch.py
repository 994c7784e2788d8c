"""Batch runs: every item of a manifest through :func:`annotator.annotate.annotate`, resumably, in parallel.

Layout of the output folder ``OUT``::

    OUT/<id>/...            each item's outputs, exactly as ``sptpt-annotate VIDEO`` writes them
    OUT/annotations.json    COCO for the whole dataset (merge_coco: ids unique across videos)
    OUT/summary.json        settings, counts and one row per item
    OUT/failures.jsonl      one JSON object per failed item: id, input, manifest line, exit code, error
    OUT/report.html         index: a sortable row per item, linking ``<id>/report.html``

Resuming
    An item is *finished* when ``OUT/<id>/run.json`` exists (annotate writes
    it last, atomically), says ``"complete": true``, and records exactly what
    this run would do: the same resolved input path and content hash
    (SHA-256 of the file, or of an image folder's names and bytes), frame
    range, boxes, labels and track ids, full tracker/flag configuration
    (seed included) and output formats. A finished item is skipped and its
    outputs are kept; anything else is redone from scratch: its ``run.json``
    is removed first, then its other outputs and leftover temporary files,
    so that a run killed part-way never leaves a folder that looks finished.
    The tool version is not compared: after upgrading, rerun with
    ``--force``, which redoes every item. Failed and partially decoded items
    are always retried. The batch-level files are rebuilt at the end of
    every run from all items' ``run.json``, so a resumed run indexes old and
    new items alike. Every file is written atomically (write to a temporary
    file, rename); a lock file (``OUT/.batch.lock``, ``flock``) stops two
    batch runs writing to one folder at once.

Failures
    An item fails alone: a missing, corrupt or unreadable input, a box
    outside the frame, a range beyond the video, even an unexpected
    exception, become a row of ``failures.jsonl`` and of the summary with the
    exit code the single-video command would have given. A worker process
    that dies (out of memory, killed) is replaced and its items retried once;
    an item in flight when a worker dies twice fails with that reason.

Determinism
    Item ``id`` gets the seed :func:`item_seed` ``(base seed, id)`` (SHA-256,
    not Python's salted ``hash``), so results depend on neither the number
    of workers nor the order items run in. Items are dispatched longest
    first (by frame-count estimate) to shorten the tail of a parallel run.

Workers
    ``workers=N``: a :class:`concurrent.futures.ProcessPoolExecutor` of N
    processes started by a fork server (``spawn`` where there is none; never
    plain fork: numba's OpenMP/workqueue thread pools are not fork-safe, and
    the parent may have run the tracker before), numba threads per worker
    ``cores // N``. See :func:`_worker_context`. ``scheduler=ADDRESS``:
    a running Dask distributed cluster; its workers must see the inputs and
    ``OUT`` at the same paths and have this package installed. Run one item
    at a time per Dask worker process (``dask worker --nthreads 1
    --nworkers N``): items in one process are serialised by a lock, since
    numba's parallel kernels are not safe to enter from two threads.

Progress
    One line for the whole run: items done, frames done across workers,
    frames per second and ETA. Workers send ``start`` (frame total) and
    ``frames`` (count, at most every 0.5 s per item) events through a queue
    that works for both executors: a ``multiprocessing`` queue handed to the
    pool's initializer, or a ``distributed.Queue`` named for the run. The
    frame count is read by wrapping the :class:`~annotator.progress.Progress`
    that ``annotate`` creates (see :func:`_install_frame_hook`).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import datetime as _dt
import hashlib
import json
import multiprocessing as mp
import os
import queue as queue_module
import sys
import threading
import time
import traceback
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, TextIO

from annotator import __version__
from annotator.annotate import ALL_FORMATS, RESULT_FILES, content_hash
from annotator.atomic import write_text_atomic
from annotator.config import ConfigError, RunConfig, resolve_config
from annotator.errors import (
    EXIT_BATCH_FAILURES,
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_OUTPUT,
    EXIT_VALUE,
    ToolError,
)
from annotator.manifest import BatchItem, InvalidManifestError, ManifestError
from annotator.pipeline import Target
from annotator.progress import Progress, format_clock
from annotator.wording import plural

__all__ = [
    "BATCH_FILES",
    "BatchProgress",
    "BatchResult",
    "ItemJob",
    "ItemOutcome",
    "PlannedItem",
    "default_workers",
    "item_seed",
    "is_item_finished",
    "plan_batch",
    "read_run_json",
    "run_batch",
    "run_item",
]

#: Batch-level outputs in ``OUT``.
BATCH_FILES = ("annotations.json", "summary.json", "report.html", "failures.jsonl")
BATCH_TEMPLATE = "batch_report.html.j2"
LOCK_NAME = ".batch.lock"
_EVENT_INTERVAL = 0.5  # seconds between a worker's frame-count events for one item
_MAX_WORKER_DEATHS = 2  # an item in flight when this many workers died fails


# --------------------------------------------------------------------------- seeds, jobs, outcomes


def item_seed(base_seed: int, item_id: str) -> int:
    """The seed of one item: a stable 48-bit hash of the batch seed and the item id.

    SHA-256 of ``"sptpt-batch:<base_seed>:<item_id>"``, first 6 bytes big-endian:
    the same on every machine and Python (unlike ``hash()``), below 2**53 so
    that JSON readers in any language keep it exact.
    """
    digest = hashlib.sha256(f"sptpt-batch:{int(base_seed)}:{item_id}".encode("utf-8")).digest()
    return int.from_bytes(digest[:6], "big")


def default_workers() -> int:
    """Cores this process may run on (``sched_getaffinity``), else ``os.cpu_count()``."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class ItemJob:
    """Everything a worker needs to run one item (picklable; paths as strings)."""

    item_id: str
    input_path: str
    targets: tuple[Target, ...]
    start: int
    stop: int | None
    step: int
    config: RunConfig
    folder: str
    formats: tuple[str, ...]
    threads: int | None = None  # numba threads for this item; None leaves the worker's setting


@dataclass
class ItemOutcome:
    """How one item ended in a worker."""

    item_id: str
    status: str  # "done", "partial" (decode error part-way, outputs written) or "failed"
    exit_code: int = EXIT_OK
    error: str | None = None
    traceback: str | None = None
    frames: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0  # user + system time of the worker process during the item
    pid: int = 0
    host: str = ""
    peak_rss_mb: float | None = None


@dataclass
class PlannedItem:
    """An item with its resolved settings and whether its finished outputs can be kept."""

    item: BatchItem
    job: ItemJob
    reuse: bool
    estimate: int  # frames, for dispatch order only


@dataclass
class BatchResult:
    """What a batch run did."""

    out_dir: Path
    rows: list[dict[str, Any]]
    exit_code: int
    counts: dict[str, int]
    frames_this_run: int
    seconds: float
    paths: dict[str, Path] = field(default_factory=dict)

    @property
    def failures(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] in ("failed", "partial")]


# --------------------------------------------------------------------------- planning and the resume rule


def _job_config(item: BatchItem, *, file_values: Mapping[str, Any], source: str, preset: str | None,
                seed: int | None) -> RunConfig:
    """Defaults < config file < command line < item params; the seed derived from the base seed and id."""
    params = item.params
    base = resolve_config(file_values, source=source, preset=preset, seed=seed)
    return resolve_config(
        file_values, source=f"{item.where} params", preset=params.get("preset") or preset,
        seed=item_seed(base.seed, item.id), tracker_overrides=params.get("tracker"),
        flag_overrides=params.get("flags"))


def _normalised(value: Any) -> Any:
    return json.loads(json.dumps(value, default=str))


def _expected_targets(targets: Sequence[Target]) -> list[dict[str, Any]]:
    return [{"track_id": t.track_id, "label": t.label, "box_xywh": [float(v) for v in t.box_xywh], "box_origin": 0}
            for t in targets]


def read_run_json(folder: str | os.PathLike) -> dict[str, Any] | None:
    """An item folder's ``run.json``, or None when it is absent or unreadable."""
    try:
        data = json.loads((Path(folder) / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_item_finished(job: ItemJob, run: Mapping[str, Any] | None) -> bool:
    """Whether a folder's ``run.json`` records a complete run of exactly this job (the resume rule).

    Compares the completion flag, input path and content hash, frame range,
    targets, full configuration (seed included) and formats; see the module
    notes. The content hash is computed only when everything else matches.
    """
    if not run or run.get("complete") is not True:
        return False
    try:
        recorded_input = run["input"]
        recorded_range = run["range"]
        frame_count = int(recorded_input["frame_count"])
        expected_stop = frame_count if job.stop is None else min(job.stop, frame_count)
        same = (
            recorded_input["path"] == str(Path(job.input_path).resolve())
            and recorded_range == {"start": job.start, "stop": expected_stop, "step": job.step}
            and _normalised(run["targets"]) == _normalised(_expected_targets(job.targets))
            and _normalised(run["config"]) == _normalised(job.config.to_dict())
            and list(run["formats"]) == list(job.formats)
        )
    except (KeyError, TypeError, ValueError):
        return False
    if not same:
        return False
    try:
        return recorded_input.get("content_hash") == content_hash(Path(job.input_path))
    except OSError:
        return False


def _estimate_frames(item: BatchItem, start: int, stop: int | None, step: int) -> int:
    """A cheap frame-count estimate for dispatch order: image files counted, video size / 4 kB."""
    path = item.input_path
    try:
        if path.is_dir():
            folder = path / "img" if (path / "img").is_dir() else path
            total = sum(1 for _ in folder.iterdir())
        else:
            total = max(1, path.stat().st_size // 4096)
    except OSError:
        return 0
    end = total if stop is None else min(stop, total)
    return max(0, (end - start + step - 1) // step) * max(1, len(item.targets))


def plan_batch(
    items: Sequence[BatchItem],
    *,
    out_dir: str | os.PathLike,
    config_values: Mapping[str, Any] | None = None,
    config_source: str = "config",
    preset: str | None = None,
    seed: int | None = None,
    formats: Sequence[str] = ALL_FORMATS,
    force: bool = False,
    start: int | None = None,
    stop: int | None = None,
    step: int | None = None,
) -> list[PlannedItem]:
    """Resolve every item's settings and decide which finished outputs to keep.

    ``start``, ``stop``, ``step`` are defaults for items that give no range.

    Raises
    ------
    InvalidManifestError
        An item's params do not resolve against the batch configuration
        (naming the item's ``file:line``).
    ToolError
        The batch configuration itself is invalid (exit code 4).
    """
    out_dir = Path(out_dir)
    file_values = dict(config_values or {})
    unknown = sorted(set(formats) - set(ALL_FORMATS))
    if unknown:
        raise ToolError(f"--formats {','.join(unknown)} is not known: choose from {','.join(ALL_FORMATS)}", EXIT_VALUE)
    try:
        resolve_config(file_values, source=config_source, preset=preset, seed=seed)
    except ConfigError as exc:
        raise ToolError(str(exc), EXIT_VALUE) from None
    planned: list[PlannedItem] = []
    errors: list[ManifestError] = []
    for item in items:
        try:
            config = _job_config(item, file_values=file_values, source=config_source, preset=preset, seed=seed)
        except ConfigError as exc:
            errors.append(ManifestError(item.source, item.line, "params", f"{exc}; fix the item's params"))
            continue
        item_start = item.start if item.start is not None else (start or 0)
        item_stop = item.stop if item.stop is not None else stop
        item_step = item.step if item.step is not None else (step or 1)
        job = ItemJob(item_id=item.id, input_path=str(item.input_path), targets=tuple(item.targets),
                      start=item_start, stop=item_stop, step=item_step, config=config,
                      folder=str(out_dir / item.id), formats=tuple(formats))
        reuse = not force and is_item_finished(job, read_run_json(job.folder))
        planned.append(PlannedItem(item, job, reuse, _estimate_frames(item, item_start, item_stop, item_step)))
    if errors:
        raise InvalidManifestError(errors)
    return planned


# --------------------------------------------------------------------------- the worker side


_THREAD = threading.local()  # .reporter: the current item's event sender in this thread
_ITEM_LOCK = threading.Lock()  # one item at a time per process (numba parallel regions are not re-entrant)
_POOL_EVENTS: Any = None  # the multiprocessing queue of a pool worker


class _Reporter:
    """Sends ``start`` / ``frames`` events of one item, at most every ``_EVENT_INTERVAL`` seconds."""

    def __init__(self, item_id: str, send: Callable[[tuple], None]) -> None:
        self.item_id = item_id
        self._send = send
        self._last = 0.0
        self.total = 0

    def emit(self, event: tuple) -> None:
        with contextlib.suppress(Exception):  # progress must never fail an item
            self._send(event)

    def start(self, total: int) -> None:
        self.total = total
        self.emit(("start", self.item_id, os.getpid(), total))

    def frames(self, done: int) -> None:
        now = time.monotonic()
        if now - self._last >= _EVENT_INTERVAL or done >= self.total:
            self._last = now
            self.emit(("frames", self.item_id, done))


class _ReportingProgress(Progress):
    """``annotate``'s per-item Progress, forwarding frame counts to the thread's reporter (if any)."""

    def __init__(self, total: int, **kwargs: Any) -> None:
        super().__init__(total, **kwargs)
        self._reporter: _Reporter | None = getattr(_THREAD, "reporter", None)
        if self._reporter is not None:
            self._reporter.start(self.total)

    def advance(self, steps: int = 1) -> None:
        super().advance(steps)
        if self._reporter is not None:
            self._reporter.frames(self.done)


def _install_frame_hook() -> None:
    """Let ``annotate`` report frames: replace the Progress class it looks up by the reporting subclass.

    ``annotate()`` takes no progress callback; it builds ``Progress(n,
    enabled=...)`` from its module globals. The subclass behaves exactly
    like Progress unless the calling thread has a reporter, so other callers
    in the same process are unaffected. Done once per process, and only
    while the name still refers to the original class.
    """
    import annotator.annotate as annotate_module

    if annotate_module.Progress is Progress:
        annotate_module.Progress = _ReportingProgress


def _peak_rss_mb() -> float | None:
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 if sys.platform != "darwin" else peak / (1024.0 * 1024.0)


def _clear_item_folder(folder: Path) -> None:
    """Remove a previous run's outputs: run.json first, so a half-redone folder never looks finished."""
    for name in ("run.json", *[n for n in RESULT_FILES if n != "run.json"]):
        with contextlib.suppress(FileNotFoundError):
            (folder / name).unlink()
    for pattern in ("*.txt", "times/*.txt", ".*.tmp*", "times/.*.tmp*"):
        for path in folder.glob(pattern):
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                path.unlink()


def run_item(job: ItemJob, send: Callable[[tuple], None] | None = None) -> ItemOutcome:
    """Run one item: clear its folder, annotate, and report how it ended; never raises for the item's faults.

    Parameters
    ----------
    job : ItemJob
    send : callable, optional
        Receives progress events ``("start", id, pid, total_frames)`` and
        ``("frames", id, done)``.
    """
    from annotator.annotate import annotate

    with _ITEM_LOCK:
        _install_frame_hook()
        if job.threads is not None:
            import numba

            numba.set_num_threads(max(1, min(job.threads, numba.config.NUMBA_NUM_THREADS)))
        outcome = ItemOutcome(item_id=job.item_id, status="failed", pid=os.getpid(), host=_hostname())
        started, cpu_started = time.perf_counter(), os.times()
        _THREAD.reporter = _Reporter(job.item_id, send) if send is not None else None
        folder = Path(job.folder)
        try:
            if folder.is_dir():
                _clear_item_folder(folder)
            result = annotate(job.input_path, job.targets, job.config, out_dir=folder, start=job.start,
                              stop=job.stop, step=job.step, formats=job.formats, force=True, show_progress=False)
            outcome.frames = result.run.frames_processed
            if result.exit_code == EXIT_OK:
                outcome.status = "done"
            else:
                outcome.status, outcome.exit_code, outcome.error = "partial", result.exit_code, result.message
        except ToolError as exc:
            outcome.exit_code, outcome.error = exc.exit_code, str(exc)
        except OSError as exc:
            outcome.exit_code = EXIT_OUTPUT
            outcome.error = f"{exc.filename or job.folder}: {exc.strerror or exc}: check the output folder"
        except Exception as exc:  # noqa: BLE001 - a bug on one item must not stop the others
            outcome.exit_code = EXIT_INTERNAL
            outcome.error = f"internal error: {type(exc).__name__}: {exc} (see traceback in failures.jsonl)"
            outcome.traceback = traceback.format_exc()
        finally:
            _THREAD.reporter = None
        if outcome.status == "failed":
            with contextlib.suppress(OSError):
                folder.rmdir()  # only if the item left nothing: no empty folders for items that never started
        outcome.seconds = time.perf_counter() - started
        cpu = os.times()
        outcome.cpu_seconds = (cpu.user - cpu_started.user) + (cpu.system - cpu_started.system)
        outcome.peak_rss_mb = _peak_rss_mb()
        return outcome


def _hostname() -> str:
    import socket

    return socket.gethostname()


def _pool_initializer(events: Any) -> None:
    """Worker start-up: keep the event queue; leave Ctrl-C to the parent; die with the parent (Linux)."""
    import signal

    global _POOL_EVENTS
    _POOL_EVENTS = events
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: no orphan keeps writing after the batch dies
            if os.getppid() == 1:
                os._exit(1)


def _pool_run_item(job: ItemJob) -> ItemOutcome:
    events = _POOL_EVENTS
    return run_item(job, events.put if events is not None else None)


def _dask_run_item(job: ItemJob, queue_name: str) -> ItemOutcome:
    from distributed import Queue, get_client

    try:
        events = Queue(queue_name, client=get_client())
        send = events.put
    except Exception:  # noqa: BLE001 - no progress rather than no result
        send = None
    return run_item(job, send)


# --------------------------------------------------------------------------- executors


def _worker_context() -> Any:
    """``forkserver`` with this module preloaded where the platform has it, else ``spawn``.

    Never plain ``fork``: the parent may have run numba's parallel kernels
    (OpenMP or workqueue threads, which do not survive a fork). The fork
    server is a fresh interpreter that only imports the tool (numba's thread
    pool is not started by importing), so forking workers from it is safe,
    and starts two workers in about 0.4 s instead of 1.0-1.5 s with spawn on
    the 2-core development machine.
    """
    if "forkserver" in mp.get_all_start_methods():
        context = mp.get_context("forkserver")
        context.set_forkserver_preload(["annotator.batch"])
        return context
    return mp.get_context("spawn")  # pragma: no cover - Windows


class _PoolBackend:
    """Local worker processes (forkserver or spawn), rebuilt if one dies."""

    name = "processes"

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._context = _worker_context()
        self._start()

    def _start(self) -> None:
        self.events = self._context.Queue()
        self.pool = cf.ProcessPoolExecutor(self.workers, mp_context=self._context, initializer=_pool_initializer,
                                           initargs=(self.events,))

    def submit(self, job: ItemJob, priority: int = 0) -> cf.Future:
        return self.pool.submit(_pool_run_item, job)

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

    def close(self, *, cancel: bool = False) -> None:
        self._drop(cancel=cancel)


class _DaskBackend:
    """An existing Dask distributed cluster."""

    name = "dask"

    def __init__(self, address: str) -> None:
        try:
            from distributed import Client, Queue
        except ImportError:  # pragma: no cover - a declared dependency
            raise ToolError("--scheduler needs dask.distributed: pip install 'dask[distributed]'", EXIT_VALUE) from None
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
        future = self.client.submit(_dask_run_item, job, self.queue_name, pure=False, priority=priority, retries=0,
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


# --------------------------------------------------------------------------- progress


class BatchProgress:
    """One status line for the whole batch: items, frames across workers, speed, ETA.

    On a terminal the line is redrawn in place; otherwise a line is printed
    when an item ends (logs stay short and say which item did what).
    """

    def __init__(self, n_items: int, *, reused: int = 0, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.n_items = n_items
        self.reused = reused
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.items_done = 0
        self.failed = 0
        self.totals: dict[str, int] = {}
        self.done: dict[str, int] = {}
        self._start = time.perf_counter()
        self._last_draw = 0.0

    @property
    def frames_done(self) -> int:
        return sum(self.done.values())

    def event(self, event: tuple) -> None:
        kind, item_id = event[0], event[1]
        if kind == "start":
            self.totals[item_id] = int(event[3])
            self.done[item_id] = 0  # a retried item starts again
        elif kind == "frames":
            self.done[item_id] = max(self.done.get(item_id, 0), int(event[2]))
        self.draw()

    def item_finished(self, item_id: str, outcome: ItemOutcome) -> None:
        self.items_done += 1
        self.failed += outcome.status != "done"
        # What an item actually processed replaces its announced total (a failed item counts 0 frames).
        self.done[item_id] = outcome.frames
        self.totals[item_id] = outcome.frames
        if not self.enabled:
            return
        if self._tty:
            self.draw(force=True)
        else:
            what = f"{plural(outcome.frames, 'frame')} in {outcome.seconds:.1f} s" if outcome.status != "failed" else ""
            reason = f": {outcome.error}" if outcome.error else ""
            self.stream.write(f"[{self.items_done}/{self.n_items}] {item_id} {outcome.status}"
                              f"{' ' + what if what else ''}{reason}\n")
            self.stream.write(self.line() + "\n")
            self.stream.flush()

    def line(self) -> str:
        elapsed = time.perf_counter() - self._start
        frames = self.frames_done
        rate = frames / elapsed if elapsed > 0 else 0.0
        known = sum(self.totals.values())
        started = len(self.totals)
        unstarted = max(self.n_items - started, 0)
        estimate = known + (known / started * unstarted if started else 0)
        approx = "~" if unstarted else ""
        eta = (estimate - frames) / rate if rate > 0 and estimate >= frames else float("nan")
        extra = [f"{self.failed} failed"] if self.failed else []
        extra += [f"{self.reused} reused"] if self.reused else []
        extra_text = f" ({', '.join(extra)})" if extra else ""
        eta_text = format_clock(eta) if eta == eta else "--:--"
        share = min(frames / estimate, 1.0) if estimate else self.items_done / max(self.n_items, 1)
        width = 20
        filled = int(round(width * share))
        return (f"[{'#' * filled}{'.' * (width - filled)}] items {self.items_done}/{self.n_items}{extra_text} | "
                f"frames {frames}/{approx}{int(round(estimate))} | {rate:5.1f} frames/s | ETA {eta_text}")

    def draw(self, *, force: bool = False) -> None:
        if not (self.enabled and self._tty):
            return
        now = time.perf_counter()
        if force or now - self._last_draw >= 0.2:
            self._last_draw = now
            self.stream.write("\r" + self.line() + "\x1b[K")
            self.stream.flush()

    def close(self) -> None:
        if self.enabled and self._tty:
            self.stream.write("\n")
            self.stream.flush()


# --------------------------------------------------------------------------- the run


@contextlib.contextmanager
def _exclusive(out_dir: Path):
    """Hold ``OUT/.batch.lock`` for the run; the kernel releases it if the process dies."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock
        yield
        return
    handle = open(out_dir / LOCK_NAME, "a+", encoding="utf-8")
    try:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            raise ToolError(f"output folder {out_dir} is in use by another batch run ({holder}): wait for it to "
                            "finish or choose another --out", EXIT_OUTPUT) from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"pid {os.getpid()}\n")
        handle.flush()
        yield
    finally:
        handle.close()


def _threads_per_worker(n_workers: int) -> int:
    """numba threads for each of ``n_workers`` local workers: the cores shared out, within NUMBA_NUM_THREADS."""
    import numba

    return max(1, min(default_workers() // n_workers, numba.config.NUMBA_NUM_THREADS))


def _prepare_out_dir(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise ToolError(f"output folder {out_dir} is a file: give --out a folder path", EXIT_OUTPUT)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe = out_dir / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ToolError(f"output folder {out_dir} cannot be written ({exc.strerror}): choose a writable --out folder",
                        EXIT_OUTPUT) from None


def _remove_stale_temporaries(out_dir: Path) -> None:
    """Temporary files of batch-level writes that a killed run left behind (atomic_path names)."""
    for name in BATCH_FILES:
        for path in out_dir.glob(f".{name}.*.tmp*"):
            with contextlib.suppress(OSError):
                path.unlink()


def run_batch(
    items: Sequence[BatchItem],
    *,
    out_dir: str | os.PathLike,
    config_values: Mapping[str, Any] | None = None,
    config_source: str = "config",
    preset: str | None = None,
    seed: int | None = None,
    formats: Sequence[str] = ALL_FORMATS,
    force: bool = False,
    start: int | None = None,
    stop: int | None = None,
    step: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    show_progress: bool = True,
    manifest: str | None = None,
    stream: TextIO | None = None,
) -> BatchResult:
    """Run every item, skipping finished ones; write the batch-level files.

    Parameters
    ----------
    items : sequence of BatchItem
        From :func:`~annotator.manifest.read_manifest` or
        :func:`~annotator.manifest.items_from_otb_root`.
    out_dir : path-like
        ``OUT``; each item writes to ``OUT/<id>/``.
    config_values, config_source, preset, seed
        The batch configuration as for ``sptpt-annotate VIDEO`` (a
        ``--config`` file's mapping and its name, ``--preset``, ``--seed``);
        item params override it; ``seed`` is the base seed.
    formats : sequence of str
        Outputs of each item (``otb, coco, flags, overlay, report``).
    force : bool
        Redo finished items too.
    start, stop, step : int, optional
        Frame range of items whose manifest row gives none.
    workers : int, optional
        Local worker processes (default: the number of cores).
    scheduler : str, optional
        Address of a Dask distributed scheduler to send the items to instead.
    show_progress : bool
    manifest : str, optional
        Where the items came from, recorded in ``summary.json``.

    Returns
    -------
    BatchResult
        ``exit_code`` 0 when every item is done, 7 (EXIT_BATCH_FAILURES)
        when some failed or were only partly decoded.

    Raises
    ------
    InvalidManifestError
        An item's params do not resolve (before any work).
    ToolError
        Invalid batch settings, or an output folder that cannot be used.
    KeyboardInterrupt
        After stopping the workers and writing the batch files for what finished.
    """
    out_dir = Path(out_dir)
    if workers is not None and workers < 1:
        raise ToolError(f"--workers {workers} is invalid: give 1 or more worker processes", EXIT_VALUE)
    if scheduler is not None and workers is not None:
        raise ToolError("--workers and --scheduler were both given: --workers sizes local processes, --scheduler "
                        "sends items to a Dask cluster; give one", EXIT_VALUE)
    n_workers = workers or default_workers()
    # Settings are checked before the output folder is touched; finished outputs are judged under the lock.
    planned = plan_batch(items, out_dir=out_dir, config_values=config_values, config_source=config_source,
                         preset=preset, seed=seed, formats=formats, force=True, start=start, stop=stop, step=step)
    _prepare_out_dir(out_dir)
    started = time.perf_counter()
    with _exclusive(out_dir):
        _remove_stale_temporaries(out_dir)
        for plan in planned:
            plan.reuse = not force and is_item_finished(plan.job, read_run_json(plan.job.folder))
        todo = sorted((p for p in planned if not p.reuse), key=lambda p: -p.estimate)
        n_workers = min(n_workers, max(len(todo), 1))
        threads = None if scheduler else _threads_per_worker(n_workers)
        for plan in todo:
            plan.job = dataclasses.replace(plan.job, threads=threads)
        progress = BatchProgress(len(todo), reused=len(planned) - len(todo), enabled=show_progress, stream=stream)
        outcomes: dict[str, ItemOutcome] = {}
        settings = {"workers": None if scheduler else n_workers, "scheduler": scheduler,
                    "start_method": None if scheduler else _worker_context().get_start_method(),
                    "numba_threads_per_worker": threads}
        interrupted = False
        try:
            if todo:
                _execute(todo, outcomes, progress, out_dir, planned, scheduler=scheduler, workers=n_workers)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            progress.close()
        result = _finish(planned, outcomes, out_dir=out_dir, seconds=time.perf_counter() - started,
                         manifest=manifest, formats=formats, seed=seed, config_values=config_values,
                         preset=preset, settings=settings, interrupted=interrupted)
    if interrupted:
        raise KeyboardInterrupt
    return result


def _execute(todo: list[PlannedItem], outcomes: dict[str, ItemOutcome], progress: BatchProgress, out_dir: Path,
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
                    _write_failures(out_dir, planned, outcomes)
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


# --------------------------------------------------------------------------- batch-level outputs


def _status_row(plan: PlannedItem, outcome: ItemOutcome | None, run: Mapping[str, Any] | None,
                out_dir: Path) -> dict[str, Any]:
    item, job = plan.item, plan.job
    if plan.reuse:
        status = "done"
    elif outcome is None:
        status = "pending"
    else:
        status = outcome.status
    row: dict[str, Any] = {
        "id": item.id,
        "status": status,
        "reused": plan.reuse,
        "input": str(item.input_path),
        "manifest": item.where,
        "seed": job.config.seed,
        "folder": item.id,
        "report": None,
        "frames": None,
        "tracks": len(item.targets),
        "flagged": None,
        "flagged_share": None,
        "longest_flagged_span": None,
        "mean_confidence": None,
        "seconds": None,
        "frames_per_second": None,
        "exit_code": outcome.exit_code if outcome is not None else EXIT_OK,
        "error": outcome.error if outcome is not None else None,
        "worker_cpu_seconds": outcome.cpu_seconds if outcome is not None else None,
        "worker_pid": outcome.pid if outcome is not None else None,
        "worker_host": outcome.host if outcome is not None else None,
        "worker_peak_rss_mb": outcome.peak_rss_mb if outcome is not None else None,
    }
    if status == "pending":
        row["error"] = "not run: the batch was interrupted; rerun to finish it"
    if run is not None and status in ("done", "partial"):
        tracks = run.get("tracks") or []
        boxes = sum(int(t.get("frames", 0)) for t in tracks)
        flagged = sum(int(t.get("flagged", 0)) for t in tracks)
        timings = run.get("timings") or {}
        confidences = [t.get("mean_confidence") for t in tracks if isinstance(t.get("mean_confidence"), (int, float))]
        row.update({
            "frames": run.get("frames_processed"),
            "flagged": flagged,
            "flagged_share": flagged / boxes if boxes else 0.0,
            "longest_flagged_span": max((int(t.get("longest_span", 0)) for t in tracks), default=0),
            "mean_confidence": sum(confidences) / len(confidences) if confidences else None,
            "seconds": timings.get("seconds_total"),
            "frames_per_second": timings.get("frames_per_second"),
        })
        if (out_dir / item.id / "report.html").is_file():
            row["report"] = f"{item.id}/report.html"
    return row


def _write_failures(out_dir: Path, planned: Sequence[PlannedItem], outcomes: Mapping[str, ItemOutcome]) -> Path:
    lines = []
    for plan in planned:
        outcome = outcomes.get(plan.item.id)
        if outcome is None or outcome.status == "done":
            continue
        record = {"id": plan.item.id, "status": outcome.status, "input": str(plan.item.input_path),
                  "manifest": plan.item.where, "exit_code": outcome.exit_code, "error": outcome.error}
        if outcome.traceback:
            record["traceback"] = outcome.traceback
        lines.append(json.dumps(record, ensure_ascii=False) + "\n")
    path = out_dir / "failures.jsonl"
    write_text_atomic(path, "".join(lines))
    return path


def _merged_coco(out_dir: Path, rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """All items' COCO files in manifest order, each video renamed to its item id (unique), ids renumbered.

    A video item's frame-dump names (``<name>/<frame:06d>.jpg``) follow the
    rename; an image-folder item's ``file_name`` is its real image path
    relative to the sequence folder's parent and is kept as it is, so a
    dataset whose sequences share a parent folder has one image root.
    """
    from annotator.exports.coco import merge_coco

    datasets = []
    for row in rows:
        path = out_dir / row["id"] / "annotations.json"
        if row["status"] not in ("done", "partial") or not path.is_file():
            continue
        data = json.loads(path.read_text(encoding="utf-8"))
        real_images = Path(row["input"]).is_dir()
        for video in data.get("videos", []):
            old = video["name"]
            if old != row["id"]:
                video["name"] = row["id"]
                if real_images:
                    continue
                prefix = f"{old}/"
                for image in data.get("images", []):
                    if image.get("video_id") == video["id"] and str(image.get("file_name", "")).startswith(prefix):
                        image["file_name"] = f"{row['id']}/{image['file_name'][len(prefix):]}"
        datasets.append(data)
    if not datasets:
        return {"info": {"description": "sptpt-annotate boxes for 0 videos", "contributor": "sptpt-annotate",
                         "bbox_format": "xywh, 0-based pixels"},
                "licenses": [], "categories": [], "videos": [], "images": [], "tracks": [], "annotations": []}
    merged = merge_coco(datasets)
    merged["info"]["description"] = f"sptpt-annotate boxes for {len(merged['videos'])} videos"
    return merged


def _render_index(path: Path, summary: Mapping[str, Any]) -> None:
    import jinja2

    from annotator.report import templates_dir

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(templates_dir())),
                             autoescape=jinja2.select_autoescape(["html", "j2"]), undefined=jinja2.StrictUndefined)
    page = env.get_template(BATCH_TEMPLATE).render(summary=summary, rows=summary["items"])
    write_text_atomic(path, page)


def _finish(planned: Sequence[PlannedItem], outcomes: Mapping[str, ItemOutcome], *, out_dir: Path, seconds: float,
            manifest: str | None, formats: Sequence[str], seed: int | None, config_values: Mapping[str, Any] | None,
            preset: str | None, settings: Mapping[str, Any], interrupted: bool) -> BatchResult:
    from annotator.exports.coco import save_coco

    rows = [_status_row(plan, outcomes.get(plan.item.id), read_run_json(plan.job.folder), out_dir)
            for plan in planned]
    counts = {"items": len(rows)}
    for status in ("done", "partial", "failed", "pending"):
        counts[status] = sum(r["status"] == status for r in rows)
    counts["reused"] = sum(r["reused"] for r in rows)
    frames_this_run = sum(o.frames for o in outcomes.values())
    frames_total = sum(int(r["frames"] or 0) for r in rows)
    exit_code = EXIT_OK if counts["done"] == counts["items"] else EXIT_BATCH_FAILURES
    base_seed = seed if seed is not None else int((config_values or {}).get("seed", 0) or 0)
    summary = {
        "tool": "sptpt-annotate batch",
        "tool_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "manifest": manifest,
        "out": str(out_dir.resolve()),
        "settings": {"base_seed": base_seed, "preset": preset, "config": _normalised(dict(config_values or {})),
                     "formats": list(formats), **dict(settings)},
        "counts": counts,
        "exit_code": exit_code,
        "interrupted": interrupted,
        "frames": frames_total,
        "frames_this_run": frames_this_run,
        "wall_seconds": seconds,
        "frames_per_second_this_run": frames_this_run / seconds if seconds > 0 and frames_this_run else None,
        "items": rows,
    }
    paths = {"failures": _write_failures(out_dir, planned, outcomes)}
    if "coco" in formats:
        save_coco(out_dir / "annotations.json", _merged_coco(out_dir, rows))
        paths["coco"] = out_dir / "annotations.json"
    write_text_atomic(out_dir / "summary.json", json.dumps(summary, indent=2, ensure_ascii=False) + "\n")
    paths["summary"] = out_dir / "summary.json"
    _render_index(out_dir / "report.html", summary)
    paths["report"] = out_dir / "report.html"
    return BatchResult(out_dir=out_dir, rows=rows, exit_code=exit_code, counts=counts,
                       frames_this_run=frames_this_run, seconds=seconds, paths=paths)

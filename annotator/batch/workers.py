"""Where items execute: :func:`run_item` and what runs inside a worker process around it.

Failures
    An item fails alone: a missing, corrupt or unreadable input, a box
    outside the frame, a range beyond the video, even an unexpected
    exception, become an :class:`ItemOutcome` with the exit code the
    single-video command would have given (and from it a row of
    ``failures.jsonl`` and of the summary). Worker processes that die are
    handled by the executor (:mod:`annotator.batch.executors`).

Progress events
    A worker sends ``("start", id, pid, total_frames)`` and ``("frames", id,
    done)`` (at most every 0.5 s per item) through whatever ``send`` it is
    given: a ``multiprocessing`` queue handed to the pool's initializer, or a
    ``distributed.Queue`` named for the run. The frame counts come from
    ``annotate``'s ``progress`` callback.

Lifetime of a pool worker
    A pool worker ends within moments of the batch's main process, however
    that process ends (``kill -9`` included), and takes its ffmpeg
    processes with it: see :func:`_exit_when_main_process_dies`. Its ffmpeg
    processes share the run's process group, so a signal to the group
    reaches them as well.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, cast

from annotator.allocator import keep_freed_memory
from annotator.batch.plan import ItemJob
from annotator.checkpoint import CHECKPOINT_NAME
from annotator.errors import EXIT_INTERNAL, EXIT_OK, EXIT_OUTPUT, ToolError
from annotator.exports.otb import otb_result_globs
from annotator.manifest import output_stem
from annotator.output_files import RUN_JSON
from annotator.output_folder import remove_staging_folders
from annotator.run import previous_outputs

_EVENT_INTERVAL = 0.5  # seconds between a worker's frame-count events for one item


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

    def update(self, done: int, total: int) -> None:
        """``annotate``'s progress callback: the item's start at 0 frames done, then its frame counts."""
        if done == 0:
            self.start(total)
        else:
            self.frames(done)

    def frames(self, done: int) -> None:
        now = time.monotonic()
        if now - self._last >= _EVENT_INTERVAL or done >= self.total:
            self._last = now
            self.emit(("frames", self.item_id, done))


def _peak_rss_mb() -> float | None:
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 if sys.platform != "darwin" else peak / (1024.0 * 1024.0)


def _clear_item_folder(folder: Path, video_name: str) -> None:
    """Remove a previous run's outputs: run.json first, so a half-redone folder never looks finished.

    Only the files that run wrote (the fixed result names, those its
    run.json lists, the OTB files of ``video_name``) and this tool's
    temporaries go; anything else in the folder is someone else's and stays.
    """
    names = previous_outputs(folder)  # read before run.json goes
    # The OTB files, which an earlier run killed before its run.json listed them leaves behind.
    for pattern in otb_result_globs(video_name):
        names |= {path.relative_to(folder).as_posix() for path in folder.glob(pattern)}
    with contextlib.suppress(FileNotFoundError):
        (folder / RUN_JSON).unlink()
    for name in sorted(names):
        with contextlib.suppress(FileNotFoundError, IsADirectoryError):
            (folder / name).unlink()
    for pattern in (".*.tmp*", "times/.*.tmp*"):
        for path in folder.glob(pattern):
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                path.unlink()
    remove_staging_folders(folder)


def run_item(job: ItemJob, send: Callable[[tuple], None] | None = None) -> ItemOutcome:
    """Run one item: clear its folder, annotate, and report how it ended; never raises for the item's faults.

    Parameters
    ----------
    job : ItemJob
    send : callable, optional
        Receives progress events ``("start", id, pid, total_frames)`` and
        ``("frames", id, done)``.
    """
    from annotator.run import annotate

    with _ITEM_LOCK:
        if job.threads is not None:
            import numba

            # numba.config sets its settings at import time, unseen by the type checker.
            numba.set_num_threads(max(1, min(job.threads, cast(Any, numba.config).NUMBA_NUM_THREADS)))
        outcome = ItemOutcome(item_id=job.item_id, status="failed", pid=os.getpid(), host=_hostname())
        started, cpu_started = time.perf_counter(), os.times()
        reporter = _Reporter(job.item_id, send) if send is not None else None
        folder = Path(job.folder)
        try:
            if folder.is_dir():
                _clear_item_folder(folder, output_stem(Path(job.input_path)))
            resume = job.resume and (folder / CHECKPOINT_NAME).is_file()
            result = annotate(job.input_path, job.targets, job.config, out_dir=folder, start=job.start,
                              stop=job.stop, step=job.step, formats=job.formats, force=True, show_progress=False,
                              media_url=job.media_url, resume=resume,
                              progress=reporter.update if reporter is not None else None)
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


def pool_initializer(events: Any, main_alive: Any = None) -> None:
    """Worker start-up: keep the event queue; leave Ctrl-C to the parent; end with the batch's main process.

    Parameters
    ----------
    events : multiprocessing queue
        Where :func:`pool_run_item` sends progress events.
    main_alive : multiprocessing.connection.Connection, optional
        The read end of a pipe whose write end only the batch's main process
        holds (see ``_PoolBackend``); watched by
        :func:`_exit_when_main_process_dies`.
    """
    import signal

    global _POOL_EVENTS
    _POOL_EVENTS = events
    keep_freed_memory()  # a process of the tool's own (not in Dask tasks: a Dask worker is shared and long-lived)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # imageio-ffmpeg puts each ffmpeg in a process group of its own (to spare it a terminal's Ctrl-C); in a
    # worker it stays in the run's group instead, so that a signal to the whole run (kill -9 -PGID) reaches
    # it too, and no orphaned encoder writes into an item folder that a rerun has just cleared.
    os.environ["IMAGEIO_FFMPEG_NO_PREVENT_SIGINT"] = "1"
    if main_alive is not None:
        threading.Thread(target=_exit_when_main_process_dies, args=(main_alive,), name="sptpt-batch-main-watch",
                         daemon=True).start()
    if sys.platform.startswith("linux"):
        # Our parent is the fork server, not the main process: this only covers the fork server being killed.
        with contextlib.suppress(Exception):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
            if os.getppid() == 1:
                os._exit(1)


def _exit_when_main_process_dies(main_alive: Any) -> None:
    """Block until the main process's end of the pipe closes, then end this worker at once.

    The kernel closes the write end when the main process dies, whatever
    kills it (``kill -9`` included), and nothing else holds it, so end of
    file means exactly that. The parent-death signal cannot say it: a
    worker's parent is the fork server, and the fork server outlives the
    main process for as long as any worker holds its "alive" pipe, so
    without this the workers would finish their queued items and then wait
    for more forever, holding memory and cores. ``os._exit``: nothing of the
    item in progress is worth saving (its folder has no ``run.json``, so a
    rerun redoes it) and a clean shutdown could block on the dead parent's
    queues. This thread needs the GIL to act: at the latest when the numba
    kernel call in progress returns.
    """
    while True:
        try:
            main_alive.recv_bytes()  # the main process never sends: only end of file ends the wait
        except (EOFError, OSError):
            break
    _kill_child_processes()
    os._exit(1)


def _kill_child_processes() -> None:
    """SIGKILL this process's children: the item's ffmpeg readers and writers (Linux; elsewhere nothing).

    Left alone, a writer would get end of file on its input when the worker
    exits and go on to finish the item's temporary overlay file.
    """
    import signal

    me = os.getpid()
    with contextlib.suppress(OSError):
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            with contextlib.suppress(OSError, ValueError, IndexError):
                with open(f"/proc/{entry.name}/stat", "rb") as handle:
                    stat = handle.read()
                # "pid (comm) state ppid ...": comm may hold spaces and parentheses, so split after the last ")".
                if int(stat.rsplit(b")", 1)[1].split()[1]) == me:
                    os.kill(int(entry.name), signal.SIGKILL)


def pool_run_item(job: ItemJob) -> ItemOutcome:
    """A process-pool task: one item, its progress sent to the queue that :func:`pool_initializer` kept."""
    events = _POOL_EVENTS
    return run_item(job, events.put if events is not None else None)


def dask_run_item(job: ItemJob, queue_name: str) -> ItemOutcome:
    """A Dask task: one item, its progress sent to the run's ``distributed.Queue`` named ``queue_name``."""
    from distributed import Queue, get_client

    try:
        events = Queue(queue_name, client=get_client())
        send = events.put
    except Exception:  # noqa: BLE001 - no progress rather than no result
        send = None
    return run_item(job, send)

"""Progress on stderr, for a single video and for a batch: one display, drawn by rich.

What is shown
    What is counted, a bar, the count, the rate (``12.3 frames/s``) and the
    time left (``ETA 01:05``); for a batch also the items done, failed and
    reused. The rate and ETA appear from the :data:`ETA_AFTER` th update
    on (see :class:`Progress`).

Where it goes
    On a terminal (the stream's ``isatty()``), one line redrawn in place by
    :class:`rich.progress.Progress`, at most every ``interval`` seconds;
    lines of their own (the slow-start note, a batch item that did not
    finish) are printed above it.

    Not on a terminal (a log file, CI, a pipe), no control codes at all:
    short plain lines, each complete in itself, so that the log of a long
    run says how far it got and how fast: a single video gets a line every
    10% (eleven in all); a batch gets one per finished item (its status,
    frames, time and the reason it failed) followed by the run's line.
    ``FORCE_COLOR`` and ``TTY_COMPATIBLE`` ask for colour, not for a line
    redrawn in a log, and change nothing here; ``TERM=dumb`` or
    ``TTY_INTERACTIVE=0`` on a terminal give the plain lines.

    ``enabled=False`` (``--quiet``) prints nothing.

The display never replaces ``sys.stdout`` or ``sys.stderr`` (rich's
redirection is off): callers of the library and worker threads keep the
streams they had. All drawing is in :class:`_Display`.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Protocol, TextIO

import rich.progress
from rich.console import Console
from rich.table import Column
from rich.text import Text

from annotator.wording import plural

__all__ = ["ETA_AFTER", "BatchProgress", "CountNote", "Progress", "format_clock"]

#: Updates before a rate and an ETA are shown. The first step often costs far more than the rest (kernels
#: compiling, a decoder starting) or far less (steps taken from a cache); a rate that counted it would mislead,
#: so the rate is measured from the first update on, and shown once a few more have come.
ETA_AFTER = 3


def format_clock(seconds: float) -> str:
    """``MM:SS``, or ``H:MM:SS`` from an hour on."""
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"


def _rate_text(rate: float | None, unit: str) -> str:
    return f"{rate:5.1f} {unit}/s" if rate else f"  ... {unit}/s"


def _eta_text(seconds: float | None) -> str:
    return f"ETA {format_clock(seconds) if seconds is not None else '--:--'}"


def _isatty(stream: TextIO) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


class _Rate:
    """Steps per second since the first update; None before :data:`ETA_AFTER` updates or while not positive."""

    def __init__(self) -> None:
        self.updates = 0
        self._first: tuple[float, float] | None = None  # time and count of the first update

    def update(self, done: float, now: float) -> None:
        self.updates += 1
        if self._first is None:
            self._first = (now, done)

    def per_second(self, done: float, now: float) -> float | None:
        if self._first is None or self.updates < ETA_AFTER:
            return None
        elapsed = now - self._first[0]
        rate = (done - self._first[1]) / elapsed if elapsed > 0 else 0.0
        return rate if rate > 0 else None


class _Cell(rich.progress.ProgressColumn):
    """The ``index`` th of the texts a status passes in its task's ``cells`` field.

    Not wrapped: on a narrow terminal the bar gives way first, and the numbers stay whole.
    """

    def __init__(self, index: int) -> None:
        super().__init__(table_column=Column(no_wrap=True))
        self.index = index

    def render(self, task: rich.progress.Task) -> Text:
        return Text(task.fields["cells"][self.index], no_wrap=True)


def _plain(description: str, cells: Sequence[str]) -> str:
    """A status as one plain line: ``frames 12/40  30%  4.1 frames/s  ETA 00:07``."""
    return " ".join([description, *cells[:1]]) + "".join("  " + cell.strip() for cell in cells[1:])


class _Display:
    """Where a status is shown: a rich bar redrawn in place on a terminal, plain lines elsewhere, nothing when off.

    A status is a description, a count of a total (None: unknown, a pulsing bar) and ``n_cells`` texts shown
    after the bar. Owners decide when a plain line is worth printing (:meth:`line`); :meth:`show` draws only on
    a terminal. Calls may come from any thread.
    """

    def __init__(self, *, enabled: bool, stream: TextIO | None, console: Console | None, n_cells: int,
                 interval: float) -> None:
        self.enabled = enabled
        self.interval = interval
        self.n_cells = n_cells
        if enabled and console is None:
            # The stream decides, not FORCE_COLOR: colour asked for in a CI log is no reason to redraw lines in it.
            console = Console(file=stream, stderr=stream is None, highlight=False,
                              force_terminal=_isatty(sys.stderr if stream is None else stream))
        self.console = console
        self.live = bool(enabled and console is not None and console.is_terminal and console.is_interactive
                         and not console.is_dumb_terminal)
        self._lock = threading.RLock()
        self._bar: rich.progress.Progress | None = None
        self._task: rich.progress.TaskID | None = None
        self._last_draw = 0.0
        self._closed = False

    def show(self, description: str, completed: float, total: float | None, cells: Sequence[str], *,
             force: bool = False) -> None:
        """Draw the status on a terminal: at once when ``force``, else if ``interval`` has passed since the last."""
        if not self.live:
            return
        with self._lock:
            if self._closed:
                return
            now = time.perf_counter()
            if self._bar is None:
                columns = [rich.progress.TextColumn("{task.description}", markup=False),
                           rich.progress.BarColumn(bar_width=20), *(_Cell(i) for i in range(self.n_cells))]
                self._bar = rich.progress.Progress(*columns, console=self.console, auto_refresh=False,
                                                   redirect_stdout=False, redirect_stderr=False)
                # rich annotates add_task's completed as int, though a Task's completed is a float (as in update).
                self._task = self._bar.add_task(description, completed=completed,  # type: ignore[arg-type]
                                                total=total, cells=tuple(cells))
                self._bar.start()  # draws
                self._last_draw = now
                return
            assert self._task is not None  # added with the bar
            # The task always holds the latest status, so the draw at close shows it even if this one is skipped.
            self._bar.update(self._task, description=description, completed=completed, total=total,
                             cells=tuple(cells))
            if force or now - self._last_draw >= self.interval:
                self._last_draw = now
                self._bar.refresh()

    def line(self, text: str) -> None:
        """A line of its own: above the bar on a terminal, a plain line elsewhere."""
        if not self.enabled:
            return
        assert self.console is not None  # enabled: __init__ made one if none was given
        with self._lock:
            if self.live:
                self.console.print(Text(text), soft_wrap=True)
            else:
                stream = self.console.file
                stream.write(text + "\n")
                stream.flush()

    def close(self) -> None:
        """End the bar on a terminal with its last status (idempotent)."""
        with self._lock:
            if self._bar is not None and not self._closed:
                self._bar.stop()
            self._closed = True


class Progress:
    """Progress of a known number of steps (frames of one video).

    On a terminal, a bar redrawn at most every ``interval`` seconds; otherwise a plain line every 10%.
    ``enabled=False`` prints nothing. The rate and ETA are measured from the first update on and shown from the
    :data:`ETA_AFTER` th (see there why). ``slow_start`` is a line printed once if the first update has not come
    after ``slow_start_after`` seconds, to say what the wait is. :meth:`advance` may be called from any thread;
    :meth:`close` (or a ``with`` block) ends the bar.

    Parameters
    ----------
    total : int
        Steps expected.
    label : str
        What is counted, first on the line (``"re-tracked frames"``).
    unit : str
        The unit of the rate (``"frames"`` → ``12.3 frames/s``).
    console : rich.console.Console, optional
        Where to draw, instead of a console on ``stream`` (default ``sys.stderr``); for tests.
    on_update : callable, optional
        Called as ``on_update(done, total)``: once with 0 when the bar starts, then after each :meth:`advance`,
        whether or not anything is drawn (a batch worker forwards it to the batch's display). Its errors are
        its own: they propagate.
    """

    def __init__(self, total: int, *, label: str = "frames", unit: str = "frames", enabled: bool = True,
                 stream: TextIO | None = None, console: Console | None = None, interval: float = 0.2,
                 slow_start: str | None = None, slow_start_after: float = 2.0,
                 on_update: Callable[[int, int], None] | None = None) -> None:
        self.total = max(int(total), 0)
        self._on_update = on_update
        self.label = label
        self.unit = unit
        self.enabled = enabled
        self.done = 0
        self._rate = _Rate()
        self._last_decile = -1
        self._lock = threading.Lock()
        self._display = _Display(enabled=enabled, stream=stream, console=console, n_cells=4, interval=interval)
        with self._lock:
            self._show(time.perf_counter(), force=True)  # on a terminal the bar is there from the start: 0/N
        self._notice: threading.Timer | None = None
        if enabled and slow_start:
            self._notice = threading.Timer(slow_start_after, self._slow_start, args=(slow_start,))
            self._notice.daemon = True
            self._notice.start()
        if on_update is not None:
            on_update(0, self.total)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _slow_start(self, text: str) -> None:
        with self._lock:
            if self._rate.updates == 0:
                self._display.line(text)

    def advance(self, steps: int = 1) -> None:
        self._advance(steps)
        if self._on_update is not None:
            self._on_update(self.done, self.total)

    def _advance(self, steps: int) -> None:
        with self._lock:
            self.done += steps
            now = time.perf_counter()
            self._rate.update(self.done, now)
            if self._notice is not None and self._rate.updates == 1:
                self._notice.cancel()
            if not self.enabled:
                return
            if self._display.live:
                self._show(now, force=self.done >= self.total)
                return
            decile = int(10 * self.done / self.total) if self.total else 10
            if decile != self._last_decile:
                self._last_decile = decile
                self._display.line(self.line(now))

    def rate(self, now: float | None = None) -> float | None:
        """Steps per second since the first update, or None before :data:`ETA_AFTER` updates."""
        return self._rate.per_second(self.done, time.perf_counter() if now is None else now)

    def _cells(self, now: float) -> tuple[str, str, str, str]:
        rate = self.rate(now)
        share = self.done / self.total if self.total else 1.0
        eta = (self.total - self.done) / rate if rate else None
        return f"{self.done}/{self.total}", f"{100 * share:3.0f}%", _rate_text(rate, self.unit), _eta_text(eta)

    def _show(self, now: float, *, force: bool = False) -> None:
        self._display.show(self.label, self.done, self.total, self._cells(now), force=force)

    def line(self, now: float | None = None) -> str:
        """The status as a plain line: ``frames 12/40  30%  4.1 frames/s  ETA 00:07``."""
        return _plain(self.label, self._cells(time.perf_counter() if now is None else now))

    def close(self) -> None:
        if self._notice is not None:
            self._notice.cancel()
        self._display.close()


class CountNote:
    """``note(n)``: "counting the frames of VIDEO: n so far", once the count has taken ``after`` seconds.

    The open-time pass that counts a video's frames decodes all of it, minutes for a long video, before the
    first frame is tracked; without a word the tool would look stuck. On a terminal a pulsing bar with the count
    so far is redrawn at most every ``interval`` seconds (and ended by :meth:`close`); in a log one line says
    what the wait is.
    """

    def __init__(self, name: str, *, enabled: bool = True, stream: TextIO | None = None,
                 console: Console | None = None, after: float = 2.0, interval: float = 0.5) -> None:
        self.name, self.enabled, self.after = name, enabled, after
        self._display = _Display(enabled=enabled, stream=stream, console=console, n_cells=1, interval=interval)
        self._start = time.perf_counter()
        self._spoken = False

    def __call__(self, frames: int) -> None:
        if not self.enabled or time.perf_counter() - self._start < self.after:
            return
        what = f"counting the frames of {self.name} (once, for exact frame numbers)"
        if self._display.live:
            self._display.show(what, frames, None, (f"{frames} so far",))
        elif not self._spoken:
            self._display.line(what + "...")
        self._spoken = True

    def close(self) -> None:
        self._display.close()


class FinishedItem(Protocol):
    """What the batch display reads of an item's outcome (``annotator.batch.workers.ItemOutcome`` has it); a
    protocol, so this module, below the batch code, does not import it."""

    status: str
    frames: int
    seconds: float
    error: str | None


class BatchProgress:
    """Progress of a batch run: items done, failed and reused, frames across workers, rate, ETA.

    Fed by the ``start`` and ``frames`` events that workers send (see :mod:`annotator.batch.workers`) and by
    each item's outcome (:meth:`item_finished`); calls may come from any thread. On a terminal, one bar for the
    whole run, with a line above it for each item that did not finish ``done`` (its reason stays on screen);
    otherwise a plain line per finished item, saying what it did, then the run's line. The frame total is
    extrapolated (``~``) from the items started while some have not.

    Parameters
    ----------
    n_items : int
        Items to run (the reused ones not counted).
    reused : int
        Items whose finished outputs are kept from an earlier run.
    console : rich.console.Console, optional
        Where to draw, instead of a console on ``stream`` (default ``sys.stderr``); for tests.
    """

    def __init__(self, n_items: int, *, reused: int = 0, enabled: bool = True, stream: TextIO | None = None,
                 console: Console | None = None, interval: float = 0.2) -> None:
        self.n_items = n_items
        self.reused = reused
        self.enabled = enabled
        self.items_done = 0
        self.failed = 0  # items that did not end "done" (failed, or partial)
        self.totals: dict[str, int] = {}  # item id -> frames announced, then frames processed
        self.done: dict[str, int] = {}  # item id -> frames processed so far
        self._rate = _Rate()
        self._lock = threading.Lock()
        self._display = _Display(enabled=enabled, stream=stream, console=console, n_cells=3, interval=interval)
        if n_items:
            with self._lock:
                self._show(time.perf_counter(), force=True)

    @property
    def frames_done(self) -> int:
        return sum(self.done.values())

    def event(self, event: tuple) -> None:
        """A worker's ``("start", id, pid, total_frames)`` or ``("frames", id, done)``."""
        with self._lock:
            kind, item_id = event[0], event[1]
            now = time.perf_counter()
            if kind == "start":
                self.totals[item_id] = int(event[3])
                self.done[item_id] = 0  # a retried item starts again
            elif kind == "frames":
                self.done[item_id] = max(self.done.get(item_id, 0), int(event[2]))
                self._rate.update(self.frames_done, now)
            self._show(now)

    def item_finished(self, item_id: str, outcome: FinishedItem) -> None:
        with self._lock:
            self.items_done += 1
            self.failed += outcome.status != "done"
            # What an item actually processed replaces its announced total (a failed item counts 0 frames).
            self.done[item_id] = outcome.frames
            self.totals[item_id] = outcome.frames
            if not self.enabled:
                return
            failed = outcome.status == "failed"
            what = "" if failed else f" {plural(outcome.frames, 'frame')} in {outcome.seconds:.1f} s"
            reason = f": {outcome.error}" if outcome.error else ""
            text = f"[{self.items_done}/{self.n_items}] {item_id} {outcome.status}{what}{reason}"
            now = time.perf_counter()
            if self._display.live:
                if outcome.status != "done":
                    self._display.line(text)
                self._show(now, force=True)
            else:
                self._display.line(text)
                self._display.line(self.line(now))

    def _status(self, now: float) -> tuple[str, float, float, tuple[str, str, str]]:
        frames = self.frames_done
        known = sum(self.totals.values())
        started = len(self.totals)
        unstarted = max(self.n_items - started, 0)
        estimate = known + (known / started * unstarted if started else 0)
        rate = self._rate.per_second(frames, now)
        eta = (estimate - frames) / rate if rate and estimate >= frames else None
        extra = [f"{self.failed} failed"] if self.failed else []
        extra += [f"{self.reused} reused"] if self.reused else []
        description = f"items {self.items_done}/{self.n_items}" + (f" ({', '.join(extra)})" if extra else "")
        completed, total = (frames, estimate) if estimate else (self.items_done, max(self.n_items, 1))
        cells = (f"frames {frames}/{'~' if unstarted else ''}{int(round(estimate))}", _rate_text(rate, "frames"),
                 _eta_text(eta))
        return description, completed, total, cells

    def _show(self, now: float, *, force: bool = False) -> None:
        description, completed, total, cells = self._status(now)
        self._display.show(description, completed, total, cells, force=force)

    def line(self, now: float | None = None) -> str:
        """The run's status as a plain line: ``items 3/10 (1 failed) frames 120/~400  12.3 frames/s  ETA 01:02``."""
        description, _, _, cells = self._status(time.perf_counter() if now is None else now)
        return _plain(description, cells)

    def close(self) -> None:
        self._display.close()

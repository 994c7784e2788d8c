"""A one-line progress bar on stderr: frames, frames per second, ETA."""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

__all__ = ["CountNote", "Progress", "format_clock"]


class Progress:
    """Progress of a known number of steps, redrawn at most every ``interval`` seconds.

    On a terminal the line is redrawn in place; otherwise (a log file, CI) a
    line is printed every 10% so logs stay short. ``enabled=False`` prints nothing.

    The rate and ETA are measured from the first update on, and shown from
    the :data:`ETA_AFTER` th: the first step often costs far more than the
    rest (kernels compiling, a decoder starting) or far less (steps taken
    from a cache), and a rate that counted it would mislead. ``slow_start``
    is a line printed once if the first update has not come after
    ``slow_start_after`` seconds, to say what the wait is.
    """

    #: Updates before the rate and ETA are shown.
    ETA_AFTER = 3

    def __init__(self, total: int, *, label: str = "frames", enabled: bool = True, stream: TextIO | None = None,
                 interval: float = 0.2, slow_start: str | None = None, slow_start_after: float = 2.0) -> None:
        self.total = max(int(total), 0)
        self.label = label
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream
        self.interval = interval
        self.done = 0
        self._start = time.perf_counter()
        self._first: tuple[float, int] | None = None  # time and count of the first update
        self._updates = 0
        self._last_draw = 0.0
        self._last_decile = -1
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._lock = threading.Lock()
        self._notice: threading.Timer | None = None
        if enabled and slow_start:
            self._notice = threading.Timer(slow_start_after, self._slow_start, args=(slow_start,))
            self._notice.daemon = True
            self._notice.start()

    def _slow_start(self, text: str) -> None:
        with self._lock:
            if self._updates == 0:
                self.stream.write(text + "\n")
                self.stream.flush()

    def advance(self, steps: int = 1) -> None:
        with self._lock:
            self._advance(steps)

    def _advance(self, steps: int) -> None:
        self.done += steps
        self._updates += 1
        now = time.perf_counter()
        if self._first is None:
            self._first = (now, self.done)
            if self._notice is not None:
                self._notice.cancel()
        if not self.enabled:
            return
        if self._tty:
            if now - self._last_draw >= self.interval or self.done >= self.total:
                self._last_draw = now
                self.stream.write("\r" + self.line() + "\x1b[K")
                self.stream.flush()
        else:
            decile = int(10 * self.done / self.total) if self.total else 10
            if decile != self._last_decile:
                self._last_decile = decile
                self.stream.write(self.line() + "\n")
                self.stream.flush()

    def rate(self) -> float | None:
        """Steps per second since the first update, or None before :data:`ETA_AFTER` updates."""
        if self._first is None or self._updates < self.ETA_AFTER:
            return None
        elapsed = time.perf_counter() - self._first[0]
        return (self.done - self._first[1]) / elapsed if elapsed > 0 else None

    def line(self) -> str:
        rate = self.rate()
        share = self.done / self.total if self.total else 1.0
        width = 24
        filled = int(round(width * min(share, 1.0)))
        if rate is None or rate <= 0:
            rate_text, eta_text = f"  ... {self.label}/s", "--:--"
        else:
            rate_text, eta_text = f"{rate:5.1f} {self.label}/s", format_clock((self.total - self.done) / rate)
        return (f"{self.label} {self.done}/{self.total} [{'#' * filled}{'.' * (width - filled)}] "
                f"{100 * share:3.0f}%  {rate_text}  ETA {eta_text}")

    def close(self) -> None:
        if self._notice is not None:
            self._notice.cancel()
        if self.enabled and self._tty:
            self.stream.write("\n")
            self.stream.flush()


class CountNote:
    """``note(n)``: "counting the frames of VIDEO: n so far", once the count has taken ``after`` seconds.

    The open-time pass that counts a video's frames decodes all of it, minutes for a long video, before the
    first frame is tracked; without a word the tool would look stuck. On a terminal the line is redrawn in place
    (and ended by :meth:`close`); in a log one line says what the wait is.
    """

    def __init__(self, name: str, *, enabled: bool = True, stream: TextIO | None = None, after: float = 2.0,
                 interval: float = 0.5) -> None:
        self.name, self.enabled, self.after, self.interval = name, enabled, after, interval
        self.stream = sys.stderr if stream is None else stream
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._start = time.perf_counter()
        self._last_draw: float | None = None

    def __call__(self, frames: int) -> None:
        now = time.perf_counter()
        if not self.enabled or now - self._start < self.after:
            return
        text = f"counting the frames of {self.name} (once, for exact frame numbers): {frames} so far"
        if self._tty:
            if self._last_draw is None or now - self._last_draw >= self.interval:
                self.stream.write("\r" + text + "\x1b[K")
                self.stream.flush()
                self._last_draw = now
        elif self._last_draw is None:
            self.stream.write(f"counting the frames of {self.name} (once, for exact frame numbers)...\n")
            self.stream.flush()
            self._last_draw = now

    def close(self) -> None:
        if self.enabled and self._tty and self._last_draw is not None:
            self.stream.write("\n")
            self.stream.flush()


def format_clock(seconds: float) -> str:
    """``MM:SS``, or ``H:MM:SS`` from an hour on."""
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"

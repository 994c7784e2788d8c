"""A one-line progress bar on stderr: frames, frames per second, ETA."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress", "format_clock"]


class Progress:
    """Progress of a known number of steps, redrawn at most every ``interval`` seconds.

    On a terminal the line is redrawn in place; otherwise (a log file, CI) a
    line is printed every 10% so logs stay short. ``enabled=False`` prints nothing.
    """

    def __init__(self, total: int, *, label: str = "frames", enabled: bool = True, stream: TextIO | None = None,
                 interval: float = 0.2) -> None:
        self.total = max(int(total), 0)
        self.label = label
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream
        self.interval = interval
        self.done = 0
        self._start = time.perf_counter()
        self._last_draw = 0.0
        self._last_decile = -1
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def advance(self, steps: int = 1) -> None:
        self.done += steps
        if not self.enabled:
            return
        now = time.perf_counter()
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

    def line(self) -> str:
        elapsed = time.perf_counter() - self._start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        share = self.done / self.total if self.total else 1.0
        width = 24
        filled = int(round(width * min(share, 1.0)))
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        eta_text = format_clock(eta) if eta == eta else "--:--"
        return (f"{self.label} {self.done}/{self.total} [{'#' * filled}{'.' * (width - filled)}] "
                f"{100 * share:3.0f}%  {rate:5.1f} {self.label}/s  ETA {eta_text}")

    def close(self) -> None:
        if self.enabled and self._tty:
            self.stream.write("\n")
            self.stream.flush()


def format_clock(seconds: float) -> str:
    """``MM:SS``, or ``H:MM:SS`` from an hour on."""
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"

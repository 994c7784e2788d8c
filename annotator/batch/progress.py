"""Progress of a batch run: one line for the whole run.

Items done, frames done across workers, frames per second and ETA, fed by
the ``start`` and ``frames`` events that workers send (see
:mod:`annotator.batch.workers`) and by each item's outcome.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from annotator.batch.workers import ItemOutcome
from annotator.progress import format_clock
from annotator.wording import plural


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

"""Seconds per tracker stage, summed: the ``stage_timer`` the benchmarks give ``sptpt.tracker.Tracker``."""

from __future__ import annotations

import collections
import contextlib
import threading
import time
from typing import Iterator


class StageClock:
    """``Tracker(stage_timer=clock)``; ``clock.seconds`` holds each stage's total.

    Thread-safe: several runs (``robust``) time their stages from their own threads at once. While ``counting``
    is False (a warm-up frame) nothing is added.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = collections.defaultdict(float)
        self.counting = True
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        tic = time.perf_counter()
        yield
        if self.counting:
            with self._lock:
                self.seconds[stage] += time.perf_counter() - tic

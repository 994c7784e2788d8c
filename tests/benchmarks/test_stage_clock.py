"""The benchmarks' stage timer (``benchmarks/_stage_clock.py``): sums per stage, from several threads at once."""

from __future__ import annotations

import threading
import types

from _benchmark_scripts import load_script


def _ticking_clock(module: types.ModuleType) -> None:
    """Make every timed block last exactly 1 s: each thread's clock reads 1, 2, 3, ... on its successive calls."""
    local = threading.local()

    def perf_counter() -> float:
        local.calls = getattr(local, "calls", 0) + 1
        return float(local.calls)

    module.time = types.SimpleNamespace(perf_counter=perf_counter)


def test_stage_clock_sums_every_block_of_every_thread():
    module = load_script("_stage_clock")
    _ticking_clock(module)
    clock = module.StageClock()
    n_threads, n_blocks = 8, 2000

    def work() -> None:
        for _ in range(n_blocks):
            with clock("coding"):
                pass
            with clock("scoring"):
                pass

    threads = [threading.Thread(target=work) for _ in range(n_threads)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert dict(clock.seconds) == {"coding": n_threads * n_blocks, "scoring": n_threads * n_blocks}


def test_stage_clock_adds_nothing_while_not_counting():
    module = load_script("_stage_clock")
    _ticking_clock(module)
    clock = module.StageClock()
    clock.counting = False
    with clock("warp"):
        pass
    clock.counting = True
    with clock("snic"):
        pass
    assert dict(clock.seconds) == {"snic": 1.0}

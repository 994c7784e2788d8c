"""The progress line: no rate or ETA from the first update alone, and a note while the first frame is slow."""

from __future__ import annotations

import io

import pytest

from annotator.progress import Progress


def test_rate_and_eta_wait_for_the_first_updates_and_leave_out_the_first_jump(monkeypatch):
    clock = iter([0.0, 10.0, 11.0, 12.0, 12.0, 12.0, 12.0, 12.0])
    monkeypatch.setattr("annotator.progress.time.perf_counter", lambda: next(clock))
    bar = Progress(100_000, stream=io.StringIO(), enabled=False)  # t=0
    bar.advance(50_000)  # t=10: steps taken from a cache, or a first frame that compiled kernels: not a rate
    assert bar.rate() is None and "ETA --:--" in bar.line() and "... frames/s" in bar.line()
    bar.advance(1)  # t=11
    assert bar.rate() is None
    bar.advance(1)  # t=12
    assert bar.rate() == 1.0  # 2 steps in the 2 s since the first update
    assert "ETA 13:53:18" in bar.line()  # 49,998 steps at 1 per second


def test_slow_first_frame_prints_the_note_once():
    stream = io.StringIO()
    bar = Progress(10, stream=stream, slow_start="compiling kernels", slow_start_after=0.0)
    bar._notice.join()
    bar.advance()
    bar.close()
    assert stream.getvalue().count("compiling kernels") == 1


def test_no_note_when_the_first_frame_comes_in_time_or_progress_is_off():
    stream = io.StringIO()
    bar = Progress(10, stream=stream, slow_start="compiling kernels", slow_start_after=60.0)
    bar.advance()
    bar._notice.join()
    bar.close()
    assert "compiling" not in stream.getvalue()
    quiet = Progress(10, stream=stream, enabled=False, slow_start="compiling kernels", slow_start_after=0.0)
    assert quiet._notice is None


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


@pytest.mark.parametrize("tty", [False, True])
def test_count_note_speaks_only_once_the_count_is_slow(tty, monkeypatch):
    from annotator import progress as module

    clock = [100.0]
    monkeypatch.setattr(module.time, "perf_counter", lambda: clock[0])
    stream = _Stream(tty)
    note = module.CountNote("long.mp4", stream=stream, after=2.0, interval=0.5)
    note(400)  # a quick count says nothing
    clock[0] += 1.9
    note(800)
    assert stream.getvalue() == ""
    for frames in (1200, 1300, 1700):
        clock[0] += 0.3
        note(frames)
    note.close()
    if tty:  # redrawn in place at most every interval, and ended with a newline
        assert stream.getvalue() == ("\rcounting the frames of long.mp4 (once, for exact frame numbers): 1200 so far"
                                     "\x1b[K\rcounting the frames of long.mp4 (once, for exact frame numbers): "
                                     "1700 so far\x1b[K\n")
    else:  # a log gets one line that says what the wait is
        assert stream.getvalue() == "counting the frames of long.mp4 (once, for exact frame numbers)...\n"
    quiet = _Stream(tty)
    silent = module.CountNote("long.mp4", stream=quiet, enabled=False, after=0.0)
    silent(10)
    silent.close()
    assert quiet.getvalue() == ""

"""The progress display: no rate or ETA from the first update alone, a note while the first frame is slow,
plain lines without control codes off a terminal, and on a terminal a bar with the count, rate and ETA."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

from annotator import progress as module
from annotator.batch.workers import ItemOutcome
from annotator.progress import BatchProgress, CountNote, Progress

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


@pytest.fixture
def clock(monkeypatch):
    """``clock[0]`` is what ``time.perf_counter`` says in annotator.progress."""
    now = [0.0]
    monkeypatch.setattr(module.time, "perf_counter", lambda: now[0])
    return now


@pytest.fixture
def terminal(monkeypatch):
    """A console that takes its StringIO for a terminal, wide enough for a batch line."""
    monkeypatch.setenv("TERM", "xterm-256color")  # not "dumb", whatever the test runner's terminal is
    monkeypatch.delenv("TTY_INTERACTIVE", raising=False)
    return Console(file=io.StringIO(), force_terminal=True, force_interactive=True, width=160)


def shown(console: Console) -> str:
    return ANSI.sub("", console.file.getvalue())


def test_rate_and_eta_wait_for_the_first_updates_and_leave_out_the_first_jump(clock):
    bar = Progress(100_000, enabled=False)  # t=0
    clock[0] = 10.0
    bar.advance(50_000)  # steps taken from a cache, or a first frame that compiled kernels: not a rate
    assert bar.rate() is None and "ETA --:--" in bar.line() and "... frames/s" in bar.line()
    clock[0] = 11.0
    bar.advance(1)
    assert bar.rate() is None
    clock[0] = 12.0
    bar.advance(1)
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


def outcome(item_id: str, status: str, frames: int, error: str | None = None) -> ItemOutcome:
    return ItemOutcome(item_id, status, error=error, frames=frames, seconds=2.0)


def run_everything(stream: io.StringIO | None = None, console: Console | None = None) -> None:
    """A counted video, its 20 frames with the slow-start note, and a three-item batch with one failure."""
    note = CountNote("long.mp4", stream=stream, console=console, after=0.0)
    for frames in (100, 200):
        note(frames)
    note.close()
    bar = Progress(20, stream=stream, console=console, slow_start="compiling kernels", slow_start_after=0.0)
    bar._notice.join()
    for _ in range(20):
        bar.advance()
    bar.close()
    batch = BatchProgress(2, reused=1, stream=stream, console=console)
    batch.event(("start", "a", 1, 10))
    batch.event(("frames", "a", 10))
    batch.item_finished("a", outcome("a", "done", 10))
    batch.item_finished("b", outcome("b", "failed", 0, error="b.mp4: no such file"))
    batch.close()


def test_off_a_terminal_plain_lines_without_control_codes(monkeypatch):
    """A log gets short complete lines and no '\\r' or escape, even when the environment asks rich for colour."""
    monkeypatch.setenv("FORCE_COLOR", "1")
    monkeypatch.setenv("TTY_COMPATIBLE", "1")
    stream = _Stream(tty=False)
    run_everything(stream)
    text = stream.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0] == "counting the frames of long.mp4 (once, for exact frame numbers)..."
    assert lines[1] == "compiling kernels"
    frame_lines = [line for line in lines if line.startswith("frames ")]
    # A line every 10%: the first update, then each tenth.
    assert [line.split()[1] for line in frame_lines] == ["1/20", *(f"{2 * k}/20" for k in range(1, 11))]
    assert frame_lines[-1].startswith("frames 20/20  100%  ") and "frames/s  ETA 00:00" in frame_lines[-1]
    # The batch: a line per finished item, with its status and reason, then the run's line.
    assert lines[-4:-2] == ["[1/2] a done 10 frames in 2.0 s",
                            "items 1/2 (1 reused) frames 10/~20  ... frames/s  ETA --:--"]
    assert lines[-2] == "[2/2] b failed: b.mp4: no such file"
    assert lines[-1].startswith("items 2/2 (1 failed, 1 reused) frames 10/10  ")


@pytest.mark.parametrize("tty", [True, False])
def test_the_stream_says_whether_it_is_a_terminal(tty, monkeypatch):
    monkeypatch.setenv("TERM", "xterm-256color")
    monkeypatch.delenv("TTY_INTERACTIVE", raising=False)
    stream = _Stream(tty)
    bar = Progress(5, stream=stream)
    bar.advance(5)
    bar.close()
    assert ("\r" in stream.getvalue()) == tty
    assert "frames" in stream.getvalue() and "5/5" in stream.getvalue()


def test_a_dumb_terminal_gets_plain_lines(monkeypatch):
    monkeypatch.setenv("TERM", "dumb")
    stream = _Stream(tty=True)
    bar = Progress(5, stream=stream)
    bar.advance(5)
    bar.close()
    assert "\r" not in stream.getvalue() and stream.getvalue().splitlines()[-1].startswith("frames 5/5  100%")


def test_on_a_terminal_the_bar_shows_count_rate_and_eta(clock, terminal):
    bar = Progress(100, console=terminal)  # t=0: 0/100 is drawn at once
    assert "0/100" in shown(terminal) and "... frames/s" in shown(terminal) and "ETA --:--" in shown(terminal)
    for t in (1.0, 2.0, 3.0):  # a second apart: each is drawn
        clock[0] = t
        bar.advance()
    text = shown(terminal)
    assert "3/100" in text and "  1.0 frames/s" in text and "ETA 01:37" in text  # 2 steps in 2 s; 97 to go
    assert "\r" in terminal.file.getvalue()  # redrawn in place
    bar.close()
    assert terminal.file.getvalue().endswith("\n\x1b[?25h")  # the line ended, the cursor shown again


def test_a_terminal_bar_is_redrawn_at_most_every_interval(clock, terminal):
    bar = Progress(100, console=terminal, interval=1.0)
    for _ in range(5):  # all within the interval: none drawn
        clock[0] += 0.1
        bar.advance()
    assert "5/100" not in shown(terminal)
    clock[0] += 1.0
    bar.advance()
    assert "6/100" in shown(terminal)
    clock[0] += 0.1
    bar.advance(94)  # the last step is always drawn
    assert "100/100" in shown(terminal)
    bar.close()


def test_on_a_terminal_a_batch_shows_items_done_failed_and_reused(clock, terminal):
    batch = BatchProgress(3, reused=1, console=terminal)
    batch.event(("start", "a", 1, 50))
    for t, frames in ((1.0, 10), (2.0, 20), (3.0, 30)):
        clock[0] = t
        batch.event(("frames", "a", frames))
    # 20 frames in the 2 s since the first event; 150 frames expected (3 items of ~50), 120 to go.
    text = shown(terminal)
    assert "items 0/3 (1 reused)" in text
    assert "frames 30/~150" in text and " 10.0 frames/s" in text and "ETA 00:12" in text
    clock[0] = 4.0
    batch.item_finished("a", outcome("a", "done", 50))
    batch.item_finished("b", outcome("b", "failed", 0, error="b.mp4: no such file"))
    text = shown(terminal)
    assert "items 2/3 (1 failed, 1 reused)" in text
    assert "[2/3] b failed: b.mp4: no such file\n" in text  # the reason, on a line of its own above the bar
    assert "[1/3] a done" not in text  # items that finished well are counted, not listed
    batch.close()


def test_on_an_80_column_terminal_the_bar_gives_way_and_the_numbers_stay_whole(clock, terminal):
    terminal.width = 80
    batch = BatchProgress(100, reused=5, console=terminal)
    batch.event(("start", "a", 1, 12345))
    for t, frames in ((1.0, 100), (2.0, 200), (3.0, 300)):
        clock[0] = t
        batch.event(("frames", "a", frames))
    batch.close()
    last = shown(terminal).split("\r")[-1]
    assert "items 0/100 (5 reused)" in last and "frames 300/~1234500" in last and "100.0 frames/s" in last
    assert "ETA 3:25:42" in last and "\u2026" not in last  # (1,234,500 - 300) frames at 100 a second; no ellipsis


def test_nothing_at_all_when_disabled(terminal):
    stream = _Stream(tty=True)
    note = CountNote("long.mp4", stream=stream, enabled=False, after=0.0)
    note(10)
    note.close()
    bar = Progress(10, console=terminal, enabled=False, slow_start="compiling kernels", slow_start_after=0.0)
    bar.advance(10)
    bar.close()
    batch = BatchProgress(2, console=terminal, enabled=False)
    batch.event(("start", "a", 1, 10))
    batch.item_finished("a", outcome("a", "failed", 0, error="boom"))
    batch.close()
    assert stream.getvalue() == "" and terminal.file.getvalue() == ""


def test_updates_from_threads_all_count(terminal):
    from concurrent.futures import ThreadPoolExecutor

    bar = Progress(4000, console=terminal)
    with ThreadPoolExecutor(max_workers=4) as pool:
        list(pool.map(lambda _: [bar.advance() for _ in range(1000)], range(4)))
    bar.close()
    assert bar.done == 4000 and "4000/4000" in shown(terminal)


@pytest.mark.parametrize("tty", [False, True])
def test_count_note_speaks_only_once_the_count_is_slow(tty, clock, terminal):
    stream = _Stream(tty=False)
    console = terminal if tty else None
    note = CountNote("long.mp4", stream=stream, console=console, after=2.0, interval=0.5)
    note(400)  # a quick count says nothing
    clock[0] += 1.9
    note(800)
    assert stream.getvalue() == "" and terminal.file.getvalue() == ""
    for frames in (1200, 1300, 1700):
        clock[0] += 0.3
        note(frames)
    note.close()
    if tty:  # drawn at most every interval, with the count so far, and ended with a newline
        text = shown(terminal)
        assert "counting the frames of long.mp4 (once, for exact frame numbers)" in text
        assert "1200 so far" in text and "1300 so far" not in text and "1700 so far" in text
        assert text.endswith("\n")
    else:  # a log gets one line that says what the wait is
        assert stream.getvalue() == "counting the frames of long.mp4 (once, for exact frame numbers)...\n"


@pytest.mark.parametrize("cached", [True, False])
def test_a_run_says_it_compiles_only_when_the_kernels_are_not_cached(tmp_path, monkeypatch, cached):
    """A slow first frame with the kernels cached (a busy machine) is no compile: the note is not armed."""
    import cv2

    import sptpt
    from annotator import run as job
    from annotator.tracks import Target
    from sptpt_dev.synthetic import make_clip

    clip = make_clip(3, size=(64, 48), object_size=(16, 12))
    (tmp_path / "seq").mkdir()
    for k, frame in enumerate(clip.frames):
        cv2.imwrite(str(tmp_path / "seq" / f"{k}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    armed = []
    real = job.Progress

    def recording(*args, **kwargs):
        armed.append(kwargs.get("slow_start"))
        return real(*args, **kwargs)

    monkeypatch.setattr(job, "Progress", recording)
    monkeypatch.setattr(sptpt, "kernels_cached", lambda: cached)
    from annotator.config import resolve_config

    config = resolve_config(tracker_overrides={"n_particles": 40, "n_negatives": 10})
    job.annotate(tmp_path / "seq", [Target(tuple(clip.boxes_xywh[0]), track_id=1)], config, out_dir=tmp_path / "out",
                 formats=["otb"], show_progress=False)
    assert armed == [None if cached else job.COMPILING_NOTE]


def test_a_progress_calls_its_on_update_at_the_start_and_after_each_advance():
    seen = []
    with Progress(3, enabled=False, on_update=lambda done, total: seen.append((done, total))) as progress:
        progress.advance()
        progress.advance(2)
    assert seen == [(0, 3), (1, 3), (3, 3)]

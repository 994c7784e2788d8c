"""What one call of :func:`sptpt.colour_contrast` costs as the box grows on a 1920x1080 frame (issue #69).

The default calls it about 20 times a frame (each run's best candidates, the consensus, the failure signal), so a
cost that grows with the box's pixels makes HD video of a big object slow. One thread, best of ``--rounds`` rounds
of ``--calls`` calls per box, on an enlarged random picture (the measure's cost does not depend on what it reads
much, and the figures are for comparing trees on one machine):

    python -m benchmarks.contrast_cost
    cd /tmp && PYTHONPATH=/tmp/before python3 /path/to/benchmarks/contrast_cost.py   # a worktree of another commit

Prints one Markdown table: box size, its pixels, milliseconds a call. With ``--video``, instead, the tool's own
command runs in this process on that video (``--no-render --formats otb,flags``) and every call of the measure,
from the tracker and from the failure signals, is counted and timed by its thread's CPU clock:

    python -m benchmarks.contrast_cost --video /tmp/vsizes/1920x1080/David/img --box 768,355.5,384,351 --stop 80
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from sptpt import colour_contrast

BOXES = ((80, 100), (144, 180), (255, 256), (256, 256), (384, 351), (500, 500), (800, 700))


def call_ms(frame: np.ndarray, box: np.ndarray, calls: int, rounds: int) -> float:
    """Best of ``rounds`` mean times of ``calls`` calls, milliseconds."""
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            colour_contrast(frame, box)
        best = min(best, (time.perf_counter() - start) / calls * 1e3)
    return best


def calls_in_a_run(video: Path, box: str, stop: int) -> dict[str, float]:
    """The measure's calls in the tool's run on ``video``'s first ``stop`` frames: how many, their thread CPU."""
    import annotator.failure.signals as signals
    import sptpt.contrast as contrast
    from annotator.cli import main as tool

    measured = {"calls": 0, "cpu_s": 0.0, "pixels": 0.0}
    lock = threading.Lock()
    measure = contrast.colour_contrast

    def counted(frame: np.ndarray, box_xywh: np.ndarray) -> float:
        start = time.thread_time()
        value = measure(frame, box_xywh)
        with lock:
            measured["calls"] += 1
            measured["cpu_s"] += time.thread_time() - start
            measured["pixels"] += float(box_xywh[2] * box_xywh[3])
        return value

    # The tracker reaches it through sptpt.contrast's own name, the signals through the name they imported.
    contrast.colour_contrast, signals.colour_contrast = counted, counted
    started = time.process_time()
    with tempfile.TemporaryDirectory(prefix="contrast_cost_") as out:
        try:
            tool([str(video), "--box", box, "--stop", str(stop), "--no-render", "--formats", "otb,flags",
                  "--out", out, "--force", "-q"])
        except SystemExit as done:
            if done.code:
                raise
        finally:
            contrast.colour_contrast, signals.colour_contrast = measure, measure
    return {**measured, "process_cpu_s": time.process_time() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--video", type=Path, help="run the tool on this video and time the measure's calls")
    parser.add_argument("--box", help="the first frame's box, x,y,w,h (0-based), with --video")
    parser.add_argument("--stop", type=int, default=80, help="frames of --video to track")
    args = parser.parse_args()
    if args.video is not None:
        run = calls_in_a_run(args.video, args.box, args.stop)
        calls = max(run["calls"], 1)
        per_frame = 1e3 / args.stop
        print(f"{run['calls']} calls in {args.stop} frames, {run['calls'] / args.stop:.1f} a frame; mean box "
              f"{run['pixels'] / calls:.0f} pixels; {run['cpu_s'] / calls * 1e3:.3f} ms a call, "
              f"{run['cpu_s'] * per_frame:.1f} ms a frame, of the process's {run['process_cpu_s'] * per_frame:.0f}")
        return
    cv2.setNumThreads(1)
    small = np.random.default_rng(0).integers(0, 256, (270, 480, 3), dtype=np.uint8)
    frame = cv2.resize(small, (1920, 1080), interpolation=cv2.INTER_LINEAR)
    print("| box | pixels | ms a call |")
    print("|---|---:|---:|")
    for w, h in BOXES:
        box = np.array([560.0, 200.0, w, h])
        print(f"| {w}x{h} | {w * h} | {call_ms(frame, box, args.calls, args.rounds):.3f} |")


if __name__ == "__main__":
    main()

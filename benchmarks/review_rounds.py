"""What a review round costs on a real-size video: reading frames back, re-tracking, re-rendering the overlay.

    python -m benchmarks.review_rounds [--frames 600] [--no-record]

On a 1920x1080 H.264 clip (ffmpeg's ``testsrc2``, libx264 veryfast) made in a
temporary folder:

1. Reading: iterate a selection that starts near the end (``start = N - 10``),
   one of every 10th frame, and ``retrack``'s reader going back to frame
   ``N * 5 / 6`` after reading near the end (``SourceFrames.frames``); the
   open-time frame count (one decode of the whole clip) is timed apart.
2. Rounds: ``sptpt-annotate CLIP --box ...`` once, then two ``retrack`` rounds
   (corrections at ``N / 2`` and ``3 N / 4``) in two copies of the folder: one
   keeps its ``passes.npz``, the other has it deleted before each round (as
   before the kept passes); the two track stores are compared. Then a third
   round (``N / 4``) in two copies of the kept folder, with and without
   ``--no-render``. Frames tracked are exact; times are one run each.

The corrections repeat the first box: the clip's pattern has no object, and
what is measured is the work of a round, not its accuracy.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from annotator.frame_sources import open_frames
from annotator.pass_cache import PASSES_NAME
from annotator.review import SourceFrames
from benchmarks._results import machine_line, update_section

HERE = Path(__file__).resolve().parent

BOX = (900, 500, 160, 120)


def make_clip(path: Path, frames: int) -> None:
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "lavfi",
                    "-i", "testsrc2=size=1920x1080:rate=30", "-frames:v", str(frames), "-c:v", "libx264",
                    "-preset", "veryfast", "-pix_fmt", "yuv420p", str(path)], check=True)


def timed(fn) -> tuple[float, object]:
    tic = time.perf_counter()
    value = fn()
    return time.perf_counter() - tic, value


def reading(clip: Path, n: int) -> list[tuple[str, float]]:
    rows = []
    seconds, source = timed(lambda: open_frames(clip))
    rows.append(("open: the exact frame count (one decode of the whole clip)", seconds))
    for label, kwargs in ((f"iterate start={n - 10} (10 frames)", dict(start=n - 10)),
                          (f"iterate step=10 ({len(range(0, n, 10))} frames)", dict(step=10))):
        selected = open_frames(clip, **kwargs)
        rows.append((label, timed(lambda selected=selected: sum(1 for _ in selected))[0]))
    reader = SourceFrames(source, source.indices)
    rows.append((f"retrack's reader: frames {n - 100}..{n - 91}",
                 timed(lambda: sum(1 for _ in reader.frames(n - 100, n - 90)))[0]))
    back = n * 5 // 6 - 100
    rows.append((f"then back to frames {back}..{back + 9}",
                 timed(lambda: sum(1 for _ in reader.frames(back, back + 10)))[0]))
    reader.close()
    return rows


def cli(*args) -> float:
    seconds, done = timed(lambda: subprocess.run(["sptpt-annotate", *map(str, args), "--quiet"], capture_output=True,
                                                 text=True))
    if done.returncode != 0:
        raise SystemExit(f"sptpt-annotate {' '.join(map(str, args))} failed: {done.stderr.strip()}")
    return seconds


def last_round(folder: Path) -> int:
    return json.loads((folder / "run.json").read_text())["review"]["retracks"][-1]["frames_tracked"]


def fix(root: Path, frame: int) -> Path:
    path = root / f"fix{frame}.csv"
    path.write_text("frame,x,y,w,h\n" + f"{frame}," + ",".join(map(str, BOX)) + "\n")
    return path


def same_store(a: Path, b: Path) -> bool:
    with np.load(a / "tracks.npz") as x, np.load(b / "tracks.npz") as y:
        return all(np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f")
                   for k in x.files if k != "header" and "seconds" not in k)


def rounds(root: Path, clip: Path, n: int) -> list[tuple[str, int, float, int, float]]:
    base = root / "run"
    cli(clip, "--box", ",".join(map(str, BOX)), "--out", base)
    kept, rerun = root / "kept", root / "rerun"
    shutil.copytree(base, kept)
    shutil.copytree(base, rerun)
    rows = []
    for k, frame in enumerate((n // 2, 3 * n // 4), start=1):
        (rerun / PASSES_NAME).unlink(missing_ok=True)
        again = cli("retrack", rerun, "--corrections", fix(root, frame))
        keep = cli("retrack", kept, "--corrections", fix(root, frame))
        if not same_store(kept, rerun):
            raise SystemExit(f"round {k}: the kept passes gave another track store than running them again")
        rows.append((f"{k} (frame {frame}): every pass run again / passes kept", last_round(rerun), again,
                     last_round(kept), keep))
    render, quick = root / "render", root / "quick"
    shutil.copytree(kept, render)
    shutil.copytree(kept, quick)
    frame = n // 4
    with_overlay = cli("retrack", render, "--corrections", fix(root, frame))
    without = cli("retrack", quick, "--corrections", fix(root, frame), "--no-render")
    rows.append((f"3 (frame {frame}): overlay rendered / --no-render", last_round(render), with_overlay,
                 last_round(quick), without))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--no-record", action="store_true", help="print only; do not update RESULTS.md")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        clip = root / "clip.mp4"
        make_clip(clip, args.frames)
        read = reading(clip, args.frames)
        done = rounds(root, clip, args.frames)
    command = "python -m benchmarks.review_rounds" + (f" --frames {args.frames}" if args.frames != 600 else "")
    lines = ["## Review rounds on a 1080p video (`benchmarks/review_rounds.py`)", "",
             f"Command: `{command}`  ", f"Machine: {machine_line()}.  ",
             f"Clip: {args.frames} frames of 1920x1080 H.264 (`testsrc2`); preset `robust`; one run each.", "",
             "| reading | seconds |", "|---|---:|", *(f"| {label} | {s:.2f} |" for label, s in read), "",
             "| round | frames tracked | seconds | frames tracked | seconds |", "|---|---:|---:|---:|---:|",
             *(f"| {label} | {a} | {sa:.1f} | {b} | {sb:.1f} |" for label, a, sa, b, sb in done), "",
             "Rounds 1 and 2: the track stores of the two folders are identical after each round (every array but "
             "the timings); the script stops if not."]
    markdown = "\n".join(lines)
    print(markdown)
    if not args.no_record:
        update_section("review-rounds", markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())

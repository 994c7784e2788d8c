"""Cost of everything around the tracker in ``sptpt-annotate VIDEO --box``, and memory against video length.

    python -m benchmarks.pipeline_overhead

1. Overhead: a 640x480 synthetic clip through the full command (decode,
   track, flag, render the overlay, encode H.264, write every export);
   reports the time outside the tracker as a share of tracking time
   (target <= 15 %), for the ``paper`` and ``fast`` presets.
2. Memory: peak resident memory of the whole command on 1,000- and
   10,000-frame videos (target: 10,000 within 1.2x of 1,000). The tracker
   runs with few particles here, since the question is whether anything in the
   pipeline grows with the number of frames.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from benchmarks._results import machine_line, update_section
from sptpt_dev.synthetic import make_clip

HERE = Path(__file__).resolve().parent


def write_video(path: Path, clip_frames: np.ndarray, repeats: int, fps: float = 25.0) -> None:
    height, width = clip_frames.shape[1:3]
    writer = imageio_ffmpeg.write_frames(str(path), (width, height), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                                         macro_block_size=1, ffmpeg_log_level="error",
                                         output_params=["-preset", "veryfast"])
    writer.send(None)
    for _ in range(repeats):
        for frame in clip_frames:
            writer.send(np.ascontiguousarray(frame))
    writer.close()


def run_command(video: Path, box: np.ndarray, out: Path, extra: list[str]) -> dict:
    """Run the real console script in a child process; return its run.json and peak RSS."""
    box_text = ",".join(f"{v:.1f}" for v in box)
    code = ("import resource, sys; from annotator.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    code = e.code\nelse:\n    code = 0\n"
            "print('PEAK_RSS_KIB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
            "sys.exit(code)\n")
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, str(video), "--box", box_text, "--out", str(out), "--force",
                           "--quiet", *extra], capture_output=True, text=True)
    wall = time.perf_counter() - started
    if proc.returncode != 0:
        raise RuntimeError(f"sptpt-annotate failed ({proc.returncode}): {proc.stderr}")
    peak = int(next(line.split()[1] for line in proc.stderr.splitlines() if line.startswith("PEAK_RSS_KIB")))
    run = json.loads((out / "run.json").read_text())
    return {"run": run, "peak_rss_mib": peak / 1024.0, "wall": wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--overhead-frames", type=int, default=150)
    parser.add_argument("--short", type=int, default=1000)
    parser.add_argument("--long", type=int, default=10000)
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args()
    lines = ["## Pipeline overhead and memory (`sptpt-annotate VIDEO --box`)", "",
             f"Command: `python -m benchmarks.pipeline_overhead {' '.join(sys.argv[1:])}`  ",
             f"Machine: {machine_line()}.", ""]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        clip = make_clip(args.overhead_frames, size=(640, 480), object_size=(96, 80), seed=5)
        video = tmp / "overhead.mp4"
        write_video(video, clip.frames, 1)
        lines += ["| Preset | Frames | Total s | Tracking s | Outside tracker s | Outside / tracking | Target <= 15% |",
                  "|---|---:|---:|---:|---:|---:|---|"]
        for preset in ("paper", "fast"):
            result = run_command(video, clip.boxes_xywh[0], tmp / f"out_{preset}", ["--preset", preset])
            t = result["run"]["timings"]
            share = t["seconds_outside_tracker"] / t["seconds_tracking"]
            lines.append(f"| {preset} | {result['run']['frames_processed']} | {t['seconds_total']:.1f} | "
                         f"{t['seconds_tracking']:.1f} | {t['seconds_outside_tracker']:.1f} | {100 * share:.1f}% | "
                         f"{'met' if share <= 0.15 else 'missed'} |")
            print(lines[-1], flush=True)
        lines += ["", "Outside the tracker: decoding, flagging, drawing the overlay (particles, superpixels, box), "
                  "H.264 encoding, and writing OTB, COCO, flags, report and run.json; 640x480, rendering on.", ""]
        base = make_clip(args.short, size=(320, 240), object_size=(48, 40), seed=6)
        cheap = tmp / "cheap.yaml"
        cheap.write_text("tracker:\n  n_particles: 40\n  n_negatives: 20\n")
        rows = []
        for frames in (args.short, args.long):
            video = tmp / f"len{frames}.mp4"
            write_video(video, base.frames, frames // args.short)
            result = run_command(video, base.boxes_xywh[0], tmp / f"out_len{frames}", ["--config", str(cheap)])
            rows.append((frames, result))
            print(frames, result["peak_rss_mib"], flush=True)
        ratio = rows[1][1]["peak_rss_mib"] / rows[0][1]["peak_rss_mib"]
        lines += ["| Video length (frames, 320x240) | Peak RSS (MiB) | Wall s |", "|---:|---:|---:|"]
        for frames, result in rows:
            lines.append(f"| {frames} | {result['peak_rss_mib']:.0f} | {result['wall']:.0f} |")
        lines += ["", f"Ratio {args.long} / {args.short} frames: **{ratio:.2f}x** (target <= 1.2x: "
                  f"{'met' if ratio <= 1.2 else 'missed'}). Tracker with 40 particles and 20 negatives "
                  "(`--config`), every output on, so that the pipeline's own memory is what is measured."]
    markdown = "\n".join(lines)
    print(markdown)
    if not args.no_record:
        update_section("pipeline", markdown)


if __name__ == "__main__":
    main()

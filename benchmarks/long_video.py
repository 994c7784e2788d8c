"""A 10,000-frame 1080p video through the default, overlay and report included: time, memory over the run.

No video of that length or size had ever been run (issue #69). The video is an OTB sequence played forward and
back (so the motion stays continuous) until it has ``--frames`` frames, resized to ``--size`` and encoded with
H.264 (``libx264 -preset veryfast -crf 28``). The run is the README's command with the default formats; the
resident memory of the whole process tree is sampled every 2 s from ``/proc`` together with the frame the
progress lines report, so memory can be read against the frames done.

    python -m benchmarks.long_video --sequence David --frames 10000 --size 1920x1080 --work /tmp/long

Prints the wall time, frames/s, peak memory, memory at the 1,000th frame and at the end, the peak of each process
(the tool, its decoder, its overlay encoder), and the outputs' sizes; the samples go to ``WORK/memory.csv``.
``--stop 1500`` tracks the first 1,500 frames only, enough to show the peak and whether it stays flat.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "otb"


def make_video(sequence: str, frames: int, size: tuple[int, int], path: Path) -> list[float]:
    """Write the ping-pong video; return the first frame's 0-based box, scaled."""
    source = SHARED / sequence
    files = sorted((source / "img").iterdir())
    order = files + files[-2:0:-1]  # forward, then back, without repeating the ends
    first = cv2.imread(str(files[0]))
    sx, sy = size[0] / first.shape[1], size[1] / first.shape[0]
    first_row = (source / "groundtruth_rect.txt").read_text().split("\n")[0].strip()
    x, y, w, h = (float(v) for v in re.split(r"[,\t ]+", first_row))
    box = [(x - 1) * sx, (y - 1) * sy, w * sx, h * sy]
    if path.exists():
        return box
    tmp = path.with_suffix(".tmp.mp4")
    writer = imageio_ffmpeg.write_frames(str(tmp), size, fps=30, codec="libx264", macro_block_size=1,
                                         ffmpeg_log_level="error", output_params=["-preset", "veryfast", "-crf", "28"])
    writer.send(None)
    for k in range(frames):
        image = cv2.resize(cv2.imread(str(order[k % len(order)])), size, interpolation=cv2.INTER_LINEAR)
        writer.send(np.ascontiguousarray(image[:, :, ::-1]))
    writer.close()
    tmp.rename(path)
    return box


#: The processes of a run, as :func:`_rss_by_process` names them.
ROLES = ("tool", "decoder", "encoder", "other")


def _role(command: list[str]) -> str:
    """What a child process of the run is, by its command line: the ffmpeg that decodes the frames the tool tracks,
    the ffmpeg that encodes the overlay (libx264), or another (the open-time counting pass, the compile child)."""
    if not command or "ffmpeg" not in Path(command[0]).name:
        return "other"
    if "libx264" in command:
        return "encoder"
    return "other" if "null" in command else "decoder"  # the counting pass writes to the null muxer


def _rss_by_process(pid: int) -> dict[str, float]:
    """Resident memory of ``pid`` and its descendants by :data:`ROLES`, MiB (issue #69: which process holds it)."""
    totals, todo = dict.fromkeys(ROLES, 0.0), [pid]
    while todo:
        p = todo.pop()
        try:
            status = Path(f"/proc/{p}/status").read_text()
            rss = int(re.search(r"VmRSS:\s+(\d+)", status).group(1)) / 1024.0
            command = Path(f"/proc/{p}/cmdline").read_bytes().decode(errors="replace").split("\0")
            role = "tool" if p == pid else _role(command)
            for task in Path(f"/proc/{p}/task").iterdir():
                children = (task / "children").read_text().split()
                todo += [int(c) for c in children]
        except (OSError, AttributeError):
            continue
        totals[role] += rss
    return totals


def _tree_rss_mib(pid: int) -> float:
    """Resident memory of ``pid`` and its descendants (the decoder, the overlay's encoder, the compile child), MiB."""
    return sum(_rss_by_process(pid).values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequence", default="David")
    parser.add_argument("--frames", type=int, default=10000)
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--work", type=Path, default=Path("/tmp/long"))
    parser.add_argument("--stop", type=int, default=None,
                        help="track only the frames before this one (the tool's --stop): the peak and its flatness "
                             "show within the first 1,500 frames, in a tenth of the time")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    args.work.mkdir(parents=True, exist_ok=True)
    video = args.work / f"long_{args.size}_{args.frames}.mp4"
    tic = time.perf_counter()
    box = make_video(args.sequence, args.frames, size, video)
    print(f"video {video} ({video.stat().st_size / 2**20:.0f} MiB) ready after {time.perf_counter() - tic:.0f} s")
    out = args.work / "run"
    # The command line of this source tree (the console script runs whichever tree is installed).
    tool = [sys.executable, "-m", "annotator.cli"]
    command = [*tool, str(video), "--box", ",".join(f"{v:.3f}" for v in box), "--out", str(out), "--force"]
    if args.stop is not None:
        command += ["--stop", str(args.stop)]
    frames = args.frames if args.stop is None else min(args.stop, args.frames)
    started = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=HERE.parent)
    done = [0]

    def read_progress() -> None:
        for line in proc.stderr:  # off a terminal the bar prints plain lines: "tracked frames 1234/10000 ..."
            match = re.search(r"(\d+)/(\d+)", line)
            if match and "frames" in line:
                done[0] = int(match.group(1))

    reader = threading.Thread(target=read_progress, daemon=True)
    reader.start()
    samples = []
    while proc.poll() is None:
        samples.append((time.perf_counter() - started, done[0], _rss_by_process(proc.pid)))
        time.sleep(2.0)
    wall = time.perf_counter() - started
    reader.join(timeout=5)
    (args.work / "memory.csv").write_text("seconds,frames_done,rss_mib," + ",".join(f"{r}_mib" for r in ROLES)
                                          + "\n" + "".join(
        f"{t:.1f},{f},{sum(m.values()):.1f}," + ",".join(f"{m[r]:.1f}" for r in ROLES) + "\n"
        for t, f, m in samples))
    if proc.returncode != 0:
        raise SystemExit(f"run failed ({proc.returncode}): {proc.stdout.read()[-2000:]}")
    rss = np.array([sum(m.values()) for _, _, m in samples])
    after = [sum(m.values()) for _, f, m in samples if f >= 1000]
    at_1000 = after[0] if after else float("nan")
    tracking = [m for _, f, m in samples if 0 < f < frames]
    print(f"{frames} frames at {args.size}: {wall:.0f} s whole process, {frames / wall:.2f} frames/s")
    print(f"peak resident memory {rss.max():.0f} MiB; at frame 1000 {at_1000:.0f} MiB; largest while tracking "
          f"after frame 1000 {max(after[:-1] or [float('nan')]):.0f} MiB; last sample {rss[-1]:.0f} MiB; "
          f"samples while tracking: {len(tracking)}")
    print("peak while tracking by process: " + ", ".join(
        f"{role} {max((m[role] for m in tracking), default=float('nan')):.0f} MiB" for role in ROLES))
    for name in ("overlay.mp4", "report.html", "tracks.npz", "annotations.json", "flags.csv", "run.json"):
        path = out / name
        print(f"  {name}: {path.stat().st_size / 2**20:.1f} MiB" if path.exists() else f"  {name}: missing")


if __name__ == "__main__":
    main()

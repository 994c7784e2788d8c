"""The default on the same content at 320x240 up to 1920x1080: speed against CSRT, memory, accuracy, outputs.

Users film 720p and 1080p; every other figure of RESULTS.md is on OTB's 320x240 to 720x304 frames (issue #69).
Each OTB sequence is resized to every size (``cv2.INTER_LINEAR``, each axis on its own, so 4:3 content is
stretched to 16:9) and written as a JPEG image folder with its ground truth scaled the same way. On each size, in
turn and in one call:

* ``sptpt-annotate FOLDER --box ... --no-render --formats otb,flags`` (whole process, wall seconds and peak
  resident memory by ``/usr/bin/time``), its success AUC against the scaled ground truth;
* the same with the default formats (the overlay and the report): the overlay's added seconds, output sizes;
* OpenCV CSRT (one thread, whole process: ``benchmarks/_peer_runner.py`` in ``benchmarks/_env``).

    python -m benchmarks.video_sizes --sequences David,Coke --frames 300 --work /tmp/vsizes
    python -m benchmarks.video_sizes --sizes 320x240,1920x1080 --repeats 3   # medians of 3 rounds in turn

Prints one Markdown table; the rows go into RESULTS.md by hand with the command.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable, NoReturn

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "otb"
SIZES = ((320, 240), (640, 480), (1280, 720), (1920, 1080))


def _timed(command: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident MiB of a whole command (``/usr/bin/time``)."""
    done = subprocess.run(["/usr/bin/time", "-f", "%e %M", *command], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    seconds, kib = done.stderr.strip().splitlines()[-1].split()
    return float(seconds), float(kib) / 1024.0


def make_sized(sequence: str, frames: int, size: tuple[int, int], work: Path) -> tuple[Path, list[float]]:
    """The first ``frames`` frames of ``sequence`` resized to ``size`` in ``work``; its folder and 0-based box."""
    source = SHARED / sequence
    folder = work / f"{size[0]}x{size[1]}" / sequence
    files = sorted((source / "img").iterdir())[:frames]
    first = cv2.imread(str(files[0]))
    sx, sy = size[0] / first.shape[1], size[1] / first.shape[0]
    rows = (source / "groundtruth_rect.txt").read_text().splitlines()[:frames]
    gt = np.array([[float(v) for v in re.split(r"[,\t ]+", r.strip()) if v] for r in rows])
    scaled = np.column_stack([(gt[:, 0] - 1) * sx, (gt[:, 1] - 1) * sy, gt[:, 2] * sx, gt[:, 3] * sy])
    if not (folder / "groundtruth_rect.txt").exists():
        (folder / "img").mkdir(parents=True, exist_ok=True)
        for k, file in enumerate(files):
            image = cv2.resize(cv2.imread(str(file)), size, interpolation=cv2.INTER_LINEAR)
            cv2.imwrite(str(folder / "img" / f"{k + 1:04d}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 95])
        (folder / "groundtruth_rect.txt").write_text(
            "".join(f"{x + 1:.3f},{y + 1:.3f},{w:.3f},{h:.3f}\n" for x, y, w, h in scaled))
    return folder, scaled[0].tolist()


def _auc(out: Path, folder: Path) -> float:
    from annotator.evaluation import evaluate_result_file

    return evaluate_result_file(out, folder / "groundtruth_rect.txt").auc


def _size_mib(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 2**20


def measure(sequence: str, frames: int, size: tuple[int, int], work: Path, peer_python: Path, repeats: int) -> dict:
    """One row: ``repeats`` rounds of ours without the overlay, ours with it and CSRT, in turn; times are medians,
    the ratio to CSRT the median of each round's own ratio (the VM's speed drifts between rounds)."""
    folder, box = make_sized(sequence, frames, size, work)
    runs = work / "runs" / f"{size[0]}x{size[1]}" / sequence
    shutil.rmtree(runs, ignore_errors=True)
    tool = str(Path(sys.executable).with_name("sptpt-annotate"))
    box_text = ",".join(f"{v:.3f}" for v in box)
    plain, plain_mib, full, full_mib, csrt = [], [], [], [], []
    for _ in range(repeats):
        seconds, mib = _timed([tool, str(folder), "--box", box_text, "--no-render", "--formats", "otb,flags",
                               "--out", str(runs / "plain"), "--force", "-q"])
        plain.append(seconds)
        plain_mib.append(mib)
        seconds, mib = _timed([tool, str(folder), "--box", box_text, "--out", str(runs / "full"), "--force", "-q"])
        full.append(seconds)
        full_mib.append(mib)
        args = {"tracker": "csrt", "seq_dir": str(folder), "out_dir": str(runs / "csrt"), "name": sequence}
        csrt.append(_timed([str(peer_python), str(HERE / "_peer_runner.py"), json.dumps(args)])[0])
    n = len(list((folder / "img").iterdir()))
    ratios = np.array(csrt) / np.array(plain)
    return {"sequence": sequence, "size": f"{size[0]}x{size[1]}", "frames": n, "repeats": repeats,
            "seconds": float(np.median(plain)), "fps": n / float(np.median(plain)),
            "ratio_csrt": float(np.median(ratios)), "ratio_range": (float(ratios.min()), float(ratios.max())),
            "peak_mib": float(np.median(plain_mib)), "auc": _auc(runs / "plain", folder),
            "overlay_seconds": float(np.median(np.array(full) - np.array(plain))),
            "full_peak_mib": float(np.median(full_mib)),
            "overlay_mib": (runs / "full" / "overlay.mp4").stat().st_size / 2**20,
            "outputs_mib": _size_mib(runs / "full"), "csrt_seconds": float(np.median(csrt))}


def parse_size(text: str, error: Callable[[str], NoReturn]) -> tuple[int, int]:
    """``WxH`` as ``(W, H)``; anything else goes to ``error`` (argparse's: one line, exit code 2)."""
    match = re.fullmatch(r"\s*(\d+)x(\d+)\s*", text)
    if match is None or min(int(match[1]), int(match[2])) < 2:
        error(f"--sizes: {text!r} is not a frame size; expected WxH with both at least 2, e.g. 1920x1080")
    return int(match[1]), int(match[2])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequences", default="David,Coke")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--work", type=Path, default=Path("/tmp/vsizes"))
    parser.add_argument("--sizes", default=",".join(f"{w}x{h}" for w, h in SIZES),
                        help="frame sizes, WxH, comma-separated (default: all four)")
    parser.add_argument("--repeats", type=int, default=1, help="rounds of the three runs per row, in turn")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    sizes = [parse_size(text, parser.error) for text in args.sizes.split(",")]
    from benchmarks.otb_benchmark import ensure_peer_env

    peer_python = ensure_peer_env()
    rows = [measure(s, args.frames, size, args.work, peer_python, args.repeats)
            for s in args.sequences.split(",") for size in sizes]
    print("| sequence | size | frames | s (--no-render) | frames/s | x CSRT (range) | peak MiB | AUC "
          "| overlay + report s | peak MiB with overlay | overlay MiB | outputs MiB |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        low, high = r["ratio_range"]
        print(f"| {r['sequence']} | {r['size']} | {r['frames']} | {r['seconds']:.1f} | {r['fps']:.2f} | "
              f"{r['ratio_csrt']:.3f} ({low:.3f}-{high:.3f}) | {r['peak_mib']:.0f} | {r['auc']:.3f} | "
              f"{r['overlay_seconds']:.1f} | {r['full_peak_mib']:.0f} | {r['overlay_mib']:.1f} | "
              f"{r['outputs_mib']:.1f} |")
    (args.work / "rows.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

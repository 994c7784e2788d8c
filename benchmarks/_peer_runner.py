"""Run OpenCV's CSRT, KCF, MIL or NanoTrack over OTB-layout sequences (peer trackers for the benchmark).

CSRT, KCF and MIL run inside the benchmark's own environment (``benchmarks/_env``)
because opencv-contrib-python-headless clashes with the project's
opencv-python-headless; NanoTrack is in OpenCV's main modules and runs with the
project's own python, its weights taken from ``../shared/anchors/nanotrack_v2``
(a benchmark peer only: the product never loads them). The script therefore
imports only the standard library, NumPy and cv2. Frames are the
same files, in the same order, as SPTPT reads; results are written in the OTB
format (1-based) with got10k's per-frame times.

    _env/bin/python _peer_runner.py '{"tracker": "csrt", "seq_dir": ..., "out_dir": ..., "name": ...}'
"""

from __future__ import annotations

import json
import os
import re
import sys
import time
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
NANOTRACK = Path(__file__).resolve().parents[2] / "shared" / "anchors" / "nanotrack_v2"


def _nanotrack():
    params = cv2.TrackerNano_Params()
    params.backbone = str(NANOTRACK / "backbone.onnx")
    params.neckhead = str(NANOTRACK / "head.onnx")
    return cv2.TrackerNano_create(params)


CREATE = {"csrt": lambda: cv2.TrackerCSRT_create(), "kcf": lambda: cv2.TrackerKCF_create(),
          "mil": lambda: cv2.TrackerMIL_create(), "nanotrack": _nanotrack}


def natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def read_gt_first(path: Path) -> list[float]:
    first = path.read_text().splitlines()[0]
    return [float(v) for v in re.split(r"[,\t ]+", first.strip()) if v]


def run(tracker: str, seq_dir: str, out_dir: str, name: str, stop: int | None = None) -> dict:
    seq_dir, out_dir = Path(seq_dir), Path(out_dir)
    cv2.setNumThreads(1)
    img_dir = seq_dir / "img" if (seq_dir / "img").is_dir() else seq_dir
    files = sorted((p for p in img_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
                   key=lambda p: natural_key(p.name))
    files = files[:stop]
    x, y, w, h = read_gt_first(seq_dir / "groundtruth_rect.txt")
    box = (x - 1.0, y - 1.0, w, h)  # OTB is 1-based; OpenCV is 0-based
    boxes, seconds, lost = [], [], 0
    model = CREATE[tracker]()
    for k, file in enumerate(files):
        frame = cv2.imread(str(file), cv2.IMREAD_COLOR)
        tic = time.perf_counter()
        if k == 0:
            model.init(frame, tuple(int(round(v)) for v in box))
        else:
            ok, found = model.update(frame)
            if ok:
                box = tuple(float(v) for v in found)
            else:
                lost += 1  # keep the last box: a row per frame, as the toolkits require
        seconds.append(time.perf_counter() - tic)
        boxes.append(box)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "times").mkdir(exist_ok=True)
    _write(out_dir / f"{name}.txt", "".join(f"{b[0] + 1:.3f},{b[1] + 1:.3f},{b[2]:.3f},{b[3]:.3f}\n" for b in boxes))
    _write(out_dir / "times" / f"{name}_time.txt", "".join(f"{s:.6f}\n" for s in seconds))
    return {"sequence": name, "frames": len(boxes), "seconds": float(np.sum(seconds)),
            "seconds_after_first": float(np.sum(seconds[1:])), "lost_frames": lost}


def _write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


if __name__ == "__main__":
    print(json.dumps(run(**json.loads(sys.argv[1]))))

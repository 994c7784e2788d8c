"""Measure the motion signals of stored runs again from their videos, without tracking them again.

The signals of :class:`annotator.failure.signals.MotionMeter` need only the frames and the boxes, so a run
tracked before one of them existed gets it, bit for bit as tracking would have measured it, from its track
store and its video: minutes instead of an hour of tracking. Every batch item's store is read, the meter
replayed over its boxes in frame order (one forward pass from its first frame: batch runs have no other
human box), the store rewritten in place with the motion signals, and the signals it already held checked
to be unchanged (``flow_iou``, ``flow_fb``, ``flow_kept`` come from the same meter): a difference means the
replay is not what tracking measured, and the script stops.

    python -m benchmarks.motion_signals 'benchmarks/_runs/failure/*/robust-s*' --otb ../shared/otb ../shared/otb_extra
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from annotator.failure.signals import MOTION_SIGNALS as MOTION
from annotator.failure.signals import NEUTRAL, MotionMeter, grey_of
from annotator.frame_sources import open_frames
from annotator.track_store import STORE_NAME, read_store, write_store

ROOT = Path(__file__).resolve().parents[1]

def replay(item: Path, otb: list[Path]) -> str:
    store = read_store(item / STORE_NAME)
    track = store.tracks[0]
    if track.keyframe[1:].any():
        raise SystemExit(f"{item}: the track has human boxes after its first frame; replay only plain batch runs")
    folder = next((root / item.name for root in otb if (root / item.name / "img").is_dir()), None)
    if folder is None:
        raise SystemExit(f"{item}: no OTB sequence {item.name} under {', '.join(map(str, otb))}; give it with --otb")
    wanted = {int(f): row for row, f in enumerate(track.frame_indices)}
    values = {name: np.full(len(track), NEUTRAL[name]) for name in MOTION}
    meter = MotionMeter()
    for index, frame in open_frames(folder):
        row = wanted.get(index)
        if row is None:
            continue
        grey, box = grey_of(frame), track.boxes_xywh[row]
        if row == 0:
            meter.first(grey, box)
            continue
        for name, value in meter.next(grey, box).items():
            values[name][row] = value
    for name in MOTION:
        if name in track.signals and not np.array_equal(track.signals[name], values[name], equal_nan=True):
            bad = np.flatnonzero(~np.isclose(track.signals[name], values[name], equal_nan=True, rtol=0, atol=0))
            raise SystemExit(f"{item}: replayed {name} differs from the stored one at rows {bad[:5].tolist()}")
    track = dataclasses.replace(track, signals={**track.signals, **values})
    write_store(item / STORE_NAME, dataclasses.replace(store, tracks=(track,)))
    return f"{item}: {len(values['flow_drift'])} frames"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="batch output folders (globs)")
    parser.add_argument("--otb", type=Path, nargs="+", required=True, help="OTB roots holding the sequences")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    items = sorted(p for g in args.runs for run in glob.glob(g) for p in Path(run).iterdir()
                   if (p / STORE_NAME).is_file())
    with ProcessPoolExecutor(args.workers) as pool:
        for line in pool.map(replay, items, [args.otb] * len(items)):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

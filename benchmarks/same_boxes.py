"""Same boxes, same seed: track the first frames of a few OTB sequences and compare with saved boxes.

    python -m benchmarks.same_boxes --save /tmp/ref_boxes      # on the reference commit
    python -m benchmarks.same_boxes --compare /tmp/ref_boxes   # after a change

Tracks the first ``--frames`` frames of each sequence with the ``paper``
preset (or ``--preset``) and the seed ``benchmarks/_sptpt_runner.py`` uses,
and saves per sequence the boxes, log-likelihoods and acceptance flags
(``<dir>/<Seq>.npz``). ``--compare`` reports for every sequence whether the
boxes are bit-identical and their largest difference in pixels, and exits
with status 1 if any box differs by more than ``--tol`` px (1e-6) or any
acceptance decision changed. Also prints the per-stage time in ms per frame
(frames 2..N), to compare speed on the same frames; take timings under
``flock /tmp/bench.lock`` on a shared machine.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
import zlib
from pathlib import Path

import numpy as np

from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from benchmarks._stage_clock import StageClock
from sptpt.params import get_preset
from sptpt.tracker import STAGES, Tracker

DEFAULT_SEQUENCES = ("Deer", "Crossing", "Coke", "Dog1")


def track(seq_dir: Path, preset: str, seed: int, frames: int) -> tuple[dict, dict, float, int]:
    """Boxes and per-frame results of the first ``frames`` frames; per-stage seconds, total s, frames."""
    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
    clock = StageClock()
    rng = np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(seq_dir.name.encode())]))
    tracker = Tracker(get_preset(preset), seed=rng, stage_timer=clock)
    boxes, loglik, accepted = [], [], []
    total = 0.0
    n = 0
    for position, (_, frame) in enumerate(open_frames(seq_dir, stop=frames)):
        clock.counting = position > 0  # the first frame's initialisation is not a stage of tracking
        tic = time.perf_counter()
        result = tracker.init(frame, gt[0]) if position == 0 else tracker.update(frame)
        if position > 0:
            total += time.perf_counter() - tic
            n += 1
        boxes.append(result.box_xywh)
        loglik.append(result.log_likelihood)
        accepted.append(result.accepted)
    out = dict(boxes=np.array(boxes), log_likelihood=np.array(loglik), accepted=np.array(accepted))
    return out, dict(clock.seconds), total, n


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--save", type=Path, help="directory to write reference boxes to")
    mode.add_argument("--compare", type=Path, help="directory of reference boxes to compare with")
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "otb")
    parser.add_argument("--sequences", default=",".join(DEFAULT_SEQUENCES))
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tol", type=float, default=1e-6, help="largest allowed box difference, px")
    args = parser.parse_args(argv)

    ok = True
    all_stages: dict[str, float] = collections.defaultdict(float)
    all_seconds = 0.0
    all_frames = 0
    for name in args.sequences.split(","):
        result, stages, seconds, n = track(args.root / name, args.preset, args.seed, args.frames)
        for key, value in stages.items():
            all_stages[key] += value
        all_seconds += seconds
        all_frames += n
        if args.save:
            args.save.mkdir(parents=True, exist_ok=True)
            np.savez(args.save / f"{name}.npz", **result)
            print(f"{name}: saved {len(result['boxes'])} boxes")
            continue
        saved = np.load(args.compare / f"{name}.npz")
        if len(saved["boxes"]) < len(result["boxes"]):
            print(f"{name}: only {len(saved['boxes'])} saved boxes for {len(result['boxes'])} frames")
            ok = False
            continue
        # A shorter run is compared with the first frames of the saved one.
        ref = {key: saved[key][: len(result["boxes"])] for key in ("boxes", "log_likelihood", "accepted")}
        diff = float(np.abs(ref["boxes"] - result["boxes"]).max())
        identical = bool(np.array_equal(ref["boxes"], result["boxes"]))
        same_accept = bool(np.array_equal(ref["accepted"], result["accepted"]))
        loglik_diff = float(np.abs(ref["log_likelihood"] - result["log_likelihood"]).max())
        verdict = "bit-identical" if identical else ("same to tol" if diff <= args.tol else "DIFFERENT")
        print(f"{name}: {verdict}; max box diff {diff:.3g} px; max log-likelihood diff {loglik_diff:.3g}; "
              f"acceptance {'same' if same_accept else 'DIFFERENT'}")
        ok &= diff <= args.tol and same_accept
    per_frame = {k: 1000.0 * all_stages[k] / max(all_frames, 1) for k in STAGES if k in all_stages}
    print("ms/frame (frames 2..N): " + ", ".join(f"{k} {v:.1f}" for k, v in per_frame.items())
          + f"; total {1000.0 * all_seconds / max(all_frames, 1):.1f} "
            f"({all_frames / max(all_seconds, 1e-9):.2f} frames/s)")
    return 0 if ok else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

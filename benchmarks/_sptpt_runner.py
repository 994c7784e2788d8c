"""Run SPTPT over OTB-layout sequences and store everything the benchmarks score.

Used by ``benchmarks/otb_benchmark.py``; one process per sequence. For each
sequence it writes ``<out>/<Seq>.txt`` (OTB, 1-based), ``<out>/times/<Seq>_time.txt``
and ``<out>/<Seq>.frames.npz`` (per-frame log-likelihood, confidence, accepted,
scoring, and with several independent runs every run's box, ``run_boxes``,
(frames, runs, 4) 0-based) so that flagging can be re-scored and each run
scored alone (``benchmarks/paired_runs.py``) without re-tracking.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from annotator.allocator import keep_freed_memory
from annotator.atomic import atomic_path
from annotator.frame_sources import open_frames
from annotator.nanotrack import guide_for
from annotator.otb_format import read_otb_boxes, write_otb_boxes, write_otb_times
from benchmarks._stage_clock import StageClock
from sptpt.params import TrackerParams
from sptpt.tracker import Tracker


def run_sequence(seq_dir: str, out_dir: str, params: dict, seed: int, name: str, stop: int | None = None) -> dict:
    """Track one sequence; return its timing record (per-stage seconds, frames, peak RSS)."""
    import resource

    import numba

    from sptpt.params import params_from_mapping

    keep_freed_memory()  # as the tool's processes do, so that frames/s here are the tool's
    seq_dir, out_dir = Path(seq_dir), Path(out_dir)
    tracker_params: TrackerParams = params_from_mapping(params)
    gt = read_otb_boxes(next(seq_dir.glob("groundtruth_rect*.txt")) if not (seq_dir / "groundtruth_rect.txt").exists()
                        else seq_dir / "groundtruth_rect.txt")
    clock = StageClock()
    tracker = Tracker(tracker_params, seed=np.random.default_rng(np.random.SeedSequence([seed, stable_id(name)])),
                      stage_timer=clock, guide=guide_for(tracker_params))
    boxes, seconds, loglik, conf, accepted, scoring, run_boxes, guide_boxes = [], [], [], [], [], [], [], []
    source = open_frames(seq_dir, stop=stop)
    for position, (_, frame) in enumerate(source):
        tic = time.perf_counter()
        result = tracker.init(frame, gt[0]) if position == 0 else tracker.update(frame)
        seconds.append(time.perf_counter() - tic)
        boxes.append(result.box_xywh)
        loglik.append(result.log_likelihood)
        conf.append(result.confidence)
        accepted.append(result.accepted)
        scoring.append(result.scoring)
        run_boxes.append(result.run_boxes_xywh)
        guide_boxes.append(result.guide_box_xywh)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "times").mkdir(exist_ok=True)
    write_otb_boxes(out_dir / f"{name}.txt", np.array(boxes), origin=1)
    write_otb_times(out_dir / "times" / f"{name}_time.txt", np.array(seconds))
    with atomic_path(out_dir / f"{name}.frames.npz") as tmp:
        with open(tmp, "wb") as handle:
            per_run = {} if run_boxes[0] is None else {"run_boxes": np.stack(run_boxes)}
            if guide_boxes[0] is not None:
                per_run["guide_boxes"] = np.stack(guide_boxes)
            np.savez(handle, log_likelihood=np.array(loglik), confidence=np.array(conf),
                     accepted=np.array(accepted), scoring=np.array(scoring), **per_run)
    return {
        "sequence": name,
        "frames": len(boxes),
        "seconds": float(np.sum(seconds)),
        "seconds_after_first": float(np.sum(seconds[1:])),
        "stages": dict(clock.seconds),
        "numba_threads": numba.get_num_threads(),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def stable_id(name: str) -> int:
    import zlib

    return zlib.crc32(name.encode())


if __name__ == "__main__":  # pragma: no cover
    import sys

    args = json.loads(sys.argv[1])
    print(json.dumps(run_sequence(**args)))

"""Score the review flags against ground truth from a saved OTB benchmark run, for the current defaults and a grid.

    python benchmarks/flag_tuning.py            # uses benchmarks/_runs/otb from otb_benchmark.py

Flagging only reads the per-frame log-likelihood, confidence and scoring
stage, which ``otb_benchmark.py`` stores beside each result file, so the
thresholds can be scored without tracking again. Quality is pooled over
frames and spans: precision and recall of flags for frames with IoU < 0.5,
the share of frames flagged, and onset recall (failure spans of at least 5
frames with a flag in their first 10 frames).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _results import machine_line, update_section  # noqa: E402

from annotator.evaluation import flag_quality_dataset  # noqa: E402
from annotator.evaluation.metrics import iou_xywh  # noqa: E402
from annotator.flagging import FlagParams, flag_frames  # noqa: E402
from annotator.otb import read_otb_boxes  # noqa: E402

GRID = {"margin": [0.0, 1.0, 2.0], "drop": [0.3, 0.5, 0.7], "recover": [0.8, 0.95, 1.0], "window": [30, 100]}


def load(runs: Path, otb: Path, preset: str) -> dict:
    data = {}
    for seq in sorted(p for p in otb.iterdir() if (p / "groundtruth_rect.txt").is_file()):
        frames = np.load(runs / preset / f"{seq.name}.frames.npz")
        pred = read_otb_boxes(runs / preset / f"{seq.name}.txt")
        gt = read_otb_boxes(seq / "groundtruth_rect.txt")[: len(pred)]
        data[seq.name] = (frames, iou_xywh(pred, gt))
    return data


def quality(data: dict, params: FlagParams):
    per = {}
    for name, (frames, ious) in data.items():
        result = flag_frames(frames["log_likelihood"], frames["confidence"], frames["scoring"], params,
                             keyframe=frames["scoring"] == "init")
        per[name] = (result.flagged, ious)
    return flag_quality_dataset(per).pooled


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=HERE / "_runs" / "otb")
    parser.add_argument("--otb", type=Path, default=HERE.parent.parent / "shared" / "otb")
    parser.add_argument("--presets", default="paper,fast")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args()
    presets = args.presets.split(",")
    data = {p: load(args.runs, args.otb, p) for p in presets}
    defaults = FlagParams()
    lines = ["## Review flags: quality of the default thresholds, and the grid they were chosen from", "",
             f"Command: `python benchmarks/flag_tuning.py {' '.join(sys.argv[1:])}`  ",
             f"Machine: {machine_line()}. Per-frame scores from the tracking run of `benchmarks/otb_benchmark.py` "
             "(section above; all 17 sequences, seed 0). The thresholds were tuned on these same sequences "
             "(the paper's evaluation set is held out of `../shared`), so expect some optimism.", "",
             "Defaults: " + ", ".join(f"`{k}={v}`" for k, v in dataclasses.asdict(defaults).items()) + ".", "",
             "| Preset | Flag precision | Flag recall | Flagged share | Onset recall | Targets (recall >= 0.8, precision >= 0.5, onset >= 0.8) |",
             "|---|---:|---:|---:|---:|---|"]
    for preset in presets:
        q = quality(data[preset], defaults)
        met = q.recall >= 0.8 and q.precision >= 0.5 and q.onset_recall >= 0.8
        lines.append(f"| {preset} | {q.precision:.3f} | {q.recall:.3f} | {q.flagged_share:.3f} | {q.onset_recall:.3f} | "
                     f"{'met' if met else 'missed'} |")
    lines += ["", "Grid (pooled over both presets' worst case; the 10 best by the lower of the two recalls):", "",
              "| margin | drop | recover | window | " + " | ".join(f"{p} prec / rec / onset" for p in presets) + " |",
              "|---:|---:|---:|---:|" + "---|" * len(presets)]
    rows = []
    for margin, drop, recover, window in itertools.product(*GRID.values()):
        params = dataclasses.replace(defaults, margin=margin, drop=drop, recover=recover, window=window)
        qs = [quality(data[p], params) for p in presets]
        rows.append((min(q.recall for q in qs), margin, drop, recover, window, qs))
    for _, margin, drop, recover, window, qs in sorted(rows, key=lambda r: -r[0])[:10]:
        lines.append(f"| {margin} | {drop} | {recover} | {window} | "
                     + " | ".join(f"{q.precision:.2f} / {q.recall:.2f} / {q.onset_recall:.2f}" for q in qs) + " |")
    markdown = "\n".join(lines)
    print(markdown)
    if not args.no_record:
        update_section("flags", markdown)


if __name__ == "__main__":
    main()

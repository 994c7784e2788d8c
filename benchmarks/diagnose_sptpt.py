"""Per-frame diagnosis of SPTPT on OTB sequences: when and why the target is lost.

    flock /tmp/bench.lock python -m benchmarks.diagnose_sptpt --preset paper --sequences Bolt2,Car4 --stop 120

For every frame it logs, next to the IoU with the ground truth: the winning
log-likelihood and whether it was accepted, the two reconstruction errors
(modes 1-2 and sample mode) of the winner under the positive and the negative
model, the log-likelihood the *ground-truth* box would have scored under the
same models (a model failure when it is below the winner's, a search failure
when the ground truth scores higher but no particle came near it), the spread
of the particle cloud (score-weighted std of the centres, px) and the scale
of the estimate against the ground truth's. It writes one ``.npz`` per
sequence and prints a summary of the first failure per sequence.

The models' view comes from :meth:`sptpt.tracker.Tracker.inspect`, which
scores boxes under the run's current models without changing the run, so the
boxes are the benchmark's.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from annotator.evaluation.metrics import iou_xywh
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from sptpt.params import TrackerParams, get_preset, params_from_mapping
from sptpt.tracker import Tracker

HERE = Path(__file__).resolve().parent


def diagnose(seq_dir: Path, params: TrackerParams, seed: int, stop: int | None) -> dict[str, np.ndarray]:
    import zlib

    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
    # Same seeding as benchmarks/_sptpt_runner.py, so the boxes equal the benchmark's.
    tracker = Tracker(params,
                      seed=np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(seq_dir.name.encode())])))
    rows: dict[str, list] = {k: [] for k in (
        "iou", "log_likelihood", "accepted", "scoring", "pos_modes", "pos_sample", "neg_modes", "neg_sample",
        "gt_log_likelihood", "spread_px", "scale", "gt_scale", "positive_batches", "pos_rank3", "neg_rank3",
        "centre_error_px")}
    for k, (_, frame) in enumerate(open_frames(seq_dir, stop=stop)):
        if k == 0:
            result = tracker.init(frame, gt[0])
            continue
        result = tracker.update(frame, details=True)
        box = result.box_xywh
        rows["iou"].append(float(iou_xywh(box[None], gt[k][None])[0]))
        rows["centre_error_px"].append(float(np.hypot(*(box[:2] + box[2:] / 2 - gt[k][:2] - gt[k][2:] / 2))))
        rows["log_likelihood"].append(result.log_likelihood)
        rows["accepted"].append(result.accepted)
        rows["scoring"].append(result.scoring)
        # The run's estimate as a box (row 0: inspect() takes boxes, so any rotation or skew of its state is left
        # out) and the ground truth (row 1), scored by the models as they are *after* this frame's update: the
        # winner's own score would mix two models; re-scoring with the current ones is close enough for a
        # diagnosis. (Run 0: main() refuses several. With negative_rank_matched, neg_* are of the negative model
        # truncated to the positive's rank, as it scores.)
        estimate = tracker.inspect(frame).estimate_xywh[0]
        inspection = tracker.inspect(frame, [estimate, gt[k]])
        for key, field in (("pos_modes", "positive_error_modes"), ("pos_sample", "positive_error_sample"),
                           ("neg_modes", "negative_error_modes"), ("neg_sample", "negative_error_sample")):
            rows[key].append(float(getattr(inspection, field)[0, 0]))
        # RE- - RE+ only: before both models exist the run's score is the bootstrap intersection, not logged here.
        rows["gt_log_likelihood"].append(float(inspection.log_likelihood[0, 1]) if inspection.subspace[0]
                                         else float("nan"))
        scores = result.particle_scores
        w = np.exp(scores - scores.max())
        w /= w.sum()
        centres = result.particles_xywh[:, :2] + result.particles_xywh[:, 2:] / 2
        mean = (w[:, None] * centres).sum(0)
        rows["spread_px"].append(float(np.sqrt((w * ((centres - mean) ** 2).sum(1)).sum())))
        rows["scale"].append(float(box[2] * box[3]) ** 0.5)
        rows["gt_scale"].append(float(gt[k][2] * gt[k][3]) ** 0.5)
        rows["positive_batches"].append(int(inspection.positive_updates[0]))
        rows["pos_rank3"].append(int(inspection.positive_ranks[0, 2]))
        rows["neg_rank3"].append(int(inspection.negative_ranks[0, 2]))
    return {k: np.array(v) for k, v in rows.items()}


def summary(name: str, d: dict[str, np.ndarray]) -> dict:
    n = len(d["iou"])
    lost = np.flatnonzero(d["iou"] < 0.1)
    first_lost = int(lost[0]) + 2 if lost.size else None  # 1-based frame number
    sub = d["scoring"] == "subspace"
    return {
        "sequence": name,
        "frames": n + 1,
        "mean_iou": round(float(d["iou"].mean()), 3),
        "first_frame_iou_below_0.1": first_lost,
        "accept_rate_subspace": round(float(d["accepted"][sub].mean()), 3) if sub.any() else None,
        "positive_batches": int(d["positive_batches"][-1]),
        "median_ll_subspace": round(float(np.median(d["log_likelihood"][sub])), 2) if sub.any() else None,
        "median_pos_re_sample": round(float(np.nanmedian(d["pos_sample"][sub])), 2) if sub.any() else None,
        "median_neg_re_sample": round(float(np.nanmedian(d["neg_sample"][sub])), 2) if sub.any() else None,
        "share_gt_scores_below_winner": round(float(np.mean(d["gt_log_likelihood"][sub] < d["log_likelihood"][sub])), 3)
        if sub.any() else None,
        "share_gt_rejected": round(float(np.mean(d["gt_log_likelihood"][sub] <= 0)), 3) if sub.any() else None,
        "median_spread_px": round(float(np.median(d["spread_px"])), 1),
        "scale_ratio_last": round(float(d["scale"][-1] / d["gt_scale"][-1]), 2),
        "ranks_pos_neg_sample_last": [int(d["pos_rank3"][-1]), int(d["neg_rank3"][-1])],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--otb", type=Path, default=HERE.parent.parent / "shared" / "otb")
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--sequences", required=True)
    parser.add_argument("--stop", type=int, default=120)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", default="{}", help='JSON overrides of the preset, e.g. \'{"negative_rank_matched": '
                                                    'true}\'')
    parser.add_argument("--label", default=None, help="output folder name (default: the preset)")
    parser.add_argument("--out", type=Path, default=HERE / "_runs" / "diagnosis")
    args = parser.parse_args()
    params = params_from_mapping(json.loads(args.set), base=get_preset(args.preset))
    if params.independent_runs != 1:
        parser.error(f"--preset {args.preset} tracks {params.independent_runs} independent runs; this diagnosis "
                     "inspects one run's models: add --set '{\"independent_runs\": 1}'")
    out = args.out / (args.label or args.preset)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.sequences.split(","):
        d = diagnose(args.otb / name, params, args.seed, args.stop)
        np.savez(out / f"{name}.seed{args.seed}.npz", **d)
        print(json.dumps(summary(name, d)), flush=True)


if __name__ == "__main__":
    sys.exit(main())

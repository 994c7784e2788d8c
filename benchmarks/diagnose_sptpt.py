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

It reads the tracker's private models on purpose: this is a diagnostic, not
part of the tool.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from annotator.evaluation.metrics import iou_xywh
from annotator.frames import open_frames
from annotator.otb import read_otb_boxes
from sptpt.affine import state_from_box_xywh
from sptpt.params import TrackerParams, get_preset, params_from_mapping
from sptpt.subspace import reconstruction_error
from sptpt.tracker import Tracker

HERE = Path(__file__).resolve().parent


def _errors(run, codes: np.ndarray) -> dict[str, np.ndarray]:
    p = run.params
    out = {}
    for name, model in (("pos", run._positive), ("neg", run._negative)):
        if model is None:
            out[f"{name}_modes"] = out[f"{name}_sample"] = out[f"{name}_re"] = np.full(len(codes), np.nan)
            continue
        modes, sample = model.errors(codes)
        out[f"{name}_modes"], out[f"{name}_sample"] = modes, sample
        out[f"{name}_re"] = reconstruction_error(model, codes, gamma=p.gamma, mode=p.re_mode)
    return out


def diagnose(seq_dir: Path, params: TrackerParams, seed: int, stop: int | None) -> dict[str, np.ndarray]:
    import zlib

    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
    # Same seeding as benchmarks/_sptpt_runner.py, so the boxes equal the benchmark's.
    tracker = Tracker(params, seed=np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(seq_dir.name.encode())])))
    run = tracker._runs[0]  # the one run (main() refuses several): its models and state
    rows: dict[str, list] = {k: [] for k in (
        "iou", "log_likelihood", "accepted", "scoring", "pos_modes", "pos_sample", "neg_modes", "neg_sample",
        "gt_log_likelihood", "spread_px", "scale", "gt_scale", "positive_batches", "pos_rank3", "neg_rank3",
        "centre_error_px")}
    batches = 0
    for k, (_, frame) in enumerate(open_frames(seq_dir, stop=stop)):
        if k == 0:
            result = tracker.init(frame, gt[0])
            continue
        had_positive = run._positive
        result = tracker.update(frame, details=True)
        if run._positive is not had_positive:
            batches += 1
        box = result.box_xywh
        rows["iou"].append(float(iou_xywh(box[None], gt[k][None])[0]))
        rows["centre_error_px"].append(float(np.hypot(*(box[:2] + box[2:] / 2 - gt[k][:2] - gt[k][2:] / 2))))
        rows["log_likelihood"].append(result.log_likelihood)
        rows["accepted"].append(result.accepted)
        rows["scoring"].append(result.scoring)
        # Errors of the winner and of the ground truth under the models as they are *after* this frame's
        # update would mix two models; re-scoring the winner with the current models is close enough for
        # a diagnosis and identical whenever the frame was rejected.
        rgb = np.ascontiguousarray(frame if frame.ndim == 3 else np.repeat(frame[:, :, None], 3, axis=2))
        states = np.stack([run._state, state_from_box_xywh(gt[k], params.template_size)])
        features, _ = run._features(rgb, states)
        codes = run._code(features)
        errs = _errors(run, codes)
        for key in ("pos_modes", "pos_sample", "neg_modes", "neg_sample"):
            rows[key].append(float(errs[key][0]))
        rows["gt_log_likelihood"].append(float(errs["neg_re"][1] - errs["pos_re"][1]))
        scores = result.particle_scores
        w = np.exp(scores - scores.max())
        w /= w.sum()
        centres = result.particles_xywh[:, :2] + result.particles_xywh[:, 2:] / 2
        mean = (w[:, None] * centres).sum(0)
        rows["spread_px"].append(float(np.sqrt((w * ((centres - mean) ** 2).sum(1)).sum())))
        rows["scale"].append(float(box[2] * box[3]) ** 0.5)
        rows["gt_scale"].append(float(gt[k][2] * gt[k][3]) ** 0.5)
        rows["positive_batches"].append(batches)
        rows["pos_rank3"].append(0 if run._positive is None else run._positive.sample.basis.shape[1])
        rows["neg_rank3"].append(0 if run._negative is None else run._negative.sample.basis.shape[1])
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
    parser.add_argument("--set", default="{}", help='JSON overrides of the preset, e.g. \'{"negative_rank_matched": true}\'')
    parser.add_argument("--label", default=None, help="output folder name (default: the preset)")
    parser.add_argument("--out", type=Path, default=HERE / "_runs" / "diagnosis")
    args = parser.parse_args()
    params = params_from_mapping(json.loads(args.set), base=get_preset(args.preset))
    if params.independent_runs != 1:
        parser.error(f"--preset {args.preset} tracks {params.independent_runs} independent runs; this diagnosis "
                     "reads one run's models: add --set '{\"independent_runs\": 1}'")
    out = args.out / (args.label or args.preset)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.sequences.split(","):
        d = diagnose(args.otb / name, params, args.seed, args.stop)
        np.savez(out / f"{name}.seed{args.seed}.npz", **d)
        print(json.dumps(summary(name, d)), flush=True)


if __name__ == "__main__":
    sys.exit(main())

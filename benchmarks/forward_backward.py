"""Does a backward pass pay? Forward, then backward from a late confident frame, merged per frame.

    python -m benchmarks.forward_backward --preset robust --seeds 0,1,2 --out benchmarks/_runs/fb
    # the merge rules again on the stored passes, no tracking:
    python -m benchmarks.forward_backward --seeds 0,1,2 --out benchmarks/_runs/fb --rescore

For every sequence of an OTB-layout root and every seed, the tracker runs
forward from the ground-truth box of the first frame, exactly as the
benchmark does. The backward pass then starts at the *end anchor*: the last
frame that closes a run of ``--stable`` consecutive accepted forward frames
(the forward pass's own claim that it holds the target there), from the
forward box of that frame, and runs back to frame 1. Frames before the
anchor take their box from one pass or the other by a merge rule of
``annotator.review.merge``; frames after it keep the forward box. Each
pass's per-frame results are stored, so merge rules can be compared without
tracking again (``--rescore``).

Reports the success AUC of the forward pass alone and of each merge, mean
and standard deviation over seeds, per sequence and overall, and the cost of
the second pass in frames per second of both passes together.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from annotator.evaluation.metrics import evaluate_sequence
from annotator.otb_format import read_otb_boxes
from annotator.review.merge import MERGES, PassResult, merge_passes
from benchmarks._sequences import SequenceError, select_sequences

ROOT = Path(__file__).resolve().parents[1]

FIELDS = ("boxes_xywh", "confidence", "log_likelihood", "accepted", "scoring", "seconds")


def end_anchor(accepted: np.ndarray, stable: int) -> int | None:
    """Last frame closing ``stable`` consecutive accepted frames (frame 0 excluded); None if there is none."""
    run = 0
    best = None
    for t in range(1, len(accepted)):
        run = run + 1 if accepted[t] else 0
        if run >= stable:
            best = t
    return best


def _run_pass(tracker, frames, box) -> dict:
    rows = {k: [] for k in FIELDS}
    for k, frame in enumerate(frames):
        tic = time.perf_counter()
        result = tracker.init(frame, box) if k == 0 else tracker.update(frame)
        rows["seconds"].append(time.perf_counter() - tic)
        rows["boxes_xywh"].append(result.box_xywh)
        rows["confidence"].append(result.confidence)
        rows["log_likelihood"].append(result.log_likelihood)
        rows["accepted"].append(result.accepted)
        rows["scoring"].append(result.scoring)
    return {k: np.array(v) for k, v in rows.items()}


def track_sequence(job: dict) -> dict:
    import numba

    numba.set_num_threads(job["threads"])
    from annotator.frame_sources import open_frames
    from benchmarks._sptpt_runner import stable_id
    from sptpt.params import get_preset
    from sptpt.tracker import Tracker

    seq_dir, name, seed = Path(job["seq_dir"]), job["name"], job["seed"]
    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
    frames = [frame for _, frame in open_frames(seq_dir)]
    params = get_preset(job["preset"])
    # The forward pass uses the benchmark's generator, so it equals otb_benchmark's run of the same seed.
    rng = np.random.default_rng(np.random.SeedSequence([seed, stable_id(name)]))
    fwd = _run_pass(Tracker(params, seed=rng), frames, gt[0])
    anchor = end_anchor(fwd["accepted"], job["stable"])
    out = {f"fwd_{k}": v for k, v in fwd.items()}
    out["anchor"] = -1 if anchor is None else anchor
    if anchor is not None:
        rng_b = np.random.default_rng(np.random.SeedSequence([seed, stable_id(name), 1]))
        bwd = _run_pass(Tracker(params, seed=rng_b), frames[anchor::-1], fwd["boxes_xywh"][anchor])
        out.update({f"bwd_{k}": v[::-1] for k, v in bwd.items()})  # frame order 0..anchor
    path = pass_path(Path(job["out"]), name, seed)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(path)
    return {"name": name, "seed": seed}


def pass_path(out: Path, name: str, seed: int) -> Path:
    """Where the forward and backward passes of one sequence and seed are stored."""
    return out / f"{name}.s{seed}.npz"


def merged_boxes(run: dict, method: str) -> np.ndarray:
    """Forward boxes, with frames 1..anchor-1 taken from the forward or backward pass by ``method``."""
    boxes = run["fwd_boxes_xywh"].copy()
    anchor = int(run["anchor"])
    if anchor < 2:
        return boxes
    inner = slice(1, anchor)
    fwd = PassResult(*(run[f"fwd_{k}"][inner] for k in FIELDS))
    bwd = PassResult(*(run[f"bwd_{k}"][inner] for k in FIELDS))
    boxes[inner] = merge_passes(fwd, bwd, method).boxes_xywh
    return boxes


def score(out: Path, sequences: dict[str, Path], seeds: list[int]) -> dict:
    table: dict[str, dict[str, list[float]]] = {}
    timing = {"fwd": 0.0, "bwd": 0.0, "frames": 0}
    for name, seq_dir in sequences.items():
        gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
        for seed in seeds:
            run = dict(np.load(pass_path(out, name, seed), allow_pickle=True))
            methods = {"forward": run["fwd_boxes_xywh"]}
            methods.update({m: merged_boxes(run, m) for m in MERGES})
            for method, boxes in methods.items():
                auc = evaluate_sequence(boxes, gt, name=name).auc
                table.setdefault(name, {}).setdefault(method, []).append(auc)
            timing["fwd"] += float(run["fwd_seconds"][1:].sum())
            timing["bwd"] += float(run["bwd_seconds"][1:].sum()) if "bwd_seconds" in run else 0.0
            timing["frames"] += len(gt) - 1
    return {"table": table, "timing": timing}


def report(result: dict, seeds: list[int]) -> str:
    table = result["table"]
    methods = ["forward", *MERGES]
    lines = ["| Sequence | " + " | ".join(methods) + " |", "|---|" + "---:|" * len(methods)]
    per_seed = {m: np.zeros(len(seeds)) for m in methods}
    for name in sorted(table):
        cells = []
        for m in methods:
            values = np.array(table[name][m])
            per_seed[m] += values / len(table)
            cells.append(f"{values.mean():.3f} ± {values.std():.3f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("| **mean over sequences** | " + " | ".join(
        f"{per_seed[m].mean():.3f} ± {per_seed[m].std():.3f}" for m in methods) + " |")
    t = result["timing"]
    lines.append("")
    lines.append(f"Forward pass {t['frames'] / t['fwd']:.1f} frames/s; "
                 f"both passes {t['frames'] / (t['fwd'] + t['bwd']):.1f} "
                 f"frames/s (tracker time over frames 2..N, init excluded).")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--otb", default=str(ROOT.parent / "shared" / "otb"))
    parser.add_argument("--preset", default="robust")
    parser.add_argument("--sequences", default=None, help="comma-separated names, or 'all' (the default: every "
                                                          "sequence)")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--stable", type=int, default=10, help="accepted frames in a row that make the end anchor")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "_runs" / "fb"))
    parser.add_argument("--rescore", action="store_true", help="score stored passes only")
    args = parser.parse_args()
    try:
        sequences = {p.name: p for p in select_sequences(args.otb, args.sequences)}
    except SequenceError as err:
        parser.error(str(err))
    seeds = [int(s) for s in args.seeds.split(",")]
    out = Path(args.out)
    if args.rescore:
        missing = [pass_path(out, n, s).name for s in seeds for n in sequences if not pass_path(out, n, s).is_file()]
        if missing:
            parser.error(f"--rescore: {out} lacks the stored passes {missing[:3]}{' ...' if len(missing) > 3 else ''}; "
                         "track them first (the same command without --rescore)")
    out.mkdir(parents=True, exist_ok=True)
    if not args.rescore:
        jobs = [dict(seq_dir=str(d), name=n, seed=s, preset=args.preset, stable=args.stable, out=str(out),
                     threads=1 if args.workers > 1 else 2)
                for s in seeds for n, d in sequences.items()]
        tic = time.perf_counter()
        if args.workers > 1:
            with ProcessPoolExecutor(args.workers) as pool:
                list(pool.map(track_sequence, jobs))
        else:
            for job in jobs:
                track_sequence(job)
        print(f"tracked {len(jobs)} sequence-seeds in {time.perf_counter() - tic:.0f} s", file=sys.stderr)
        (out / "run.json").write_text(json.dumps(vars(args), indent=1))
    print(report(score(out, sequences, seeds), seeds))


if __name__ == "__main__":
    main()

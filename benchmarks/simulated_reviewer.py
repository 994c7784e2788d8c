"""Simulated reviewer: how many corrections the review loop needs, against keyframe interpolation.

    python benchmarks/simulated_reviewer.py                                  # default subset, records RESULTS.md
    python benchmarks/simulated_reviewer.py --sequences Deer,Crossing --no-record
    python benchmarks/simulated_reviewer.py --sequences all --budget 40

Per OTB sequence (frames held in memory, the tracker driven through
:func:`annotator.review.retrack_tracks`; no files are written):

1. **Simulated reviewer.** Track from the first ground-truth box. Then,
   until at least ``--target`` (95%) of the frames have IoU >= 0.5 with the
   ground truth, or ``--budget`` corrections per 100 frames are spent:
   take the flagged frame with the lowest confidence, replace its box by
   the ground truth, and re-track the spans it affects (forward and
   backward between anchors, as ``sptpt-annotate retrack`` does). When no
   frame is flagged but the target is not met, the tool gives no hint; the
   reviewer then (``--fallback first-wrong``, default) scrubs the overlay
   and corrects the first frame whose box is wrong (IoU < 0.5), or
   (``lowest-confidence``) the least confident frame not yet an anchor.
   Count the corrections; the first-frame box is given, not counted.
   Passes from unchanged anchors are reused through ``pass_cache`` (they
   are deterministic), which halves the tracking and changes no number.
2. **Interpolation baseline** (what interpolation-based tools do): the
   ground truth on frames 0, k, 2k, ... and the last frame, linear
   interpolation of ``x, y, w, h`` in between. The largest k that reaches
   the same target gives its corrections (again not counting frame 0). This
   is the baseline's best case: a real user does not know the right k.
3. **Merge study** (``--merge-study M``): ground truth every M frames,
   forward and backward passes between them, and the share of frames with
   IoU >= 0.5 for each way of merging the two passes
   (:data:`annotator.review.MERGES`), forward only and backward only.
   It measures on the same passes, so it costs one forward and one
   backward pass per sequence, and it is what chose ``DEFAULT_MERGE``.

Corrections per 100 frames are pooled over the sequences (total
corrections / total frames x 100). Tracker settings: ``--preset`` (default
``fast`` when ``sptpt.params.PRESETS`` has it, else ``paper`` with
``n_particles`` and ``n_negatives`` lowered to ``--particles`` /
``--negatives`` so that the loop fits in minutes; the figures printed say
which). Flags use the run defaults (:class:`annotator.flagging.FlagParams`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _results import machine_line, update_section  # noqa: E402

from annotator.config import RunConfig  # noqa: E402
from annotator.flagging import FlagParams  # noqa: E402
from annotator.frames import open_frames  # noqa: E402
from annotator.otb import read_otb_boxes  # noqa: E402
from annotator.review import DEFAULT_MERGE, MERGES, ArrayFrames, PreviousTrack, merge_passes, retrack_tracks  # noqa: E402
from sptpt.params import PRESETS, get_preset, params_from_mapping  # noqa: E402

DEFAULT_SUBSET = ("Deer", "Skiing", "Crossing", "Couple", "Diving", "Jogging.1", "Bolt2")


def iou_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise IoU of (N, 4) xywh boxes, 0 for NaN rows (as the toolkits score them)."""
    from annotator.evaluation.metrics import iou_xywh

    iou = np.asarray(iou_xywh(a, b), dtype=np.float64)
    return np.where(np.isfinite(iou), iou, 0.0)


def success_share(boxes: np.ndarray, gt: np.ndarray, threshold: float) -> float:
    return float(np.mean(iou_rows(boxes, gt) >= threshold))


def interpolate(gt: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Linear interpolation of x, y, w, h between the ground truth at ``keys`` (sorted, including 0 and N-1)."""
    t = np.arange(len(gt))
    return np.stack([np.interp(t, keys, gt[keys, j]) for j in range(4)], axis=1)


def interpolation_baseline(gt: np.ndarray, target: float, threshold: float) -> dict:
    """The largest keyframe interval k whose interpolation reaches ``target``, and its corrections."""
    n = len(gt)
    best = None
    for k in range(1, n):
        keys = np.unique(np.concatenate([np.arange(0, n, k), [n - 1]]))
        share = success_share(interpolate(gt, keys), gt, threshold)
        if share >= target:
            best = {"k": k, "corrections": int(len(keys) - 1), "success": share}
    assert best is not None  # k = 1 is the ground truth itself
    return best


def load_sequence(seq_dir: Path, stop: int | None) -> tuple[list[np.ndarray], np.ndarray]:
    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
    source = open_frames(seq_dir, stop=stop)
    frames = [frame for _, frame in source]
    return frames, gt[: len(frames)]


def merge_study(frames, gt, config: RunConfig, every: int, threshold: float) -> dict:
    """Share of interior frames with IoU >= threshold for each merge, forward only and backward only."""
    n = len(frames)
    anchors = {p: tuple(gt[p]) for p in range(0, n, every)}
    if n - 1 not in anchors:
        anchors[n - 1] = tuple(gt[n - 1])
    result = retrack_tracks(ArrayFrames(frames), np.arange(n), {1: anchors}, config)
    hits: dict[str, list[np.ndarray]] = {m: [] for m in (*MERGES, "forward only", "backward only")}
    for (_, start, stop), (fwd, bwd) in result.passes.items():
        if bwd is None or stop - start < 2:
            continue
        truth = gt[start + 1 : stop]
        for m in MERGES:
            hits[m].append(iou_rows(merge_passes(fwd, bwd, m).boxes_xywh, truth))
        hits["forward only"].append(iou_rows(fwd.boxes_xywh, truth))
        hits["backward only"].append(iou_rows(bwd.boxes_xywh, truth))
    out = {}
    for m, parts in hits.items():
        iou = np.concatenate(parts) if parts else np.zeros(0)
        out[m] = {"frames": int(iou.size), "success": float(np.mean(iou >= threshold)) if iou.size else math.nan,
                  "mean_iou": float(iou.mean()) if iou.size else math.nan}
    out["tracker_calls"] = result.frames_tracked
    return out


def simulated_reviewer(frames, gt, config: RunConfig, *, merge: str, target: float, threshold: float,
                       budget: int, fallback: str) -> dict:
    n = len(frames)
    provider = ArrayFrames(frames)
    indices = np.arange(n)
    cache: dict = {}  # passes from unchanged anchors are reused, not re-run (identical results, half the time)
    tic = time.perf_counter()
    result = retrack_tracks(provider, indices, {1: {0: tuple(gt[0])}}, config, merge=merge, pass_cache=cache)
    calls = result.frames_tracked
    track, scoring = result.tracks[0], result.scoring[1]
    curve = [success_share(track.boxes_xywh, gt, threshold)]
    corrections, fallbacks = [], 0
    while curve[-1] < target and len(corrections) < budget:
        candidates = track.flagged & ~track.keyframe
        if candidates.any():
            position = int(np.argmin(np.where(candidates, track.confidence, np.inf)))
        else:
            # Nothing flagged, target not met: the tool gave no hint.
            fallbacks += 1
            if fallback == "first-wrong":  # the reviewer scrubs the overlay and fixes the first wrong box
                wrong = (iou_rows(track.boxes_xywh, gt) < threshold) & ~track.keyframe
            else:  # "lowest-confidence": the reviewer trusts the confidence alone
                wrong = ~track.keyframe
            if not wrong.any():
                break
            position = int(np.argmax(wrong)) if fallback == "first-wrong" else int(
                np.argmin(np.where(wrong, track.confidence, np.inf)))
        corrections.append(position)
        result = retrack_tracks(provider, indices, {1: {position: tuple(gt[position])}}, config, merge=merge,
                                previous={1: PreviousTrack(track, scoring)}, pass_cache=cache)
        calls += result.frames_tracked
        track, scoring = result.tracks[0], result.scoring[1]
        curve.append(success_share(track.boxes_xywh, gt, threshold))
    return {
        "frames": n,
        "corrections": len(corrections),
        "reached": curve[-1] >= target,
        "initial_success": curve[0],
        "final_success": curve[-1],
        "corrected_frames": corrections,
        "fallbacks": fallbacks,
        "curve": curve,
        "tracker_calls": calls,
        "seconds": time.perf_counter() - tic,
    }


def run_sequence(job: dict) -> dict:
    import numba

    if job.get("threads"):
        numba.set_num_threads(job["threads"])
    seq_dir = Path(job["seq_dir"])
    config = RunConfig(preset=job["preset"], tracker=params_from_mapping(job["params"]), flags=FlagParams(),
                       seed=job["seed"])
    frames, gt = load_sequence(seq_dir, job["stop"])
    record = {"sequence": seq_dir.name, "frames": len(frames)}
    record["baseline"] = interpolation_baseline(gt, job["target"], job["threshold"])
    if job["merge_study"]:
        tic = time.perf_counter()
        record["merge_study"] = merge_study(frames, gt, config, job["merge_study"], job["threshold"])
        record["merge_study"]["seconds"] = time.perf_counter() - tic
    if not job["skip_reviewer"]:
        budget = max(1, math.ceil(job["budget"] * len(frames) / 100))
        record["reviewer"] = simulated_reviewer(frames, gt, config, merge=job["merge"], target=job["target"],
                                                threshold=job["threshold"], budget=budget, fallback=job["fallback"])
    print(json.dumps({k: v for k, v in record.items() if k != "merge_study"} | {
        "reviewer": {k: v for k, v in record.get("reviewer", {}).items() if k not in ("curve",)}}), file=sys.stderr,
        flush=True)
    return record


def per100(corrections: int, frames: int) -> float:
    return 100.0 * corrections / frames if frames else math.nan


def markdown(records: list[dict], args, preset_text: str, seconds: float, command: str) -> str:
    lines = ["## Simulated reviewer", "",
             f"Command: `{command}`  ",
             f"Machine: {machine_line()}; shared with other processes. Wall time {seconds / 60:.1f} min.  ",
             f"Tracker: {preset_text}; seed {args.seed}; flags: run defaults. Target: {100 * args.target:.0f}% of frames "
             f"with IoU >= {args.threshold} with the ground truth; budget {args.budget:g} corrections per 100 frames.  ",
             f"Sequences: {', '.join(r['sequence'] for r in records)} (frames {'1..' + str(args.stop) if args.stop else 'all'})."
             , ""]
    if not args.skip_reviewer:
        fallback_text = ("the first frame whose box is wrong, IoU < the threshold, as a reviewer scrubbing the overlay "
                         "finds it" if args.fallback == "first-wrong" else "the least confident non-anchor frame")
        lines += ["Reviewer: repeatedly correct the flagged frame with the lowest confidence (when nothing is flagged "
                  f"but the target is not met: {fallback_text}; counted as 'fallback picks'), re-track forward and "
                  "backward between anchors "
                  f"(merge `{args.merge}`), stop at the target. Baseline: ground truth every k-th frame plus the "
                  "last, linear interpolation, the largest k that reaches the target (its best case). The given "
                  "first-frame box is not counted in either.", "",
                  "| sequence | frames | success before review | reviewer corrections | per 100 frames | reached | "
                  "fallback picks | baseline k | baseline corrections | per 100 frames | ratio |",
                  "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|"]
        tot_f = tot_r = tot_b = 0
        for r in records:
            rv, b = r["reviewer"], r["baseline"]
            tot_f += r["frames"]
            tot_r += rv["corrections"]
            tot_b += b["corrections"]
            ratio = rv["corrections"] / b["corrections"] if b["corrections"] else math.nan
            lines.append(f"| {r['sequence']} | {r['frames']} | {100 * rv['initial_success']:.1f}% | {rv['corrections']} | "
                         f"{per100(rv['corrections'], r['frames']):.2f} | {'yes' if rv['reached'] else 'no (budget)'} | "
                         f"{rv['fallbacks']} | {b['k']} | {b['corrections']} | {per100(b['corrections'], r['frames']):.2f} | "
                         f"{ratio:.2f} |")
        ratio = tot_r / tot_b if tot_b else math.nan
        lines.append(f"| **pooled** | {tot_f} | | {tot_r} | **{per100(tot_r, tot_f):.2f}** | | | | {tot_b} | "
                     f"**{per100(tot_b, tot_f):.2f}** | **{ratio:.2f}** |")
        verdict = "meets" if ratio <= 0.5 and all(r["reviewer"]["reached"] for r in records) else "misses"
        lines += ["", f"Target (at most half the baseline's corrections): **{verdict}** it, ratio {ratio:.2f}."
                  + ("" if all(r["reviewer"]["reached"] for r in records) else
                     " Sequences marked 'no (budget)' stopped at the budget, so their count is a lower bound.")]
    if args.merge_study:
        methods = [*MERGES, "forward only", "backward only"]
        lines += ["", f"Merge study: ground truth every {args.merge_study} frames; frames strictly between anchors; "
                  "share with IoU >= 0.5 (mean IoU).", "",
                  "| sequence | " + " | ".join(methods) + " |", "|---|" + "---:|" * len(methods)]
        pooled = {m: [0, 0.0, 0.0] for m in methods}
        for r in records:
            ms = r["merge_study"]
            cells = []
            for m in methods:
                cells.append(f"{100 * ms[m]['success']:.1f}% ({ms[m]['mean_iou']:.2f})")
                pooled[m][0] += ms[m]["frames"]
                pooled[m][1] += ms[m]["success"] * ms[m]["frames"]
                pooled[m][2] += ms[m]["mean_iou"] * ms[m]["frames"]
            lines.append(f"| {r['sequence']} | " + " | ".join(cells) + " |")
        lines.append("| **pooled** | " + " | ".join(
            f"**{100 * pooled[m][1] / pooled[m][0]:.1f}%** ({pooled[m][2] / pooled[m][0]:.2f})" if pooled[m][0] else ""
            for m in methods) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--otb", type=Path, default=HERE.parent.parent / "shared" / "otb")
    parser.add_argument("--sequences", default=",".join(DEFAULT_SUBSET), help="comma-separated names, or 'all'")
    parser.add_argument("--stop", type=int, default=None, help="only the first N frames of each sequence")
    parser.add_argument("--preset", default="fast" if "fast" in PRESETS else "paper")
    parser.add_argument("--particles", type=int, default=120,
                        help="n_particles when the preset is 'paper' (ignored for other presets)")
    parser.add_argument("--negatives", type=int, default=60,
                        help="n_negatives when the preset is 'paper' (ignored for other presets)")
    parser.add_argument("--merge", default=DEFAULT_MERGE, choices=MERGES)
    parser.add_argument("--merge-study", type=int, default=0, metavar="M",
                        help="also compare merges with ground truth every M frames (0: skip)")
    parser.add_argument("--fallback", default="first-wrong", choices=("first-wrong", "lowest-confidence"),
                        help="the reviewer's pick when no frame is flagged but the target is not met")
    parser.add_argument("--skip-reviewer", action="store_true", help="only the baseline and the merge study")
    parser.add_argument("--target", type=float, default=0.95)
    parser.add_argument("--threshold", type=float, default=0.5)
    parser.add_argument("--budget", type=float, default=30.0, help="max corrections per 100 frames")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=HERE / "_runs" / "simulated_reviewer.json")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = parser.parse_args()

    all_sequences = sorted(p for p in args.otb.iterdir() if (p / "groundtruth_rect.txt").is_file())
    if args.sequences != "all":
        wanted = [s for s in args.sequences.split(",") if s]
        names = {p.name: p for p in all_sequences}
        missing = [s for s in wanted if s not in names]
        if missing:
            parser.error(f"unknown sequences {missing}; found {sorted(names)}")
        all_sequences = [names[s] for s in wanted]
    params = get_preset(args.preset)
    preset_text = f"preset `{args.preset}`"
    if args.preset == "paper":
        params = dataclasses.replace(params, n_particles=args.particles, n_negatives=args.negatives)
        preset_text = (f"preset `paper` with n_particles={args.particles} and n_negatives={args.negatives} "
                       "(no `fast` preset in sptpt.params.PRESETS)")
    jobs = [dict(seq_dir=str(s), params=params.to_dict(), preset=args.preset, seed=args.seed, stop=args.stop,
                 target=args.target, threshold=args.threshold, budget=args.budget, merge=args.merge,
                 merge_study=args.merge_study, skip_reviewer=args.skip_reviewer, fallback=args.fallback,
                 threads=1 if args.workers > 1 else 0) for s in all_sequences]
    started = time.perf_counter()
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn")) as pool:
            records = list(pool.map(run_sequence, jobs))
    else:
        records = [run_sequence(job) for job in jobs]
    seconds = time.perf_counter() - started
    command = "python benchmarks/simulated_reviewer.py " + " ".join(sys.argv[1:])
    text = markdown(records, args, preset_text, seconds, command.strip())
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": command, "records": records}, indent=1, default=float) + "\n")
    if not args.no_record:
        if args.skip_reviewer:
            update_section("simulated-reviewer-merge-study",
                           text.replace("## Simulated reviewer", "## Simulated reviewer: merge study", 1))
        else:
            update_section("simulated-reviewer", text)


if __name__ == "__main__":
    main()

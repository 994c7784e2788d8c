"""Simulated reviewer: the human seconds the review loop needs, against keyframe interpolation.

    python -m benchmarks.simulated_reviewer  # default subset, seeds 0,1,2, records RESULTS.md
    python -m benchmarks.simulated_reviewer --sequences Deer,Crossing --stop 100 --seeds 0 --no-record
    python -m benchmarks.simulated_reviewer --sequences all --budget 40
    python -m benchmarks.simulated_reviewer --policy spans  # records its own section

Human time (issue #9 item 6): ``--inspect-seconds`` (1 s) per frame a person
looks at, ``--correct-seconds`` (6 s) per box a person draws. Per OTB
sequence and seed (frames held in memory, the tracker driven through
:func:`annotator.review.retrack_tracks`; no files are written):

1. **Simulated reviewer.** Track from the first ground-truth box. Then, in
   rounds: the reviewer is shown the flagged frames and looks at each one
   (1 s) unless it already looked at that frame with the same box: a frame
   counts again only after a re-track changed its box (the tool reports
   which spans moved, and a reviewer does not re-check a box it has judged).
   If at least ``--target`` (95%) of the frames have IoU >= 0.5 with the
   ground truth, or ``--budget`` corrections per 100 frames are spent, it
   stops (the flags of the final round are looked at too: a reviewer checks
   them before stopping). Otherwise it corrects (6 s a box) and the tool
   re-tracks the spans the corrections affect (forward and backward between
   anchors, as ``sptpt-annotate retrack`` does). ``--policy worst``
   (default) corrects one box a round, on the flagged frame with the highest
   failure probability; ``--policy spans`` corrects, in every flagged span,
   the first frame whose box is wrong, all before one re-track (the README's
   workflow: one fixes.csv for the whole report, one ``retrack``). When no
   frame is flagged (``spans``: no flagged box is wrong) but the target is
   not met, the tool gives no hint; the reviewer then
   (``--fallback first-wrong``, default) scrubs the overlay from the start
   and corrects the first frame whose box is wrong (IoU < 0.5), looking at
   every frame up to it (same rule: boxes already seen are free), or
   (``lowest-confidence``) corrects the least confident frame not yet an
   anchor. The first-frame box is given, not counted. ``inspected_every_round``
   in the JSON counts every flagged frame again in every round (the upper
   bound: a reviewer with no memory); the markdown gives that figure too.
   The correction policy and the stopping rule use the ground truth (an
   oracle), as before; only what the person looks at is new.
   Passes from unchanged anchors are reused through ``pass_cache`` (they
   are deterministic), which halves the tracking and changes no number.
2. **Interpolation baseline** (what interpolation-based tools do): a person
   boxes frames k, 2k, ... and the last, the tool interpolates ``x, y, w, h``
   linearly in between. The k with the fewest keyframes that reaches the
   same target is taken (the baseline's best case: a real user does not know
   the right k). Each keyframe costs 1 s + 6 s (looked at and boxed, as a
   reviewer's correction is); the interpolated frames are not looked at, just
   as the reviewer trusts the unflagged frames: each method's person looks at
   what that method asks them to. Frame 0 is given, not counted. The figure
   if the person also checked every interpolated frame is printed beside it.
   It has no randomness, so it is the same for every seed.
3. **Merge study** (``--merge-study M``, first seed only): ground truth every
   M frames, forward and backward passes between them, and the share of
   frames with IoU >= 0.5 for each way of merging the two passes
   (:data:`annotator.review.MERGES`), forward only and backward only.
   It measures on the same passes, so it costs one forward and one
   backward pass per sequence, and it is what chose ``DEFAULT_MERGE``.

Human seconds per 100 frames are pooled over the sequences (total seconds /
total frames x 100) per seed; the ratio reviewer / baseline is pooled the same
way; figures are mean ± sample std over ``--seeds`` (default 0,1,2). The
target is met when the pooled ratio is at most 0.5 for every seed and every
sequence reached the accuracy target.

Flags come from the failure probability of the installed failure model
(``annotator/data/failure_model.json``, or ``--failure-model``) with its
threshold (or ``--flag-threshold``) and the other run defaults of
:class:`annotator.flagging.FlagParams`; the output names the model (path, its
``info`` field, a hash of its canonical JSON). Tracker settings: ``--preset``
(default: the tool's default preset, ``annotator.config.DEFAULT_PRESET``;
``paper`` runs with ``n_particles`` and ``n_negatives`` lowered to
``--particles`` / ``--negatives`` so that the loop fits in minutes; the
figures printed say which).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from annotator.config import DEFAULT_PRESET, RunConfig
from annotator.failure import FailureModelError, load_model
from annotator.failure.fit import video
from annotator.failure.model import shipped_model_path
from annotator.flagging import FlagParams, keyframe_rows, spans_from_mask
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from annotator.review import (
    DEFAULT_MERGE,
    MERGES,
    ArrayFrames,
    PreviousTrack,
    merge_passes,
    retrack_tracks,
)
from annotator.wording import ordinal
from benchmarks._results import machine_line, update_section
from benchmarks._sequences import SequenceError, select_sequences
from sptpt.params import get_preset, params_from_mapping

HERE = Path(__file__).resolve().parent

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
    """The keyframe interval k with the fewest keyframes whose interpolation reaches ``target`` (ties: larger k).

    ``keyframes`` counts the boxes a person draws: frames k, 2k, ... and the
    last, not frame 0 (given, as for the reviewer).
    """
    n = len(gt)
    best = None
    for k in range(1, n):
        keys = np.unique(np.concatenate([np.arange(0, n, k), [n - 1]]))
        share = success_share(interpolate(gt, keys), gt, threshold)
        if share >= target and (best is None or len(keys) - 1 <= best["keyframes"]):
            best = {"k": k, "keyframes": int(len(keys) - 1), "success": share}
    if best is None:  # k = 1 is the ground truth itself, so only a sequence of one frame gets here
        best = {"k": 1, "keyframes": 0, "success": 1.0}
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
    model = config.load_failure_model()
    hits: dict[str, list[np.ndarray]] = {m: [] for m in (*MERGES, "forward only", "backward only")}
    for (_, start, stop), (fwd, bwd) in result.passes.items():
        if bwd is None or stop - start < 2:
            continue
        truth = gt[start + 1 : stop]
        for m in MERGES:
            merged = merge_passes(fwd, bwd, m, model=model, ends=(tuple(gt[start]), tuple(gt[stop])))
            hits[m].append(iou_rows(merged.boxes_xywh, truth))
        hits["forward only"].append(iou_rows(fwd.boxes_xywh, truth))
        hits["backward only"].append(iou_rows(bwd.boxes_xywh, truth))
    out = {}
    for m, parts in hits.items():
        iou = np.concatenate(parts) if parts else np.zeros(0)
        out[m] = {"frames": int(iou.size), "success": float(np.mean(iou >= threshold)) if iou.size else math.nan,
                  "mean_iou": float(iou.mean()) if iou.size else math.nan}
    out["tracker_calls"] = result.frames_tracked
    return out


#: How the reviewer corrects, each round:
#:
#: * ``worst``: one box, on the flagged frame with the highest p_fail, then the tool re-tracks (an interactive
#:   loop: one correction, one re-track);
#: * ``spans``: in every flagged span, the first frame whose box is wrong, all at once, then one re-track (the
#:   README's workflow: read the report, write the fixes of every span into one CSV, run ``retrack`` once).
#:   A span whose boxes are all right gets no correction.
POLICIES = ("worst", "worst-wrong", "spans")
NOTHING_TO_CORRECT = {"worst": "nothing is flagged", "worst-wrong": "no flagged box is wrong",
                      "spans": "no flagged box is wrong"}
POLICY_TEXT = {"worst": "the flagged frame with the highest p_fail",
               "worst-wrong": "the flagged frame with the highest p_fail among those whose box is wrong "
                              "(IoU < the threshold: it has just looked at them)",
               "spans": "the first wrong box (IoU < the threshold) of every flagged span, all before one re-track"}
#: Tolerant counts of looks, kept beside the strict one: a frame counts again only when its box moved to IoU below
#: this with the box of the frame's last counted look (so small moves cannot add up unnoticed; the strict count
#: re-counts any change, however small).
MOVED_IOU = (0.95, 0.9, 0.8)


def simulated_reviewer(frames, gt, config: RunConfig, *, merge: str, target: float, threshold: float,
                       budget: int, fallback: str, policy: str = "worst", accept: bool = False) -> dict:
    """The review loop against the ground truth; counts what a person looks at and what they correct.

    Each round the reviewer is shown the flagged frames and looks at every
    one whose box it has not seen yet (``inspected``; a frame is seen again
    only when a re-track changed its box), then stops if the target is met,
    else corrects (see :data:`POLICIES`) and the tool re-tracks.
    ``inspected_every_round`` counts every flagged frame again in every round
    instead (an upper bound: a reviewer who does not remember what it already
    checked).
    """
    n = len(frames)
    provider = ArrayFrames(frames)
    indices = np.arange(n)
    cache: dict = {}  # passes from unchanged anchors are reused, not re-run (identical results, half the time)
    tic = time.perf_counter()
    result = retrack_tracks(provider, indices, {1: {0: tuple(gt[0])}}, config, merge=merge, pass_cache=cache)
    calls = result.frames_tracked
    track, scoring = result.tracks[0], result.scoring[1]
    curve = [success_share(track.boxes_xywh, gt, threshold)]
    seen = np.full((n, 4), np.nan)  # each frame's box when the reviewer last looked at it (NaN: never)
    looks = {"new": 0, "all": 0}
    seen_moved = {tol: np.full((n, 4), np.nan) for tol in MOVED_IOU}
    looks_moved = {tol: 0 for tol in MOVED_IOU}

    pending_accepts: dict[int, tuple] = {}  # flagged frames seen to be right, sent as anchors with the next re-track
    accept_spans = accepted = 0

    def look(mask: np.ndarray) -> None:
        new = mask & ~np.all(seen == track.boxes_xywh, axis=1)
        if accept:
            # Only flagged boxes are accepted: frames scrubbed through by the fallback are not in a flagged span.
            right = new & track.flagged & (iou_rows(track.boxes_xywh, gt) >= threshold) & ~track.keyframe
            pending_accepts.update({int(p): tuple(track.boxes_xywh[p]) for p in np.flatnonzero(right)})
        looks["new"] += int(new.sum())
        looks["all"] += int(mask.sum())
        seen[mask] = track.boxes_xywh[mask]
        for tol, memory in seen_moved.items():
            moved = mask & (np.isnan(memory[:, 0]) | (iou_rows(np.nan_to_num(memory), track.boxes_xywh) < tol))
            looks_moved[tol] += int(moved.sum())
            memory[moved] = track.boxes_xywh[moved]

    corrections, fallbacks, shown, right_picks, requested = [], 0, [], 0, 0
    while True:
        candidates = track.flagged & ~track.keyframe
        shown.append(int(candidates.sum()))
        look(candidates)  # also in the last round: the reviewer checks what is flagged before it stops
        if curve[-1] >= target or len(corrections) >= budget:
            break
        picks = []
        asked = [p for p in keyframe_rows(track.reasons) if candidates[p]]
        if asked:
            # The tool judged the track lost and asks for keyframes instead of flagging doubtful spans: whatever
            # its policy, the reviewer boxes them (looked at above, as the baseline's keyframes are), then re-tracks.
            picks = asked[: budget - len(corrections)]
            requested += len(picks)
        elif policy == "spans":
            # The reviewer has just looked at every flagged frame, so it knows which boxes are wrong.
            wrong = iou_rows(track.boxes_xywh, gt) < threshold
            picks = [int(lo + np.argmax(wrong[lo:hi])) for lo, hi in spans_from_mask(candidates) if wrong[lo:hi].any()]
            picks = picks[: budget - len(corrections)]
        elif policy == "worst-wrong":
            pool = candidates & (iou_rows(track.boxes_xywh, gt) < threshold)
            if pool.any():
                picks = [int(np.argmin(np.where(pool, track.confidence, np.inf)))]
        elif candidates.any():
            picks = [int(np.argmin(np.where(candidates, track.confidence, np.inf)))]
        if not picks:
            # Nothing flagged (or, with "spans", nothing flagged is wrong), target not met: the tool gave no hint.
            fallbacks += 1
            if fallback == "first-wrong":  # the reviewer scrubs the overlay and fixes the first wrong box
                wrong = (iou_rows(track.boxes_xywh, gt) < threshold) & ~track.keyframe
                if not wrong.any():
                    break
                position = int(np.argmax(wrong))
                look(~track.keyframe & (indices <= position))  # every frame scrubbed through up to it
            else:  # "lowest-confidence": the reviewer trusts the confidence alone
                pool = ~track.keyframe
                if not pool.any():
                    break
                position = int(np.argmin(np.where(pool, track.confidence, np.inf)))
                look(indices == position)
            picks = [position]
        right_picks += int((iou_rows(track.boxes_xywh[picks], gt[picks]) >= threshold).sum())
        corrections += picks
        new_anchors = {p: tuple(gt[p]) for p in picks}
        if accept:
            kept = {p: box for p, box in pending_accepts.items() if p not in new_anchors}
            mask = np.zeros(n, bool)
            mask[list(kept)] = True
            accept_spans += len(spans_from_mask(mask))
            accepted += len(kept)
            new_anchors = {**kept, **new_anchors}
            pending_accepts.clear()
        result = retrack_tracks(provider, indices, {1: new_anchors}, config, merge=merge,
                                previous={1: PreviousTrack(track, scoring)}, pass_cache=cache)
        calls += result.frames_tracked
        track, scoring = result.tracks[0], result.scoring[1]
        curve.append(success_share(track.boxes_xywh, gt, threshold))
    return {
        "frames": n,
        "corrections": len(corrections),
        "inspected": looks["new"],
        "inspected_every_round": looks["all"],
        "inspected_moved": {str(tol): count for tol, count in looks_moved.items()},
        "right_picks": right_picks,
        "accepted": accepted,
        "accept_spans": accept_spans,
        "flagged_per_round": shown,
        "reached": curve[-1] >= target,
        "initial_success": curve[0],
        "final_success": curve[-1],
        "corrected_frames": corrections,
        "fallbacks": fallbacks,
        "keyframes_requested": requested,
        "curve": curve,
        "tracker_calls": calls,
        "seconds": time.perf_counter() - tic,
    }


def run_sequence(job: dict) -> dict:
    import numba

    if job.get("threads"):
        numba.set_num_threads(job["threads"])
    seq_dir = Path(job["seq_dir"])
    config = RunConfig(preset=job["preset"], tracker=params_from_mapping(job["params"]),
                       flags=FlagParams(threshold=job["flag_threshold"], lost_threshold=job["lost_threshold"],
                                        keyframe_every=job["keyframe_every"]), seed=job["seed"],
                       failure_model=job["failure_model"])
    frames, gt = load_sequence(seq_dir, job["stop"])
    record = {"sequence": seq_dir.name, "seed": job["seed"], "frames": len(frames)}
    record["baseline"] = interpolation_baseline(gt, job["target"], job["threshold"])
    if job["merge_study"]:
        tic = time.perf_counter()
        record["merge_study"] = merge_study(frames, gt, config, job["merge_study"], job["threshold"])
        record["merge_study"]["seconds"] = time.perf_counter() - tic
    if not job["skip_reviewer"]:
        budget = max(1, math.ceil(job["budget"] * len(frames) / 100))
        record["reviewer"] = simulated_reviewer(frames, gt, config, merge=job["merge"], target=job["target"],
                                                threshold=job["threshold"], budget=budget, fallback=job["fallback"],
                                                policy=job["policy"], accept=job["accept"])
    print(json.dumps({k: v for k, v in record.items() if k != "merge_study"} | {
        "reviewer": {k: v for k, v in record.get("reviewer", {}).items() if k not in ("curve",)}}), file=sys.stderr,
        flush=True)
    return record


def per100(amount: float, frames: int) -> float:
    return 100.0 * amount / frames if frames else math.nan


def human_seconds(record: dict, inspect_s: float, correct_s: float, accept_s: float = 0.0) -> dict:
    """Human seconds of one record: the reviewer, the baseline, and the alternative counts shown beside them."""
    rv, b, n = record["reviewer"], record["baseline"], record["frames"]
    accepting = accept_s * rv.get("accept_spans", 0)
    return {
        "reviewer": inspect_s * rv["inspected"] + correct_s * rv["corrections"] + accepting,
        "reviewer_every_round": inspect_s * rv["inspected_every_round"] + correct_s * rv["corrections"] + accepting,
        # A keyframe is looked at and boxed; the interpolated frames are trusted unseen, as unflagged frames are.
        "baseline": (inspect_s + correct_s) * b["keyframes"],
        # ... or the person also checks every interpolated frame (frame 0 is given to both).
        "baseline_check_all": inspect_s * (n - 1) + correct_s * b["keyframes"],
    }


def mean_std(values, digits: int = 1) -> str:
    """``mean ± std`` over seeds (sample std, ddof=1); the mean alone for one seed."""
    v = np.asarray(list(values), dtype=np.float64)
    if v.size == 1:
        return f"{v[0]:.{digits}f}"
    return f"{v.mean():.{digits}f} ± {v.std(ddof=1):.{digits}f}"


def pooled_by_seed(records: list[dict], args) -> dict[int, dict]:
    """Per seed: frames and human seconds summed over the sequences."""
    out: dict[int, dict] = {}
    for r in records:
        p = out.setdefault(r["seed"], {"frames": 0, "reached": True, "reviewer": 0.0, "reviewer_every_round": 0.0,
                                       "baseline": 0.0, "baseline_check_all": 0.0})
        p["frames"] += r["frames"]
        p["reached"] &= bool(r["reviewer"]["reached"])
        for key, value in human_seconds(r, args.inspect_seconds, args.correct_seconds, args.accept_seconds).items():
            p[key] += value
    return out


def markdown(records: list[dict], args, preset_text: str, model_text: str, seconds: float, command: str) -> str:
    seeds = sorted({r["seed"] for r in records})
    names = list(dict.fromkeys(r["sequence"] for r in records))
    lines = ["## Simulated reviewer", "",
             f"Command: `{command}`  ",
             f"Machine: {machine_line()}; shared with other processes. Wall time {seconds / 60:.1f} min.  ",
             f"Tracker: {preset_text}; seeds {', '.join(map(str, seeds))}. Flags: {model_text}.  ",
             f"Target: {100 * args.target:.0f}% of frames with IoU >= {args.threshold} with the ground truth; budget "
             f"{args.budget:g} corrections per 100 frames.  ",
             f"Sequences: {', '.join(names)} (frames {'1..' + str(args.stop) if args.stop else 'all'}).", ""]
    if not args.skip_reviewer:
        i_s, c_s = args.inspect_seconds, args.correct_seconds
        fallback_text = ("scrubs the overlay to the first frame whose box is wrong, IoU < the threshold, and "
                         "corrects it (the frames scrubbed through count as looked at)"
                         if args.fallback == "first-wrong" else "corrects the least confident non-anchor frame")
        lines += [f"Human time: {i_s:g} s per frame looked at, {c_s:g} s per box drawn. **Reviewer**: each round it "
                  f"looks at every flagged frame whose box it has not seen (a frame counts again only after a "
                  f"re-track changed its box), stops if the target is met, else boxes the keyframes the tool asks for "
                  f"if it asks (a track it judges lost), else corrects {POLICY_TEXT[args.policy]} "
                  f"(policy `{args.policy}`; when {NOTHING_TO_CORRECT[args.policy]} "
                  f"it {fallback_text}; 'fallback picks'), and the tool "
                  f"re-tracks forward and backward between anchors (merge `{args.merge}`). **Baseline**: a person "
                  f"boxes every k-th frame and the last, the tool interpolates x, y, w, h linearly; the k with the "
                  f"fewest keyframes that reaches the target (its best case: a real user does not know k); each "
                  f"keyframe costs {i_s + c_s:g} s (looked at and boxed), interpolated frames are trusted unseen as "
                  f"the reviewer trusts unflagged frames. Frame 0's box is given to both and not counted. "
                  f"Figures are mean ± std over seeds (sample std); the baseline has no randomness.", "",
                  "| sequence | frames | success before review | looked at | corrections | of which keyframes asked | "
                  "reached (seeds) | fallback picks | reviewer s / 100 frames | baseline k | keyframes | "
                  "baseline s / 100 frames | ratio |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for name in names:
            rs = [r for r in records if r["sequence"] == name]
            n, b = rs[0]["frames"], rs[0]["baseline"]
            cost = [human_seconds(r, i_s, c_s, args.accept_seconds) for r in rs]
            lines.append(
                f"| {name} | {n} | {mean_std(100 * r['reviewer']['initial_success'] for r in rs)}% | "
                f"{mean_std(r['reviewer']['inspected'] for r in rs)} | "
                f"{mean_std(r['reviewer']['corrections'] for r in rs)} | "
                f"{mean_std(r['reviewer'].get('keyframes_requested', 0) for r in rs)} | "
                f"{sum(r['reviewer']['reached'] for r in rs)}/{len(rs)} | "
                f"{mean_std(r['reviewer']['fallbacks'] for r in rs)} | "
                f"{mean_std(per100(c['reviewer'], n) for c in cost)} | {b['k']} | {b['keyframes']} | "
                f"{per100(cost[0]['baseline'], n):.1f} | "
                f"{mean_std((c['reviewer'] / c['baseline'] if c['baseline'] else math.nan for c in cost), 2)} |")
        pooled = pooled_by_seed(records, args)
        ps = [pooled[s] for s in seeds]
        ratio = [p["reviewer"] / p["baseline"] if p["baseline"] else math.nan for p in ps]
        asked = mean_std(sum(r['reviewer'].get('keyframes_requested', 0) for r in records if r['seed'] == s)
                         for s in seeds)
        lines.append(f"| **pooled** | {ps[0]['frames']} | | "
                     f"{mean_std(sum(r['reviewer']['inspected'] for r in records if r['seed'] == s) for s in seeds)} | "
                     f"{mean_std(sum(r['reviewer']['corrections'] for r in records if r['seed'] == s) for s in seeds)}"
                     f" | {asked}"
                     f" | | | **{mean_std(per100(p['reviewer'], p['frames']) for p in ps)}** | | "
                     f"{sum(r['baseline']['keyframes'] for r in records if r['seed'] == seeds[0])} | "
                     f"**{per100(ps[0]['baseline'], ps[0]['frames']):.1f}** | **{mean_std(ratio, 2)}** |")
        reached = all(p["reached"] for p in ps)
        every = all(x <= 0.5 for x in ratio)
        verdict = ("meets" if every and reached else
                   "meets on average only" if np.mean(ratio) <= 0.5 and reached else "misses")
        lines += ["", f"Target (reviewer's human seconds at most half the baseline's, pooled): **{verdict}** it; "
                  f"ratio {mean_std(ratio, 2)} (per seed: {', '.join(f'{x:.2f}' for x in ratio)})."
                  + ("" if reached else " Some sequences stopped at the correction budget (reached < all seeds), "
                     "so the reviewer's time there is a lower bound.")]
        every_round = [p["reviewer_every_round"] / p["baseline"] if p["baseline"] else math.nan for p in ps]
        lines += ["", "The same runs counted otherwise, pooled: if the reviewer looked again at every flagged frame "
                  f"in every round, {mean_std(per100(p['reviewer_every_round'], p['frames']) for p in ps)} s per 100 "
                  f"frames, ratio {mean_std(every_round, 2)}; if the baseline's person also checked every interpolated "
                  f"frame, {per100(ps[0]['baseline_check_all'], ps[0]['frames']):.1f} s per 100 frames, ratio "
                  f"{mean_std((p['reviewer'] / p['baseline_check_all'] for p in ps), 2)}."]
        moved = []
        for tol in MOVED_IOU:
            per_seed = [sum(i_s * r["reviewer"]["inspected_moved"][str(tol)] + c_s * r["reviewer"]["corrections"]
                            + args.accept_seconds * r["reviewer"].get("accept_spans", 0)
                            for r in records if r["seed"] == s) for s in seeds]
            moved.append(f"IoU {tol:g}: {mean_std(per100(x, p['frames']) for x, p in zip(per_seed, ps))} s, ratio "
                         f"{mean_std((x / p['baseline'] for x, p in zip(per_seed, ps)), 2)}")
        picks = [sum(r["reviewer"]["right_picks"] for r in records if r["seed"] == s) for s in seeds]
        lines += ["", "If a frame counted again only when its box moved below an IoU with the box last looked at "
                  f"(per 100 frames, pooled): {'; '.join(moved)}. Corrections whose box was right (IoU >= "
                  f"{args.threshold:g}) when picked: {mean_std(picks)}."]
        if args.accept:
            accepted = [sum(r["reviewer"]["accepted"] for r in records if r["seed"] == s) for s in seeds]
            runs = [sum(r["reviewer"]["accept_spans"] for r in records if r["seed"] == s) for s in seeds]
            lines += ["", f"Accepted (`--accept`): the reviewer keeps the flagged boxes it saw to be right as anchors; "
                      f"{mean_std(accepted)} boxes in {mean_std(runs)} runs of consecutive frames, "
                      f"{args.accept_seconds:g} s per run (included above)."]
    if args.merge_study:
        methods = [*MERGES, "forward only", "backward only"]
        study_seed = next(r["seed"] for r in records if "merge_study" in r)
        lines += ["", f"Merge study (seed {study_seed}): ground truth every {args.merge_study} frames; frames "
                  "strictly between anchors; "
                  "share with IoU >= 0.5 (mean IoU).", "",
                  "| sequence | " + " | ".join(methods) + " |", "|---|" + "---:|" * len(methods)]
        pooled = {m: [0, 0.0, 0.0] for m in methods}
        for r in (r for r in records if "merge_study" in r):
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
    parser.add_argument("--preset", default=DEFAULT_PRESET)
    parser.add_argument("--particles", type=int, default=120,
                        help="n_particles when the preset is 'paper' (ignored for other presets)")
    parser.add_argument("--negatives", type=int, default=60,
                        help="n_negatives when the preset is 'paper' (ignored for other presets)")
    parser.add_argument("--merge", default=DEFAULT_MERGE, choices=MERGES)
    parser.add_argument("--merge-study", type=int, default=0, metavar="M",
                        help="also compare merges with ground truth every M frames (0: skip)")
    parser.add_argument("--policy", default="worst", choices=POLICIES,
                        help="how the reviewer corrects each round (see POLICIES): 'worst' one box on the most "
                             "doubtful flagged frame; 'spans' the first wrong box of every flagged span at once "
                             "(default worst; each policy records its own RESULTS.md section)")
    parser.add_argument("--fallback", default="first-wrong", choices=("first-wrong", "lowest-confidence"),
                        help="the reviewer's pick when no frame is flagged but the target is not met")
    parser.add_argument("--accept", action="store_true",
                        help="the reviewer also accepts the flagged boxes it saw to be right: they become anchors "
                             "with the next re-track (a 'keep' row per run of consecutive frames)")
    parser.add_argument("--accept-seconds", type=float, default=1.0,
                        help="human seconds per run of consecutive accepted frames (with --accept)")
    parser.add_argument("--skip-reviewer", action="store_true", help="only the baseline and the merge study")
    parser.add_argument("--target", type=float, default=0.95)
    parser.add_argument("--threshold", type=float, default=0.5)
    parser.add_argument("--budget", type=float, default=30.0, help="max corrections per 100 frames")
    parser.add_argument("--seeds", default="0,1,2",
                        help="comma-separated run seeds; figures are mean ± std over them (default 0,1,2)")
    parser.add_argument("--inspect-seconds", type=float, default=1.0, help="human seconds per frame looked at")
    parser.add_argument("--correct-seconds", type=float, default=6.0, help="human seconds per box drawn")
    parser.add_argument("--failure-model", type=Path, default=None,
                        help="failure-model JSON (default: the one installed with the package)")
    parser.add_argument("--fold-models", type=Path, default=None, metavar="DIR",
                        help="score each sequence with DIR/SEQUENCE.json instead (the per-fold models of "
                             "benchmarks/anchored_failure.py --write or benchmarks/pass_choice.py --write: their "
                             "between_anchors or pass_choice section fitted without that sequence)")
    parser.add_argument("--flag-threshold", type=float, default=None,
                        help="flag frames with p_fail above this (default: the failure model's threshold)")
    parser.add_argument("--lost-threshold", type=lambda v: None if v.lower() == "none" else float(v),
                        default=FlagParams.lost_threshold,
                        help="mean p_fail above which the tool asks for keyframes instead of flagging spans "
                             f"(default {FlagParams.lost_threshold}, the run default; 'none': never)")
    parser.add_argument("--keyframe-every", type=int, default=FlagParams.keyframe_every,
                        help="frames between the keyframes a lost track asks for "
                             f"(default {FlagParams.keyframe_every})")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None,
                        help="JSON of every record (default: benchmarks/_runs/simulated_reviewer[-POLICY].json)")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = parser.parse_args()
    if args.policy in ("spans", "worst-wrong") and args.fallback == "lowest-confidence":
        # Its fallback starts when every flagged box was seen to be right, and would pick one of those again.
        parser.error(f"--policy {args.policy} needs --fallback first-wrong: the least confident frame is then a "
                     "flagged frame the reviewer has just seen to be right")
    # Each way of running records its own JSON and RESULTS.md section.
    variant = "".join([("" if args.policy == "worst" else "-" + args.policy), ("-accept" if args.accept else ""),
                       ("-folds" if args.fold_models is not None else "")])
    if args.out is None:
        args.out = HERE / "_runs" / f"simulated_reviewer{variant}.json"
    try:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
    except ValueError:
        parser.error(f"--seeds {args.seeds!r} is not a comma-separated list of integers (e.g. 0,1,2)")
    if not seeds or len(set(seeds)) != len(seeds):
        parser.error(f"--seeds {args.seeds!r} must name at least one seed, each once")
    model_path = None if args.failure_model is None else str(args.failure_model.resolve())
    try:
        guided = get_preset(args.preset).uses_guide
        model = load_model(model_path, guided=guided)
        FlagParams(threshold=args.flag_threshold, lost_threshold=args.lost_threshold,
                   keyframe_every=args.keyframe_every)
    except (FailureModelError, ValueError) as exc:
        parser.error(str(exc))
    model_record = {"path": model_path or f"annotator/{shipped_model_path(guided=guided)}", "info": dict(model.info),
                    "threshold": model.threshold, "flag_threshold": args.flag_threshold,
                    "sha256": hashlib.sha256(json.dumps(model.to_json(), sort_keys=True).encode()).hexdigest()}
    threshold_text = (f"{args.flag_threshold:g} (given)" if args.flag_threshold is not None
                      else f"{model.threshold:g} (the model's)")
    keyframe_text = ("never a keyframe request" if args.lost_threshold is None else
                     f"a track with mean p_fail above {args.lost_threshold:g} asks for every "
                     f"{ordinal(args.keyframe_every)} frame and the last instead (reason `keyframe`)")
    model_text = (f"failure model `{model_record['path']}`{'' if model_path else ' (installed)'}, info "
                  f"`{json.dumps(model_record['info'])}`, sha256 of its canonical JSON "
                  f"{model_record['sha256'][:12]}; flag threshold {threshold_text}, {keyframe_text}, other flag "
                  "settings the run defaults")

    try:
        all_sequences = select_sequences(args.otb, args.sequences)
    except SequenceError as err:
        parser.error(str(err))
    sequence_models = {s.name: model_path for s in all_sequences}
    if args.fold_models is not None:
        if args.failure_model is not None:
            parser.error("give --fold-models or --failure-model, not both")
        held_out_parts, folds = set(), {}
        for s in all_sequences:
            path = (args.fold_models / f"{s.name}.json").resolve()
            try:
                fold = load_model(path)
            except FailureModelError as exc:
                parser.error(f"{exc} (--fold-models needs one model file per sequence)")
            sections = {name: part for name, part in (("between_anchors", fold.between_anchors),
                                                      ("pass_choice", fold.pass_choice)) if part is not None}
            if not sections or any(part.info.get("held_out") != s.name for part in sections.values()):
                parser.error(f"{path} is not the fold model of {s.name}: its between_anchors or pass_choice "
                             "section must be fitted without that sequence (benchmarks/anchored_failure.py or "
                             "benchmarks/pass_choice.py --write)")
            held_out_parts |= sections.keys()
            sequence_models[s.name] = str(path)
            folds[s.name] = fold
            model_record.setdefault("fold_sha256", {})[s.name] = hashlib.sha256(
                json.dumps(fold.to_json(), sort_keys=True).encode()).hexdigest()
        made_by = {"between_anchors": "benchmarks/anchored_failure.py --write: main part and between_anchors "
                                      "section both fitted without the sequence's video",
                   "pass_choice": "benchmarks/pass_choice.py --write: the pass_choice section fitted without the "
                                  "sequence's video"}
        # failure_model.py names the sequence a fold model is for, anchored_failure.py the video it holds out.
        held_main = [name for name, fold in folds.items() if fold.info.get("held_out") in (name, video(name))]
        if args.flag_threshold is None:
            thresholds = sorted({fold.threshold for fold in folds.values()})
            threshold_text = (f"each fold model's own ({thresholds[0]:g}-{thresholds[-1]:g})" if len(thresholds) > 1
                              else f"{thresholds[0]:g} (the fold models')")
        main_text = ("main part of every fold fitted without the sequence's video (benchmarks/failure_model.py "
                     "--write)" if len(held_main) == len(all_sequences) else
                     f"main part fitted without the sequence's video for {', '.join(held_main)}, the installed "
                     "one for the rest" if held_main else "the installed main part")
        model_text = (f"per-sequence fold models `{args.fold_models}/SEQUENCE.json` ("
                      + "; ".join([main_text, *(made_by[part] for part in sorted(held_out_parts))])
                      + f"); flag threshold "
                      f"{threshold_text}, {keyframe_text}, other flag settings the run defaults")
        model_record["fold_models"] = str(args.fold_models.resolve())
    params = get_preset(args.preset)
    preset_text = f"preset `{args.preset}`"
    if args.preset == "paper":
        params = dataclasses.replace(params, n_particles=args.particles, n_negatives=args.negatives)
        preset_text = f"preset `paper` with n_particles={args.particles} and n_negatives={args.negatives}"
    # The merge study runs on the first seed only; with --skip-reviewer that is all there is to run.
    jobs = [dict(seq_dir=str(s), params=params.to_dict(), preset=args.preset, seed=seed, stop=args.stop,
                 target=args.target, threshold=args.threshold, budget=args.budget, merge=args.merge,
                 merge_study=args.merge_study if seed == seeds[0] else 0, skip_reviewer=args.skip_reviewer,
                 fallback=args.fallback, policy=args.policy, accept=args.accept,
                 failure_model=sequence_models[s.name],
                 flag_threshold=args.flag_threshold, lost_threshold=args.lost_threshold,
                 keyframe_every=args.keyframe_every,
                 threads=1 if args.workers > 1 else 0)
            for seed in (seeds[:1] if args.skip_reviewer else seeds) for s in all_sequences]
    started = time.perf_counter()
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn")) as pool:
            records = list(pool.map(run_sequence, jobs))
    else:
        records = [run_sequence(job) for job in jobs]
    seconds = time.perf_counter() - started
    command = "python -m benchmarks.simulated_reviewer " + " ".join(sys.argv[1:])
    text = markdown(records, args, preset_text, model_text, seconds, command.strip())
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": command, "failure_model": model_record, "seeds": seeds,
                                          "human_seconds": {"inspect": args.inspect_seconds,
                                                            "correct": args.correct_seconds,
                                                            "accept_run": args.accept_seconds if args.accept else None},
                                          "records": records}, indent=1, default=float) + "\n")
    if not args.no_record:
        if args.skip_reviewer:
            update_section("simulated-reviewer-merge-study",
                           text.replace("## Simulated reviewer", "## Simulated reviewer: merge study", 1))
        else:
            key = f"simulated-reviewer{variant}"
            heading = "## Simulated reviewer" + (f" (`{variant[1:]}`)" if variant else "")
            update_section(key, text.replace("## Simulated reviewer", heading, 1))


if __name__ == "__main__":
    main()

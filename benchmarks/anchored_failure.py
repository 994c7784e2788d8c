"""Fit and measure the failure probability of frames between two human boxes: the passes' agreement.

    python -m benchmarks.anchored_failure --generate            # track, then fit and measure (records RESULTS.md)
    python -m benchmarks.anchored_failure --write               # refit on the stored data; write the model section
    python -m benchmarks.anchored_failure --generate --seeds 0 --sequences Deer,Crossing --no-record

Re-tracking puts every frame between two anchors through two passes, forward
from the earlier box and backward from the later one, and keeps one box
(``annotator.review.merge``). Where the two passes put the box in different
places, one has lost the object: the forward-backward check of issue #9,
here at no extra cost. This script measures what it is worth and fits the
``between_anchors`` section of the failure model
(``annotator.failure.model.PassAgreement``).

1. **Data** (``--generate``): for every sequence of ``../shared/otb`` (first
   ``--stop`` frames), every seed and every anchor interval M of ``--every``,
   the tool's own re-tracking (:func:`annotator.review.retrack_tracks`) from
   ground-truth boxes every M frames; per frame strictly between two anchors:
   the track probability (the installed model without its
   ``between_anchors`` section, exactly as ``reflag`` computes it), the
   passes' IoU ``pass_iou``, and whether the kept box failed (IoU < 0.5).
   Stored in ``--data`` (one ``.npz`` per sequence, seed and M), with each
   frame's failure-model features.
2. **Held out**: the sequences are split into folds by video (Jogging.1 and
   Jogging.2 are two people in one video, so one fold). A fold's frames are
   scored by a main model fitted without them (``fit_model`` on the runs of
   ``benchmarks/failure_model.py``, ``--main-runs``, with the shipped
   model's C) and a section fitted without them: the installed main model
   was fitted on these same sequences, so its own probabilities would be
   optimistic here. Per seed: AUROC of ``p_fail`` for failure, expected
   calibration error (10 bins), and, at the fold model's flag threshold,
   frame precision, recall and flagged share, for the track probability
   alone and corrected by the passes' agreement.
3. ``--write``: the installed model with the section fitted on every
   sequence (with the installed main model's probabilities, as the tool
   computes them) goes to ``--model-out``, and one model file per sequence
   into ``--data``/folds (that fold's main model and section), for
   ``benchmarks/simulated_reviewer.py --fold-models``.

The package does not ship the section: it ranks and calibrates the frames
between two anchors far better, but it flags more of them, and the simulated
reviewer, who looks at every flagged frame, then spent more time, not less
(RESULTS.md, "anchored-failure"). A user who prefers recall between their
boxes can pass ``--model-out``'s file with ``--failure-model``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from annotator.atomic import write_text_atomic
from annotator.config import RunConfig
from annotator.evaluation.calibration import auroc, expected_calibration_error
from annotator.failure import FEATURES, feature_matrix, load_model
from annotator.failure.fit import APPEARANCE_LEVELS, fit_model, fit_pass_agreement
from annotator.flagging import FlagParams
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from annotator.review import ArrayFrames, retrack_tracks
from annotator.review.merge import PASS_IOU, filled_signals, track_p_fail
from benchmarks._anchor_runs import add_arguments, mean_std, stored_data, stored_rows, video
from benchmarks._results import machine_line, update_section
from benchmarks.failure_model import load_samples
from sptpt.boxes import iou_xywh

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

PRESET = "robust"


def generate(job: dict) -> str:
    """Re-track one sequence from ground-truth anchors every ``every`` frames; store the frames between anchors."""
    import numba

    from sptpt.params import get_preset

    if job.get("threads"):
        numba.set_num_threads(job["threads"])
    seq_dir = Path(job["seq_dir"])
    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")
    frames = [frame for _, frame in open_frames(seq_dir, stop=job["stop"])]
    n = len(frames)
    gt = gt[:n]
    anchors = {p: tuple(gt[p]) for p in sorted(set(range(0, n, job["every"])) | {n - 1})}
    config = RunConfig(preset=PRESET, tracker=get_preset(PRESET), flags=FlagParams(), seed=job["seed"],
                       failure_model=None)
    # anchored, as when its data were first made: the chosen merge reads a section fitted on every sequence.
    track = retrack_tracks(ArrayFrames(frames), np.arange(n), {1: anchors}, config, merge="anchored").tracks[0]
    # The track probability as reflag computes it, from the model without any between_anchors section.
    model = dataclasses.replace(load_model(None), between_anchors=None)
    p_track, _ = track_p_fail(track.signals, track.keyframe, track.outside, model)
    features = feature_matrix(filled_signals(track.signals), track.keyframe | track.outside)
    pass_iou = np.asarray(track.signals.get(PASS_IOU, np.full(n, np.nan)), dtype=np.float64)
    use = ~np.isnan(pass_iou) & ~track.keyframe & ~track.outside
    out = Path(job["out"])
    np.savez(out, p_track=p_track[use], pass_iou=pass_iou[use], features=features[use], stop=job["stop"],
             failed=np.nan_to_num(iou_xywh(track.boxes_xywh[use], gt[use]), nan=0.0) < 0.5,
             position=np.flatnonzero(use))
    print(f"{seq_dir.name} seed {job['seed']} every {job['every']}: {int(use.sum())} frames", file=sys.stderr,
          flush=True)
    return str(out)


def load_data(folder: Path, sequences: set[str] | None, seeds, everies, stop: int) -> dict[str, np.ndarray]:
    """The stored frames of the given sequences (all when None), seeds and intervals, tracked with ``stop``."""
    def check(path: Path, d) -> None:
        if "features" not in d or int(d["stop"]) != stop or d["features"].shape[1] != len(FEATURES):
            raise SystemExit(f"{path} was generated by an older version of this script, for other failure "
                             "features or with another --stop: run with --generate again")

    return stored_rows(folder, sequences, seeds, everies, ("failed", "p_track", "pass_iou", "features"), check)


def held_out(data: dict[str, np.ndarray], samples, C: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Per frame, the track probability and ``p_fail`` of models fitted without the frame's video, the fold
    model's threshold per frame, and each sequence's fold model (main part and section)."""
    n = len(data["failed"])
    p_track, p, threshold = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    folds = {}
    fold_of = np.array([video(name) for name in data["sequence"]])
    for fold in sorted(set(fold_of)):
        train, test = fold_of != fold, fold_of == fold
        main = fit_model([s for s in samples if video(s.sequence) != fold], C=C, drop=APPEARANCE_LEVELS,
                         info={"held_out": fold, "note": "fold model of benchmarks/anchored_failure.py"})
        p_fold = main.p_fail(data["features"])
        section = fit_pass_agreement(p_fold[train], data["pass_iou"][train], data["failed"][train],
                                     info={"held_out": fold})
        p_track[test], p[test] = p_fold[test], section.p_fail(p_fold[test], data["pass_iou"][test])
        threshold[test] = main.threshold
        for name in set(data["sequence"][test]):
            folds[name] = dataclasses.replace(main, between_anchors=dataclasses.replace(
                section, info={"held_out": name, "fold": fold}))
    return p_track, p, threshold, folds


def metrics(p: np.ndarray, failed: np.ndarray, threshold) -> dict[str, float]:
    flagged = p > threshold
    return {"auroc": auroc(p, failed), "ece": expected_calibration_error(p, failed),
            "precision": float(failed[flagged].mean()) if flagged.any() else math.nan,
            "recall": float(flagged[failed].mean()) if failed.any() else math.nan,
            "flagged": float(flagged.mean())}


def markdown(data, p_alone, p_held, threshold, command, seconds, shipped, C) -> str:
    seeds = sorted(set(data["seed"].tolist()))
    everies = sorted(set(data["every"].tolist()))
    names = sorted(set(data["sequence"]))
    rows = {"track probability alone (held out)": p_alone, "corrected by the passes' agreement (held out)": p_held}
    lines = ["## Failure probability between two human boxes: the passes' agreement (held out)", "",
             f"Command: `{command}`  ",
             f"Machine: {machine_line()}; wall time {seconds / 60:.1f} min.  ",
             f"Data: {len(names)} sequences of `../shared/otb` ({', '.join(names)}), preset `{PRESET}`, seeds "
             f"{', '.join(map(str, seeds))}, ground-truth anchors every {' and every '.join(map(str, everies))} "
             f"frames, re-tracked by the tool (`retrack_tracks`, merge `anchored`); {len(p_held)} frames strictly "
             f"between two anchors, {100 * data['failed'].mean():.1f}% failed (IoU < 0.5). Held out by video "
             "(Jogging.1 and Jogging.2 one fold): each fold is scored by a main model (C = "
             f"{C:g}, recalibrated, `fit_model` on the runs of `benchmarks/failure_model.py`) and a section fitted "
             "without it. Flags here are frames above the fold model's threshold "
             f"({', '.join(f'{t:.2f}' for t in sorted(set(np.round(threshold, 2))))}), before span merging.", "",
             "| p_fail | AUROC | ECE | precision | recall | flagged share |", "|---|---:|---:|---:|---:|---:|"]
    for label, p in rows.items():
        per_seed = [metrics(p[data["seed"] == s], data["failed"][data["seed"] == s], threshold[data["seed"] == s])
                    for s in seeds]
        lines.append(f"| {label} | " + " | ".join(mean_std(m[k] for m in per_seed) for k in
                                                    ("auroc", "ece", "precision", "recall", "flagged")) + " |")
    lines += ["", "By anchor interval (pooled over seeds, AUROC alone → corrected): " + "; ".join(
        f"every {e}: {auroc(p_alone[data['every'] == e], data['failed'][data['every'] == e]):.3f} → "
        f"{auroc(p_held[data['every'] == e], data['failed'][data['every'] == e]):.3f}" for e in everies) + ".",
        "", f"Shipped section (fitted on every sequence): p = sigmoid({shipped.log_odds:.3f} logit(p_track) "
        f"{shipped.pass_iou:+.3f} pass_iou {shipped.intercept:+.3f})."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser, otb=ROOT.parent / "shared" / "otb", stop=150, every="10,30",
                  every_help="anchor intervals M, comma-separated (default 10,30)", data=HERE / "_runs" / "anchored")
    parser.add_argument("--main-runs", default=str(HERE / "_runs" / "failure" / "robust-s*"),
                        help="glob of the batch runs the main failure model is fitted on (benchmarks/failure_model.py)")
    parser.add_argument("--write", action="store_true",
                        help="write the installed model with the fitted section to --model-out, and the fold models")
    parser.add_argument("--model-out", type=Path, default=HERE / "_runs" / "anchored" / "failure_model_between.json",
                        help="where --write puts the model with the section (not the package's file: see above)")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = parser.parse_args()
    started = time.perf_counter()
    seeds, everies, data = stored_data(parser, args, generate, load_data)
    samples, _, _ = load_samples([args.main_runs], args.otb)
    if not samples:
        parser.error(f"--main-runs {args.main_runs!r} matches no batch run: run step 1 of benchmarks/failure_model.py")
    model = load_model(None)
    C = float(model.info.get("C", 0.001))
    p_alone, p_held, threshold, folds = held_out(data, samples, C)
    shipped = fit_pass_agreement(
        data["p_track"], data["pass_iou"], data["failed"],
        info={"fitted_by": "python -m benchmarks.anchored_failure " + " ".join(sys.argv[1:]),
              "data": {"preset": PRESET, "seeds": seeds, "every": everies, "stop": args.stop,
                       "sequences": sorted(set(data["sequence"])), "frames": int(len(data["failed"]))}})
    command = "python -m benchmarks.anchored_failure " + " ".join(sys.argv[1:])
    text = markdown(data, p_alone, p_held, threshold, command.strip(), time.perf_counter() - started, shipped, C)
    text = text.replace("Shipped section (fitted on every sequence)", "Section fitted on every sequence (not shipped)")
    print(text)
    if args.write:
        path = args.model_out
        path.parent.mkdir(parents=True, exist_ok=True)
        model_file = dataclasses.replace(model, between_anchors=shipped)
        write_text_atomic(path, json.dumps(model_file.to_json(), indent=1) + "\n")
        fold_dir = args.data / "folds"
        fold_dir.mkdir(parents=True, exist_ok=True)
        for name, fold_model in folds.items():
            write_text_atomic(fold_dir / f"{name}.json", json.dumps(fold_model.to_json(), indent=1) + "\n")
        print(f"wrote {path} and {len(folds)} fold models in {fold_dir}", file=sys.stderr)
    if not args.no_record:
        update_section("anchored-failure", text)


if __name__ == "__main__":
    main()

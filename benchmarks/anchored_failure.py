"""Fit and measure the failure probability of frames between two human boxes: the passes' agreement.

    python benchmarks/anchored_failure.py --generate            # track, then fit and measure (records RESULTS.md)
    python benchmarks/anchored_failure.py --write               # refit on the stored data; write the model section
    python benchmarks/anchored_failure.py --generate --seeds 0 --sequences Deer,Crossing --no-record

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
   Stored in ``--data`` (one ``.npz`` per sequence, seed and M).
2. **Held out**: each sequence is scored by a section fitted on the other
   sequences (all seeds and intervals; a sequence's frames never train its
   own fold). Per seed: AUROC of ``p_fail`` for failure, expected
   calibration error (10 bins), and, at the model's flag threshold, frame
   precision, recall and flagged share, for the track probability alone and
   corrected by the passes' agreement.
3. ``--write``: the section fitted on every sequence goes into
   ``annotator/data/failure_model.json`` (the rest of the file unchanged),
   and one model file per held-out sequence into ``--data``/folds (the
   installed model with that fold's section), for
   ``benchmarks/simulated_reviewer.py --fold-models``.
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
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

from _results import machine_line, update_section  # noqa: E402
from _sequences import SequenceError, select_sequences  # noqa: E402

from annotator.atomic import write_text_atomic  # noqa: E402
from annotator.config import RunConfig  # noqa: E402
from annotator.evaluation.calibration import auroc, expected_calibration_error  # noqa: E402
from annotator.failure import load_model  # noqa: E402
from annotator.failure.fit import fit_pass_agreement  # noqa: E402
from annotator.failure.model import MODEL_PATH  # noqa: E402
from annotator.flagging import FlagParams  # noqa: E402
from annotator.otb import read_otb_boxes  # noqa: E402
from annotator.review import ArrayFrames, retrack_tracks  # noqa: E402
from annotator.review.merge import PASS_IOU, track_p_fail  # noqa: E402
from annotator.review.segments import _iou  # noqa: E402
from annotator.frames import open_frames  # noqa: E402

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
    track = retrack_tracks(ArrayFrames(frames), np.arange(n), {1: anchors}, config).tracks[0]
    # The track probability as reflag computes it, from the model without any between_anchors section.
    model = dataclasses.replace(load_model(None), between_anchors=None)
    p_track, _ = track_p_fail(track.signals, track.keyframe, track.outside, model)
    pass_iou = np.asarray(track.signals.get(PASS_IOU, np.full(n, np.nan)), dtype=np.float64)
    use = ~np.isnan(pass_iou) & ~track.keyframe & ~track.outside
    out = Path(job["out"])
    np.savez(out, p_track=p_track[use], pass_iou=pass_iou[use],
             failed=_iou(track.boxes_xywh[use], gt[use]) < 0.5, position=np.flatnonzero(use))
    print(f"{seq_dir.name} seed {job['seed']} every {job['every']}: {int(use.sum())} frames", file=sys.stderr,
          flush=True)
    return str(out)


def load_data(folder: Path) -> dict[str, np.ndarray]:
    parts = []
    for path in sorted(folder.glob("*.npz")):
        name, seed, every = path.stem.rsplit("__", 2)
        with np.load(path) as d:
            k = len(d["failed"])
            parts.append(dict(sequence=np.full(k, name), seed=np.full(k, int(seed[1:])),
                              every=np.full(k, int(every[1:])), p_track=d["p_track"], pass_iou=d["pass_iou"],
                              failed=d["failed"]))
    if not parts:
        raise SystemExit(f"no data in {folder}: run with --generate first")
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def held_out(data: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, dict]]:
    """Per frame, ``p_fail`` from the section fitted without the frame's sequence; and each fold's section."""
    p = np.full(len(data["failed"]), np.nan)
    folds = {}
    for name in sorted(set(data["sequence"])):
        train, test = data["sequence"] != name, data["sequence"] == name
        section = fit_pass_agreement(data["p_track"][train], data["pass_iou"][train], data["failed"][train],
                                     info={"held_out": name})
        z = section.log_odds_of(data["p_track"][test], data["pass_iou"][test])
        p[test] = 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))
        folds[name] = section
    return p, folds


def metrics(p: np.ndarray, failed: np.ndarray, threshold: float) -> dict[str, float]:
    flagged = p > threshold
    return {"auroc": auroc(p, failed), "ece": expected_calibration_error(p, failed),
            "precision": float(failed[flagged].mean()) if flagged.any() else math.nan,
            "recall": float(flagged[failed].mean()) if failed.any() else math.nan,
            "flagged": float(flagged.mean())}


def mean_std(values, digits: int = 3) -> str:
    v = np.asarray(list(values), dtype=np.float64)
    return f"{v[0]:.{digits}f}" if v.size == 1 else f"{v.mean():.{digits}f} ± {v.std(ddof=1):.{digits}f}"


def markdown(data, p_held, threshold, command, seconds, shipped) -> str:
    seeds = sorted(set(data["seed"].tolist()))
    everies = sorted(set(data["every"].tolist()))
    names = sorted(set(data["sequence"]))
    rows = {"track probability alone": data["p_track"], "corrected by the passes' agreement (held out)": p_held}
    lines = ["## Failure probability between two human boxes: the passes' agreement (held out)", "",
             f"Command: `{command}`  ",
             f"Machine: {machine_line()}; wall time {seconds / 60:.1f} min.  ",
             f"Data: {len(names)} sequences of `../shared/otb` ({', '.join(names)}), preset `{PRESET}`, seeds "
             f"{', '.join(map(str, seeds))}, ground-truth anchors every {' and every '.join(map(str, everies))} "
             f"frames, re-tracked by the tool (`retrack_tracks`, merge `anchored`); {len(p_held)} frames strictly "
             f"between two anchors, {100 * data['failed'].mean():.1f}% failed (IoU < 0.5). Each sequence is scored "
             "by a section fitted on the other sequences (every seed and interval). Flags here are frames above "
             f"the model's threshold {threshold:g}, before span merging.", "",
             "| p_fail | AUROC | ECE | precision | recall | flagged share |", "|---|---:|---:|---:|---:|---:|"]
    for label, p in rows.items():
        per_seed = [metrics(p[data["seed"] == s], data["failed"][data["seed"] == s], threshold) for s in seeds]
        lines.append(f"| {label} | " + " | ".join(mean_std(m[k] for m in per_seed) for k in
                                                    ("auroc", "ece", "precision", "recall", "flagged")) + " |")
    lines += ["", "By anchor interval (pooled over seeds, AUROC alone → corrected): " + "; ".join(
        f"every {e}: {auroc(data['p_track'][data['every'] == e], data['failed'][data['every'] == e]):.3f} → "
        f"{auroc(p_held[data['every'] == e], data['failed'][data['every'] == e]):.3f}" for e in everies) + ".",
        "", f"Shipped section (fitted on every sequence): p = sigmoid({shipped.log_odds:.3f} logit(p_track) "
        f"{shipped.pass_iou:+.3f} pass_iou {shipped.intercept:+.3f})."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--otb", type=Path, default=ROOT.parent / "shared" / "otb")
    parser.add_argument("--sequences", default="all", help="comma-separated names, or 'all'")
    parser.add_argument("--stop", type=int, default=150, help="first N frames of each sequence (default 150)")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--every", default="10,30", help="anchor intervals M, comma-separated (default 10,30)")
    parser.add_argument("--data", type=Path, default=HERE / "_runs" / "anchored")
    parser.add_argument("--generate", action="store_true", help="track first (else use the stored data)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--write", action="store_true",
                        help=f"write the fitted section into annotator/{MODEL_PATH} and the fold models")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = parser.parse_args()
    try:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        everies = [int(v) for v in args.every.split(",") if v.strip()]
    except ValueError:
        parser.error(f"--seeds {args.seeds!r} and --every {args.every!r} must be comma-separated integers")
    if not seeds or not everies or min(everies) < 2:
        parser.error("--seeds needs at least one seed and --every intervals of at least 2 frames")
    started = time.perf_counter()
    if args.generate:
        try:
            sequences = select_sequences(args.otb, args.sequences)
        except SequenceError as err:
            parser.error(str(err))
        args.data.mkdir(parents=True, exist_ok=True)
        jobs = [dict(seq_dir=str(s), seed=seed, every=every, stop=args.stop, threads=1 if args.workers > 1 else 0,
                     out=str(args.data / f"{s.name}__s{seed}__m{every}.npz"))
                for seed in seeds for every in everies for s in sequences]
        with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn")) as pool:
            list(pool.map(generate, jobs))
    data = load_data(args.data)
    keep = np.isin(data["seed"], seeds) & np.isin(data["every"], everies)
    data = {k: v[keep] for k, v in data.items()}
    model = load_model(None)
    threshold = model.threshold
    p_held, folds = held_out(data)
    shipped = fit_pass_agreement(
        data["p_track"], data["pass_iou"], data["failed"],
        info={"fitted_by": "python benchmarks/anchored_failure.py --generate --write",
              "data": {"preset": PRESET, "seeds": seeds, "every": everies, "stop": args.stop,
                       "sequences": sorted(set(data["sequence"])), "frames": int(len(data["failed"]))}})
    command = "python benchmarks/anchored_failure.py " + " ".join(sys.argv[1:])
    text = markdown(data, p_held, threshold, command.strip(), time.perf_counter() - started, shipped)
    print(text)
    if args.write:
        base = dataclasses.replace(model, between_anchors=None)
        path = ROOT / "annotator" / MODEL_PATH
        write_text_atomic(path, json.dumps(dataclasses.replace(base, between_anchors=shipped).to_json(), indent=1)
                          + "\n")
        fold_dir = args.data / "folds"
        fold_dir.mkdir(parents=True, exist_ok=True)
        for name, section in folds.items():
            (fold_dir / f"{name}.json").write_text(
                json.dumps(dataclasses.replace(base, between_anchors=section).to_json(), indent=1) + "\n")
        print(f"wrote {path} and {len(folds)} fold models in {fold_dir}", file=sys.stderr)
    if not args.no_record:
        update_section("anchored-failure", text)


if __name__ == "__main__":
    main()

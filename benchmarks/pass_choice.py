"""Fit and measure which box a frame between two human boxes takes where the two passes disagree.

    python -m benchmarks.pass_choice --generate             # track (14 min), then fit and measure (RESULTS.md)
    python -m benchmarks.pass_choice --write                # refit on the stored data; write the package's model
    python -m benchmarks.pass_choice --generate --seeds 0 --sequences Deer,Diving --no-record

Re-tracking runs every frame between two anchors twice, forward from the
earlier human box and backward from the later one. Where the two boxes
differ (IoU < 0.5) one pass, or both, lost the object. The ``anchored``
merge then keeps the more confident pass, and ``chosen`` keeps the forward
box, the backward box or the linear interpolation of the two human boxes,
whichever the failure model's ``pass_choice`` section
(:class:`annotator.failure.model.PassChoice`) finds most probably right.

1. **Data** (``--generate``): for every sequence of ``../shared/otb`` (first
   ``--stop`` frames), every seed and every anchor interval of ``--every``,
   the tool's own re-tracking (:func:`annotator.review.retrack_tracks`, merge
   ``anchored``) from ground-truth boxes every M frames. Per frame strictly
   between two anchors: whether the ``anchored`` box, the forward box, the
   backward box and the interpolation were right (IoU >= 0.5 with the ground
   truth), and the frame's :data:`~annotator.failure.model.PASS_CHOICE_FEATURES`
   (each pass's own ``p_fail`` under the installed main model). Stored in
   ``--data``, one ``.npz`` per sequence, seed and M.
2. **Held out**: the sequences are split into folds by video (Jogging.1 and
   Jogging.2 are one video). A fold's frames are chosen by a section fitted on
   the other folds' disagreeing frames. Per seed: the share of frames between
   anchors whose box is right with ``anchored`` and with ``chosen``.
3. ``--write``: the section fitted on every sequence goes into the package's
   ``annotator/data/failure_model.json`` (the rest of the file unchanged),
   and one model file per sequence (that fold's section) into
   ``--data``/folds, for ``benchmarks/simulated_reviewer.py --fold-models``.
   A fold file's main part is the sequence's own fold model from
   ``--main-folds`` (fitted without its video by ``benchmarks/failure_model.py
   --write``; since 2026-11-27, 6th session), so the reviewer's flags are held
   out as well; where there is none, the installed main model.

The per-pass probabilities the section reads, in the data and so in its fit,
are the installed main model's: it was fitted on these sequences
(``benchmarks/failure_model.py``), so they are not themselves held out.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from importlib import resources
from pathlib import Path

import numpy as np

from annotator.atomic import write_text_atomic
from annotator.config import DEFAULT_PRESET, RunConfig
from annotator.evaluation.calibration import auroc, expected_calibration_error
from annotator.failure import FailureModelError, load_model
from annotator.failure.fit import fit_pass_choice
from annotator.failure.model import PASS_CHOICE_FEATURES, PASS_OPTIONS, shipped_model_path
from annotator.flagging import FlagParams
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from annotator.review import ArrayFrames, retrack_tracks
from annotator.review.merge import merge_passes, pass_choice_features, pass_p_fail
from benchmarks._anchor_runs import add_arguments, mean_std, stored_data, stored_rows, video
from benchmarks._results import machine_line, update_section
from sptpt.boxes import iou_xywh
from sptpt.params import get_preset

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

PRESET = DEFAULT_PRESET
#: Whether PRESET runs a learned tracker beside SPTPT: its passes are scored, and its section written, by the
#: shipped model of such runs.
GUIDED = get_preset(PRESET).uses_guide
#: Rows whose passes' IoU is below this are chosen for (the failure model's own line between right and wrong).
DISAGREE_BELOW = 0.5


def generate(job: dict) -> str:
    """Re-track one sequence from ground-truth anchors every ``every`` frames; store the rows between anchors."""
    import numba

    if job.get("threads"):
        numba.set_num_threads(job["threads"])
    seq_dir = Path(job["seq_dir"])
    frames = [frame for _, frame in open_frames(seq_dir, stop=job["stop"])]
    n = len(frames)
    gt = read_otb_boxes(seq_dir / "groundtruth_rect.txt")[:n]
    anchors = {p: tuple(gt[p]) for p in sorted(set(range(0, n, job["every"])) | {n - 1})}
    config = RunConfig(preset=PRESET, tracker=get_preset(PRESET), flags=FlagParams(), seed=job["seed"],
                       failure_model=None)
    result = retrack_tracks(ArrayFrames(frames), np.arange(n), {1: anchors}, config, merge="anchored")
    model = load_model(guided=GUIDED)
    parts = []
    for (_, start, stop), (fwd, bwd) in sorted(result.passes.items()):
        if bwd is None or stop - start < 2:
            continue
        truth = gt[start + 1: stop]

        def right(boxes, truth=truth):
            return np.nan_to_num(iou_xywh(boxes, truth), nan=0.0) >= 0.5

        features, interpolation = pass_choice_features(
            pass_p_fail(fwd, model, backward=False), pass_p_fail(bwd, model, backward=True), fwd.boxes_xywh,
            bwd.boxes_xywh, (gt[start], gt[stop]))
        parts.append(dict(features=features, anchored=right(merge_passes(fwd, bwd, "anchored").boxes_xywh),
                          options=np.stack([right(fwd.boxes_xywh), right(bwd.boxes_xywh), right(interpolation)], 1),
                          gap=np.full(len(features), stop - start)))
    out = Path(job["out"])
    np.savez(out, stop=job["stop"], feature_names=np.array(PASS_CHOICE_FEATURES), main_model=main_model_digest(model),
             **{k: np.concatenate([p[k] for p in parts]) for k in ("features", "anchored", "options", "gap")})
    print(f"{seq_dir.name} seed {job['seed']} every {job['every']}: {sum(len(p['anchored']) for p in parts)} frames",
          file=sys.stderr, flush=True)
    return str(out)


def main_model_digest(model) -> str:
    """sha256 of the main part of a failure model (its optional sections left out): the per-pass probabilities
    stored with the rows are this part's, so rows stored under another main part are stale."""
    main = dataclasses.replace(model, between_anchors=None, pass_choice=None)
    return hashlib.sha256(json.dumps(main.to_json(), sort_keys=True).encode()).hexdigest()


def load_data(folder: Path, sequences: set[str], seeds, everies, stop: int) -> dict[str, np.ndarray]:
    """The stored rows of the given sequences, seeds and intervals, tracked with ``stop`` and scored by the
    installed main failure model."""
    digest = main_model_digest(load_model(guided=GUIDED))

    def check(path: Path, d) -> None:
        if int(d["stop"]) != stop or tuple(d["feature_names"]) != PASS_CHOICE_FEATURES or "gap" not in d:
            raise SystemExit(f"{path} was generated with another --stop, for other features or by an older "
                             "version of this script: run with --generate again")
        if "main_model" not in d or str(d["main_model"]) != digest:
            raise SystemExit(f"{path} holds per-pass probabilities of another main failure model than the "
                             "installed one: run with --generate again")

    return stored_rows(folder, sequences, seeds, everies, ("anchored", "features", "options", "gap"), check)


def _choose(data: dict[str, np.ndarray], section, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(disagree, picks, p_right)`` on ``rows`` (a boolean mask): which of them the ``chosen`` merge chooses on,
    its pick there, and each option's probability of being right there."""
    disagree = data["features"][rows, PASS_CHOICE_FEATURES.index("pass_iou")] < section.disagree_below
    features = data["features"][rows][disagree]
    return disagree, section.choose(features, data["gap"][rows][disagree] <= section.max_gap), \
        section.p_right(features)


def fit_section(data: dict[str, np.ndarray], rows: np.ndarray, max_gap: int, info: dict):
    disagree = rows & (data["features"][:, PASS_CHOICE_FEATURES.index("pass_iou")] < DISAGREE_BELOW)
    return fit_pass_choice(data["features"][disagree], data["options"][disagree], data["gap"][disagree],
                           disagree_below=DISAGREE_BELOW, max_gap=max_gap, info=info)


def held_out(data: dict[str, np.ndarray], max_gap: int) -> tuple[np.ndarray, dict, dict[str, np.ndarray]]:
    """Each video's rows chosen by a section fitted without that video: per row, whether the ``chosen`` box is
    right; each sequence's fold section; and on the rows where the passes disagree, how doubtful the chosen box
    is: whether it is wrong, the section's probability that it is (1 - the chosen option's probability of being
    right), and the p_fail the row keeps in the tool (its source pass's own; for an interpolated row, that of the
    pass that doubts itself less)."""
    right = np.zeros(len(data["anchored"]), bool)
    folds = {}
    doubt: dict[str, list[np.ndarray]] = {"wrong": [], "section": [], "kept": []}
    fold_of = np.array([video(name) for name in data["sequence"]])
    for fold in sorted(set(fold_of)):
        test = fold_of == fold
        section = fit_section(data, ~test, max_gap, {"held_out": fold})
        disagree, picks, p_right = _choose(data, section, test)
        taken_right = data["options"][test][disagree][np.arange(len(picks)), picks]
        fold_right = data["anchored"][test].copy()
        fold_right[disagree] = taken_right
        right[test] = fold_right
        features = data["features"][test][disagree]
        p_forward, p_backward = (1.0 / (1.0 + np.exp(-features[:, PASS_CHOICE_FEATURES.index(name)]))
                                 for name in ("logit_p_forward", "logit_p_backward"))
        index = np.arange(len(picks))
        doubt["wrong"].append(~taken_right)
        doubt["section"].append(1.0 - p_right[index, picks])
        doubt["kept"].append(np.choose(picks, [p_forward, p_backward, np.minimum(p_forward, p_backward)]))
        for name in set(data["sequence"][test]):
            folds[name] = dataclasses.replace(section, info={"held_out": name, "fold": fold})
    return right, folds, {k: np.concatenate(v) for k, v in doubt.items()}


def markdown(data, chosen, command, seconds, shipped, generated: bool, doubt: dict[str, np.ndarray]) -> str:
    seeds = sorted(set(data["seed"].tolist()))
    everies = sorted(set(data["every"].tolist()))
    names = sorted(set(data["sequence"]))
    disagree = data["features"][:, PASS_CHOICE_FEATURES.index("pass_iou")] < DISAGREE_BELOW
    anchored = data["anchored"]
    threshold = load_model(guided=GUIDED).threshold

    def share(right, rows):
        return [right[rows & (data["seed"] == s)].mean() for s in seeds]

    everywhere = np.ones(len(anchored), bool)
    taken = np.zeros((len(anchored), 3), bool)
    lines = ["## Which box between two human boxes: the passes' choice (issue #9, held out)", "",
             f"Command: `{command}`  ",
             f"Machine: {machine_line()}; wall time {seconds / 60:.1f} min"
             + ("." if generated else ", fitting only: the rows were tracked before by the same command with "
                "`--generate`.") + "  ",
             f"Data: {len(names)} sequences of `../shared/otb`, preset `{PRESET}`, seeds "
             f"{', '.join(map(str, seeds))}, ground-truth anchors every {' and every '.join(map(str, everies))} "
             f"frames, re-tracked by the tool (`retrack_tracks`); {len(anchored)} frames strictly between two "
             f"anchors, {int(disagree.sum())} of them ({100 * disagree.mean():.1f}%) where the passes disagree "
             f"(IoU < {DISAGREE_BELOW}). Held out by video (Jogging.1 and Jogging.2 one fold): each fold's frames "
             "are chosen by a section fitted on the other folds. Share of frames whose box is right (IoU >= 0.5), "
             "mean ± std over seeds:", "",
             "| merge | all frames between anchors | where the passes disagree |", "|---|---:|---:|"]
    for label, right in (("`anchored` (before)", anchored), ("`chosen` (held out)", chosen)):
        lines.append(f"| {label} | {mean_std(share(right, everywhere))} | {mean_std(share(right, disagree))} |")
    for k in range(len(PASS_OPTIONS)):
        taken[:, k] = data["options"][:, k]
    lines.append("| always forward / backward / interpolation, where they disagree | | "
                 + " / ".join(mean_std(share(taken[:, k], disagree)) for k in range(3)) + " |")
    lines.append(f"| either pass right (no rule can beat it without the interpolation) | | "
                 f"{mean_std(share(taken[:, 0] | taken[:, 1], disagree))} |")
    wrong = doubt["wrong"].astype(bool)
    lines += ["", f"How doubtful the chosen box is, on the {len(wrong)} frames where the passes disagree (held out; "
              f"{wrong.mean():.3f} of them wrong): the section's own probability that the chosen box is wrong ranks "
              f"those failures at AUROC {auroc(doubt['section'], wrong):.3f} (ECE "
              f"{expected_calibration_error(doubt['section'], wrong):.3f}); the p_fail such a frame keeps in the tool, "
              f"its source pass's own (for an interpolated frame, that of the pass that doubts itself less), at AUROC "
              f"{auroc(doubt['kept'], wrong):.3f} (ECE {expected_calibration_error(doubt['kept'], wrong):.3f}); "
              f"above the main model's flag threshold {threshold:g}: {int((doubt['section'] > threshold).sum())} and "
              f"{int((doubt['kept'] > threshold).sum())} frames. (Each pass's p_fail here is scored along the pass "
              "alone; "
              "the tool scores the merged track.)"]
    lines += ["", "Per sequence (all seeds pooled), frames right between anchors, `anchored` → `chosen`: " + "; ".join(
        f"{name} {anchored[data['sequence'] == name].mean():.3f} → {chosen[data['sequence'] == name].mean():.3f}"
        for name in names) + ".",
        "", f"Shipped section (fitted on every sequence, max_gap {shipped.max_gap}): coefficients per option on the "
        "standardised features " + "; ".join(
            f"{option}: " + ", ".join(f"{f} {c:+.2f}" for f, c in zip(PASS_CHOICE_FEATURES, shipped.coef[k]))
            + f", intercept {shipped.intercept[k]:+.2f}" for k, option in enumerate(PASS_OPTIONS)) + "."]
    return "\n".join(lines) + "\n"


def held_out_main(folder: Path, name: str, parser: argparse.ArgumentParser):
    """The main model fitted without ``name``'s video, from ``folder``, or None where there is none."""
    path = folder / f"{name}.json"
    if not path.is_file():
        return None
    try:
        model = load_model(path)
    except FailureModelError as exc:
        parser.error(f"--main-folds: {exc}")
    if model.info.get("held_out") != name:
        parser.error(f"--main-folds: {path} is not the fold model of {name} (its info.held_out is "
                     f"{model.info.get('held_out')!r}); write the folds again with benchmarks/failure_model.py --write")
    return dataclasses.replace(model, pass_choice=None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser, otb=ROOT.parent / "shared" / "otb", stop=200, every="10",
                  every_help="anchor intervals M, comma-separated (default 10: the interval of the tool's keyframe "
                             "request; with several, the interpolation is an option up to the longest)",
                  data=HERE / "_runs" / "pass_choice")
    parser.add_argument("--write", action="store_true",
                        help="write the section into the package's failure model, and the fold models")
    parser.add_argument("--main-folds", type=Path, default=HERE / "_runs" / "failure" / "folds", metavar="DIR",
                        help="each sequence's main model fitted without its video, DIR/SEQUENCE.json (written by "
                             "benchmarks/failure_model.py --write): --write builds that sequence's fold model on it; "
                             "a sequence without one gets the installed main model (default: %(default)s)")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = parser.parse_args()
    started = time.perf_counter()
    seeds, everies, data = stored_data(parser, args, generate, load_data)
    max_gap = max(everies)
    chosen, folds, doubt = held_out(data, max_gap)
    command = "python -m benchmarks.pass_choice " + " ".join(sys.argv[1:])
    shipped = fit_section(data, np.ones(len(chosen), bool), max_gap, {
        "fitted_by": command.strip(), "data": {"preset": PRESET, "seeds": seeds, "every": everies, "stop": args.stop,
                                               "sequences": sorted(set(data["sequence"])),
                                               "frames": int(len(chosen))}})
    text = markdown(data, chosen, command.strip(), time.perf_counter() - started, shipped, args.generate, doubt)
    print(text)
    if args.write:
        model = load_model(guided=GUIDED)
        package_file = Path(str(resources.files("annotator").joinpath(shipped_model_path(guided=GUIDED))))
        write_text_atomic(package_file, json.dumps(dataclasses.replace(model, pass_choice=shipped).to_json(),
                                                   indent=1) + "\n")
        fold_dir = args.data / "folds"
        fold_dir.mkdir(parents=True, exist_ok=True)
        held_main = 0
        for name, section in folds.items():
            main_part = held_out_main(args.main_folds, name, parser)
            held_main += main_part is not None
            write_text_atomic(fold_dir / f"{name}.json", json.dumps(dataclasses.replace(
                model if main_part is None else main_part, pass_choice=section).to_json(), indent=1) + "\n")
        print(f"wrote {package_file} and {len(folds)} fold models in {fold_dir} ({held_main} on a main model fitted "
              f"without the sequence's video, from {args.main_folds}; the rest on the installed one)",
              file=sys.stderr)
    if not args.no_record:
        update_section("pass-choice", text)


if __name__ == "__main__":
    main()

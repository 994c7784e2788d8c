"""Independent runs, paired: does the per-frame choice beat the same runs tracked alone?

    python -m benchmarks.paired_runs benchmarks/_runs/otb6 --tracker robust
    python -m benchmarks.paired_runs benchmarks/_runs/otb6 --tracker robust --sequences Girl,Human9
    python -m benchmarks.paired_runs benchmarks/_runs/otb6 --tracker robust --rechoose contrast

A tracker with ``independent_runs`` R > 1 (``robust``) tracks R one-run
trackers side by side and reports, each frame, one run's box
(``TrackerParams.run_choice``: the more confident run, or the one whose box
stands out most from its surroundings) or the mean box of the runs that
agree (``"consensus"``).
The runs never see each other's results, so each run's boxes are exactly what
that run would have given alone (``tests/sptpt/test_independent_runs.py`` checks
this). ``benchmarks/_sptpt_runner.py`` stores them (``run_boxes`` in
``<Seq>.frames.npz``), so the comparison that separates the choice from the
luck of the seeds costs no extra tracking: for every seed folder of an
``otb_benchmark.py`` run, the success AUC of the choice, of each run alone,
and of the choice minus the mean of its runs, per seed and per sequence.

``--rechoose contrast`` scores instead the choice ``run_choice="contrast"``
would have made from the same runs (:func:`sptpt.contrast.most_contrasted`
on each frame, read again from ``--otb``; the stored choice breaks ties, as
the tracker's confident run does when the stored run chose by confidence).
Exact, because a run's boxes do not depend on the choice: this is how the
contrast choice was measured from runs tracked by confidence.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from annotator.evaluation.metrics import evaluate_sequence
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from benchmarks._sequences import SequenceError, select_sequences
from sptpt.contrast import most_contrasted

HERE = Path(__file__).resolve().parent


class PairedError(ValueError):
    """A run folder that holds no per-run boxes; the message says what to run first."""


def seed_folders(out: Path) -> list[Path]:
    """``out/seed<k>`` folders in seed order, or ``out`` itself for a single-seed run."""
    folders = [p for p in out.glob("seed*") if p.name[4:].isdigit()]
    return sorted(folders, key=lambda p: int(p.name[4:])) or [out]


def sequence_aucs(folder: Path, tracker: str, gt: dict[str, np.ndarray], rechoose: str | None = None,
                  otb: Path | None = None) -> dict[str, np.ndarray]:
    """Sequence -> AUC of ``[choice, run 1 alone, run 2 alone, ...]`` from one seed's stored results.

    ``rechoose="contrast"``: the choice is made again from the run boxes by colour contrast, on the frames of
    ``otb``/<sequence>.
    """
    aucs = {}
    for name, truth in gt.items():
        frames = folder / tracker / f"{name}.frames.npz"
        if not frames.is_file():
            raise PairedError(f"{frames}: missing; track it first with benchmarks/otb_benchmark.py "
                              f"--trackers {tracker} --out pointing at the folder given here")
        with np.load(frames) as stored:
            if "run_boxes" not in stored:
                raise PairedError(f"{frames}: no per-run boxes; the tracker {tracker!r} has one run, or the file "
                                  "predates them: track again with benchmarks/otb_benchmark.py")
            runs = stored["run_boxes"]
        choice = read_otb_boxes(folder / tracker / f"{name}.txt")
        truth = truth[: len(choice)]
        if rechoose == "contrast":
            choice = contrast_choice(otb / name, runs, choice)
        boxes = [choice, *(runs[:, r] for r in range(runs.shape[1]))]
        aucs[name] = np.array([evaluate_sequence(b, truth, name=name).auc for b in boxes])
    return aucs


def contrast_choice(seq_dir: Path, runs: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """Per frame, the run box :func:`most_contrasted` picks, the stored choice's run breaking ties."""
    boxes = stored.copy()
    for k, (_, frame) in enumerate(open_frames(seq_dir, stop=len(stored))):
        # The stored text keeps 3 decimals: the stored choice is the run whose box it rounds (for a consensus
        # tracker, whose reported box may be a mean, the run nearest it).
        default = int(np.argmin(np.abs(runs[k] - stored[k]).max(axis=1)))
        boxes[k] = runs[k, most_contrasted(frame, runs[k], default)]
    return boxes


def _mean_std(values: np.ndarray) -> str:
    """Mean ± sample standard deviation (as otb_benchmark.py reports seeds); the mean alone for one value."""
    return f"{values.mean():.3f}" if len(values) == 1 else f"{values.mean():.3f} ± {values.std(ddof=1):.3f}"


def paired_table(per_seed: dict[Path, dict[str, np.ndarray]]) -> str:
    """Markdown: per seed, the choice, each run alone, and the choice minus the mean of its runs."""
    n_runs = len(next(iter(next(iter(per_seed.values())).values()))) - 1
    head = "| seed folder | choice | " + " | ".join(f"run {r + 1} alone" for r in range(n_runs)) + \
           " | choice minus the mean of its runs |"
    lines = [head, "|---|" + "---:|" * (n_runs + 2)]
    gains = []
    for folder, aucs in per_seed.items():
        mean = np.mean(list(aucs.values()), axis=0)
        gains.append(mean[0] - mean[1:].mean())
        lines.append(f"| {folder.name} | " + " | ".join(f"{v:.3f}" for v in mean) + f" | {gains[-1]:+.3f} |")
    all_means = np.array([np.mean(list(a.values()), axis=0) for a in per_seed.values()])
    singles = all_means[:, 1:].ravel()
    lines.append(f"| **mean ± std** | {_mean_std(all_means[:, 0])} | "
                 + " | ".join([f"all single runs: {_mean_std(singles)}"]
                              + [""] * (n_runs - 1))
                 + f" | {np.mean(gains):+.3f} ({sum(g > 0 for g in gains)} of {len(gains)} positive) |")
    return "\n".join(lines)


def sequence_table(per_seed: dict[Path, dict[str, np.ndarray]]) -> str:
    """Markdown: per sequence, over seeds, the choice against the mean of its runs."""
    names = list(next(iter(per_seed.values())))
    lines = ["| sequence | choice | mean of its runs alone | difference |", "|---|---:|---:|---:|"]
    for name in names:
        choice = np.array([a[name][0] for a in per_seed.values()])
        alone = np.array([a[name][1:].mean() for a in per_seed.values()])
        lines.append(f"| {name} | {choice.mean():.3f} | {alone.mean():.3f} | {choice.mean() - alone.mean():+.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="an otb_benchmark.py --out folder (with seed<k>/ folders or not)")
    parser.add_argument("--tracker", default="robust", help="the SPTPT tracker name in that run (default robust)")
    parser.add_argument("--otb", type=Path, default=HERE.parent.parent / "shared" / "otb")
    parser.add_argument("--sequences", default="", help="comma-separated names, or 'all' (the default)")
    parser.add_argument("--rechoose", choices=("contrast",), default=None,
                        help="score the choice run_choice='contrast' makes from the stored runs instead of the "
                             "stored one")
    args = parser.parse_args(argv)
    try:
        sequences = select_sequences(args.otb, args.sequences)
        if not args.out.is_dir():
            raise PairedError(f"{args.out}: not a folder; give the --out folder of an otb_benchmark.py run")
        gt = {s.name: read_otb_boxes(s / "groundtruth_rect.txt") for s in sequences}
        per_seed = {folder: sequence_aucs(folder, args.tracker, gt, args.rechoose, args.otb)
                    for folder in seed_folders(args.out)}
    except (SequenceError, PairedError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    what = "the choice by contrast made again from its runs" if args.rechoose else "its per-frame choice"
    print(f"Success AUC of `{args.tracker}`: {what}, and each of its runs alone ({args.out}, "
          f"{len(sequences)} sequences):\n")
    print(paired_table(per_seed))
    print("\nPer sequence, mean over seed folders:\n")
    print(sequence_table(per_seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())

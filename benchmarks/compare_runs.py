"""Success AUC of two sets of stored batch runs of the same sequences and seeds, paired.

    python -m benchmarks.compare_runs --otb ../shared/otb \\
        --before 'benchmarks/_runs/failure/otb/robust-s*' --after 'benchmarks/_runs/failure/otb/prescreen-s*'

Each glob names batch output folders (``sptpt-annotate batch --otb-root ... --seed S``, one folder per seed, as
``benchmarks/failure_model.py``'s docstring makes them). Runs are paired by seed (``summary.json``) and
sequence, so a change is judged on the same seeds: the overall AUC per seed and its mean ± std over seeds for
each side, the paired difference, and per sequence the mean over seeds of each side and their difference
(sequences that lost more than ``--worst`` marked). Also the tracker's own time per frame as the runs stored it
(frames 2..N, ``TrackResult.seconds``): a figure of the machine the runs were made on, comparable between the two
sides only when both were made the same day on the same machine.
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np

from annotator.evaluation import evaluate_sequence
from annotator.otb_format import read_otb_boxes
from annotator.track_store import STORE_NAME, read_store
from benchmarks._sequences import ground_truth_file


def load_runs(pattern: str, roots: list[Path]) -> tuple[dict[tuple[str, int], float], dict[int, float]]:
    """(sequence, seed) -> success AUC, and seed -> mean tracker seconds per frame, of the runs ``pattern`` names."""
    aucs, seconds = {}, {}
    folders = sorted(p for p in map(Path, glob.glob(pattern)) if (p / "summary.json").is_file())
    if not folders:
        raise SystemExit(f"{pattern!r}: no batch output folder (with summary.json) matches; give the folders of "
                         "'sptpt-annotate batch --otb-root ...' runs")
    for run in folders:
        seed = int(json.loads((run / "summary.json").read_text())["settings"]["base_seed"])
        per_frame = []
        for folder in sorted(p for p in run.iterdir() if (p / STORE_NAME).is_file()):
            track = read_store(folder / STORE_NAME).tracks[0]
            gt = read_otb_boxes(ground_truth_file(roots, folder.name))[track.frame_indices]
            aucs[(folder.name, seed)] = evaluate_sequence(track.boxes_xywh, gt, name=folder.name).auc
            per_frame.append(track.seconds[1:])
        seconds[seed] = float(np.concatenate(per_frame).mean())
    return aucs, seconds


def compare(before: dict, after: dict, worst: float) -> list[str]:
    """The report's lines: overall per seed, mean ± std, paired difference; then per sequence."""
    pairs = set(before) & set(after)
    if not pairs:
        raise SystemExit("the two sets of runs share no (sequence, seed): compare runs of the same sequences and seeds")
    seeds = sorted({seed for _, seed in pairs})
    sequences = sorted({name for name, _ in pairs})
    lines = [f"{len(sequences)} sequences, seeds {', '.join(map(str, seeds))} (pairs present in both sets only)", "",
             "| seed | before | after | after - before |", "|---:|---:|---:|---:|"]
    overall = {side: [] for side in ("before", "after")}
    for seed in seeds:
        b = np.mean([before[(s, seed)] for s in sequences if (s, seed) in pairs])
        a = np.mean([after[(s, seed)] for s in sequences if (s, seed) in pairs])
        overall["before"].append(b)
        overall["after"].append(a)
        lines.append(f"| {seed} | {b:.3f} | {a:.3f} | {a - b:+.3f} |")
    b, a = np.array(overall["before"]), np.array(overall["after"])
    lines.append(f"| mean ± std | {b.mean():.3f} ± {b.std(ddof=1) if len(b) > 1 else 0:.3f} | "
                 f"{a.mean():.3f} ± {a.std(ddof=1) if len(a) > 1 else 0:.3f} | {(a - b).mean():+.3f} |")
    lines += ["", "| sequence | before | after | after - before |", "|---|---:|---:|---:|"]
    for name in sequences:
        b_seq = np.mean([before[(name, s)] for s in seeds if (name, s) in pairs])
        a_seq = np.mean([after[(name, s)] for s in seeds if (name, s) in pairs])
        mark = " **lower by more than %.2f**" % worst if a_seq - b_seq < -worst else ""
        lines.append(f"| {name} | {b_seq:.3f} | {a_seq:.3f} | {a_seq - b_seq:+.3f}{mark} |")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="glob of the batch output folders before the change")
    parser.add_argument("--after", required=True, help="glob of the batch output folders after the change")
    parser.add_argument("--otb", type=Path, action="append", required=True,
                        help="OTB root(s) holding each sequence's groundtruth_rect.txt (repeatable)")
    parser.add_argument("--worst", type=float, default=0.03, help="mark sequences whose mean AUC fell by more")
    args = parser.parse_args(argv)
    before, before_seconds = load_runs(args.before, args.otb)
    after, after_seconds = load_runs(args.after, args.otb)
    print("\n".join(compare(before, after, args.worst)))
    print("\ntracker ms per frame (as stored, mean over seeds): "
          f"before {1e3 * np.mean(list(before_seconds.values())):.1f}, "
          f"after {1e3 * np.mean(list(after_seconds.values())):.1f}")


if __name__ == "__main__":
    main()

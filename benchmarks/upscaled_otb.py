"""The default's accuracy on ``../shared/otb`` resized to HD: the same content, a bigger frame (issue #69).

Every sequence of the OTB root is resized to ``--size`` (``cv2.INTER_LINEAR``, each axis on its own, so 4:3
content is stretched to 16:9), written as a JPEG image folder (quality 95, the images' own names) with its ground
truth scaled the same way, under ``WORK/otb_WxH``. Then, per seed, the whole set runs through ``sptpt-annotate
batch`` (``--no-render --formats otb,flags``, the default preset) and is scored against the scaled ground truth;
``--native`` names the runs of the same seeds on the original frames (e.g. the ``fused-s*`` folders of RESULTS.md,
"The fused preset"), scored against the original ground truth in the same call.

    python -m benchmarks.upscaled_otb --size 1920x1080 --seeds 0,1,2 --work /tmp/upscaled \\
        --native '/tmp/runs/failure/otb/fused-s*'

Prints success AUC per sequence and overall (mean ± std over seeds) at both sizes, and their difference.
"""

from __future__ import annotations

import argparse
import glob
import re
import statistics
import subprocess
import sys
from pathlib import Path

import cv2

from annotator.evaluation import evaluate_results_dir

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "otb"


def _scaled_row(row: str, sx: float, sy: float) -> str:
    """One ground-truth row (1-based x, y, w, h; commas, tabs or spaces) in the resized frame, 1-based again."""
    values = [float(v) for v in re.split(r"[,\t ]+", row.strip()) if v]
    x, y, w, h = values[:4]
    return f"{(x - 1) * sx + 1:.3f},{(y - 1) * sy + 1:.3f},{w * sx:.3f},{h * sy:.3f}\n"


def make_resized_root(root: Path, size: tuple[int, int], work: Path) -> Path:
    """``root``'s sequences resized to ``size`` under ``work/otb_WxH`` (made once; a finished sequence is kept)."""
    out_root = work / f"otb_{size[0]}x{size[1]}"
    for source in sorted(p for p in root.iterdir() if (p / "img").is_dir()):
        folder = out_root / source.name
        if (folder / "groundtruth_rect.txt").exists():
            continue
        (folder / "img").mkdir(parents=True, exist_ok=True)
        files = sorted((source / "img").iterdir())
        first = cv2.imread(str(files[0]))
        sx, sy = size[0] / first.shape[1], size[1] / first.shape[0]
        for file in files:
            image = cv2.resize(cv2.imread(str(file)), size, interpolation=cv2.INTER_LINEAR)
            cv2.imwrite(str(folder / "img" / f"{file.stem}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 95])
        rows = [r for r in (source / "groundtruth_rect.txt").read_text().splitlines() if r.strip()]
        # Written last: its presence marks a finished sequence.
        (folder / "groundtruth_rect.txt").write_text("".join(_scaled_row(r, sx, sy) for r in rows))
    return out_root


def run_seed(otb_root: Path, out: Path, seed: int) -> None:
    tool = str(Path(sys.executable).with_name("sptpt-annotate"))
    subprocess.run([tool, "batch", "--otb-root", str(otb_root), "--out", str(out), "--seed", str(seed),
                    "--no-render", "--formats", "otb,flags", "--workers", "2", "--quiet"], check=True)


def scores(otb_root: Path, runs: list[Path]) -> dict[str, list[float]]:
    """``{sequence: [AUC per run]}`` with ``"all"`` the mean over sequences, per run."""
    table: dict[str, list[float]] = {}
    for run in runs:
        score = evaluate_results_dir(otb_root, run)
        for name, seq in score.sequences.items():
            table.setdefault(name, []).append(seq.auc)
        table.setdefault("all", []).append(score.auc)
    return table


def _cell(values: list[float]) -> str:
    spread = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):.3f} ± {spread:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--otb", type=Path, default=SHARED)
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--work", type=Path, default=Path("/tmp/upscaled"))
    parser.add_argument("--native", help="glob of the runs of the same seeds on the original frames")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    assert len(size) == 2
    seeds = [int(s) for s in args.seeds.split(",")]
    resized = make_resized_root(args.otb, (size[0], size[1]), args.work)
    runs = []
    for seed in seeds:
        out = args.work / f"runs_{args.size}" / f"s{seed}"
        if not (out / "summary.json").is_file():
            run_seed(resized, out, seed)
        runs.append(out)
    big = scores(resized, runs)
    native = scores(args.otb, sorted(Path(p) for p in glob.glob(args.native))) if args.native else {}
    print(f"| sequence | {args.size} | native | difference |")
    print("|---|---|---|---|")
    for name in [n for n in big if n != "all"] + ["all"]:
        here = big[name]
        there = native.get(name)
        difference = f"{statistics.mean(here) - statistics.mean(there):+.3f}" if there else "-"
        print(f"| {name} | {_cell(here)} | {_cell(there) if there else '-'} | {difference} |")


if __name__ == "__main__":
    main()

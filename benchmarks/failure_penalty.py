"""L1 against L2: which penalty of the failure model's logistic regression ranks and flags held-out videos better.

    python -m benchmarks.failure_penalty --runs 'benchmarks/_runs/failure/robust-s*'

The same runs as ``benchmarks/failure_model.py`` (its docstring has the batch commands). For each penalty and
each C of ``--C``, every video is scored by a model fitted on the other videos, every signal offered, C fixed
(not chosen per fold), recalibrated and its threshold chosen on its own training videos, exactly as
``annotator.failure.fit.fit_model`` does it; only the regression differs. L1 is the product's
(``annotator.failure.fit.l1_fit``); L2 is the regression it replaced (scikit-learn's default penalty, lbfgs).
Prints the held-out figures, mean ± std over seeds, and records them in RESULTS.md (section "failure-penalty").

This is how the penalty was chosen (2026-11-27, 6th session), on the sequences whose held-out figures
``failure_model.py`` reports: those figures measure the procedure, not the choice of it (RESULTS.md says so).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import annotator.failure.fit as fit
from annotator.flagging import FlagParams
from benchmarks._results import machine_line, update_section
from benchmarks.failure_model import (
    checked_C_and_workers,
    flag_metrics,
    fmt,
    held_out,
    load_samples,
    mean_std,
    per_seed_probability,
    run_preset,
)

ROOT = Path(__file__).resolve().parents[1]


def l2_fit(X: np.ndarray, y: np.ndarray, C: float):
    """The regression before L1: the same standardisation, scikit-learn's default L2 penalty."""
    from sklearn.linear_model import LogisticRegression

    Z, mean, scale = fit.standardised(X)
    model = LogisticRegression(C=C, max_iter=5000, solver="lbfgs").fit(Z, y.astype(int))
    return mean, scale, model.coef_[0].astype(np.float64), float(model.intercept_[0])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", nargs="+", default=["benchmarks/_runs/failure/robust-s*"])
    parser.add_argument("--otb", type=Path, default=ROOT.parent / "shared" / "otb")
    parser.add_argument("--C", default="0.001,0.003,0.01,0.03", help="comma-separated C values (default %(default)s)")
    parser.add_argument("--workers", type=int, default=2, help="processes for the held-out folds (default 2)")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = parser.parse_args()
    grid = checked_C_and_workers(parser, args)
    started = time.time()
    samples, aucs, _ = load_samples(args.runs, args.otb)
    run_preset(args.runs)  # one preset, and at least one run
    rows = ["| penalty | C | AUROC | ECE | precision | recall | share on AUC >= 0.6 | weights exactly 0 |",
            "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for penalty, regression in (("L2", l2_fit), ("L1", fit.l1_fit)):
        for C in grid:
            results, models = held_out(samples, C=C, workers=args.workers, regression=regression)
            # L2 leaves a weight at exactly 0 only on a constant column (its scale set to 1); L1 on many more.
            if penalty == "L2" and any(np.any((m.coef == 0.0) & (m.scale != 1.0)) for m in models.values()):
                raise SystemExit("an L2 fold model has a weight of exactly 0: the folds were fitted with another "
                                 "regression than l2_fit")
            prob = per_seed_probability(results)
            flags = flag_metrics(results, aucs, FlagParams(lost_threshold=None))
            zeros = np.mean([np.sum(m.coef == 0.0) for m in models.values()])
            rows.append(f"| {penalty} | {C:g} | {fmt(mean_std(prob, 'auroc'))} | {fmt(mean_std(prob, 'ece'))} | "
                        f"{fmt(mean_std(flags, 'precision'))} | {fmt(mean_std(flags, 'recall'))} | "
                        f"{fmt(mean_std(flags, 'good_flagged_share'))} | "
                        f"{zeros:.1f} of {len(models[next(iter(models))].coef)} |")
            print(rows[-1], flush=True)
    if args.no_record:
        return 0
    command = "python -m benchmarks.failure_penalty --runs " + " ".join(f"'{g}'" for g in args.runs) + \
              (f" --C {args.C}" if args.C != "0.001,0.003,0.01,0.03" else "")
    update_section("failure-penalty", "\n".join([
        "## Failure model: sparse (L1 against L2 at fixed C, held out by video)",
        "",
        f"Command: `{command}`  ",
        f"Machine: {machine_line()}; wall time {time.time() - started:.0f} s.  ",
        "Every video scored by a model fitted on the others (Jogging.1 and Jogging.2 held out together), every "
        "signal offered, C fixed in every fold, recalibrated and thresholded on its training videos as the product "
        "does; mean ± std over seeds; weights exactly 0: mean over the folds.",
        "",
        *rows,
    ]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How well a failure probability ranks and predicts failures: AUROC, expected calibration error, reliability.

A frame **fails** when its IoU with the ground truth is below 0.5 (NaN and
invalid ground truth count as failures, as in :mod:`~annotator.evaluation.flag_quality`).

* **AUROC**: the probability that a failed frame gets a higher ``p_fail``
  than a good one (ties count half); NaN when only one class is present.
* **Expected calibration error** (ECE): frames are put in 10 equal-width
  bins of ``p_fail``; ECE is the frame-weighted mean of ``|observed failure
  rate - mean p_fail|`` over the bins (Naeini et al., AAAI 2015).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Reliability", "auroc", "expected_calibration_error", "plot_calibration", "reliability"]


def _clean(p_fail, failed) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(p_fail, dtype=np.float64)
    y = np.asarray(failed, dtype=bool)
    if p.shape != y.shape or p.ndim != 1:
        raise ValueError(f"p_fail and failed must be (N,) arrays of one length, got {p.shape} and {y.shape}")
    keep = np.isfinite(p)
    return p[keep], y[keep]


def auroc(p_fail, failed) -> float:
    """Area under the ROC curve of ``p_fail`` for ``failed`` (rank formula, ties half); NaN for one class."""
    p, y = _clean(p_fail, failed)
    n_pos, n_neg = int(y.sum()), int((~y).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(p, kind="mergesort")
    ranks = np.empty(len(p))
    sorted_p = p[order]
    # Average ranks over ties (1-based).
    starts = np.flatnonzero(np.concatenate([[True], sorted_p[1:] != sorted_p[:-1]]))
    ends = np.concatenate([starts[1:], [len(p)]])
    for a, b in zip(starts, ends):
        ranks[order[a:b]] = (a + b + 1) / 2.0
    return float((ranks[y].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


@dataclass(frozen=True)
class Reliability:
    """Per bin of ``p_fail``: frames, mean predicted probability, observed failure rate (NaN for empty bins)."""

    edges: np.ndarray
    count: np.ndarray
    predicted: np.ndarray
    observed: np.ndarray


def reliability(p_fail, failed, *, bins: int = 10) -> Reliability:
    p, y = _clean(p_fail, failed)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, bins - 1)
    count = np.bincount(which, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        predicted = np.bincount(which, weights=p, minlength=bins) / count
        observed = np.bincount(which, weights=y.astype(float), minlength=bins) / count
    return Reliability(edges=edges, count=count, predicted=predicted, observed=observed)


def expected_calibration_error(p_fail, failed, *, bins: int = 10) -> float:
    """ECE over ``bins`` equal-width bins (see the module notes); NaN without frames."""
    r = reliability(p_fail, failed, bins=bins)
    total = r.count.sum()
    if total == 0:
        return float("nan")
    used = r.count > 0
    return float(np.sum(r.count[used] * np.abs(r.observed[used] - r.predicted[used])) / total)


def plot_calibration(path: str | os.PathLike, curves: dict[str, tuple[np.ndarray, np.ndarray]], *,
                     bins: int = 10) -> Path:
    """A reliability diagram (observed failure rate against mean p_fail per bin), one curve per name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, ax = plt.subplots(figsize=(5, 5), dpi=100)
    ax.plot([0, 1], [0, 1], color="0.6", linestyle="--", linewidth=1, label="perfect calibration")
    for name, (p_fail, failed) in curves.items():
        r = reliability(p_fail, failed, bins=bins)
        used = r.count > 0
        ece = expected_calibration_error(p_fail, failed, bins=bins)
        ax.plot(r.predicted[used], r.observed[used], marker="o", label=f"{name} (ECE {ece:.3f})")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("predicted failure probability (mean p_fail in bin)")
    ax.set_ylabel("observed failure rate (IoU < 0.5)")
    ax.set_title("Calibration of p_fail")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    from annotator.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def failure_summary(pairs) -> dict[str, float] | None:
    """The failure probability and flags of output folders against ground truth, pooled over sequences.

    ``pairs`` holds ``(SequencePair, SequenceScore)`` as the evaluation
    functions collect them; sequences without a failure probability (results
    of other tools) are left out, and None is returned when none has one.
    Keys: ``auroc``, ``ece``, ``precision``, ``recall``, ``flagged_share``,
    ``onset_recall``, ``good_flagged_share`` (on sequences tracked with
    success AUC >= 0.6), NaN where undefined; and the counts ``sequences``,
    ``frames``, ``flag_sequences``, ``failed_frames``, ``flagged_frames``,
    ``failure_spans``. The flag metrics leave out tracks whose flags ask
    for keyframes.
    """
    from annotator.evaluation.flag_quality import flag_quality_dataset

    scored = [(pair, score) for pair, score in pairs if pair.p_fail is not None]
    if not scored:
        return None
    failed = [~(score.ious >= 0.5) for _, score in scored]
    p = np.concatenate([pair.p_fail for pair, _ in scored])
    y = np.concatenate(failed)
    # A track whose flags ask for keyframes has no doubtful-frame flags to score (SequencePair.keyframes_asked).
    flagged = [(pair, score) for pair, score in scored if pair.flagged is not None]
    nan = float("nan")
    pooled = (flag_quality_dataset({pair.name: (pair.flagged, score.ious) for pair, score in flagged}).pooled
              if flagged else None)
    good = [(pair, score) for pair, score in flagged if score.auc >= 0.6]
    good_frames = sum(len(pair.flagged) for pair, _ in good)
    return {
        "auroc": auroc(p, y),
        "ece": expected_calibration_error(p, y),
        "precision": pooled.precision if pooled else nan,
        "recall": pooled.recall if pooled else nan,
        "flagged_share": pooled.flagged_share if pooled else nan,
        "onset_recall": pooled.onset_recall if pooled else nan,
        "good_flagged_share": (sum(int(pair.flagged.sum()) for pair, _ in good) / good_frames
                               if good_frames else float("nan")),
        "sequences": len(scored),
        "frames": int(len(p)),
        "flag_sequences": len(flagged),
        "failed_frames": int(y.sum()),
        "flagged_frames": pooled.n_flagged if pooled else 0,
        "failure_spans": pooled.n_failure_spans if pooled else 0,
    }


def _why_undefined(summary: dict[str, float], key: str) -> str:
    """Why a metric of :func:`failure_summary` has no value, in the words a reader of the table needs."""
    if key in ("auroc", "ece"):
        return "every frame failed (IoU < 0.5)" if summary["failed_frames"] == summary["frames"] else \
            "no frame failed (IoU < 0.5)"
    if summary["flag_sequences"] == 0:
        return "no track with doubtful-frame flags: every track looked lost and its flags ask for keyframes"
    return {"precision": "no frame flagged", "recall": "no frame failed (IoU < 0.5)", "flagged_share": "no frame",
            "onset_recall": "no failure span of 5 frames or more",
            "good_flagged_share": "no sequence tracked with success AUC >= 0.6"}[key]


def failure_markdown(summary: dict[str, float]) -> str:
    """The eval command's table of :func:`failure_summary`."""
    rows = [("AUROC of p_fail for failure frames (IoU < 0.5)", "auroc"),
            ("expected calibration error (10 bins)", "ece"), ("flag precision", "precision"),
            ("flag recall", "recall"), ("flagged share", "flagged_share"),
            ("onset recall (spans >= 5 frames, flag within 10)", "onset_recall"),
            ("flagged share on sequences with AUC >= 0.6", "good_flagged_share")]
    lines = [f"## Failure probability and flags ({summary['sequences']} sequences, {summary['frames']} frames)", "",
             "| metric | value |", "|---|---:|"]
    lines += [f"| {label} | {summary[key]:.3f} |" if np.isfinite(summary[key])
              else f"| {label} | n/a: {_why_undefined(summary, key)} |" for label, key in rows]
    return "\n".join(lines) + "\n"

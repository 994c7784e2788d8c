"""Success and precision plots, and result tables in Markdown and JSON.

Plots follow the OTB paper (Wu, Lim, Yang, TPAMI 2015, ``perfPlot.m``):
one curve per tracker on shared axes, titled "Success plots of OPE" and
"Precision plots of OPE", with legend entries ``name [score]`` sorted by
score, best first (AUC for success, precision at 20 px for precision).
Tables and JSON use got10k's ``performance.json`` key names
(``success_score``, ``precision_score``, ``success_rate``), so scripts
written for got10k reports read ours.

Every file is written atomically through :mod:`annotator.atomic`.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Mapping, Sequence

import numpy as np

from annotator.atomic import atomic_path, write_text_atomic
from annotator.evaluation.flag_quality import FlagQuality, FlagQualityReport
from annotator.evaluation.metrics import (
    PRECISION_AT_PX,
    PRECISION_THRESHOLDS,
    SUCCESS_THRESHOLDS,
    DatasetScore,
    EvaluationError,
)
from annotator.output_files import PRECISION_PLOT, RESULTS_JSON, RESULTS_MD, SUCCESS_PLOT

__all__ = [
    "PROTOCOL",
    "plot_otb",
    "plot_success",
    "plot_precision",
    "results_markdown",
    "results_json",
    "write_results_markdown",
    "write_results_json",
    "write_report",
]

#: The evaluation protocol in words, stated in every table and JSON report.
PROTOCOL: dict[str, str] = {
    "protocol": "OTB one-pass evaluation (OPE), Wu, Lim, Yang TPAMI 2015",
    "iou": (
        "continuous areas, box [x, x+w) x [y, y+h) (got10k rect_iou, pysot overlap_ratio; "
        "algebraically equal to OTB calcRectInt)"
    ),
    "success": "fraction of frames with IoU > t (strict), t = 0:0.05:1 (21 thresholds); AUC = mean of the 21 rates",
    "precision": "fraction of frames with centre error <= t px, t = 0..50; headline at 20 px; centre = x + (w-1)/2",
    "invalid_ground_truth": (
        "NaN or w<=0 or h<=0: IoU -1 (failure), centre error -1 (success), frame kept in the denominator"
    ),
    "invalid_results": (
        "NaN or w<=0 or h<=0: rule 'previous' replaces them by the previous valid box (OTB), "
        "rule 'failure' counts a failure at every threshold (got10k, pysot); the rule used is listed per tracker"
    ),
    "first_frame": "with replace_first (the toolkits' default), result row 1 is replaced by the ground truth",
    "aggregation": "per-sequence curves, unweighted mean over sequences",
}

# OTB perfPlot draws the top trackers in distinct colours, then repeats colours with other line styles.
_COLOURS = (
    "#d62728", "#1f77b4", "#2ca02c", "#000000", "#ff7f0e", "#9467bd", "#17becf", "#8c564b", "#e377c2", "#7f7f7f",
)
_LINESTYLES = ("-", "--", ":", "-.")


def _as_score_list(scores: DatasetScore | Sequence[DatasetScore]) -> list[DatasetScore]:
    items = [scores] if isinstance(scores, DatasetScore) else list(scores)
    if not items:
        raise EvaluationError("no tracker scores given; pass one DatasetScore or a list of them")
    names = [s.tracker for s in items]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise EvaluationError(f"tracker names must be unique in one report, got {', '.join(duplicates)} twice")
    return items


def _ranked(scores: list[DatasetScore], key: str) -> list[DatasetScore]:
    return sorted(scores, key=lambda s: (-getattr(s, key), s.tracker))


@dataclass(frozen=True)
class _Curve:
    """What one kind of OTB plot draws: a curve of each score against ``x``, its legend value ``key``."""

    title: str
    x: np.ndarray
    curve: str
    key: str
    xlabel: str
    ylabel: str
    xlim: tuple[float, float]
    legend_loc: Literal["lower left", "lower right"]  # corners matplotlib's legend(loc=...) knows


_CURVES = {
    "success": _Curve(title="Success plots of OPE", x=SUCCESS_THRESHOLDS, curve="success_curve", key="auc",
                      xlabel="Overlap threshold", ylabel="Success rate", xlim=(0.0, 1.0), legend_loc="lower left"),
    # Legend scores are precision at 20 px.
    "precision": _Curve(title="Precision plots of OPE", x=PRECISION_THRESHOLDS, curve="precision_curve",
                        key="precision_20", xlabel="Location error threshold", ylabel="Precision",
                        xlim=(0.0, float(PRECISION_THRESHOLDS[-1])), legend_loc="lower right"),
}


def plot_otb(
    scores: DatasetScore | Sequence[DatasetScore],
    path: str | os.PathLike,
    *,
    kind: str = "success",
    title: str | None = None,
    max_trackers: int | None = None,
    figsize: tuple[float, float] = (6.4, 4.8),
    dpi: int = 100,
) -> Path:
    """Draw the OTB success or precision plot of one or more trackers to a PNG file.

    Parameters
    ----------
    scores : DatasetScore or sequence of DatasetScore
        One entry per tracker (a single sequence: evaluate it as a dataset of one).
    path : path-like
        PNG file to write (atomically).
    kind : {"success", "precision"}
        The success plot (legend: AUC) or the precision plot (legend: precision at 20 px).
    title : str, optional
        Plot title; default OTB's ("Success plots of OPE", "Precision plots of OPE").
    max_trackers : int, optional
        Draw only the best this-many trackers (OTB draws 10).
    figsize : (float, float)
        Inches; the image is ``figsize * dpi`` pixels.
    dpi : int
        Pixels per inch.

    Returns
    -------
    Path
        ``path``.
    """
    if kind not in _CURVES:
        raise ValueError(f"plot kind {kind!r} is unknown: expected one of {', '.join(_CURVES)}")
    curve = _CURVES[kind]
    title = curve.title if title is None else title
    # The object API with an explicit Agg canvas: no pyplot global state, no
    # display needed, and the process-wide backend of a caller is left alone.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ranked = _ranked(_as_score_list(scores), curve.key)
    if max_trackers is not None:
        ranked = ranked[:max_trackers]
    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for index, score in enumerate(ranked):
        ax.plot(
            curve.x,
            getattr(score, curve.curve),
            color=_COLOURS[index % len(_COLOURS)],
            linestyle=_LINESTYLES[(index // len(_COLOURS)) % len(_LINESTYLES)],
            linewidth=2.0 if index < 3 else 1.5,
            label=f"{score.tracker} [{getattr(score, curve.key):.3f}]",
        )
    ax.set(xlabel=curve.xlabel, ylabel=curve.ylabel, title=title, xlim=curve.xlim, ylim=(0.0, 1.0))
    ax.grid(True, linestyle=":", linewidth=0.5)
    ax.legend(loc=curve.legend_loc, fontsize="small", frameon=True)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return path


def plot_success(scores: DatasetScore | Sequence[DatasetScore], path: str | os.PathLike, **options) -> Path:
    """The OTB success plot: :func:`plot_otb` with ``kind="success"``."""
    return plot_otb(scores, path, kind="success", **options)


def plot_precision(scores: DatasetScore | Sequence[DatasetScore], path: str | os.PathLike, **options) -> Path:
    """The OTB precision plot: :func:`plot_otb` with ``kind="precision"``."""
    return plot_otb(scores, path, kind="precision", **options)


def _fmt(value: float, digits: int = 3) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|")


def _flag_row(label: list[str], quality: FlagQuality) -> str:
    cells = [
        *label,
        _fmt(quality.precision),
        _fmt(quality.recall),
        _fmt(quality.flagged_share),
        _fmt(quality.onset_recall),
        str(quality.n_failure_frames),
        str(quality.n_failure_spans),
        str(quality.n_frames),
    ]
    return "| " + " | ".join(_cell(c) for c in cells) + " |"


def results_markdown(
    scores: DatasetScore | Sequence[DatasetScore],
    *,
    flag_quality: Mapping[str, FlagQualityReport] | None = None,
    title: str = "OTB one-pass evaluation",
) -> str:
    """Results as Markdown: protocol, per-tracker table, per-sequence table, optional flag quality.

    Parameters
    ----------
    scores : DatasetScore or sequence of DatasetScore
        One entry per tracker; the overall table is ranked by AUC.
    flag_quality : Mapping[str, FlagQualityReport], optional
        Tracker name -> flag quality, added as two more tables.
    title : str
        Top-level heading.

    Returns
    -------
    str
        Markdown text ending with a newline.
    """
    items = _ranked(_as_score_list(scores), "auc")
    px = int(PRECISION_AT_PX)
    lines = [f"# {title}", ""]
    lines += [f"- {key.replace('_', ' ')}: {text}" for key, text in PROTOCOL.items()]
    lines += ["", "## Trackers", ""]
    lines += [
        f"| Rank | Tracker | AUC | Precision@{px}px | Success@0.5 | Sequences | Frames "
        "| Invalid results | First frame |",
        "|---:|---|---:|---:|---:|---:|---:|---|---|",
    ]
    for rank, score in enumerate(items, start=1):
        n_frames = sum(s.n_frames for s in score.sequences.values())
        rules = score.rules
        first = {True: "ground truth", False: "as tracked"}.get(rules["replace_first"], "mixed")
        lines.append(
            f"| {rank} | {_cell(score.tracker)} | {score.auc:.3f} | {score.precision_20:.3f} | "
            f"{score.success_50:.3f} | {len(score.sequences)} | {n_frames} | {rules['invalid_pred']} | {first} |"
        )

    sequence_names: dict[str, int] = {}
    for score in items:
        for name, seq in score.sequences.items():
            sequence_names.setdefault(name, seq.n_frames)
    lines += ["", f"## Sequences (AUC / precision@{px}px)", ""]
    lines.append("| Sequence | Frames | " + " | ".join(_cell(s.tracker) for s in items) + " |")
    lines.append("|---|---:|" + "---:|" * len(items))
    for name, n_frames in sequence_names.items():
        cells = []
        for score in items:
            found = score.sequences.get(name)
            cells.append("-" if found is None else f"{found.auc:.3f} / {found.precision_20:.3f}")
        lines.append(f"| {_cell(name)} | {n_frames} | " + " | ".join(cells) + " |")

    if flag_quality:
        lines += _flag_quality_tables(flag_quality)
    return "\n".join(lines) + "\n"


def _flag_quality_tables(flag_quality: Mapping[str, FlagQualityReport]) -> list[str]:
    """The flag-quality tables' Markdown lines: pooled per tracker, then per sequence."""
    definitions = {(r.fail_iou, r.min_span, r.onset_window) for r in flag_quality.values()}
    if len(definitions) > 1:
        raise EvaluationError(
            f"flag-quality reports use different definitions {sorted(definitions)} (fail_iou, min_span, "
            "onset_window); compute them all with the same settings to put them in one table"
        )
    fail_iou, min_span, onset_window = definitions.pop()
    header = "| Precision | Recall | Flagged share | Onset recall | Failure frames | Failure spans | Frames |"
    rule = "---:|---:|---:|---:|---:|---:|---:|"
    lines = [
        "",
        "## Flag quality (pooled over frames and spans)",
        "",
        f"Failure: IoU < {fail_iou:g} (NaN and invalid ground truth included). Precision and recall of "
        f"flags for failure frames; onset recall: share of failure runs of at least {min_span} frames with "
        f"a flag within their first {onset_window} frames. n/a: undefined (0/0).",
        "",
        "| Tracker " + header,
        "|---|" + rule,
    ]
    lines += [_flag_row([tracker], report.pooled) for tracker, report in flag_quality.items()]
    lines += ["", "### Flag quality per sequence", "", "| Tracker | Sequence " + header, "|---|---|" + rule]
    for tracker, report in flag_quality.items():
        lines += [_flag_row([tracker, name], quality) for name, quality in report.sequences.items()]
    return lines


def results_json(
    scores: DatasetScore | Sequence[DatasetScore],
    *,
    flag_quality: Mapping[str, FlagQualityReport] | None = None,
) -> dict:
    """Results as a JSON-ready dict.

    Returns
    -------
    dict
        ``{"protocol": {...}, "thresholds": {...}, "trackers": {name:
        {"overall": {...}, "seq_wise": {...}, "flag_quality": {...}}}}``;
        the per-tracker part has got10k's ``performance.json`` layout.
    """
    items = _as_score_list(scores)
    trackers = {}
    for score in items:
        entry = score.to_dict()
        if flag_quality and score.tracker in flag_quality:
            entry["flag_quality"] = flag_quality[score.tracker].to_dict()
        trackers[score.tracker] = entry
    return {
        "protocol": dict(PROTOCOL),
        "thresholds": {
            "success_iou": SUCCESS_THRESHOLDS.tolist(),
            "precision_px": PRECISION_THRESHOLDS.tolist(),
        },
        "trackers": trackers,
    }


def write_results_markdown(
    path: str | os.PathLike,
    scores: DatasetScore | Sequence[DatasetScore],
    *,
    flag_quality: Mapping[str, FlagQualityReport] | None = None,
) -> Path:
    """Write :func:`results_markdown` to ``path`` atomically and return the path."""
    write_text_atomic(path, results_markdown(scores, flag_quality=flag_quality))
    return Path(path)


def write_results_json(
    path: str | os.PathLike,
    scores: DatasetScore | Sequence[DatasetScore],
    *,
    flag_quality: Mapping[str, FlagQualityReport] | None = None,
) -> Path:
    """Write :func:`results_json` to ``path`` atomically (strict JSON: no NaN) and return the path."""
    text = json.dumps(results_json(scores, flag_quality=flag_quality), indent=2, allow_nan=False)
    write_text_atomic(path, text + "\n")
    return Path(path)


def write_report(
    out_dir: str | os.PathLike,
    scores: DatasetScore | Sequence[DatasetScore],
    *,
    flag_quality: Mapping[str, FlagQualityReport] | None = None,
    dpi: int = 100,
) -> dict[str, Path]:
    """Write both plots and both tables into ``out_dir`` (created if needed).

    Returns
    -------
    dict[str, Path]
        ``{"success_plot": .../success_plots.png, "precision_plot":
        .../precision_plots.png, "markdown": .../results.md, "json":
        .../results.json}`` (got10k's plot file names).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return {
        "success_plot": plot_success(scores, out_dir / SUCCESS_PLOT, dpi=dpi),
        "precision_plot": plot_precision(scores, out_dir / PRECISION_PLOT, dpi=dpi),
        "markdown": write_results_markdown(out_dir / RESULTS_MD, scores, flag_quality=flag_quality),
        "json": write_results_json(out_dir / RESULTS_JSON, scores, flag_quality=flag_quality),
    }

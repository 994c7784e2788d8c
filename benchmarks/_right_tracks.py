"""How the failure model flags tracks that are right: restarted segments and replays of the true boxes.

The runs that the failure model learns from are the tracker's own, and on ``../shared/otb`` the videos whose object
changes its look all the time (a diver, a runner, a skier) are also the videos the tracker loses: a model fitted on
them learns that a box which resembles little of the object's past is wrong, and that holds there. On videos the
tracker follows such an object right, the same model flags most of the frames (issue #43: 55-83% of the frames of
athletes and animals tracked right, on videos nobody tuned on). Two measurements show it on the videos we have:

* **Restarted segments**: every sequence tracked anew from its true box every :data:`EVERY` frames, for
  :data:`LENGTH` frames (``benchmarks/segments.py``): short tracks, mostly right even on videos the tracker loses
  when it runs from the first frame alone, with every signal as the tracker measures it. Per video, the share of
  their right frames (IoU >= 0.5) that the model flags.
* **The true boxes' look**: the signals that depend only on the pixels in the box (the ``appearance`` and
  ``contrast`` groups) measured along the ground-truth boxes of every frame, a track that is right by definition;
  every other feature at its median over the right frames of the training runs (the tracker's scores do not exist
  along a box the tracker did not find, and the box's motion against the optical flow follows how a tracker's box
  moves, not an annotator's), and so are the runs' agreement signals where an appearance feature reads them
  (``ncc_memory_parted``). Per video, the share of the frames flagged: what a right track of that video is
  flagged for how its object looks.

Both are scored with the model of the fold that held the video out, at that model's threshold, flagged as the tool
flags them (spans merged, no keyframe request).
"""

from __future__ import annotations

import glob
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from annotator.evaluation import iou_xywh
from annotator.failure import SIGNALS, SignalMeter, feature_matrix
from annotator.failure.fit import Sample, video
from annotator.failure.model import FEATURE_GROUPS, FEATURES, FailureModel
from annotator.flagging import FlagParams, flag_p_fail
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from annotator.track_store import STORE_NAME, read_store
from benchmarks._sequences import ground_truth_file

#: Restarted segments: a new track from the true box every EVERY frames, LENGTH frames long.
LENGTH, EVERY = 40, 80
#: Features replayed from the true boxes: what the box's pixels look like. The rest sit at right-frame medians.
LOOK = tuple(f for f in FEATURES if FEATURE_GROUPS[f] in ("appearance", "contrast"))
#: A right track of a video must not have more of its frames flagged than this (issue #43's cap for a sequence
#: with under 5% wrong frames).
RIGHT_CAP = 0.15
#: How right tracks are flagged: as the tool flags them, without the keyframe request.
FLAGS = FlagParams(lost_threshold=None)


def segment_id(sequence: str, start: int) -> str:
    """A restarted segment's batch item id: the sequence and its first frame."""
    return f"{sequence}-from-{start}"


def sequence_of(item: str) -> str:
    """The sequence of a batch item: a restarted segment's id names it before its ``-from-``."""
    return item.split("-from-", 1)[0]


def segment_rows(root: Path, length: int = LENGTH, every: int = EVERY) -> list[dict[str, str | int]]:
    """Batch manifest rows of the restarted segments of every OTB sequence under ``root`` (boxes 0-based)."""
    rows = []
    for folder in sorted(p for p in root.iterdir() if (p / "groundtruth_rect.txt").is_file()):
        truth = read_otb_boxes(folder / "groundtruth_rect.txt")
        for start in range(0, len(truth) - 20 + 1, every):  # a segment shorter than 20 frames says little
            x, y, w, h = truth[start]
            rows.append({"id": segment_id(folder.name, start), "video": str(folder / "img"),
                         "box": f"{x:.2f},{y:.2f},{w:.2f},{h:.2f}", "start": start,
                         "stop": min(start + length, len(truth))})
    return rows


def load_segments(run_globs: list[str], roots: list[Path]) -> list[Sample]:
    """One sample per restarted segment of every batch run in ``run_globs``, named by its sequence."""
    samples = []
    for run in sorted({p for g in run_globs for p in glob.glob(g) if Path(p).is_dir()}):
        seed = int(json.loads((Path(run) / "summary.json").read_text())["settings"]["base_seed"])
        for folder in sorted(p for p in Path(run).iterdir() if (p / STORE_NAME).is_file()):
            track = read_store(folder / STORE_NAME).tracks[0]
            name = sequence_of(folder.name)
            truth = read_otb_boxes(ground_truth_file(roots, name))[track.frame_indices]
            lacking = [s for s in SIGNALS if s not in track.signals]
            if lacking:
                raise SystemExit(f"{folder / STORE_NAME} has no {', '.join(lacking)} signal: track the segments "
                                 "again (benchmarks/segments.py)")
            failed = ~(iou_xywh(track.boxes_xywh, truth) >= 0.5)
            features = feature_matrix({s: track.signals[s] for s in SIGNALS}, track.keyframe)
            samples.append(Sample(name, seed, features, failed, ~track.keyframe))
    return samples


#: The runs' signals a replay of the true boxes sets to their right-frame level (there are no runs to compare).
RUN_SIGNALS = ("run_iou", "run_support")


def _truth_look(args: tuple[Path, str, dict[str, float]]) -> tuple[str, np.ndarray]:
    """``(sequence, features)`` along the true boxes of one sequence, the tracker's inputs fixed and the runs'
    signals at ``levels``."""
    truth_file, name, levels = args
    boxes = read_otb_boxes(truth_file)
    meter, rows = SignalMeter(), []
    for index, frame in open_frames(truth_file.parent):
        if index == 0:
            rows.append(meter.first(frame, boxes[0]))
        else:
            rows.append(meter.next(frame, boxes[index], log_likelihood=0.0, scoring="subspace", accepted=True))
    keyframe = np.zeros(len(rows), bool)
    keyframe[0] = True
    signals = {s: np.array([r[s] for r in rows]) for s in SIGNALS}
    for s in RUN_SIGNALS:
        signals[s][1:] = levels[s]
    return name, feature_matrix(signals, keyframe)


def truth_look(roots: list[Path], sequences: list[str], medians: np.ndarray, workers: int = 2
               ) -> dict[str, np.ndarray]:
    """Per sequence, the features of its true boxes (all of them; only :data:`LOOK` is read), the runs' signals at
    their ``medians`` (:func:`right_medians`)."""
    levels = {s: float(medians[FEATURES.index(s)]) for s in RUN_SIGNALS}
    jobs = [(ground_truth_file(roots, name), name, levels) for name in sequences]
    with ProcessPoolExecutor(workers) as pool:
        return dict(pool.map(_truth_look, jobs))


def right_medians(samples: list[Sample]) -> np.ndarray:
    """Each feature's median over the right frames of ``samples``: the level a right track sits at."""
    X = np.concatenate([s.features[s.use & ~s.failed] for s in samples])
    with np.errstate(all="ignore"):
        return np.array([np.nanmedian(X[:, k]) if np.isfinite(X[:, k]).any() else np.nan for k in range(X.shape[1])])


def flagged(model: FailureModel, features: np.ndarray, use: np.ndarray) -> np.ndarray:
    """The frames the tool flags with ``model`` on a track of ``features`` (``use``: not a person's box)."""
    p = np.where(use, model.p_fail(features), 0.0)
    return flag_p_fail(p, model.main_group(features), model.threshold, FLAGS, keyframe=~use).flagged


def truth_flagged(models: dict[str, FailureModel], look: dict[str, np.ndarray], medians: np.ndarray
                  ) -> dict[str, float]:
    """Per sequence, the share of its true boxes' frames its fold model flags (look replayed, the rest at
    ``medians``)."""
    keep = np.array([f in LOOK for f in FEATURES])
    out = {}
    for name, features in sorted(look.items()):
        rows = np.where(keep, features, medians)
        use = np.ones(len(rows), bool)
        use[0] = False
        out[name] = float(flagged(models[video(name)], rows, use)[use].mean())
    return out


def segments_flagged(models: dict[str, FailureModel], segments: list[Sample]) -> dict[str, dict[str, float]]:
    """Per sequence, over its restarted segments (all seeds pooled): the share of right frames flagged, the share of
    wrong frames flagged, and the share of frames wrong."""
    counts: dict[str, np.ndarray] = {}
    for s in segments:
        f = flagged(models[video(s.sequence)], s.features, s.use)[s.use]
        failed = s.failed[s.use]
        c = counts.setdefault(s.sequence, np.zeros(4))
        c += [(f & ~failed).sum(), (~failed).sum(), (f & failed).sum(), failed.sum()]
    return {name: {"right_flagged": c[0] / c[1] if c[1] else float("nan"),
                   "wrong_flagged": c[2] / c[3] if c[3] else float("nan"),
                   "wrong": c[3] / (c[1] + c[3])} for name, c in sorted(counts.items())}


def right_tracks_table(truth: dict[str, float], segments: dict[str, dict[str, float]]) -> list[str]:
    """Markdown rows: per sequence, the true boxes' flagged share and the restarted segments' figures."""
    lines = ["| sequence | true boxes flagged | segments: wrong frames | right frames flagged | wrong frames flagged |",
             "|---|---:|---:|---:|---:|"]

    def cell(v: float, cap: bool = False) -> str:
        if not np.isfinite(v):
            return "n/a"
        return f"**{v:.3f}**" if cap and v > RIGHT_CAP else f"{v:.3f}"

    for name in sorted(set(truth) | set(segments)):
        seg = segments.get(name, {})
        nan = float("nan")
        lines.append(f"| {name} | {cell(truth.get(name, nan), True)} | {cell(seg.get('wrong', nan))} | "
                     f"{cell(seg.get('right_flagged', nan), True)} | {cell(seg.get('wrong_flagged', nan))} |")
    return lines


def right_tracks_summary(truth: dict[str, float], segments: dict[str, dict[str, float]]) -> str:
    """One line: the means, and the sequences over :data:`RIGHT_CAP` on either measure."""
    over_t = [n for n, v in truth.items() if v > RIGHT_CAP]
    seg_right = {n: v["right_flagged"] for n, v in segments.items() if np.isfinite(v["right_flagged"])}
    over_s = [n for n, v in seg_right.items() if v > RIGHT_CAP]
    return (f"true boxes flagged: mean {np.mean(list(truth.values())) if truth else float('nan'):.3f}, over "
            f"{RIGHT_CAP:.0%}: {', '.join(over_t) or 'none'}; restarted segments' right frames flagged: mean "
            f"{np.mean(list(seg_right.values())) if seg_right else float('nan'):.3f}, over {RIGHT_CAP:.0%}: "
            f"{', '.join(over_s) or 'none'}")

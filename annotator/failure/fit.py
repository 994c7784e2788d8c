"""Fitting the failure model: L1-regularised logistic regression, leave-one-video-out, recalibrated on held-out videos.

Used by ``benchmarks/failure_model.py`` (which gathers the runs and writes the
model file); kept in the package so that a test can refit on fixed data and
check the result is reproduced.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence, cast

import numpy as np

from annotator.failure.model import (
    FEATURE_GROUPS,
    FEATURES,
    PASS_CHOICE_FEATURES,
    PASS_OPTIONS,
    FailureModel,
    PassAgreement,
    PassChoice,
    logit,
    model_from_fit,
    sigmoid,
)
from annotator.flagging import FlagParams, span_flags

__all__ = ["APPEARANCE_LEVELS", "Sample", "backward_elimination", "choose_C", "choose_groups", "choose_threshold",
           "fit_fold", "fit_model", "fit_pass_choice", "fit_pass_agreement", "group_features", "leave_one_video_out",
           "platt", "video"]

#: The appearance features the shipped design leaves out (issue #43, HISTORY.md 2026-12-01): how much a right box
#: resembles the object's first frame or its past depends on the object, and on ../shared/otb the objects that change
#: their look all the time are the ones the tracker loses, so a fit that reads these levels flags a right track of
#: such an object on most of its frames (Diving's true boxes on 0.82 of them). Appearance enters the model as
#: ``ncc_memory_parted`` instead: a box unlike the object's past where a run of the tracker parts from it.
APPEARANCE_LEVELS: tuple[str, ...] = ("ncc_first", "ncc_first_w5", "ncc_prev", "ncc_memory", "ncc_memory_w5")

#: A group of signals is left out only when that raises the leave-one-video-out AUROC by at least this much.
MIN_GROUP_GAIN = 0.002


@dataclass(frozen=True)
class Sample:
    """One tracked sequence (one seed): features per frame and whether each frame failed.

    ``use`` marks the frames to learn from and score: not the boxes a person gave.
    """

    sequence: str
    seed: int
    features: np.ndarray  # (F, len(FEATURES))
    failed: np.ndarray  # (F,) bool: IoU < 0.5 with the ground truth
    use: np.ndarray  # (F,) bool


def _stack(samples: Sequence[Sample]) -> tuple[np.ndarray, np.ndarray]:
    X = np.concatenate([s.features[s.use] for s in samples]) if samples else np.zeros((0, len(FEATURES)))
    y = np.concatenate([s.failed[s.use] for s in samples]) if samples else np.zeros(0, bool)
    return X, y


#: Issue #9's targets for the flags at the default threshold: they choose it (:func:`choose_threshold`).
TARGET_RECALL = 0.80
TARGET_PRECISION = 0.70
#: The thresholds :func:`choose_threshold` chooses from.
THRESHOLD_GRID = tuple(round(0.05 + 0.01 * k, 2) for k in range(91))
#: How the threshold's flags are made when it is chosen: the tool's span merging, without the keyframe request
#: (which replaces a lost track's flags by every 10th frame: frames for a person to box, not predictions of
#: wrong boxes, and not what the targets score).
THRESHOLD_FLAGS = FlagParams(lost_threshold=None)
#: The threshold of a model that had no held-out predictions to choose one on: fitted on one video, with
#: ``calibrate=False`` (such models only rank frames), or when a fold's training frames were all of one kind.
UNCHOSEN_THRESHOLD = 0.5


def standardised(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Z, mean, scale)``: the features standardised as :class:`FailureModel` reads them, ``Z = (X - mean) / scale``.

    NaN (a signal not measured) sits at the mean; a constant column keeps scale 1.
    """
    measured = ~np.isnan(X)
    mean = np.where(measured, X, 0.0).sum(axis=0) / np.maximum(measured.sum(axis=0), 1)
    X = np.where(measured, X, mean)
    scale = X.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    return (X - mean) / scale, mean, scale


@functools.cache  # asked at the first fit, not at import: scikit-learn takes a second to import
def _l1_penalty() -> dict[str, Any]:
    """The keyword that makes LogisticRegression's penalty L1: ``l1_ratio=1`` from scikit-learn 1.8 (which
    deprecates ``penalty``), ``penalty="l1"`` before (where ``l1_ratio`` alone is ignored: a silent L2 fit)."""
    import sklearn

    major, minor = (int(part) for part in sklearn.__version__.split(".")[:2])
    return {"l1_ratio": 1.0} if (major, minor) >= (1, 8) else {"penalty": "l1"}


#: How a fit turns features ``X`` (n, d), labels ``y`` (n,) and a regularisation ``C`` into
#: ``(mean, scale, coef, intercept)``: :func:`l1_fit` in the product; a benchmark passes another to compare.
Regression = Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray, np.ndarray, float]]


def l1_fit(X: np.ndarray, y: np.ndarray, C: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The product's regression: ``(mean, scale, coef, intercept)`` of an L1-penalised logistic regression of ``y``
    on the :func:`standardised` features ``X``, regularisation ``C``. A :data:`Regression`."""
    from sklearn.linear_model import LogisticRegression

    Z, mean, scale = standardised(X)
    # L1 (lasso): most signals repeat what another says, and the model ranks unseen videos better when it weighs a
    # few of them and gives the rest weight exactly 0 than when it gives all of them small weights (HISTORY.md,
    # "Failure model: sparse"). liblinear penalises the intercept as a weight on a
    # constant column of intercept_scaling; at 100 the penalty on it is negligible. Its coordinate descent visits
    # the features in a random order: random_state fixes it, so a refit on the same data gives the same file.
    model = LogisticRegression(C=C, solver="liblinear", intercept_scaling=100.0, max_iter=10000, random_state=0,
                               **_l1_penalty())
    model.fit(Z, y.astype(int))
    return mean, scale, model.coef_[0].astype(np.float64), float(model.intercept_[0])


def group_features(groups: Sequence[str]) -> list[str]:
    """The :data:`FEATURES` of the named signal groups (:data:`~annotator.failure.model.FEATURE_GROUPS`)."""
    return [f for f in FEATURES if FEATURE_GROUPS[f] in set(groups)]


def _masked(samples: Sequence[Sample], drop: Sequence[str]) -> list[Sample]:
    keep = np.array([f not in set(drop) for f in FEATURES])
    return [Sample(s.sequence, s.seed, np.where(keep, s.features, 0.0), s.failed, s.use) for s in samples]


def fit_model(samples: Sequence[Sample], *, C: float = 1.0, info: Mapping[str, Any] | None = None,
              drop: Sequence[str] = (), calibrate: bool = True, regression: Regression = l1_fit) -> FailureModel:
    """Fit on every sample's usable frames, recalibrate, and choose the flag threshold.

    Features named in ``drop`` get weight 0 (their columns are zeroed for the fit, so the regression leaves
    their coefficients at exactly 0, with mean 0 and scale 1): the model reads them and ignores them.

    With ``calibrate`` (and samples of two videos or more) the model then learns from its own
    leave-one-video-out predictions on the same samples, the only ones that show how it does on a sequence
    it has not seen:

    - its log-odds are recalibrated by :func:`platt`, and the slope and offset folded into the coefficients and
      intercept (``info["calibration"]``), so the file keeps its form. The strong regularisation that ranks
      unseen sequences best (small C) also shrinks the log-odds towards 0: on held-out sequences the model was
      underconfident (slope 1.1-1.4, HISTORY.md "Failure model: calibrated"). The recalibration is monotone, so
      it changes no frame's rank, only what ``p_fail`` says;
    - its flag threshold is chosen for issue #9's targets by :func:`choose_threshold` on those predictions,
      recalibrated (``info["threshold"]``).

    Without, the threshold is :data:`UNCHOSEN_THRESHOLD`.
    """
    X, y = _stack(_masked(samples, drop))
    if len(np.unique(y)) < 2:
        raise ValueError("the training frames must hold both failed and good frames")
    mean, scale, coef, intercept = regression(X, y, C)
    info = dict(info or {})
    threshold = UNCHOSEN_THRESHOLD
    if calibrate and len({video(s.sequence) for s in samples}) >= 2:
        try:
            held = _held_out_by_sample(samples, C=C, drop=drop, regression=regression)
        except ValueError as exc:  # a fold's training frames are of one kind
            info["calibration"] = {"skipped": str(exc)}
        else:
            slope, offset, skipped = _calibration(held)
            if skipped:
                info["calibration"] = {"skipped": skipped}
            else:
                coef, intercept = coef * slope, intercept * slope + offset
                info["calibration"] = {"slope": slope, "offset": offset}
                held = [(s, sigmoid(slope * logit(p) + offset)) for s, p in held]
            # On the probabilities the model gives: recalibrated, or raw where the recalibration was skipped.
            threshold = choose_threshold(held)
            info["threshold"] = {"rule": f"widest margin over recall >= {TARGET_RECALL} and precision >= "
                                         f"{TARGET_PRECISION} on the {'raw' if skipped else 'recalibrated'} "
                                         "leave-one-video-out predictions of the training sequences",
                                 **_flag_figures(held, threshold)}
    return model_from_fit(FEATURES, mean, scale, coef, intercept, threshold, info)


def _calibration(held: Sequence[tuple[Sample, np.ndarray]]) -> tuple[float, float, str]:
    """Platt's ``(slope, offset, "")`` on held-out predictions, or ``(1, 0, why)`` if unusable."""
    try:
        slope, offset = platt(*_pooled(held))
    except ValueError as exc:  # all held-out frames are of one kind
        return 1.0, 0.0, str(exc)
    if slope <= 0:
        # Held-out sequences ranked backwards (too few or too unlike to learn from): a negative slope would turn
        # the model around on the frames it was fitted to, so it stays as fitted.
        return 1.0, 0.0, f"held-out slope {slope:.3g} is not positive"
    return slope, offset, ""


def _flag_counts(held: Sequence[tuple[Sample, np.ndarray]], threshold: float) -> tuple[int, int, int]:
    """Flagged frames, flagged failures and failures of the held-out predictions at ``threshold``."""
    flagged = hits = failures = 0
    for s, p in held:
        f = span_flags(p > threshold, THRESHOLD_FLAGS, blocked=~s.use)[s.use]
        failed = s.failed[s.use]
        flagged += int(f.sum())
        hits += int((f & failed).sum())
        failures += int(failed.sum())
    return flagged, hits, failures


def _flag_figures(held: Sequence[tuple[Sample, np.ndarray]], threshold: float) -> dict[str, float | None]:
    """Precision and recall of the flags at ``threshold`` (None where undefined: the model file is strict JSON)."""
    flagged, hits, failures = _flag_counts(held, threshold)
    return {"precision": hits / flagged if flagged else None, "recall": hits / failures if failures else None}


def choose_threshold(held: Sequence[tuple[Sample, np.ndarray]], grid: Sequence[float] = THRESHOLD_GRID) -> float:
    """The threshold of ``grid`` at which flags on held-out ``(sample, p_fail)`` meet the targets most widely.

    Issue #9 asks that the default threshold's flags find :data:`TARGET_RECALL` of the wrong boxes with
    :data:`TARGET_PRECISION` of the flags on wrong boxes. At each threshold the frames are flagged as the tool
    flags them (:data:`THRESHOLD_FLAGS`), pooled over the samples, and the threshold with the largest
    ``min(recall - TARGET_RECALL, precision - TARGET_PRECISION)`` wins (ties: the higher threshold, fewer
    flags): where both targets are met, the one with the most room on the closer target; where they cannot
    both be, the nearest miss. The predictions must be of sequences the model did not learn from: on its own
    training frames a model looks surer than it is.
    """
    best = None
    for threshold in sorted(grid):
        flagged, hits, failures = _flag_counts(held, threshold)
        if not failures:
            raise ValueError("choosing a threshold needs held-out frames that hold failed frames")
        precision = hits / flagged if flagged else 0.0
        margin = min(hits / failures - TARGET_RECALL, precision - TARGET_PRECISION)
        if best is None or margin >= best[0]:
            best = (margin, threshold)
    assert best is not None  # the grid is not empty
    return float(best[1])


def platt(p_fail: np.ndarray, failed: np.ndarray) -> tuple[float, float]:
    """Platt scaling: ``(slope, offset)`` with ``P(failed) = sigmoid(slope * logit(p_fail) + offset)``.

    Fitted by unregularised logistic regression of the outcomes on the log-odds of ``p_fail``, which must
    be predictions for frames the model did not learn from (held-out sequences).
    """
    from sklearn.linear_model import LogisticRegression

    p = np.clip(np.asarray(p_fail, dtype=np.float64), 1e-9, 1 - 1e-9)
    failed = np.asarray(failed, dtype=bool)
    if len(np.unique(failed)) < 2:
        raise ValueError("calibration needs held-out frames that hold both failed and good frames")
    fit = LogisticRegression(C=1e6, max_iter=1000, solver="lbfgs").fit(np.log(p / (1 - p))[:, None], failed)
    return float(fit.coef_[0, 0]), float(fit.intercept_[0])


def video(sequence: str) -> str:
    """The video a sequence was cut from: OTB splits a video with two targets into ``Jogging.1`` and ``Jogging.2``.

    Cross-validation holds out whole videos: a model that learned one person of a video has seen the other's
    frames, lighting and background, and would look better on it than on a video it has never seen.
    """
    return sequence.split(".")[0]


def leave_one_video_out(samples: Sequence[Sample], *, C: float | Sequence[float] = 1.0,
                        drop: Sequence[str] = (), select_groups: bool = False, calibrate: bool = True,
                        regression: Regression = l1_fit) -> dict[str, tuple[FailureModel, list[Sample]]]:
    """For each :func:`video`: the model fitted on all *other* videos (every seed), and that video's samples.

    ``C`` is the regularisation, or a grid of values: then each fold chooses
    its own from the grid by :func:`choose_C` on its training sequences alone
    (nested cross-validation), and the chosen value is in the model's
    ``info["C"]``. ``drop`` names features to leave out (their columns are
    zeroed in training and scoring alike), for measuring what a group of
    signals is worth. With ``select_groups`` each fold also leaves out the
    signal groups :func:`choose_groups` picks on its training sequences alone
    (``info["dropped_groups"]``). ``calibrate`` is passed to :func:`fit_model`, and ``regression`` to every fit,
    nested ones included.
    """
    return {name: fit_fold(samples, name, C=C, drop=drop, select_groups=select_groups, calibrate=calibrate,
                           regression=regression)
            for name in sorted({video(s.sequence) for s in samples})}


def fit_fold(samples: Sequence[Sample], held_out: str, *, C: float | Sequence[float] = 1.0,
             drop: Sequence[str] = (), select_groups: bool = False, calibrate: bool = True,
             regression: Regression = l1_fit) -> tuple[FailureModel, list[Sample]]:
    """One fold of :func:`leave_one_video_out`: the model fitted without the video ``held_out``, and its samples."""
    masked = _masked(samples, drop)
    train = [s for s in masked if video(s.sequence) != held_out]
    held = [s for s in masked if video(s.sequence) == held_out]
    # One C, or a grid to choose from on the training videos (a list or an array).
    fold_C = float(cast(float, C)) if np.ndim(C) == 0 else choose_C(train, cast(Sequence[float], C),
                                                                     regression=regression)
    dropped = choose_groups(train, C=fold_C, regression=regression) if select_groups else ()
    model = fit_model(train, C=fold_C, drop=group_features(dropped), calibrate=calibrate, regression=regression,
                      info={"C": fold_C, **({"dropped_groups": list(dropped)} if select_groups else {})})
    return model, held


def choose_groups(samples: Sequence[Sample], *, C: float, min_gain: float = MIN_GROUP_GAIN,
                  regression: Regression = l1_fit) -> tuple[str, ...]:
    """Signal groups to leave out: greedy backward elimination on the leave-one-video-out AUROC of ``samples``.

    Each step leaves out the group whose absence raises the AUROC (pooled over
    the held-out sequences) most, as long as it rises by ``min_gain``. Signals
    whose level differs between sequences more than between good and failed
    frames teach the model which sequence it is looking at; only held-out
    sequences show that, so the choice is made by cross-validation, and, in
    :func:`leave_one_video_out`, on the training sequences of each fold alone.
    """
    from annotator.evaluation.calibration import auroc

    def score(dropped: Sequence[str]) -> float:
        return auroc(*_held_out_predictions(samples, C=C, drop=group_features(dropped), regression=regression))

    return backward_elimination(sorted(set(FEATURE_GROUPS.values())), score, min_gain=min_gain)


def backward_elimination(groups: Sequence[str], score: Callable[[Sequence[str]], float], *,
                         min_gain: float = MIN_GROUP_GAIN) -> tuple[str, ...]:
    """Greedy backward elimination: ``score(dropped)`` for the groups left out; at least one group stays.

    Each step leaves out the group whose absence scores highest (ties: the first in ``groups``), if that beats
    the current score by ``min_gain``; otherwise it stops. Returns the groups left out, in order.
    """
    dropped: list[str] = []
    best = score(dropped)
    while len(dropped) < len(groups) - 1:
        trials = [(score([*dropped, g]), -k, g) for k, g in enumerate(groups) if g not in dropped]
        value, _, group = max(trials)
        if value < best + min_gain:
            break
        dropped.append(group)
        best = value
    return tuple(dropped)


def choose_C(samples: Sequence[Sample], grid: Sequence[float], *, regression: Regression = l1_fit) -> float:
    """The regularisation of ``grid`` whose leave-one-video-out predictions on ``samples`` rank failures best.

    The criterion is the AUROC pooled over the held-out sequences; ties go to the stronger regularisation
    (smaller C). Only held-out sequences show how well a model ranks a sequence it has not seen: the errors
    lie mostly between sequences. What ``p_fail`` says (its calibration) is set afterwards by
    :func:`fit_model`'s recalibration; choosing C by calibration error instead picked weaker regularisation
    in two folds of 17 and cost held-out AUROC (HISTORY.md, "Failure model: calibrated").
    """
    from annotator.evaluation.calibration import auroc

    if len({video(s.sequence) for s in samples}) < 2:
        raise ValueError("choosing C needs samples of at least two videos")
    scores = [(auroc(*_held_out_predictions(samples, C=value, regression=regression)), -value)
              for value in (float(c) for c in grid)]
    return -max(scores)[1]


def _held_out_by_sample(samples: Sequence[Sample], **fold_options) -> list[tuple[Sample, np.ndarray]]:
    """``(sample, p_fail)`` for every sample, each scored by the model fitted without its video.

    The fold models are not recalibrated (one more level of folds for nothing): the C and group choices only
    need their ranking; :func:`fit_model` recalibrates them itself before it chooses the threshold.
    """
    return [(s, model.p_fail(s.features))
            for model, held in leave_one_video_out(samples, calibrate=False, **fold_options).values()
            for s in held]


def _held_out_predictions(samples: Sequence[Sample], **fold_options) -> tuple[np.ndarray, np.ndarray]:
    """``(p_fail, failed)`` of every usable frame of :func:`_held_out_by_sample`, concatenated."""
    return _pooled(_held_out_by_sample(samples, **fold_options))


def _pooled(held: Sequence[tuple[Sample, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """``(p_fail, failed)`` of the usable frames of every ``(sample, p_fail)``, concatenated."""
    return np.concatenate([p[s.use] for s, p in held]), np.concatenate([s.failed[s.use] for s, _ in held])


def fit_pass_agreement(p_track: np.ndarray, pass_iou: np.ndarray, failed: np.ndarray,
                       info: Mapping[str, Any] | None = None) -> PassAgreement:
    """The ``between_anchors`` section from frames re-tracked from both sides (``benchmarks/anchored_failure.py``).

    A logistic regression of ``failed`` on ``logit(p_track)`` and ``pass_iou``, nearly unregularised: two
    features and thousands of frames, and the fitted slope of the log-odds is what recalibrates them.
    """
    from sklearn.linear_model import LogisticRegression

    X = np.column_stack([logit(p_track), np.asarray(pass_iou, dtype=np.float64)])
    failed = np.asarray(failed, dtype=bool)
    if len(np.unique(failed)) < 2 or not np.all(np.isfinite(X)):
        raise ValueError("the frames must hold both failed and good frames, each with a measured pass_iou")
    fit = LogisticRegression(C=1e4, max_iter=1000, solver="lbfgs").fit(X, failed)
    return PassAgreement(log_odds=float(fit.coef_[0, 0]), pass_iou=float(fit.coef_[0, 1]),
                         intercept=float(fit.intercept_[0]), info=dict(info or {}))


def fit_pass_choice(features: np.ndarray, right: np.ndarray, gaps: np.ndarray, *, disagree_below: float,
                    max_gap: int, C: float = 1.0, info: Mapping[str, Any] | None = None) -> PassChoice:
    """The ``pass_choice`` section from frames where two passes disagreed (``benchmarks/pass_choice.py``).

    ``features``: ``(n, len(PASS_CHOICE_FEATURES))`` rows; ``right``: ``(n, 3)`` whether the forward box, the
    backward box and the interpolation were right (IoU >= 0.5); ``gaps``: ``(n,)`` frames from one human box to
    the other. One logistic regression per option on the standardised features, each fitted on the rows where
    that option was possible (the interpolation only on rows whose two human boxes are at most ``max_gap``
    frames apart).
    """
    from sklearn.linear_model import LogisticRegression

    features = np.asarray(features, dtype=np.float64)
    right = np.asarray(right, dtype=bool)
    gaps = np.asarray(gaps)
    if features.ndim != 2 or features.shape[1] != len(PASS_CHOICE_FEATURES) or right.shape != (len(features), 3) \
            or gaps.shape != (len(features),):
        raise ValueError(f"features must be (n, {len(PASS_CHOICE_FEATURES)}), right (n, 3) and gaps (n,)")
    if not np.all(np.isfinite(features)):
        raise ValueError("every pass-choice feature must be finite")
    mean, scale = features.mean(axis=0), features.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    z = (features - mean) / scale
    allowed = [np.ones(len(z), bool), np.ones(len(z), bool), gaps <= max_gap]
    coef, intercept = np.zeros((3, z.shape[1])), np.zeros(3)
    for k in range(3):
        y = right[allowed[k], k]
        if len(np.unique(y)) < 2:
            raise ValueError(f"the {PASS_OPTIONS[k]} option needs frames where it was right and frames where it "
                             "was wrong")
        fit = LogisticRegression(C=C, max_iter=2000, solver="lbfgs").fit(z[allowed[k]], y)
        coef[k], intercept[k] = fit.coef_[0], fit.intercept_[0]
    return PassChoice(mean=mean, scale=scale, coef=coef, intercept=intercept, disagree_below=float(disagree_below),
                      max_gap=int(max_gap), info=dict(info or {}))

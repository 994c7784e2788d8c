"""The failure probability: ``p_fail = P(IoU < 0.5)`` per frame, from the signals of a track.

Features
--------
:func:`feature_matrix` turns a track's :data:`~annotator.failure.signals.SIGNALS`
into one row of :data:`FEATURES` per frame. Besides the signals themselves:

* ``ll_subspace``: the log-likelihood where the subspace models score (0 in
  bootstrap, whose score is on another scale);
* ``ll_drop``: how far it fell below its running level, the median of the
  last :data:`LEVEL_WINDOW` frames the tracker trusted (subspace-scored, above
  :data:`TRUSTED_MARGIN`), as a share of that level;
* ``since_anchor``: ``log(1 + frames since the last human box)``: drift grows
  with distance from the last box a person gave;
* ``ncc_memory_parted``: ``(1 - ncc_memory) * (1 - run_iou)`` (``ncc_memory``
  clipped to [0, 1]), and ``ncc_memory_parted_w5`` the same of their 5-frame
  means: a box unlike the object's past, where a run of the tracker parts from
  it. How much a right box resembles the object's past depends on the object
  (an athlete or an animal changes its look all the time, and the tracker's
  runs all follow it); a box that slid off the object, or that two runs carry
  onto a look-alike, parts from the run that stayed. NaN (not measured) with
  one run;
* ``*_w5``: the mean of a signal over the five frames centred on this one.
  The tool has the whole video, so a frame may be judged by the two after it;
  a frame's probability is final :data:`LOOKAHEAD` frames later, which is the
  look-ahead of online flagging (:class:`OnlineFailure`).

Model
-----
A logistic regression on standardised features (L1-regularised: most
weights are exactly 0), fitted on ../shared/otb with leave-one-video-out
cross-validation by ``benchmarks/failure_model.py``,
which writes :data:`MODEL_PATH`: a small JSON file (feature names, means,
scales, coefficients, intercept, default threshold, and how it was fitted).
No pickles: the file is read with ``json`` and checked field by field.

Between two human boxes
-----------------------
A frame between two anchors is re-tracked twice, forward from the earlier
box and backward from the later one (:mod:`annotator.review.retrack`), and
where the two passes put the box in different places one of them has lost
the object: the classic forward-backward check, free here because both
passes are run anyway. The file's optional ``between_anchors`` section
(:class:`PassAgreement`, fitted by ``benchmarks/anchored_failure.py``)
corrects such frames' probability with the passes' agreement ``pass_iou``::

    p = sigmoid(log_odds * logit(p_track) + pass_iou * iou + intercept)

where ``p_track`` is the model's probability from the track's own signals.
A file without the section leaves those frames as they are. The shipped file
has none: measured, the section ranks failures between anchors better but
flags more frames there, and the simulated reviewer, who looks at every
flagged frame, spent more time with it (RESULTS.md, "anchored-failure");
``benchmarks/anchored_failure.py --write`` makes a file with it.

Which box between two human boxes
---------------------------------
Where the two passes disagree (``pass_iou`` below
:attr:`PassChoice.disagree_below`), one of them, or both, lost the object, and
the frame's box is chosen among three: the forward pass's, the backward
pass's, or the linear interpolation of the two human boxes (only where they
are at most :attr:`PassChoice.max_gap` frames apart, as in the data it was
fitted on). The optional ``pass_choice`` section (:class:`PassChoice`,
fitted by ``benchmarks/pass_choice.py``) holds one logistic regression per
option for "this option's box is right" (IoU >= 0.5) on
:data:`PASS_CHOICE_FEATURES`, and the option with the highest probability is
taken. Its features read each pass's own failure probability under this
file's main model, so the section is refitted whenever the main model is.
"""

from __future__ import annotations

import json
import math
import os
from collections import deque
from dataclasses import dataclass
from importlib import resources
from typing import Any, Mapping, Sequence

import numpy as np

from annotator.errors import EXIT_VALUE
from annotator.failure.signals import SIGNALS, measured_mean
from annotator.text_input import read_given_file

__all__ = [
    "FEATURES",
    "FEATURE_GROUPS",
    "LOOKAHEAD",
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "FailureModel",
    "FailureModelError",
    "OnlineFailure",
    "PASS_CHOICE_FEATURES",
    "PASS_OPTIONS",
    "PassAgreement",
    "PassChoice",
    "feature_matrix",
    "load_model",
    "shipped_model_path",
]

MODEL_FORMAT = "sptpt-annotate failure model"
MODEL_VERSION = 1
#: The shipped model of runs without a learned tracker, inside the package.
MODEL_PATH = "data/failure_model.json"
#: The shipped model of runs with a learned tracker beside SPTPT (``TrackerParams.uses_guide``), fitted on such runs:
#: its strongest evidence is where SPTPT's box parts from the learned tracker's, which a run without one lacks (a
#: NaN feature sits at its training mean), so each kind of run gets the model fitted on its own kind.
GUIDED_MODEL_PATH = "data/failure_model_guided.json"

LOOKAHEAD = 2  # frames after a frame that its features read
LEVEL_WINDOW = 100  # trusted frames in the running level of the log-likelihood
TRUSTED_MARGIN = 2.0  # a subspace score above this is "trusted" for the running level
_SMOOTHED = ("flow_iou", "ncc_first", "ll_subspace", "run_iou", "run_support", "contrast", "ncc_memory", "guide_iou")

#: Appearance where a run parts, per frame and from the 5-frame means (module docstring).
_PARTED = ("ncc_memory_parted", "ncc_memory_parted_w5")

FEATURES: tuple[str, ...] = (*SIGNALS, "ll_subspace", "ll_drop", "since_anchor", *(f"{s}_w5" for s in _SMOOTHED),
                             *_PARTED)

#: Feature -> the group named in a flag's reason (the group of the feature that raised p_fail most).
FEATURE_GROUPS: Mapping[str, str] = {
    "log_likelihood": "score", "bootstrap": "score", "accepted": "score", "ll_subspace": "score",
    "ll_drop": "score", "ll_subspace_w5": "score",
    "score_gap": "candidates", "particle_spread": "candidates",
    "jump": "motion", "scale_change": "motion",
    "scale_drift": "drift", "aspect_drift": "drift", "since_anchor": "drift",
    "flow_iou": "flow", "flow_fb": "flow", "flow_kept": "flow", "flow_iou_w5": "flow",
    "ncc_first": "appearance", "ncc_prev": "appearance", "ncc_first_w5": "appearance", "ncc_memory": "appearance",
    "ncc_memory_w5": "appearance", "ncc_memory_parted": "appearance", "ncc_memory_parted_w5": "appearance",
    "run_iou": "runs", "run_iou_w5": "runs", "run_support": "runs", "run_support_w5": "runs",
    "contrast": "contrast", "contrast_w5": "contrast",
    "flow_drift": "flow", "flow_scale_drift": "extent", "ring_with_box": "extent", "box_with_background": "extent",
    "guide_iou": "guide", "guide_iou_w5": "guide", "guide_scale": "guide",
}


def logit(p: np.ndarray) -> np.ndarray:
    """Log-odds of probabilities, clipped to [1e-12, 1 - 1e-12] so that 0 and 1 stay finite."""
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-12, 1.0 - 1e-12)
    return np.log(p / (1.0 - p))


def sigmoid(z: np.ndarray) -> np.ndarray:
    """Probabilities of log-odds (clipped to +-40: beyond, the probability is 0 or 1 to double precision)."""
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40.0, 40.0)))


@dataclass(frozen=True)
class PassAgreement:
    """The ``between_anchors`` section: ``p_fail`` of a frame re-tracked from both sides, from its track
    probability and the IoU of the two passes' boxes (see the module docstring)."""

    log_odds: float
    pass_iou: float
    intercept: float
    info: Mapping[str, Any]

    def log_odds_of(self, p_track: np.ndarray, pass_iou: np.ndarray) -> np.ndarray:
        """The corrected log-odds; NaN where ``pass_iou`` is NaN (one pass only)."""
        return self.log_odds * logit(p_track) + self.pass_iou * np.asarray(pass_iou, np.float64) + self.intercept

    def p_fail(self, p_track: np.ndarray, pass_iou: np.ndarray) -> np.ndarray:
        """The corrected probability; NaN where ``pass_iou`` is NaN."""
        return sigmoid(self.log_odds_of(p_track, pass_iou))

    def to_json(self) -> dict[str, Any]:
        return {"log_odds": self.log_odds, "pass_iou": self.pass_iou, "intercept": self.intercept,
                "info": dict(self.info)}

    @classmethod
    def from_json(cls, data: Any, where: str) -> PassAgreement:
        try:
            values = {k: float(data[k]) for k in ("log_odds", "pass_iou", "intercept")}
            info = dict(data.get("info") or {})
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise FailureModelError(f"{where}: its between_anchors section lacks or garbles a field "
                                    f"({type(exc).__name__}: {exc}); refit it with benchmarks/anchored_failure.py"
                                    ) from None
        if not all(math.isfinite(v) for v in values.values()):
            raise FailureModelError(f"{where}: between_anchors log_odds, pass_iou and intercept must be finite")
        return cls(info=info, **values)


#: Features of a frame where two passes disagree (:func:`annotator.review.merge.pass_choice_features`): each pass's
#: own failure probability (as log-odds), the IoU of each pass's box with the interpolation of the two human boxes,
#: the passes' IoU, and the frame's place between the two boxes (0..1) and its distance to the nearer one (0..0.5).
#: Not the number of frames between the boxes: the section is fitted on boxes 10 frames apart, where it carries
#: nothing, and read on any gap it was extrapolated far outside its range (at 2 frames it pushed the choice to the
#: forward box whatever the rest said).
PASS_CHOICE_FEATURES: tuple[str, ...] = ("logit_p_forward", "logit_p_backward", "forward_iou_interpolation",
                                         "backward_iou_interpolation", "pass_iou", "position", "edge_distance")
#: What a frame between two human boxes may take its box from, in the order of :attr:`PassChoice.coef`'s rows.
PASS_OPTIONS: tuple[str, ...] = ("forward", "backward", "interpolation")
_FORWARD, _BACKWARD, _INTERPOLATION = range(3)


@dataclass(frozen=True)
class PassChoice:
    """The ``pass_choice`` section: which box a frame between two human boxes takes where the passes disagree.

    One logistic regression per :data:`PASS_OPTIONS` entry on standardised :data:`PASS_CHOICE_FEATURES` (rows of
    ``coef`` and ``intercept``), for the probability that the option's box is right (see the module docstring).
    """

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: np.ndarray
    disagree_below: float
    max_gap: int
    info: Mapping[str, Any]

    def p_right(self, features: np.ndarray) -> np.ndarray:
        """``(n, 3)`` probability that each option's box is right, for ``(n, len(PASS_CHOICE_FEATURES))`` rows."""
        z = (np.asarray(features, dtype=np.float64) - self.mean) / self.scale
        return sigmoid((z[:, None, :] * self.coef[None]).sum(axis=2) + self.intercept)

    def choose(self, features: np.ndarray, interpolation: np.ndarray) -> np.ndarray:
        """Per row, the index in :data:`PASS_OPTIONS` of the option most probably right; interpolation only where
        ``interpolation`` allows it (ties go forward, then backward)."""
        p = self.p_right(features)
        p[:, _INTERPOLATION] = np.where(np.asarray(interpolation, dtype=bool), p[:, _INTERPOLATION], -np.inf)
        return np.argmax(p, axis=1)

    def to_json(self) -> dict[str, Any]:
        return {"features": list(PASS_CHOICE_FEATURES), "options": list(PASS_OPTIONS), "mean": self.mean.tolist(),
                "scale": self.scale.tolist(), "coef": self.coef.tolist(), "intercept": self.intercept.tolist(),
                "disagree_below": self.disagree_below, "max_gap": self.max_gap, "info": dict(self.info)}

    @classmethod
    def from_json(cls, data: Any, where: str) -> PassChoice:
        refit = "refit it with benchmarks/pass_choice.py --write"
        try:
            features, options = tuple(data["features"]), tuple(data["options"])
            arrays = {k: np.asarray(data[k], dtype=np.float64) for k in ("mean", "scale", "coef", "intercept")}
            disagree_below, max_gap = float(data["disagree_below"]), data["max_gap"]
            info = dict(data.get("info") or {})
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise FailureModelError(f"{where}: its pass_choice section lacks or garbles a field "
                                    f"({type(exc).__name__}: {exc}); {refit}") from None
        if features != PASS_CHOICE_FEATURES or options != PASS_OPTIONS:
            raise FailureModelError(f"{where}: its pass_choice section is for features {list(features)} and options "
                                    f"{list(options)}, this version computes {list(PASS_CHOICE_FEATURES)} and "
                                    f"{list(PASS_OPTIONS)}; {refit}")
        k, m = len(PASS_CHOICE_FEATURES), len(PASS_OPTIONS)
        shapes = {"mean": (k,), "scale": (k,), "coef": (m, k), "intercept": (m,)}
        for key, shape in shapes.items():
            if arrays[key].shape != shape or not np.all(np.isfinite(arrays[key])):
                raise FailureModelError(f"{where}: pass_choice {key} must be {' x '.join(map(str, shape))} finite "
                                        f"numbers; {refit}")
        if np.any(arrays["scale"] <= 0) or not 0.0 < disagree_below <= 1.0 or isinstance(max_gap, bool) \
                or not isinstance(max_gap, int) or max_gap < 2:
            raise FailureModelError(f"{where}: pass_choice scales must be > 0, disagree_below in (0, 1] and max_gap "
                                    f"an integer >= 2; {refit}")
        return cls(disagree_below=disagree_below, max_gap=max_gap, info=info, **arrays)


class FailureModelError(ValueError):
    """A failure-model file that cannot be used; the message names the file and says what is wrong.

    ``exit_code``: 3 (EXIT_INPUT) when the file cannot be read, 4 (EXIT_VALUE) when what it holds cannot be used.
    """

    def __init__(self, message: str, exit_code: int = EXIT_VALUE) -> None:
        super().__init__(message)
        self.exit_code = exit_code


class _Causal:
    """The causal part of the features: running level of the log-likelihood, frames since an anchor."""

    def __init__(self) -> None:
        self._trusted: deque[float] = deque(maxlen=LEVEL_WINDOW)
        self._since = 0

    def step(self, signals: Mapping[str, float], keyframe: bool) -> tuple[float, float, float]:
        ll = float(signals["log_likelihood"])
        subspace = signals["bootstrap"] == 0.0
        ll_subspace = ll if subspace and not keyframe else 0.0
        drop = 0.0
        if subspace and not keyframe and self._trusted:
            level = float(np.median(self._trusted))
            drop = float(np.clip((level - ll) / max(abs(level), 1.0), -5.0, 5.0))
        self._since = 0 if keyframe else self._since + 1
        if subspace and not keyframe and ll > TRUSTED_MARGIN:
            self._trusted.append(ll)
        return ll_subspace, drop, math.log1p(self._since)


def _row(raw: np.ndarray, causal: np.ndarray, window: np.ndarray, centre: int) -> np.ndarray:
    """One feature row: raw signals, causal features, the centred means over ``window`` (<= 5 rows), and
    :data:`_PARTED`."""
    # NaN (a signal not measured) is left out of a mean, and stays NaN where nothing in the window was measured.
    smoothed = [measured_mean(window[:, k]) for k in range(window.shape[1])]
    return np.concatenate([raw, causal, smoothed, _parted(raw, smoothed)])


# Where _parted reads its inputs: in the raw signals, and in the 5-frame means (ordered as _SMOOTHED).
_MEMORY, _RUNS = list(SIGNALS).index("ncc_memory"), list(SIGNALS).index("run_iou")
_MEMORY5, _RUNS5 = _SMOOTHED.index("ncc_memory"), _SMOOTHED.index("run_iou")


def _parted(raw: np.ndarray, smoothed: list[float]) -> list[float]:
    """:data:`_PARTED` of one row: from the frame's ``ncc_memory`` and ``run_iou``, and from their 5-frame means."""
    memory5, runs5 = smoothed[_MEMORY5], smoothed[_RUNS5]
    return [float((1.0 - np.clip(raw[_MEMORY], 0.0, 1.0)) * (1.0 - raw[_RUNS])),
            float((1.0 - np.clip(memory5, 0.0, 1.0)) * (1.0 - runs5))]


def _smoothing_columns(raw: np.ndarray, causal: np.ndarray) -> np.ndarray:
    """The columns of :data:`_SMOOTHED`, in its order: signals from ``raw``, ``ll_subspace`` from ``causal``."""
    names = list(SIGNALS)
    cols = [causal[:, 0] if name == "ll_subspace" else raw[:, names.index(name)] for name in _SMOOTHED]
    return np.stack(cols, axis=1)


def feature_matrix(signals: Mapping[str, np.ndarray], keyframe: np.ndarray) -> np.ndarray:
    """``(F, len(FEATURES))`` features of a whole track from its ``(F,)`` signal arrays (see module docstring).

    Equal, row for row, to what :class:`OnlineFailure` computes frame by frame.
    """
    keyframe = np.asarray(keyframe, dtype=bool)
    n = keyframe.shape[0]
    missing = [name for name in SIGNALS if name not in signals]
    if missing:
        raise ValueError(f"signals lack {', '.join(missing)}; expected every name of annotator.failure.SIGNALS")
    raw = np.stack([np.asarray(signals[name], dtype=np.float64) for name in SIGNALS], axis=1) if n else \
        np.zeros((0, len(SIGNALS)))
    if raw.shape != (n, len(SIGNALS)):
        raise ValueError(f"every signal must have shape ({n},) like keyframe")
    state = _Causal()
    causal = np.array([state.step(dict(zip(SIGNALS, raw[t])), bool(keyframe[t])) for t in range(n)]).reshape(n, 3)
    smooth = _smoothing_columns(raw, causal)
    rows = [_row(raw[t], causal[t], smooth[max(0, t - LOOKAHEAD): t + LOOKAHEAD + 1], t) for t in range(n)]
    return np.array(rows).reshape(n, len(FEATURES))


@dataclass(frozen=True)
class FailureModel:
    """A logistic regression on standardised :data:`FEATURES`, read from its JSON file."""

    features: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    threshold: float
    info: Mapping[str, Any]
    between_anchors: PassAgreement | None = None
    pass_choice: PassChoice | None = None

    def p_fail(self, features: np.ndarray) -> np.ndarray:
        """``(F,)`` failure probabilities of ``(F, len(FEATURES))`` feature rows."""
        # A row-wise sum, not a matrix product: BLAS sums a one-row product (OnlineFailure, frame by frame) in
        # another order than a whole track's (score_track), and the two must give the same bits.
        z = self.intercept + self._contributions(features).sum(axis=1)
        return sigmoid(z)

    @property
    def weighed_groups(self) -> list[str]:
        """The :data:`FEATURE_GROUPS` groups with a feature of non-zero weight, sorted: the ``doubt:<group>``
        reasons this model can give (docs/flags.md lists them per shipped model)."""
        return sorted({FEATURE_GROUPS[f] for f, c in zip(self.features, self.coef) if c != 0.0})

    def main_group(self, features: np.ndarray) -> list[str]:
        """Per row, the :data:`FEATURE_GROUPS` group whose features raise the log-odds most.

        Only groups the model weighs: a group it leaves out (all weights 0) always contributes 0, which would
        otherwise "raise the log-odds most" on a frame where every weighed group lowers them, and name a reason
        (``--review-budget`` flags such frames too) that the model does not read.
        """
        contrib = self._contributions(features)
        groups = self.weighed_groups or sorted(set(FEATURE_GROUPS.values()))
        by_group = np.stack([contrib[:, [i for i, f in enumerate(self.features) if FEATURE_GROUPS[f] == g]].sum(axis=1)
                             for g in groups], axis=1)
        return [groups[int(k)] for k in np.argmax(by_group, axis=1)]

    def _contributions(self, features: np.ndarray) -> np.ndarray:
        """Per row and feature, the term of the log-odds; a NaN feature (not measured) sits at the training mean: 0."""
        standardised = (np.asarray(features, dtype=np.float64) - self.mean) / self.scale
        return np.where(np.isnan(standardised), 0.0, standardised) * self.coef

    def with_pass_agreement(self, p_fail: np.ndarray, pass_iou: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``(p_fail, corrected)``: ``p_fail`` corrected by the passes' agreement where ``pass_iou`` was measured.

        Without a ``between_anchors`` section, or without ``pass_iou``, nothing changes. ``corrected`` marks the
        rows whose probability the disagreement raised (their flag reason is ``doubt:passes``).
        """
        p_fail = np.asarray(p_fail, dtype=np.float64)
        if self.between_anchors is None or pass_iou is None:
            return p_fail, np.zeros(p_fail.shape, bool)
        pass_iou = np.asarray(pass_iou, dtype=np.float64)
        measured = ~np.isnan(pass_iou) & ~np.isnan(p_fail)
        corrected = self.between_anchors.p_fail(np.where(measured, p_fail, 0.5), np.where(measured, pass_iou, 1.0))
        out = np.where(measured, corrected, p_fail)
        return out, measured & (out > p_fail)

    def to_json(self) -> dict[str, Any]:
        data = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "features": list(self.features),
                "mean": self.mean.tolist(), "scale": self.scale.tolist(), "coef": self.coef.tolist(),
                "intercept": self.intercept, "threshold": self.threshold, "info": dict(self.info)}
        if self.between_anchors is not None:
            data["between_anchors"] = self.between_anchors.to_json()
        if self.pass_choice is not None:
            data["pass_choice"] = self.pass_choice.to_json()
        return data

    @classmethod
    def from_json(cls, data: Any, where: str) -> FailureModel:
        if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT:
            raise FailureModelError(f"{where} is not a {MODEL_FORMAT} (its 'format' field is "
                                    f"{data.get('format') if isinstance(data, dict) else None!r}); give a file "
                                    "written by benchmarks/failure_model.py")
        if data.get("version") != MODEL_VERSION:
            raise FailureModelError(f"{where} has version {data.get('version')!r}, this sptpt-annotate reads "
                                    f"version {MODEL_VERSION}: refit it with benchmarks/failure_model.py")
        try:
            features = tuple(str(f) for f in data["features"])
            arrays = {k: np.asarray(data[k], dtype=np.float64) for k in ("mean", "scale", "coef")}
            intercept, threshold = float(data["intercept"]), float(data["threshold"])
            info = dict(data.get("info") or {})
        except (KeyError, TypeError, ValueError) as exc:
            raise FailureModelError(f"{where} lacks or garbles a field ({type(exc).__name__}: {exc}); refit it "
                                    "with benchmarks/failure_model.py") from None
        if features != FEATURES:
            lacks, extra = [f for f in FEATURES if f not in features], [f for f in features if f not in FEATURES]
            parts = []
            if lacks:
                parts.append(f"lacks {', '.join(lacks)}")
            if extra:
                parts.append(f"has {', '.join(extra)}, which this version does not compute")
            differs = "; ".join(parts) or "lists them in another order"
            raise FailureModelError(f"{where} is for other features than the {len(FEATURES)} this version computes "
                                    f"(it {differs}): refit it with benchmarks/failure_model.py")
        for key, values in arrays.items():
            if values.shape != (len(FEATURES),) or not np.all(np.isfinite(values)):
                raise FailureModelError(f"{where}: {key} must be {len(FEATURES)} finite numbers")
        if np.any(arrays["scale"] <= 0) or not (math.isfinite(intercept) and 0.0 < threshold < 1.0):
            raise FailureModelError(f"{where}: scales must be > 0, the intercept finite and the threshold in (0, 1)")
        section = data.get("between_anchors")
        between = None if section is None else PassAgreement.from_json(section, where)
        choice = None if data.get("pass_choice") is None else PassChoice.from_json(data["pass_choice"], where)
        return cls(features=features, intercept=intercept, threshold=threshold, info=info,
                   between_anchors=between, pass_choice=choice, **arrays)


def shipped_model_path(*, guided: bool = False) -> str:
    """The package-relative path of the shipped model for runs with (``guided``) or without a learned tracker."""
    return GUIDED_MODEL_PATH if guided else MODEL_PATH


def load_model(path: str | os.PathLike | None = None, *, guided: bool = False) -> FailureModel:
    """The failure model in ``path``, or the one shipped with the package for runs with (``guided``) or without a
    learned tracker beside SPTPT."""
    if path is None:
        shipped = shipped_model_path(guided=guided)
        where = f"the package's {shipped}"
        try:
            text = resources.files("annotator").joinpath(shipped).read_text(encoding="utf-8")
        except OSError as exc:
            raise FailureModelError(f"{where} cannot be read ({exc}); reinstall sptpt-annotate") from None
    else:
        where = str(path)
        text = read_given_file(path, what="failure model", error=FailureModelError,
                               expected="a model JSON written by benchmarks/failure_model.py --write, or leave "
                                        "--failure-model out to use the shipped model")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FailureModelError(f"{where}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    return FailureModel.from_json(data, where)


class OnlineFailure:
    """Failure probabilities frame by frame, each final :data:`LOOKAHEAD` frames later.

    ``push`` takes a frame's signals (and whether a person gave its box) and
    returns the ``(position, p_fail, group)`` of frames that became final;
    ``finish`` the rest at the end of the track. The numbers equal
    ``model.p_fail(feature_matrix(...))`` on the whole track.
    """

    def __init__(self, model: FailureModel) -> None:
        self.model = model
        self._causal = _Causal()
        self._raw: deque[np.ndarray] = deque()
        self._causal_rows: deque[np.ndarray] = deque()
        self._first = 0  # position of the oldest buffered row
        self._emitted = 0
        self._n = 0

    def push(self, signals: Mapping[str, float], keyframe: bool) -> list[tuple[int, float, str]]:
        raw = np.array([float(signals[name]) for name in SIGNALS])
        self._raw.append(raw)
        self._causal_rows.append(np.array(self._causal.step(signals, keyframe)))
        self._n += 1
        return self._emit(self._n - LOOKAHEAD)

    def finish(self) -> list[tuple[int, float, str]]:
        return self._emit(self._n)

    def _emit(self, until: int) -> list[tuple[int, float, str]]:
        out = []
        while self._emitted < until:
            t = self._emitted
            raw, causal = np.array(self._raw), np.array(self._causal_rows)
            smooth = _smoothing_columns(raw, causal)
            lo = max(0, t - LOOKAHEAD) - self._first
            row = _row(raw[t - self._first], causal[t - self._first], smooth[lo: t - self._first + LOOKAHEAD + 1], t)
            p = float(self.model.p_fail(row[None])[0])
            out.append((t, p, self.model.main_group(row[None])[0]))
            self._emitted += 1
            # Keep only what later rows' windows still read.
            while self._first < self._emitted - LOOKAHEAD:
                self._raw.popleft()
                self._causal_rows.popleft()
                self._first += 1
        return out


def model_from_fit(features: Sequence[str], mean, scale, coef, intercept: float, threshold: float,
                   info: Mapping[str, Any]) -> FailureModel:
    """A model from fitted numbers (benchmarks/failure_model.py), validated as if read from its file."""
    data = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "features": list(features),
            "mean": list(map(float, mean)), "scale": list(map(float, scale)), "coef": list(map(float, coef)),
            "intercept": float(intercept), "threshold": float(threshold), "info": dict(info)}
    return FailureModel.from_json(data, "the fitted model")

"""A discriminative scale filter (DSST) that sets the estimate's scale once SPTPT has placed its centre.

Why: on ``../shared/otb`` the most common failure of the subspace score is
scale drift with the centre still on the object (Dog1 at 0.6 of its side,
Human9 growing to 1.8, CarDark to 2.4): SPTPT's log-likelihood is not peaked
at the true scale on real frames, so neither random scale particles nor a
deterministic scale search over it hold the size (``benchmarks/HISTORY.md``,
"robust development"). A scale cue from outside the subspace model is needed.
Fed back into SPTPT's state (``TrackerParams.scale_filter``) a wrong size
loses the centre too, so ``robust`` uses the filter only for the size of the
box it reports (``TrackerParams.reported_scale_filter``).

Danelljan et al., "Accurate Scale Estimation for Robust Visual Tracking"
(BMVC 2014; the scale part of OpenCV's CSRT): samples of the box at
:data:`N_SCALES` scales ``STEP**k`` around the current one, each described by
gradient-orientation histograms, and a one-dimensional correlation filter
over the scale axis, learned in the Fourier domain and updated with a
running average (:class:`sptpt.correlation.CorrelationFilter`). The scale
whose response peaks is the new scale. All
constants are the paper's (33 scales, step 1.02, Gaussian label of
``sqrt(33) / 4`` scales, learning rate 0.025, regularisation 0.01), except
the sampling and the features. Samples are the 32x32 templates the tracker
already warps: bilinear, without anti-aliasing, 0 outside the frame (DSST
resizes with area averaging and repeats the border pixels), and the box
from :meth:`ScaleFilter.step` is at most as wide as the frame's longer side
(DSST bounds it by the image size; :meth:`ScaleFilter.factor` alone has no
bound). Features are HOG-like
histograms of 9 unsigned orientations over 4-pixel cells of the grey
template (DSST: fHOG over a patch of at most 512 pixels). A prototype of
this filter (OpenCV sampling, script not kept), run with ground-truth
centres on ``../shared/otb``, kept the side within 0.8-1.25 of the truth on
95% of the frames.
"""

from __future__ import annotations

import math

import numpy as np

from sptpt.affine import warp_candidates
from sptpt.correlation import CorrelationFilter
from sptpt.gradients import GREY, cell_histograms

__all__ = ["ScaleFilter", "orientation_histograms", "N_SCALES", "STEP"]

N_SCALES = 33
STEP = 1.02
LABEL_SIGMA = math.sqrt(N_SCALES) / 4.0  # scales
LEARNING_RATE = 0.025
REGULARISATION = 0.01
CELL = 4  # px of the template per histogram cell
BINS = 9  # unsigned orientations over [0, pi)
# Per-cell normalised values are clipped here (HOG's clip, without its renormalisation), so that one strong edge
# cannot dominate a cell.
CLIP = 0.2


def orientation_histograms(templates: np.ndarray, *, cell: int = CELL, bins: int = BINS) -> np.ndarray:
    """``(N, T, T, 3)`` uint8 templates -> ``(N, (T // cell) ** 2 * bins)`` gradient-orientation histograms.

    Central-difference gradients of the grey template (0 on its border),
    magnitude split linearly between the two nearest of ``bins`` unsigned
    orientations, summed per ``cell x cell`` cell (pixels past the last whole
    cell join it), each cell's histogram L2-normalised and clipped at :data:`CLIP`.
    """
    grey = np.asarray(templates, dtype=np.float64) @ GREY
    hist = cell_histograms(grey, bins, cell)
    hist /= np.sqrt((hist ** 2).sum(axis=2, keepdims=True)) + 1e-3
    return np.minimum(hist, CLIP).reshape(len(hist), -1)


class ScaleFilter:
    """DSST's scale filter on affine states: ``init`` at the first box, then ``factor`` and ``update`` per frame.

    Deterministic: no randomness, so the tracker's seed alone fixes its output. ``correlation`` is the filter over
    the scales (its ``A`` and ``B`` can be read there).
    """

    def __init__(self, template_size: int) -> None:
        self.template_size = template_size
        k = np.arange(N_SCALES) - (N_SCALES - 1) / 2
        self.factors = STEP ** (-k)  # largest first, as in DSST; the label peaks at factor 1
        self.correlation = CorrelationFilter(np.exp(-0.5 * (k / LABEL_SIGMA) ** 2), np.hanning(N_SCALES),
                                         learning_rate=LEARNING_RATE, regularisation=REGULARISATION)
        # The scales step() keeps to; set by init() from the frame and the first state.
        self.min_scale, self.max_scale = 0.0, math.inf

    def _spectrum(self, rgb: np.ndarray, state: np.ndarray) -> np.ndarray:
        """``(features, N_SCALES)`` Fourier transform over the scale axis of the samples around ``state``.

        ``rgb`` is the ``(H, W, 3)`` uint8 frame, ``state`` the ``(6,)`` affine state (``sptpt.affine``); the
        windowed samples are DSST's ``f``, one column per scale.
        """
        states = np.repeat(np.asarray(state, dtype=np.float64)[None], N_SCALES, axis=0)
        states[:, 2] *= self.factors
        samples = orientation_histograms(warp_candidates(rgb, states, self.template_size))
        return self.correlation.spectrum(samples.T)

    def init(self, rgb: np.ndarray, state: np.ndarray) -> None:
        """Learn the filter from the samples around the first state, and bound the scales :meth:`step` gives.

        The box is at least one template pixel wide and, as in DSST, no wider than the frame's longer side (or the
        first box): on a black frame the response is flat, its peak the largest of the scales, and an unbounded
        box grew by 1.37 a frame without end.
        """
        self.min_scale = 1.0 / self.template_size
        self.max_scale = max(max(rgb.shape[:2]) / self.template_size, float(state[2]))
        self.correlation.learn(self._spectrum(rgb, state))

    def factor(self, rgb: np.ndarray, state: np.ndarray) -> float:
        """The scale change (a factor of ``state``'s scale) whose samples the filter answers most strongly.

        Response ``y = IFFT(sum conj(A) Z / (B + lambda))`` over the scales, as in DSST; its peak's factor.
        """
        if not self.correlation.learned:
            raise RuntimeError("ScaleFilter.factor() before init()")
        return self._factor(self._spectrum(rgb, state))

    def step(self, rgb: np.ndarray, state: np.ndarray, *, learn: bool = False) -> float:
        """``state``'s scale times :meth:`factor`, kept within ``[min_scale, max_scale]`` (the bounds :meth:`init`
        set); with ``learn``, then :meth:`update` at the new scale.

        The same numbers as the two calls, sampling once where the scale stays (a factor of exactly 1, on most
        frames, or a bound that holds it): the update's samples around the new state are then the factor's.
        """
        if not self.correlation.learned:
            raise RuntimeError("ScaleFilter.step() before init()")
        spectrum = self._spectrum(rgb, state)
        scale = min(max(float(state[2]) * self._factor(spectrum), self.min_scale), self.max_scale)
        if learn:
            if scale != state[2]:
                moved = np.array(state, dtype=np.float64)
                moved[2] = scale
                spectrum = self._spectrum(rgb, moved)
            self.correlation.blend(spectrum)
        return scale

    def _factor(self, spectrum: np.ndarray) -> float:
        return float(self.factors[int(np.argmax(self.correlation.response(spectrum)))])

    def update(self, rgb: np.ndarray, state: np.ndarray) -> None:
        """Blend the samples around ``state`` (the accepted estimate) into ``A`` and ``B``, as in DSST.

        The running average weighs the new samples by :data:`LEARNING_RATE`.
        """
        if not self.correlation.learned:
            raise RuntimeError("ScaleFilter.update() before init()")
        self.correlation.blend(self._spectrum(rgb, state))

"""A discriminative translation filter (DSST) that places the reported box's centre near SPTPT's.

Why: where SPTPT keeps the object, its winner still jitters about the
object's centre by a fraction of its size (600 or fewer random candidates,
each judged on a 32x32 template), and every pixel of that jitter costs
overlap. A correlation filter learned from SPTPT's own boxes over many
frames averages the jitter out: the object sits, on average, where the
filter learned it, and the filter's peak on a new frame says how far the
object is from the box SPTPT drew. ``TrackerParams.reported_translation_filter``
moves only the reported box by that much. The filter learns from SPTPT's
box, never from the box it moved: fed its own answers, a correlation filter
drifts with them, and in a screen on stored ``robust`` boxes that drift
lost Coke, Human9 and Tiger1 (``benchmarks/HISTORY.md``, "robust development").
(That drift is accepted in :mod:`sptpt.filter_tracker`, where the filter does
follow its own answers: a tracker apart from SPTPT, whose box only votes.)

Danelljan et al., "Accurate Scale Estimation for Robust Visual Tracking"
(BMVC 2014; the translation part): a multichannel correlation filter over a
patch of twice the box's width and height, learned in the Fourier domain
with a Gaussian label and updated with a running average
(:class:`sptpt.correlation.CorrelationFilter`). The constants are
the paper's (padding 1, so a patch of 2x the box; label std of 1/16 of the
object's size; learning rate 0.025; regularisation 0.01). The patch is
warped to :data:`PATCH` x :data:`PATCH` pixels whatever the box's aspect,
bilinear and 0 outside the frame, like the tracker's templates. Features
are per pixel: the grey level (less its mean) and :data:`BINS` unsigned
gradient orientations, each averaged over a 4x4 neighbourhood (DSST: fHOG
cells of 4 px and the grey level).
"""

from __future__ import annotations

import cv2
import numpy as np

from sptpt.affine import box_xywh_from_states, state_from_box_xywh, warp_candidates
from sptpt.correlation import CorrelationFilter
from sptpt.gradients import GREY, orientation_channels

__all__ = ["TranslationFilter", "translation_features", "PATCH", "PADDING", "BINS"]

PATCH = 64  # px per side of the warped patch
PADDING = 2.0  # patch side / box side
LABEL_SIGMA = PATCH / PADDING / 16.0  # px of the patch: 1/16 of the object's size
LEARNING_RATE = 0.025
REGULARISATION = 0.01
BINS = 9  # unsigned orientations over [0, pi)
NEIGHBOURHOOD = 4  # px of the patch over which each orientation channel is averaged
# The orientation channels hold gradient magnitudes of grey levels in [0, 1] (at most about 1.4 each); doubled,
# they weigh about as much as the grey channel in the filter.
ORIENTATION_WEIGHT = 2.0


def translation_features(patch: np.ndarray) -> np.ndarray:
    """``(P, P, 3)`` uint8 patch -> ``(1 + BINS, P, P)`` float64 channels: grey less its mean, then orientations.

    Grey is in [0, 1]. Central-difference gradients (0 on the patch's border); each pixel's magnitude is split
    linearly between the two nearest of :data:`BINS` unsigned orientations, each orientation channel averaged
    over a :data:`NEIGHBOURHOOD`-pixel square (OpenCV's box filter: the pixel and the next 1 and previous 2
    along each axis, borders mirrored without repeating the edge) and weighted by :data:`ORIENTATION_WEIGHT`.
    """
    grey = (np.asarray(patch, dtype=np.float64) @ GREY) / 255.0
    channels = np.empty((1 + BINS,) + grey.shape)
    channels[0] = grey - grey.mean()
    for b, split in enumerate(orientation_channels(grey, BINS)):
        channels[1 + b] = ORIENTATION_WEIGHT * cv2.boxFilter(split, -1, (NEIGHBOURHOOD, NEIGHBOURHOOD))
    return channels


class TranslationFilter:
    """DSST's translation filter on affine states: ``init`` at the first box, then ``shift`` and ``update``.

    Deterministic: no randomness, so the tracker's seed alone fixes its output. ``correlation`` is the filter over
    the patch (its ``A`` and ``B`` can be read there).
    """

    def __init__(self, template_size: int) -> None:
        self.template_size = template_size  # the states' scale is the box's width over this
        offset = (np.arange(PATCH) + PATCH // 2) % PATCH - PATCH // 2  # 0 at index 0: the label peaks at no shift
        label = np.exp(-0.5 * (offset[:, None] ** 2 + offset[None, :] ** 2) / LABEL_SIGMA ** 2)
        self.correlation = CorrelationFilter(label, np.outer(np.hanning(PATCH), np.hanning(PATCH)),
                                         learning_rate=LEARNING_RATE, regularisation=REGULARISATION)

    def _spectrum(self, rgb: np.ndarray, state: np.ndarray) -> np.ndarray:
        """``(1 + BINS, PATCH, PATCH)`` Fourier transform of the windowed features of the patch around ``state``."""
        x, y, w, h = box_xywh_from_states(np.asarray(state, dtype=np.float64), self.template_size)
        padded = np.array([x - (PADDING - 1) * w / 2, y - (PADDING - 1) * h / 2, PADDING * w, PADDING * h])
        patch = warp_candidates(rgb, state_from_box_xywh(padded, PATCH)[None], PATCH)[0]
        return self.correlation.spectrum(translation_features(patch))

    def init(self, rgb: np.ndarray, state: np.ndarray) -> None:
        """Learn the filter from the patch around the first state."""
        self.correlation.learn(self._spectrum(rgb, state))

    def shift(self, rgb: np.ndarray, state: np.ndarray, *, learn: bool = False) -> tuple[float, float]:
        """How far, in frame pixels (dx, dy), the object is from ``state``'s centre by the filter's answer.

        Response ``y = IFFT(sum conj(A) Z / (B + lambda))`` over the patch, as in DSST; its peak, refined to a
        fraction of a patch pixel by a parabola through it and its two neighbours along each axis, and scaled
        from patch pixels to the box's. With ``learn``, the filter then learns from the same patch, as
        :meth:`update` at ``state`` would, sampling it once instead of twice.
        """
        if not self.correlation.learned:
            raise RuntimeError("TranslationFilter.shift() before init()")
        spectrum = self._spectrum(rgb, state)
        response = self.correlation.response(spectrum)
        if learn:
            self.correlation.blend(spectrum)
        row, col = np.unravel_index(int(np.argmax(response)), response.shape)
        dy = row + _vertex(response[(row - 1) % PATCH, col], response[row, col], response[(row + 1) % PATCH, col])
        dx = col + _vertex(response[row, (col - 1) % PATCH], response[row, col], response[row, (col + 1) % PATCH])
        dy = (dy + PATCH / 2) % PATCH - PATCH / 2  # the response wraps around: past half the patch is a negative shift
        dx = (dx + PATCH / 2) % PATCH - PATCH / 2
        _, _, w, h = box_xywh_from_states(np.asarray(state, dtype=np.float64), self.template_size)
        return float(dx * PADDING * w / PATCH), float(dy * PADDING * h / PATCH)

    def update(self, rgb: np.ndarray, state: np.ndarray) -> None:
        """Blend the patch around ``state`` into ``A`` and ``B`` by :data:`LEARNING_RATE`, as in DSST."""
        if not self.correlation.learned:
            raise RuntimeError("TranslationFilter.update() before init()")
        self.correlation.blend(self._spectrum(rgb, state))


def _vertex(before: float, peak: float, after: float) -> float:
    """Offset in (-0.5, 0.5) of the vertex of the parabola through three equally spaced values; 0 if not a peak."""
    curvature = before - 2.0 * peak + after
    if curvature >= 0:
        return 0.0
    return float(np.clip(0.5 * (before - after) / curvature, -0.5, 0.5))

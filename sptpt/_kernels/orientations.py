"""Gradient magnitudes split between two orientation bins: per-cell histograms and per-bin channels.

For the scale and translation filters' features (:mod:`sptpt.gradients`). The arithmetic is the one NumPy did
before these kernels, operation for operation: the C library's ``hypot`` (NumPy's too), the remainder modulo
pi of Python's and NumPy's sign rule, ``floor``, and sums in pixel order, so the features are bit-identical
(``tests/_orientation_reference.py`` keeps the NumPy code, ``tests/sptpt/test_scale.py`` compares). The angle itself
stays NumPy's ``arctan2``, whose SIMD code may round differently from the C library's ``atan2``. NumPy spent most of
the filters' feature time on the temporaries of these element-wise steps (about fifteen arrays the size of the batch).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def _split(gx, gy, angle, bins):  # pragma: no cover - compiled
    """One pixel's gradient magnitude, its lower and upper orientation bin, and the upper bin's share."""
    magnitude = math.hypot(gx, gy)
    # angle % pi for an angle in [-pi, pi], as fmod and the sign rule give it, without the division: the remainder
    # of |angle| < pi is the angle itself, which gains pi where it is negative; that of +-pi is 0.
    if angle < 0.0:
        folded = angle + np.pi if angle > -np.pi else 0.0
    else:
        folded = angle + 0.0 if angle < np.pi else 0.0  # + 0.0: the remainder of -0.0 is +0.0
    position = folded * (bins / np.pi)
    lower = np.floor(position)
    upper_weight = position - lower
    low = np.int64(lower) % bins
    return magnitude, low, (low + 1) % bins, upper_weight


@numba.njit(cache=True, nogil=True)
def cell_histograms(gx, gy, angle, bins, cell):  # pragma: no cover - compiled
    """``(N, T, T)`` gradients and their angles -> ``(N, cells * cells, bins)`` split magnitudes summed per cell.

    A pixel counts in cell ``min(row // cell, cells - 1), min(col // cell, cells - 1)``. The lower bins' shares
    and the upper bins' shares are summed apart, each in pixel order, and added at the end, as two
    ``np.bincount`` passes did.
    """
    n, size = gx.shape[0], gx.shape[1]
    cells = size // cell
    lower_sums = np.zeros((n, cells * cells, bins))
    upper_sums = np.zeros((n, cells * cells, bins))
    for i in range(n):
        for r in range(size):
            cell_row = min(r // cell, cells - 1) * cells
            for c in range(size):
                k = cell_row + min(c // cell, cells - 1)
                magnitude, low, up, upper_weight = _split(gx[i, r, c], gy[i, r, c], angle[i, r, c], bins)
                lower_sums[i, k, low] += magnitude * (1 - upper_weight)
                upper_sums[i, k, up] += magnitude * upper_weight
    return lower_sums + upper_sums


@numba.njit(cache=True, nogil=True)
def orientation_channels(gx, gy, angle, bins):  # pragma: no cover - compiled
    """``(rows, cols)`` gradients and their angles -> ``(bins, rows, cols)``: each pixel's magnitude split between
    its lower and upper bin's channel, 0 in the others."""
    rows, cols = gx.shape
    channels = np.zeros((bins, rows, cols))
    for r in range(rows):
        for c in range(cols):
            magnitude, low, up, upper_weight = _split(gx[r, c], gy[r, c], angle[r, c], bins)
            # += onto zeros: the same values where the two bins differ, and the whole magnitude where one bin
            # is both (bins == 1).
            channels[low, r, c] += magnitude * (1.0 - upper_weight)
            channels[up, r, c] += magnitude * upper_weight
    return channels

"""The orientation split of ``sptpt.gradients`` as it was before its numba kernels: pixel by pixel, and the NumPy
code, kept to show the kernels give the same bits (the scale and the translation filters' features are built on it)."""

from __future__ import annotations

import math

import numpy as np


def slow_orientation_split(grey: np.ndarray, bins: int) -> np.ndarray:
    """``(rows, cols)`` grey -> ``(bins, rows, cols)``: each pixel's central-difference gradient magnitude (0 on the
    border), split linearly between its two nearest unsigned orientations; pixel by pixel, as
    the NumPy code of ``sptpt.gradients`` did before its numba kernels."""
    rows, cols = grey.shape
    split = np.zeros((bins, rows, cols))
    for r in range(rows):
        for c in range(cols):
            gx = grey[r, c + 1] - grey[r, c - 1] if 0 < c < cols - 1 else 0.0
            gy = grey[r + 1, c] - grey[r - 1, c] if 0 < r < rows - 1 else 0.0
            magnitude = math.hypot(gx, gy)
            position = (math.atan2(gy, gx) % math.pi) * bins / math.pi
            lower = math.floor(position)
            weight = position - lower
            split[lower % bins, r, c] += magnitude * (1 - weight)
            split[(lower + 1) % bins, r, c] += magnitude * weight
    return split


def numpy_orientation_split(grey: np.ndarray, bins: int):
    """The NumPy code ``sptpt.gradients`` ran before its kernels, kept to show they give the same bits."""
    gx = np.zeros_like(grey)
    gy = np.zeros_like(grey)
    gx[..., 1:-1] = grey[..., 2:] - grey[..., :-2]
    gy[..., 1:-1, :] = grey[..., 2:, :] - grey[..., :-2, :]
    magnitude = np.hypot(gx, gy)
    position = (np.arctan2(gy, gx) % np.pi) * (bins / np.pi)
    lower = np.floor(position)
    upper_weight = position - lower
    lower = lower.astype(np.int64) % bins
    return magnitude, lower, (lower + 1) % bins, upper_weight


def edge_templates(size: int = 32) -> np.ndarray:
    """Templates whose gradients point exactly along the axes, both ways (angles 0, +-pi/2, pi and -pi: the
    remainder's edge cases), and one that is flat (no gradient, angle 0)."""
    ramp = np.tile(np.arange(size, dtype=np.uint8) * 7, (size, 1))
    out = np.stack([ramp, ramp[:, ::-1], ramp.T, ramp.T[::-1], np.full((size, size), 90, np.uint8)])
    return np.repeat(out[..., None], 3, axis=3)

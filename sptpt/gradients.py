"""Gradient orientations of grey images, shared by the scale and translation filters' features.

Each pixel's central-difference gradient (0 on the border) has a magnitude, split linearly between the two
nearest of ``bins`` unsigned orientations over ``[0, pi)``: the share of the upper one grows with the angle's
distance from the lower one's. The loops are kernels (:mod:`sptpt._kernels.orientations`).
"""

from __future__ import annotations

import numpy as np

from sptpt._kernels import orientations

__all__ = ["GREY", "cell_histograms", "orientation_channels"]

GREY = np.array([0.299, 0.587, 0.114])  # ITU-R BT.601 luma weights of R, G, B


def _gradients(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Central differences along the last two axes (0 on the border) and their angle, ``arctan2(gy, gx)``."""
    gx = np.zeros_like(grey)
    gy = np.zeros_like(grey)
    gx[..., 1:-1] = grey[..., 2:] - grey[..., :-2]
    gy[..., 1:-1, :] = grey[..., 2:, :] - grey[..., :-2, :]
    return gx, gy, np.arctan2(gy, gx)


def cell_histograms(grey: np.ndarray, bins: int, cell: int) -> np.ndarray:
    """``(N, T, T)`` float grey images -> ``(N, cells * cells, bins)`` split magnitudes summed per ``cell x cell``
    cell, ``cells = T // cell`` (pixels past the last whole cell join it)."""
    return orientations.cell_histograms(*_gradients(np.ascontiguousarray(grey, dtype=np.float64)), bins, cell)


def orientation_channels(grey: np.ndarray, bins: int) -> np.ndarray:
    """``(rows, cols)`` float grey image -> ``(bins, rows, cols)``: each pixel's magnitude in its two bins' channels,
    0 in the others."""
    return orientations.orientation_channels(*_gradients(np.ascontiguousarray(grey, dtype=np.float64)), bins)

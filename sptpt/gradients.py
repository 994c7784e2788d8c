"""Gradient orientations of grey images, shared by the scale and translation filters' features."""

from __future__ import annotations

import numpy as np

__all__ = ["GREY", "orientation_split"]

GREY = np.array([0.299, 0.587, 0.114])  # ITU-R BT.601 luma weights of R, G, B


def orientation_split(grey: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's gradient magnitude, split linearly between the two nearest of ``bins`` unsigned orientations.

    ``grey`` is ``(..., rows, cols)`` float; gradients are central differences along the last two axes, 0 on
    the border. Returns ``magnitude``, ``lower`` and ``upper`` (the two bins, int) and ``upper_weight`` (the share
    of the magnitude that goes to ``upper``), each of ``grey``'s shape.
    """
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

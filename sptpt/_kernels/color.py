"""sRGB -> CIELAB for batches of uint8 templates, parallel over images.

The same formula and constants as :func:`sptpt.color.rgb_to_lab` (the
reference, used by the tests), evaluated per pixel so the ``cbrt`` calls run
on both cores; results agree to about 1e-13.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(parallel=True, cache=True)
def rgb_to_lab_batch(images, linear, rgb_to_xyz, white):  # pragma: no cover - compiled
    """images: (N, H, W, 3) uint8; linear: (256,) inverse sRGB gamma table. Returns (N, H, W, 3) float64."""
    n, height, width = images.shape[0], images.shape[1], images.shape[2]
    out = np.empty((n, height, width, 3), dtype=np.float64)
    for i in numba.prange(n):
        for r in range(height):
            for c in range(width):
                lr = linear[images[i, r, c, 0]]
                lg = linear[images[i, r, c, 1]]
                lb = linear[images[i, r, c, 2]]
                tx = (rgb_to_xyz[0, 0] * lr + rgb_to_xyz[0, 1] * lg + rgb_to_xyz[0, 2] * lb) / white[0]
                ty = (rgb_to_xyz[1, 0] * lr + rgb_to_xyz[1, 1] * lg + rgb_to_xyz[1, 2] * lb) / white[1]
                tz = (rgb_to_xyz[2, 0] * lr + rgb_to_xyz[2, 1] * lg + rgb_to_xyz[2, 2] * lb) / white[2]
                fx = np.cbrt(tx) if tx > 0.008856 else (903.3 * tx + 16.0) / 116.0
                fy = np.cbrt(ty) if ty > 0.008856 else (903.3 * ty + 16.0) / 116.0
                fz = np.cbrt(tz) if tz > 0.008856 else (903.3 * tz + 16.0) / 116.0
                out[i, r, c, 0] = 116.0 * fy - 16.0
                out[i, r, c, 1] = 500.0 * (fx - fy)
                out[i, r, c, 2] = 200.0 * (fy - fz)
    return out

"""Bilinear affine warping of many candidates from one frame."""

from __future__ import annotations

import numba
import numpy as np

from sptpt._kernels import run_in_chunks


def warp_affine_batch(frame, q, offsets, n_threads):
    """Sample ``frame`` at ``(cx + A11 x + A12 y, cy + A21 x + A22 y)`` for every template pixel.

    frame: (H, W, 3) uint8. q: (N, 6) float64, 0-based centre and the 2x2
    linear part. offsets: (T,) template offsets. n_threads: threads that warp
    blocks of candidates in turn. Returns (N, T, T, 3) uint8. Positions outside
    ``[0, W-1] x [0, H-1]`` give 0, as MATLAB ``interp2`` returns NaN there
    and ``warpimg`` replaces NaN by 0.
    """
    size = offsets.shape[0]
    out = np.empty((q.shape[0], size, size, 3), dtype=np.uint8)  # every pixel is written, 0 outside the frame
    run_in_chunks(_warp_range, q.shape[0], n_threads, frame, q, offsets, out)
    return out


@numba.njit(cache=True, nogil=True, fastmath=False)
def _warp_range(frame, q, offsets, out, start, stop):  # pragma: no cover - compiled
    """Candidates ``start:stop`` of :func:`warp_affine_batch` into ``out`` (contents ignored).

    Pixels are addressed in the flattened frame and template with unsigned
    indices (a floor of a coordinate already tested >= 0), which spares numba
    the negative-index wraparound and the three-axis address of every read:
    about 10% of the warp. The arithmetic is the same, operation for operation.
    """
    height, width = frame.shape[0], frame.shape[1]
    size = offsets.shape[0]
    flat = frame.reshape(height * width * 3)
    row_stride = np.uint64(width * 3)
    three = np.uint64(3)
    last_col = np.uint64(width - 1)
    last_row = np.uint64(height - 1)
    for i in range(start, stop):
        cx, cy, a11, a12, a21, a22 = q[i, 0], q[i, 1], q[i, 2], q[i, 3], q[i, 4], q[i, 5]
        template = out[i].reshape(size * size * 3)
        for r in range(size):
            y = offsets[r]
            for c in range(size):
                x = offsets[c]
                px = cx + a11 * x + a12 * y
                py = cy + a21 * x + a22 * y
                o = np.uint64((r * size + c) * 3)
                if not (px >= 0.0 and px <= width - 1 and py >= 0.0 and py <= height - 1):
                    template[o] = 0
                    template[o + np.uint64(1)] = 0
                    template[o + np.uint64(2)] = 0
                    continue
                fx0 = np.floor(px)
                fy0 = np.floor(py)
                fx = px - fx0
                fy = py - fy0
                x0 = np.uint64(fx0)
                y0 = np.uint64(fy0)
                x1 = min(x0 + np.uint64(1), last_col)
                y1 = min(y0 + np.uint64(1), last_row)
                p00 = y0 * row_stride + x0 * three
                p01 = y0 * row_stride + x1 * three
                p10 = y1 * row_stride + x0 * three
                p11 = y1 * row_stride + x1 * three
                for ch in range(3):
                    k = np.uint64(ch)
                    top = flat[p00 + k] * (1.0 - fx) + flat[p01 + k] * fx
                    bottom = flat[p10 + k] * (1.0 - fx) + flat[p11 + k] * fx
                    value = top * (1.0 - fy) + bottom * fy
                    template[o + k] = np.uint8(min(max(np.rint(value), 0.0), 255.0))

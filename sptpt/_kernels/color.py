"""sRGB -> CIELAB for batches of uint8 templates, parallel over images.

The same formula and constants as :func:`sptpt.color.rgb_to_lab` (the
reference, used by the tests), evaluated per pixel so the ``cbrt`` calls run
on both cores; results agree to about 1e-13.

:func:`lab_image_memo` converts one image through a small per-thread memo of
colours already converted. The Lab of a pixel depends only on its three
bytes, and the 800 templates of a frame are bilinear samples of overlapping
windows of one smooth frame: on ``../shared/otb`` about one pixel in ten has
a colour not seen before in the batch, so nine in ten skip the three ``cbrt``
calls. A memo hit returns the value computed by the very same
:func:`lab_pixel`, so the result is bit-identical to :func:`rgb_to_lab_batch`.
"""

from __future__ import annotations

import numba
import numpy as np

# Memo slots (a power of two): 2**16 colours, 1.75 MiB per thread.
MEMO_BITS = 16
# Fibonacci hashing multiplier (2**32 / golden ratio), for the slot of a 24-bit colour key.
_HASH = 2654435761


@numba.njit(cache=True)
def lab_pixel(red, green, blue, linear, rgb_to_xyz, white, out, o):  # pragma: no cover - compiled
    """Write the Lab of one uint8 RGB pixel to ``out[o:o + 3]``."""
    lr = linear[red]
    lg = linear[green]
    lb = linear[blue]
    tx = (rgb_to_xyz[0, 0] * lr + rgb_to_xyz[0, 1] * lg + rgb_to_xyz[0, 2] * lb) / white[0]
    ty = (rgb_to_xyz[1, 0] * lr + rgb_to_xyz[1, 1] * lg + rgb_to_xyz[1, 2] * lb) / white[1]
    tz = (rgb_to_xyz[2, 0] * lr + rgb_to_xyz[2, 1] * lg + rgb_to_xyz[2, 2] * lb) / white[2]
    fx = np.cbrt(tx) if tx > 0.008856 else (903.3 * tx + 16.0) / 116.0
    fy = np.cbrt(ty) if ty > 0.008856 else (903.3 * ty + 16.0) / 116.0
    fz = np.cbrt(tz) if tz > 0.008856 else (903.3 * tz + 16.0) / 116.0
    out[o] = 116.0 * fy - 16.0
    out[o + 1] = 500.0 * (fx - fy)
    out[o + 2] = 200.0 * (fy - fz)


@numba.njit(parallel=True, cache=True)
def rgb_to_lab_batch(images, linear, rgb_to_xyz, white):  # pragma: no cover - compiled
    """images: (N, H, W, 3) uint8; linear: (256,) inverse sRGB gamma table. Returns (N, H, W, 3) float64."""
    n, height, width = images.shape[0], images.shape[1], images.shape[2]
    out = np.empty((n, height, width, 3), dtype=np.float64)
    n_pixels = height * width
    for i in numba.prange(n):
        flat_in = images[i].reshape(n_pixels * 3)
        flat_out = out[i].reshape(n_pixels * 3)
        for p in range(n_pixels):
            lab_pixel(flat_in[3 * p], flat_in[3 * p + 1], flat_in[3 * p + 2], linear, rgb_to_xyz, white,
                      flat_out, 3 * p)
    return out


@numba.njit(cache=True)
def new_lab_memo():  # pragma: no cover - compiled
    """An empty memo: per slot the colour key (as a float64, -1 when free) then its L, a, b.

    Key and value share a cache line, so a lookup costs one memory access.
    """
    memo = np.empty((1 << MEMO_BITS) * 4, dtype=np.float64)
    memo[::4] = -1.0
    return memo


@numba.njit(cache=True)
def lab_image_memo(image, linear, rgb_to_xyz, white, memo, out):  # pragma: no cover - compiled
    """Lab of one (H, W, 3) uint8 C-contiguous image into ``out`` (H * W * 3,) float64, through the memo.

    memo: from :func:`new_lab_memo`, updated in place (direct-mapped: a new
    colour overwrites its slot).
    """
    n = image.shape[0] * image.shape[1]
    flat = image.reshape(n * 3)
    shift = 32 - MEMO_BITS
    for p in range(n):
        red = flat[3 * p]
        green = flat[3 * p + 1]
        blue = flat[3 * p + 2]
        key = (np.int64(red) << 16) | (np.int64(green) << 8) | np.int64(blue)
        slot = ((key * _HASH) & 0xFFFFFFFF) >> shift
        v = 4 * slot
        if memo[v] != key:
            memo[v] = key
            lab_pixel(red, green, blue, linear, rgb_to_xyz, white, memo, v + 1)
        out[3 * p] = memo[v + 1]
        out[3 * p + 1] = memo[v + 2]
        out[3 * p + 2] = memo[v + 3]

"""Per-superpixel cue histograms for a batch of templates (``docs/design/tracker.md``, "Cue histograms")."""

from __future__ import annotations

import math

import numba
import numpy as np

from sptpt._kernels import run_in_chunks

# Same constants as sptpt.color.rgb_to_hsi, so that the HSI computed here is
# bit-for-bit the one computed there.
_EPS = np.finfo(np.float64).eps
_TWO_PI = 2.0 * np.pi


# Half-width of the band around a hue bin edge, on the arccos argument, inside
# which the H bin is taken from arccos itself. Outside it the edge is at least
# 1e-6 rad away in angle (|d acos / dx| >= 1), far beyond the few-ulp error of
# any arccos, so comparing the argument with cos(edge) gives the same bin.
_EDGE_BAND = 1e-6


@numba.njit(cache=True)
def hue_edge_cosines(n_bins):  # pragma: no cover - compiled
    """``cos(2 pi k / n)`` for k = 0..n-1: the arccos argument at each hue bin edge."""
    out = np.empty(n_bins, dtype=np.float64)
    for k in range(n_bins):
        out[k] = math.cos(_TWO_PI * k / n_bins)
    return out


@numba.njit(cache=True, inline="always")
def hsi_bins(red, green, blue, n_bins, edge_cosines, unit):  # pragma: no cover - compiled
    """Bins of H, S, I for one uint8 pixel, with ``min(floor(v * n), n - 1)``.

    Replays ``sptpt.color.rgb_to_hsi`` operation by operation (same order,
    same constants, no fused multiply-add because fastmath is off), so S and
    I, which use only correctly rounded operations, are bit-identical to the
    reference. It works from the uint8 values instead of calling the NumPy
    function because that one allocates about ten float64 temporaries per
    pixel, which costs more than the whole histogram pass.

    ``unit[v] = v / 255.0`` is a 256-entry table holding exactly the values
    of ``rgb.astype(float64) / 255.0``; it saves three divisions per pixel.

    H needs ``arccos``, which took half of the pass's time when computed for
    every pixel. Since the hue is monotone in
    the arccos argument on each side of ``B > G``, the H bin is found by
    comparing the argument with the precomputed ``edge_cosines``; only an
    argument within ``_EDGE_BAND`` of an edge takes the exact arccos route.
    """
    r = unit[red]
    g = unit[green]
    b = unit[blue]
    rg = r - g
    rb = r - b
    total = r + g + b
    lowest = min(min(r, g), b)
    saturation = 1.0 - 3.0 * lowest / (total if total != 0.0 else _EPS)
    intensity = total / 3.0
    top = n_bins - 1
    s_bin = min(int(math.floor(saturation * n_bins)), top)
    i_bin = min(int(math.floor(intensity * n_bins)), top)
    if saturation == 0.0:
        # rgb_to_hsi sets H = 0 on gray pixels.
        return 0, s_bin, i_bin
    numerator = 0.5 * (rg + rb)
    denominator = math.sqrt(rg * rg + rb * (g - b))
    ratio = numerator / (denominator + _EPS)
    if ratio < -1.0:
        ratio = -1.0
    elif ratio > 1.0:
        ratio = 1.0
    upper = b > g
    # hue >= k/n for k = 1..n-1, counted. B <= G: hue = theta / 2pi in
    # [0, 1/2], and hue >= k/n iff k/n <= 1/2 and ratio <= cos(2 pi k/n).
    # B > G: hue = 1 - theta / 2pi in [1/2, 1], and hue >= k/n iff
    # k/n <= 1/2 or ratio >= cos(2 pi k/n).
    h_bin = 0
    exact = False
    for k in range(1, n_bins):
        lower_half = 2 * k <= n_bins
        if upper and lower_half:
            h_bin += 1
            continue
        if not upper and not lower_half:
            break
        edge = edge_cosines[k]
        if abs(ratio - edge) < _EDGE_BAND:
            exact = True
            break
        if upper:
            if ratio >= edge:
                h_bin += 1
        elif ratio <= edge:
            h_bin += 1
    if exact:
        theta = math.acos(ratio)
        if upper:
            hue = (_TWO_PI - theta) / _TWO_PI
        else:
            hue = theta / _TWO_PI
        h_bin = min(int(math.floor(hue * n_bins)), top)
    return h_bin, s_bin, i_bin


def cue_features(templates, labels, n_superpixels, n_bins, n_threads):
    """Normalised, concatenated cue histograms of every superpixel of every template.

    templates: (N, H, W, 3) uint8 RGB, C-contiguous. labels: (N, H, W) int32
    in ``0..n_superpixels-1`` (not checked). n_threads: threads that take
    blocks of templates in turn. Returns (N, n_superpixels, 8 * n_bins) float64, cue-major in
    the order H, S, I, R, G, B, x, y; each cue block is ``counts /
    pixel_count`` and the whole row is then divided by its L2 norm. Rows of
    empty superpixels stay zero.

    One pass over the pixels of a template accumulates all eight cues as
    float counts (exact below 2**53) straight into the output rows, which are
    then normalised in place.
    """
    n_templates = labels.shape[0]
    # Not zero-filled here: each thread clears its templates' rows just before counting into them, in cache,
    # instead of one thread writing 10 MiB of zeros first.
    out = np.empty((n_templates, n_superpixels, 8 * n_bins), dtype=np.float64)
    run_in_chunks(_cue_features_range, n_templates, n_threads, templates, labels, n_bins, out)
    return out


@numba.njit(cache=True, nogil=True)
def _cue_features_range(templates, labels, n_bins, out, start, stop):  # pragma: no cover - compiled
    """Templates ``start:stop`` of :func:`cue_features` into ``out`` (contents ignored)."""
    n_templates, height, width = labels.shape
    n_superpixels = out.shape[1]
    width_features = 8 * n_bins
    # Position bins depend only on the row/column index: floor(i * n / H).
    x_bins = np.empty(width, dtype=np.int64)
    for col in range(width):
        x_bins[col] = 6 * n_bins + (col * n_bins) // width
    y_bins = np.empty(height, dtype=np.int64)
    for row in range(height):
        y_bins[row] = 7 * n_bins + (row * n_bins) // height
    edge_cosines = hue_edge_cosines(n_bins)
    unit = np.arange(256) / 255.0
    for t in range(start, stop):
        hist = out[t]
        hist[:, :] = 0.0
        for row in range(height):
            y_bin = y_bins[row]
            for col in range(width):
                k = labels[t, row, col]
                red = templates[t, row, col, 0]
                green = templates[t, row, col, 1]
                blue = templates[t, row, col, 2]
                h_bin, s_bin, i_bin = hsi_bins(red, green, blue, n_bins, edge_cosines, unit)
                hist[k, h_bin] += 1.0
                hist[k, n_bins + s_bin] += 1.0
                hist[k, 2 * n_bins + i_bin] += 1.0
                hist[k, 3 * n_bins + (np.int64(red) * n_bins) // 256] += 1.0
                hist[k, 4 * n_bins + (np.int64(green) * n_bins) // 256] += 1.0
                hist[k, 5 * n_bins + (np.int64(blue) * n_bins) // 256] += 1.0
                hist[k, x_bins[col]] += 1.0
                hist[k, y_bin] += 1.0
        for k in range(n_superpixels):
            # The x histogram holds one count per pixel of the superpixel.
            size = 0.0
            for j in range(6 * n_bins, 7 * n_bins):
                size += hist[k, j]
            if size == 0.0:
                continue
            # Same operation order as the reference: counts / size, then a
            # sequential sum of squares, so the result is bit-identical.
            squares = 0.0
            for j in range(width_features):
                value = hist[k, j] / size
                hist[k, j] = value
                squares += value * value
            norm = math.sqrt(squares)
            for j in range(width_features):
                hist[k, j] = hist[k, j] / norm

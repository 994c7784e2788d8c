"""Midlevel cue histograms of superpixels (paper eqs 1-3; ``docs/design/tracker.md``, "Cue histograms").

Every superpixel of every template is described by eight marginal
histograms, one per cue (H, S, I, R, G, B, x, y), of ``n_bins`` bins each.
Each histogram counts the superpixel's pixels per bin and is divided by the
pixel count, so it sums to 1 (paper eq 2); the eight are concatenated
cue-major and the result is L2-normalised (TPT practice, needed for the
``lambda = 0.01`` scale of the sparse coding).
"""

from __future__ import annotations

import numba
import numpy as np

from sptpt._kernels.histograms import cue_features
from sptpt._validation import positive_int as _positive_int

__all__ = ["CUES", "superpixel_features"]

#: Cue order of the feature vector: block ``c`` holds bins ``c*n .. c*n+n-1``.
CUES: tuple[str, ...] = ("H", "S", "I", "R", "G", "B", "x", "y")


def superpixel_features(
    templates: np.ndarray,
    labels: np.ndarray,
    n_superpixels: int,
    *,
    n_bins: int = 8,
) -> np.ndarray:
    """Cue histograms of every superpixel of a batch of templates.

    Binning follows ``docs/design/tracker.md``, "Cue histograms":

    - H, S, I from :func:`sptpt.color.rgb_to_hsi` (SPT's ``rgb2hsi``), bin
      ``min(floor(v * n), n - 1)``;
    - R, G, B from the uint8 values, bin ``floor(c * n / 256)``;
    - x = column index, y = row index, bins ``floor(x * n / W)`` and
      ``floor(y * n / H)``.

    Parameters
    ----------
    templates : (N, H, W, 3) uint8 ndarray
        RGB templates (32 x 32 in the tracker).
    labels : (N, H, W) integer ndarray
        Superpixel label of every pixel, in ``0 .. n_superpixels - 1``
        (SNIC output, seed raster order). Converted to int32.
    n_superpixels : int
        Number of superpixels ``s`` per template (25 for the paper setting).
    n_bins : int, optional
        Bins per cue histogram ``n`` (8, from SPT).

    Returns
    -------
    features : (N, n_superpixels, 8 * n_bins) float64 ndarray
        ``[hist_H, hist_S, hist_I, hist_R, hist_G, hist_B, hist_x, hist_y]``
        per superpixel (see :data:`CUES`). Each block sums to 1 before the
        final L2 normalisation, and every row has unit L2 norm. A label
        with no pixel in a template (never the case for SNIC, whose every
        seed labels its own pixel) gets an all-zero row rather than a
        division by zero.

    Raises
    ------
    TypeError
        If ``templates`` is not uint8 or ``labels`` is not an integer array.
    ValueError
        If the shapes disagree, ``n_superpixels`` or ``n_bins`` is not a
        positive integer, or a label is outside ``0 .. n_superpixels - 1``.

    Notes
    -----
    The HSI bins are computed inside the numba kernel from the uint8 values
    with the operations of ``rgb_to_hsi`` replayed in the same order, instead
    of materialising float64 HSI arrays (about ten temporaries per pixel,
    more than the cost of the whole pass). The bins are then identical to
    those of ``rgb_to_hsi``: checked for all 2**24 colours with ``n_bins`` in
    (5, 7, 8, 10, 16, 32). The one caveat is ``n_bins`` divisible by 3: hues
    of exactly 1/3 and 2/3 (for instance pure greens ``(0, g, 0)``), and 1/6
    and 5/6 for multiples of 6, come out within one ulp of a bin edge, where
    NumPy's SIMD ``arccos`` and libm's ``acos`` may round to opposite sides;
    such pixels can then land one H bin apart from a NumPy computation. By
    Niven's theorem no other hue of an 8-bit colour lies on a bin edge. At
    multiples of 1/4 the ``arccos`` argument is 0 but for rounding, and
    NumPy 1.x on AVX-512 processors (SVML's ``arccos``) can return one ulp
    below libm there: ``rgb_to_hsi`` then puts such a hue one H bin lower
    than this kernel does, which agrees with libm and NumPy 2.
    """
    templates = np.asarray(templates)
    labels = np.asarray(labels)
    if templates.dtype != np.uint8:
        raise TypeError(
            f"templates must be uint8 RGB, got dtype {templates.dtype}; "
            "convert with np.clip(x, 0, 255).astype(np.uint8)"
        )
    if templates.ndim != 4 or templates.shape[-1] != 3:
        raise ValueError(f"templates must have shape (N, H, W, 3), got {templates.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise TypeError(f"labels must be an integer array, got dtype {labels.dtype}")
    if labels.shape != templates.shape[:3]:
        raise ValueError(
            f"labels must have shape (N, H, W) = {templates.shape[:3]} to match templates, "
            f"got {labels.shape}"
        )
    n_superpixels = _positive_int(n_superpixels, "n_superpixels")
    n_bins = _positive_int(n_bins, "n_bins")
    if labels.size:
        low, high = int(labels.min()), int(labels.max())
        if low < 0 or high >= n_superpixels:
            raise ValueError(
                f"labels must lie in 0..{n_superpixels - 1} (n_superpixels={n_superpixels}), "
                f"got values in {low}..{high}"
            )
    templates = np.ascontiguousarray(templates)
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    return cue_features(templates, labels, n_superpixels, n_bins, numba.get_num_threads())


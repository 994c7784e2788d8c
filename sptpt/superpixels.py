"""SNIC superpixels of SPTPT templates (``docs/design/tracker.md``, "SNIC superpixels").

SNIC (Simple Non-Iterative Clustering; Achanta & Suesstrunk, CVPR 2017) grows
superpixels from a fixed grid of seeds with a priority queue. It never merges
or drops a seed, so the number of superpixels equals the number of seeds and
label ``k`` is the region grown from seed ``k``. Because the seeds depend only
on the template size, label ``k`` is the same grid place in every candidate:
that is the "spatial order" tensor pooling relies on.

Public API:

- :func:`seed_grid` -- the seed positions, ``official`` (MATLAB ``snic_mex``)
  or ``exact`` (exactly ``n_segments`` seeds).
- :func:`snic` -- uint8 RGB image(s) in, int32 labels out.
- :func:`snic_lab` -- the same from CIELAB image(s) and explicit seeds, for
  callers that already hold Lab templates.

The loops live in :mod:`sptpt._kernels.snic`.
"""

from __future__ import annotations

import math
import numbers
from fractions import Fraction

import numba
import numpy as np

from sptpt._kernels.snic import MAX_PIXELS, snic_batch, snic_batch_rgb
from sptpt.color import RGB_TO_XYZ, SRGB_TO_LINEAR, WHITE

__all__ = ["SEEDINGS", "seed_grid", "snic", "snic_lab"]

#: Valid values of the ``seeding`` argument.
SEEDINGS = ("official", "exact")


def _check_int(name: str, value: object, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an int, got {type(value).__name__} {value!r}")
    if value < low:
        raise ValueError(f"{name} must be >= {low}, got {value}")
    return int(value)


def _check_seeding(seeding: object) -> str:
    if seeding not in SEEDINGS:
        raise ValueError(f"seeding must be one of {SEEDINGS}, got {seeding!r}")
    return str(seeding)


def _check_compactness(compactness: object) -> float:
    if isinstance(compactness, bool) or not isinstance(compactness, numbers.Real):
        raise TypeError(f"compactness must be a real number, got {type(compactness).__name__} {compactness!r}")
    value = float(compactness)
    if not math.isfinite(value) or value < 0.0:
        raise ValueError(f"compactness must be finite and >= 0 (official default 20, range 10-40), got {compactness!r}")
    return value


def _check_size(height: int, width: int, name: str) -> None:
    if height * width > MAX_PIXELS:
        raise ValueError(
            f"{name} has {height} x {width} = {height * width} pixels per image; SNIC here takes at most "
            f"{MAX_PIXELS} (2**28 - 1); split the image into tiles"
        )


def _official_seeds(height: int, width: int, n_segments: int) -> np.ndarray:
    """``FindSeeds`` of the 2016 MATLAB ``snic_mex.cpp``, step for step."""
    n_pixels = height * width
    step = int(math.sqrt(n_pixels / n_segments) + 0.5)
    # The half step is taken before the optional decrement below, as in the
    # official code.
    half = step // 2
    nx, ny = width // step, height // step
    # The official code divides by step - 1 unguarded; at step 1 there is no
    # smaller step to try.
    if step > 1:
        err_here = abs(nx * ny - n_segments)
        err_finer = abs((width // (step - 1)) * (height // (step - 1)) - n_segments)
        if err_finer < err_here:
            step -= 1
            nx, ny = width // step, height // step
    n_max = nx * ny
    seeds: list[tuple[int, int]] = []
    y = half
    while y < height and len(seeds) < n_max:
        x = half
        while x < width and len(seeds) < n_max:
            if y <= height - half and x <= width - half:
                seeds.append((y, x))
            x += step
        y += step
    return np.array(seeds, dtype=np.int64).reshape(-1, 2)


def _exact_shape(height: int, width: int, n_segments: int) -> tuple[int, int]:
    """Factorisation ``rows * cols == n_segments`` whose cells are closest to square."""
    best: tuple[Fraction, int, int, int] | None = None
    for rows in range(1, n_segments + 1):
        if n_segments % rows:
            continue
        cols = n_segments // rows
        if rows > height or cols > width:
            continue
        # Distance from the image aspect as an exact ratio >= 1 (a log-ratio
        # distance without float rounding): 2:1 and 1:2 are equally far. On a
        # tie (a square image, rows * cols = cols * rows) the longer side of
        # the image gets the larger count: cols >= rows when width >= height.
        wide, tall = cols * height, rows * width
        misfit = Fraction(max(wide, tall), min(wide, tall))
        tie = 0 if (cols >= rows) == (width >= height) else 1
        key = (misfit, tie, rows, cols)
        if best is None or key[:2] < best[:2]:
            best = key
    if best is None:
        raise ValueError(
            f"n_segments={n_segments} has no factorisation rows * cols with rows <= height={height} "
            f"and cols <= width={width}; use seeding='official' or another n_segments"
        )
    return best[2], best[3]


def seed_grid(height: int, width: int, n_segments: int, *, seeding: str = "official") -> np.ndarray:
    """Seed positions of SNIC on a ``height x width`` image.

    Parameters
    ----------
    height, width : int
        Image size in pixels, each >= 1.
    n_segments : int
        Requested number of superpixels ``K``, ``1 <= K <= height * width``.
    seeding : {"official", "exact"}
        ``"official"`` (default; ``docs/design/tracker.md``, "Seed grid"): ``FindSeeds`` of the official 2016
        MATLAB ``snic_mex.cpp``. Integer grid step
        ``g = floor(sqrt(N / K) + 0.5)``, replaced by ``g - 1`` if that brings
        ``floor(W / g) * floor(H / g)`` closer to ``K``; seeds at
        ``(half + b g, half + a g)`` with ``half = floor(g_initial / 2)``,
        kept if ``x <= W - half`` and ``y <= H - half``, at most
        ``floor(W / g) * floor(H / g)`` of them. The count is generally not
        ``K``: 32 x 32 with ``K = 30`` gives 25 seeds at rows and columns
        ``{3, 9, 15, 21, 27}``. Two quirks of the official loop are kept for
        fidelity: when a row fits one more seed than ``floor(W / g)`` the
        raster simply continues, so the grid can be staggered (29 x 29,
        ``K = 30``); when fewer positions pass the filter than the cap, the
        official code pads with seeds at pixel (0, 0) that yield empty or
        corner labels, and this function instead returns only the placed
        seeds. Neither case occurs for 32 x 32 templates.
        ``"exact"``: exactly ``K`` seeds on a ``rows x cols`` grid with
        ``rows * cols == K`` and ``cols / rows`` closest to ``width / height``
        (in log ratio); on a tie the larger count goes along the longer
        side, ``cols >= rows`` when ``width >= height`` (32 x 32, ``K = 30``:
        5 rows x 6 columns). Seeds sit at the cell centres
        ``(floor((i + 0.5) H / rows), floor((j + 0.5) W / cols))``.

    Returns
    -------
    seeds : (s, 2) int64 ndarray
        ``(row, col)`` of each seed, 0-based, in raster order (rows outer).
        Seed ``k`` grows label ``k``.

    Raises
    ------
    TypeError
        If a size or ``n_segments`` is not an int.
    ValueError
        If a size is < 1, ``n_segments`` is outside ``[1, height * width]``,
        ``seeding`` is unknown, the official grid places no seed (an image
        side shorter than the grid step), or (``"exact"``) ``n_segments``
        has no factorisation fitting the image.
    """
    height = _check_int("height", height, 1)
    width = _check_int("width", width, 1)
    n_segments = _check_int("n_segments", n_segments, 1)
    seeding = _check_seeding(seeding)
    if n_segments > height * width:
        raise ValueError(
            f"n_segments={n_segments} exceeds the number of pixels ({height} x {width} = {height * width})"
        )
    if seeding == "official":
        seeds = _official_seeds(height, width, n_segments)
        if len(seeds) == 0:
            # snic_mex would return no superpixel at all (every label -1,
            # patched to 0): an image narrower than the grid step.
            raise ValueError(
                f"seeding='official' places no seed on a {height} x {width} image with "
                f"n_segments={n_segments} (the grid step exceeds a side); use a larger n_segments "
                "or seeding='exact'"
            )
        return seeds
    rows, cols = _exact_shape(height, width, n_segments)
    # Integer arithmetic for floor((i + 0.5) * H / rows): no float rounding.
    r = (2 * np.arange(rows, dtype=np.int64) + 1) * height // (2 * rows)
    c = (2 * np.arange(cols, dtype=np.int64) + 1) * width // (2 * cols)
    return np.stack(np.meshgrid(r, c, indexing="ij"), axis=-1).reshape(-1, 2)


def snic_lab(lab: np.ndarray, seeds: np.ndarray, *, compactness: float = 20.0) -> np.ndarray:
    """SNIC labels from CIELAB image(s) and an explicit seed grid.

    Parameters
    ----------
    lab : (H, W, 3) or (B, H, W, 3) float ndarray
        CIELAB image or batch of same-size images (e.g. from
        :func:`sptpt.color.rgb_to_lab`); converted to C-contiguous float64.
    seeds : (s, 2) int ndarray
        Distinct ``(row, col)`` seed positions inside the image, e.g. from
        :func:`seed_grid`. Seed ``k`` grows label ``k``.
    compactness : float, keyword-only
        ``M >= 0``. The distance of pixel ``q`` to superpixel ``k`` is
        ``||c_q - mu_c(k)||^2 + (M^2 s / N) ||xy_q - mu_xy(k)||^2`` against
        ``k``'s running centroid (official SNIC code), with ``s``
        the seed count and ``N = H W``. 20 is the paper's and the official
        demo's value.

    Returns
    -------
    labels : (H, W) or (B, H, W) int32 ndarray
        Labels in ``[0, s)``; every label is present and 4-connected.

    Raises
    ------
    TypeError, ValueError
        If an argument has the wrong type, shape or range; the message names
        the argument.
    """
    lab = np.asarray(lab)
    if lab.dtype.kind not in "fiu" or lab.ndim not in (3, 4) or lab.shape[-1] != 3:
        raise ValueError(f"lab must be a real (H, W, 3) or (B, H, W, 3) array, got {lab.dtype} {lab.shape}")
    if lab.shape[-3] < 1 or lab.shape[-2] < 1:
        raise ValueError(f"lab must have at least one pixel, got shape {lab.shape}")
    _check_size(lab.shape[-3], lab.shape[-2], "lab")
    if not np.all(np.isfinite(lab)):
        raise ValueError("lab contains NaN or infinite values")
    seeds = np.asarray(seeds)
    if seeds.dtype.kind not in "iu" or seeds.ndim != 2 or seeds.shape[1] != 2 or seeds.shape[0] < 1:
        raise ValueError(f"seeds must be an integer (s, 2) array with s >= 1, got {seeds.dtype} {seeds.shape}")
    height, width = lab.shape[-3], lab.shape[-2]
    if seeds.min() < 0 or seeds[:, 0].max() >= height or seeds[:, 1].max() >= width:
        raise ValueError(f"seeds must lie inside the {height} x {width} image (0-based row, col)")
    if np.unique(seeds[:, 0] * width + seeds[:, 1]).size != seeds.shape[0]:
        raise ValueError("seeds must be distinct: two seeds on one pixel leave one label empty")
    compactness = _check_compactness(compactness)
    labels = _grow(lab.reshape((-1, height, width, 3)), seeds, compactness)
    return labels[0] if lab.ndim == 3 else labels


def _spatial_weight(compactness: float, n_seeds: int, height: int, width: int) -> float:
    # Same operation order as the official invwt = (M*M*numk)/double(sz).
    return (compactness * compactness * n_seeds) / (height * width)


def _grow(lab: np.ndarray, seeds: np.ndarray, compactness: float) -> np.ndarray:
    """Validated (B, H, W, 3) Lab batch -> (B, H, W) int32 labels."""
    n_images, height, width = lab.shape[:3]
    if n_images == 0:
        return np.empty((0, height, width), dtype=np.int32)
    return snic_batch(
        np.ascontiguousarray(lab, dtype=np.float64),
        np.ascontiguousarray(seeds, dtype=np.int64),
        _spatial_weight(compactness, len(seeds), height, width),
        numba.get_num_threads(),
    )


def _grow_rgb(images: np.ndarray, seeds: np.ndarray, compactness: float) -> np.ndarray:
    """Validated (B, H, W, 3) uint8 batch -> (B, H, W) int32 labels, Lab converted inside the kernel.

    The same labels as ``_grow(rgb_to_lab_templates(images), ...)`` bit for bit
    (the kernel converts with the same per-pixel code), without the float64
    Lab batch in memory and with about half of the ``cbrt`` calls.
    """
    n_images, height, width = images.shape[:3]
    if n_images == 0:
        return np.empty((0, height, width), dtype=np.int32)
    return snic_batch_rgb(
        np.ascontiguousarray(images),
        np.ascontiguousarray(seeds, dtype=np.int64),
        _spatial_weight(compactness, len(seeds), height, width),
        numba.get_num_threads(),
        SRGB_TO_LINEAR,
        RGB_TO_XYZ,
        WHITE,
    )


def snic(
    images: np.ndarray,
    *,
    n_segments: int = 30,
    compactness: float = 20.0,
    seeding: str = "official",
) -> np.ndarray:
    """SNIC superpixels of uint8 RGB image(s).

    Converts to CIELAB with the official SNIC constants (each image just
    before it grows, through a memo of converted colours), places the seeds
    with :func:`seed_grid` and grows all images in parallel (contiguous
    ranges on threads; thread count from ``numba.set_num_threads``).

    Parameters
    ----------
    images : (H, W, 3) or (B, H, W, 3) uint8 ndarray
        RGB image or batch of same-size images (e.g. 32 x 32 templates).
        Grayscale input is not accepted: replicate it to three channels.
    n_segments : int, keyword-only
        Requested superpixels ``K`` (paper: 30). The produced count ``s`` is
        the seed count of ``seeding``; see :func:`seed_grid`.
    compactness : float, keyword-only
        SNIC compactness ``M >= 0`` (paper: 20); see :func:`snic_lab`.
    seeding : {"official", "exact"}, keyword-only
        Seed layout; see :func:`seed_grid`. ``"official"`` gives 25
        superpixels on 32 x 32 with ``K = 30``, ``"exact"`` gives 30.

    Returns
    -------
    labels : (H, W) or (B, H, W) int32 ndarray
        Label ``k`` in ``[0, s)`` is the superpixel grown from seed ``k`` of
        ``seed_grid(H, W, n_segments, seeding=seeding)``, the same grid place
        in every image. Every label is present and 4-connected.

    Raises
    ------
    TypeError
        If ``images`` is not uint8, or ``n_segments`` / ``compactness`` has
        the wrong type.
    ValueError
        If ``images`` has the wrong shape, or an argument is out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from sptpt.superpixels import snic
    >>> snic(np.zeros((32, 32, 3), np.uint8)).max() + 1
    25
    """
    if not isinstance(images, np.ndarray):
        raise TypeError(f"images must be a numpy uint8 array, got {type(images).__name__}")
    if images.dtype != np.uint8:
        raise TypeError(
            f"images must be uint8 RGB (as snic_mex reads bytes), got dtype {images.dtype}; "
            "convert with np.clip(x, 0, 255).astype(np.uint8)"
        )
    if images.ndim not in (3, 4) or images.shape[-1] != 3:
        raise ValueError(
            f"images must have shape (H, W, 3) or (B, H, W, 3), got {images.shape}; "
            "replicate grayscale images to three channels"
        )
    height, width = images.shape[-3], images.shape[-2]
    if height < 1 or width < 1:
        raise ValueError(f"images must have at least one pixel, got shape {images.shape}")
    _check_size(height, width, "images")
    seeds = seed_grid(height, width, n_segments, seeding=seeding)
    compactness = _check_compactness(compactness)
    # Lab of uint8 input is always finite and seed_grid's seeds are valid:
    # skip snic_lab's checks.
    labels = _grow_rgb(images.reshape((-1, height, width, 3)), seeds, compactness)
    return labels[0] if images.ndim == 3 else labels

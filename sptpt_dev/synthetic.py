"""Synthetic video with exact ground truth: a textured object on a textured background.

Used by the sample clip in ``samples/``, by the tests and by benchmarks that
need a sequence whose every box is known. The object translates along a
smooth path, changes scale, and is partly covered by an occluder for a
stretch of frames, which is what real clips do to a tracker. On request a
look-alike (the object's colours in another pattern) crosses in front of it,
which is what makes a tracker follow the wrong thing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SyntheticClip", "changing_object", "make_clip"]


@dataclass(frozen=True)
class SyntheticClip:
    """Frames and their ground truth.

    Attributes
    ----------
    frames : (F, H, W, 3) uint8 ndarray
    boxes_xywh : (F, 4) float64 ndarray
        0-based ground-truth boxes of the object.
    occluded : (F,) bool ndarray
        Frames in which the occluder covers part of the object.
    lookalike_xywh : (F, 4) float64 ndarray or None
        0-based boxes of the look-alike (partly or wholly outside the frame
        where it has not entered or has left), or None for a clip without one.
    """

    frames: np.ndarray
    boxes_xywh: np.ndarray
    occluded: np.ndarray
    lookalike_xywh: np.ndarray | None = None


#: The look-alike's speed, as a multiple of the object's speed at the frame where they meet. Slower than the
#: object, so that it covers the object for many frames: on the sample's path (``samples/make_sample.py``) the
#: ``robust`` tracker followed it away at 0.8 and 1.0, and came back to the object at 1.3, 2 and 3, where the
#: two part within a few frames. Our choice, measured, not a model of anything.
_LOOKALIKE_SPEED = 0.8
#: The angle from the object's direction of motion to the look-alike's, counter-clockwise in image coordinates
#: (x right, y down): the two cross at right angles.
_LOOKALIKE_ANGLE_DEG = 90.0


def changing_object(deformation: float, frames: int = 60, seed: int = 5) -> tuple[list[np.ndarray], np.ndarray]:
    """A textured grey object on a textured background, moving right 1 px a frame, that re-draws ``deformation`` of
    its texture every frame (0: rigid; 0.8: an athlete or an animal, whose look changes all the time): RGB uint8
    frames and their true boxes ``(frames, 4)`` xywh."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(32, 32))
    background = _gaussian_blur(rng.normal(size=(120, 200, 1)), 3.0)[..., 0] * 60 + 128
    video, boxes = [], []
    for k in range(frames):
        look = (1 - deformation) * base + deformation * rng.normal(size=(32, 32))
        image = background.copy()
        image[40:72, 40 + k:72 + k] = 128 + 40 * look / look.std()
        video.append(np.repeat(np.clip(image, 0, 255).astype(np.uint8)[..., None], 3, axis=2))
        boxes.append([40.0 + k, 40.0, 32.0, 32.0])
    return video, np.array(boxes)


def _paste(image: np.ndarray, pattern: np.ndarray, box_xywh: tuple[float, float, float, float]) -> np.ndarray:
    """``pattern`` scaled into ``box_xywh`` over ``image`` with sub-pixel placement (bilinear, like an affine warp).

    Frame pixel ``(x, y)`` samples the pattern at ``((x - x0) * pw / w, (y - y0) * ph / h)``, pixel indices as
    OpenCV's ``warpAffine`` maps them; outside the pattern it samples zero, and a mask sampled the same way
    blends the pattern's edge into the frame. Computed with element-wise float64 NumPy operations in a fixed
    order, so every NumPy and OpenCV version gives the same clip (``cv2.warpAffine`` did not: OpenCV 4 rounds
    the sub-pixel position to 1/32 pixel, OpenCV 5 does not, and ~3% of the pasted pixels differed by up to 6
    grey levels).
    """
    x0, y0, w, h = (float(v) for v in box_xywh)
    height, width = image.shape[:2]
    rows, cols = pattern.shape[:2]
    # The pattern with a channel of ones (the mask) and a border of zeros, which every position outside reads.
    padded = np.zeros((rows + 2, cols + 2, pattern.shape[2] + 1))
    padded[1:-1, 1:-1, :-1] = pattern
    padded[1:-1, 1:-1, -1] = 1.0
    sy = (np.arange(height) - y0) * (rows / h)
    sx = (np.arange(width) - x0) * (cols / w)
    iy, ix = np.floor(sy).astype(np.int64), np.floor(sx).astype(np.int64)
    out = np.array(image, np.float32)
    # Only frame pixels with a pattern pixel among their four neighbours change (the mask is 0 elsewhere).
    ys, xs = np.flatnonzero((iy >= -1) & (iy < rows)), np.flatnonzero((ix >= -1) & (ix < cols))
    if ys.size == 0 or xs.size == 0:
        return out
    ys, xs = slice(ys[0], ys[-1] + 1), slice(xs[0], xs[-1] + 1)
    fy, fx = (sy[ys] - iy[ys])[:, None, None], (sx[xs] - ix[xs])[None, :, None]
    # Corner indices into ``padded``, whose border row and column (index 0 and the last) hold the zeros outside.
    top, left = iy[ys] + 1, ix[xs] + 1
    upper = padded[top][:, left] * (1.0 - fx) + padded[top][:, left + 1] * fx
    lower = padded[top + 1][:, left] * (1.0 - fx) + padded[top + 1][:, left + 1] * fx
    sampled = upper * (1.0 - fy) + lower * fy
    warped, mask = sampled[..., :-1], sampled[..., -1:]
    out[ys, xs] = image[ys, xs] * (1.0 - mask) + warped * mask
    return out


def _resize_cubic(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """``(H, W, C)`` float64 ``image`` resized to ``(height, width)`` by bicubic interpolation, with OpenCV's
    ``INTER_CUBIC`` conventions (Keys' kernel with a = -0.75, pixel centres aligned, edge pixels repeated)."""
    for axis, size in ((0, height), (1, width)):
        n = image.shape[axis]
        source = (np.arange(size) + 0.5) * (n / size) - 0.5
        first = np.floor(source)
        t = source - first
        a = -0.75
        weights = [((a * (t + 1) - 5 * a) * (t + 1) + 8 * a) * (t + 1) - 4 * a,
                   ((a + 2) * t - (a + 3)) * t * t + 1,
                   ((a + 2) * (1 - t) - (a + 3)) * (1 - t) * (1 - t) + 1]
        weights.append(1.0 - weights[0] - weights[1] - weights[2])
        shape = [1] * image.ndim
        shape[axis] = size
        out = np.zeros(image.shape[:axis] + (size,) + image.shape[axis + 1:])
        for k, weight in enumerate(weights):
            index = np.clip(first.astype(np.int64) + k - 1, 0, n - 1)
            out += np.take(image, index, axis=axis) * weight.reshape(shape)
        image = out
    return image


def _gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """``(H, W, C)`` float64 ``image`` blurred by a Gaussian of ``sigma`` pixels, with OpenCV's ``GaussianBlur``
    conventions for float images (a kernel of ``round(8 sigma + 1) | 1`` taps, mirrored border without repeating
    the edge pixel). The taps come from ``math.exp``, not from NumPy, whose SIMD exp differs between versions."""
    radius = (int(math.floor(sigma * 8 + 1 + 0.5)) | 1) // 2
    taps = [math.exp(-(k * k) / (2.0 * sigma * sigma)) for k in range(-radius, radius + 1)]
    total = sum(taps)
    for axis in (0, 1):
        n = image.shape[axis]
        pad = [(0, 0)] * image.ndim
        pad[axis] = (radius, radius)
        padded = np.pad(image, pad, mode="reflect")
        out = np.zeros(image.shape)
        for k, tap in enumerate(taps):
            out += np.take(padded, np.arange(k, k + n), axis=axis) * (tap / total)
        image = out
    return image


def _texture(rng: np.random.Generator, height: int, width: int, cell: int, palette: np.ndarray) -> np.ndarray:
    """Smooth multi-colour noise: random palette indices upsampled and blurred, ``(height, width, 3)`` float32."""
    coarse = rng.integers(0, len(palette), size=(height // cell + 2, width // cell + 2))
    image = np.asarray(palette, np.float64)[coarse]
    image = _gaussian_blur(_resize_cubic(image, height + 2 * cell, width + 2 * cell), cell / 3)
    return np.clip(image[cell : cell + height, cell : cell + width], 0, 255).astype(np.float32)


def _sin(values: np.ndarray) -> np.ndarray:
    """``sin`` of every value from ``math.sin``: NumPy's SIMD sin differs in the last bit between versions."""
    return np.array([math.sin(v) for v in np.ravel(values)]).reshape(np.shape(values))


def make_clip(
    n_frames: int = 60,
    *,
    size: tuple[int, int] = (320, 240),
    object_size: tuple[int, int] = (48, 40),
    seed: int = 0,
    occlusion: tuple[float, float] | None = (0.45, 0.6),
    noise: float = 3.0,
    lookalike: float | None = None,
) -> SyntheticClip:
    """Render a synthetic clip.

    Parameters
    ----------
    n_frames : int
    size : (width, height)
    object_size : (width, height) of the object at scale 1.
    seed : int
        The same seed gives the same clip, with every NumPy version.
    occlusion : (start, stop) or None
        Fractions of the clip during which an occluding bar covers about a
        third of the object; None for no occluder.
    noise : float
        Standard deviation of per-frame sensor noise, in grey levels.
    lookalike : float or None
        Fraction of the clip at which a look-alike passes in front of the
        object and covers it exactly: an object of the same size and colours
        in another pattern, moving in a straight line across the object's
        path (at right angles to the object's motion at that frame, at 0.8
        times its speed), visible wherever that line is in the frame. None
        (the default) for no look-alike; the clip is then the same, bit for
        bit, as without this argument.

    Returns
    -------
    SyntheticClip
    """
    if lookalike is not None and not 0.0 <= lookalike <= 1.0:
        raise ValueError(f"lookalike must be a fraction of the clip in [0, 1] or None, got {lookalike!r}")
    rng = np.random.default_rng(seed)
    width, height = size
    background_palette = np.array([[70, 90, 60], [120, 110, 80], [90, 100, 120], [60, 70, 50], [140, 130, 110]],
                                  np.float32)
    object_palette = np.array([[220, 40, 40], [250, 200, 30], [30, 30, 200], [240, 240, 240], [20, 120, 20]],
                              np.float32)
    background = _texture(rng, height, width, 16, background_palette)
    obj_w, obj_h = object_size
    pattern = _texture(rng, obj_h * 2, obj_w * 2, 10, object_palette)
    t = np.arange(n_frames) / max(n_frames - 1, 1)
    # A smooth loop across the frame with a scale swell in the middle.
    margin_x, margin_y = obj_w * 1.5, obj_h * 1.5
    cx = width / 2 + (width / 2 - margin_x) * _sin(2 * np.pi * t * 0.9)
    cy = height / 2 + (height / 2 - margin_y) * _sin(2 * np.pi * t * 0.6 + 0.5)
    scale = 1.0 + 0.3 * _sin(np.pi * t)
    frames = np.empty((n_frames, height, width, 3), np.uint8)
    boxes = np.empty((n_frames, 4))
    if occlusion is None:
        occluded = np.zeros(n_frames, bool)
    else:
        occluded = (t >= occlusion[0]) & (t < occlusion[1])
    lookalike_boxes = None
    if lookalike is not None:
        # Its own generator, so that the object, the background and the noise are those of the clip without it.
        lookalike_pattern = _texture(np.random.default_rng((seed, 1)), obj_h * 2, obj_w * 2, 10, object_palette)
        meet = int(round(lookalike * (n_frames - 1)))
        angle = math.radians(_LOOKALIKE_ANGLE_DEG)
        vx, vy = np.gradient(cx)[meet], np.gradient(cy)[meet]  # the object's velocity there, pixels per frame
        lx = cx[meet] + _LOOKALIKE_SPEED * (math.cos(angle) * vx - math.sin(angle) * vy) * (np.arange(n_frames) - meet)
        ly = cy[meet] + _LOOKALIKE_SPEED * (math.sin(angle) * vx + math.cos(angle) * vy) * (np.arange(n_frames) - meet)
        lookalike_boxes = np.empty((n_frames, 4))
    for k in range(n_frames):
        w, h = obj_w * scale[k], obj_h * scale[k]
        x0, y0 = cx[k] - w / 2, cy[k] - h / 2
        image = _paste(background, pattern, (x0, y0, w, h))
        if lookalike_boxes is not None:
            lookalike_boxes[k] = (lx[k] - w / 2, ly[k] - h / 2, w, h)
            image = _paste(image, lookalike_pattern, tuple(lookalike_boxes[k]))
        if occluded[k]:
            bar_x = int(round(x0 + w * 0.6))
            image[:, bar_x : bar_x + int(w / 3)] = (150, 150, 150)
        image += rng.normal(0.0, noise, image.shape).astype(np.float32)
        frames[k] = np.clip(np.rint(image), 0, 255).astype(np.uint8)
        boxes[k] = (x0, y0, w, h)
    return SyntheticClip(frames, boxes, occluded, lookalike_boxes)

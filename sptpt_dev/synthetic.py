"""Synthetic video with exact ground truth: a textured object on a textured background.

Used by the sample clip in ``samples/``, by the tests and by benchmarks that
need a sequence whose every box is known. The object translates along a
smooth path, changes scale, and is partly covered by an occluder for a
stretch of frames, which is what real clips do to a tracker. On request a
look-alike (the object's colours in another pattern) crosses in front of it,
which is what makes a tracker follow the wrong thing.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["SyntheticClip", "make_clip"]


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


def _paste(image: np.ndarray, pattern: np.ndarray, box_xywh: tuple[float, float, float, float]) -> np.ndarray:
    """``pattern`` scaled into ``box_xywh`` over ``image`` with sub-pixel placement (an affine warp)."""
    x0, y0, w, h = box_xywh
    height, width = image.shape[:2]
    m = np.array([[w / pattern.shape[1], 0, x0], [0, h / pattern.shape[0], y0]], np.float32)
    warped = cv2.warpAffine(pattern, m, (width, height), flags=cv2.INTER_LINEAR)
    mask = cv2.warpAffine(np.ones(pattern.shape[:2], np.float32), m, (width, height), flags=cv2.INTER_LINEAR)
    return image * (1 - mask[..., None]) + warped * mask[..., None]


def _texture(rng: np.random.Generator, height: int, width: int, cell: int, palette: np.ndarray) -> np.ndarray:
    """Smooth multi-colour noise: random palette indices upsampled and blurred."""
    coarse = rng.integers(0, len(palette), size=(height // cell + 2, width // cell + 2))
    image = palette[coarse].astype(np.float32)
    image = cv2.resize(image, (width + 2 * cell, height + 2 * cell), interpolation=cv2.INTER_CUBIC)
    image = cv2.GaussianBlur(image, (0, 0), cell / 3)
    return np.clip(image[cell : cell + height, cell : cell + width], 0, 255)


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
        The same seed gives the same clip.
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
    background_palette = np.array([[70, 90, 60], [120, 110, 80], [90, 100, 120], [60, 70, 50], [140, 130, 110]], np.float32)
    object_palette = np.array([[220, 40, 40], [250, 200, 30], [30, 30, 200], [240, 240, 240], [20, 120, 20]], np.float32)
    background = _texture(rng, height, width, 16, background_palette)
    obj_w, obj_h = object_size
    pattern = _texture(rng, obj_h * 2, obj_w * 2, 10, object_palette)
    t = np.linspace(0.0, 1.0, n_frames)
    # A smooth loop across the frame with a scale swell in the middle.
    margin_x, margin_y = obj_w * 1.5, obj_h * 1.5
    cx = width / 2 + (width / 2 - margin_x) * np.sin(2 * np.pi * t * 0.9)
    cy = height / 2 + (height / 2 - margin_y) * np.sin(2 * np.pi * t * 0.6 + 0.5)
    scale = 1.0 + 0.3 * np.sin(np.pi * t)
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
        angle = np.deg2rad(_LOOKALIKE_ANGLE_DEG)
        vx, vy = np.gradient(cx)[meet], np.gradient(cy)[meet]  # the object's velocity there, pixels per frame
        lx = cx[meet] + _LOOKALIKE_SPEED * (np.cos(angle) * vx - np.sin(angle) * vy) * (np.arange(n_frames) - meet)
        ly = cy[meet] + _LOOKALIKE_SPEED * (np.sin(angle) * vx + np.cos(angle) * vy) * (np.arange(n_frames) - meet)
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

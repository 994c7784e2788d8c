"""Synthetic clips for the tracker's tests, with exact ground truth: a textured object that grows, moves, jumps, or
vanishes and comes back over a textured background; and the results of tracking one."""

from __future__ import annotations

import cv2
import numpy as np

from sptpt.tracker import Tracker
from sptpt_dev.synthetic import _texture

# The frames a lost object stays covered or away (reappearing_clip, and test_robust.py's other clips).
GAP = 10


def background_and_object(rng: np.random.Generator, width: int, height: int, cell: int):
    """A 320x240 textured background and a ``width x height`` textured object, drawn from ``rng`` in that order."""
    background = _texture(rng, 240, 320, 16, np.array([[70, 90, 60], [120, 110, 80], [90, 100, 120]], np.float32))
    pattern = _texture(rng, height, width, cell,
                       np.array([[220, 40, 40], [250, 200, 30], [30, 30, 200], [240, 240, 240]], np.float32))
    return background, pattern


def paste(background: np.ndarray, pattern: np.ndarray, scale: float, x: float, y: float) -> np.ndarray:
    """``pattern`` scaled by ``scale`` with its top-left corner at ``(x, y)`` over ``background`` (float image)."""
    m = np.array([[scale, 0, x], [0, scale, y]], np.float32)
    size = (background.shape[1], background.shape[0])
    warped = cv2.warpAffine(pattern, m, size, flags=cv2.INTER_LINEAR)
    mask = cv2.warpAffine(np.ones(pattern.shape[:2], np.float32), m, size, flags=cv2.INTER_LINEAR)[..., None]
    return background * (1 - mask) + warped * mask


def growing_clip(n_frames: int = 50, growth: float = 1.6):
    """The object's side grows smoothly by ``growth`` while its centre moves 1 px a frame."""
    rng = np.random.default_rng(7)
    background, pattern = background_and_object(rng, 44, 36, 8)
    frames, boxes = [], []
    for k in range(n_frames):
        s = growth ** (k / (n_frames - 1))
        w, h = 44 * s, 36 * s
        x, y = 130 + k - w / 2, 120 - h / 2
        image = paste(background, pattern, s, x, y) + rng.normal(0, 3.0, background.shape)
        frames.append(np.clip(np.rint(image), 0, 255).astype(np.uint8))
        boxes.append([x, y, w, h])
    return np.array(frames), np.array(boxes)


def moving_clip(n_frames: int = 40):
    """The object moves 2 px right and 1 px down a frame over a textured background, with sensor noise."""
    rng = np.random.default_rng(11)
    background, pattern = background_and_object(rng, 44, 36, 8)
    frames, boxes = [], []
    for k in range(n_frames):
        x, y = 100 + 2 * k, 90 + k
        image = paste(background, pattern, 1.0, x, y) + rng.normal(0, 3.0, background.shape)
        frames.append(np.clip(np.rint(image), 0, 255).astype(np.uint8))
        boxes.append([x, y, 44.0, 36.0])
    return np.array(frames), np.array(boxes)


def render_clip(boxes: np.ndarray, visible: np.ndarray, seed: int = 7) -> np.ndarray:
    """A 44x36 textured object at ``boxes`` (0-based xywh) on a textured 320x240 background, where visible."""
    rng = np.random.default_rng(seed)
    width, height = 320, 240
    obj_w, obj_h = int(boxes[0, 2]), int(boxes[0, 3])
    background = _texture(rng, height, width, 16, np.array([[70, 90, 60], [120, 110, 80], [90, 100, 120]], np.float32))
    pattern = _texture(rng, obj_h, obj_w, 8, np.array([[220, 40, 40], [250, 200, 30], [30, 30, 200], [240, 240, 240]],
                                                      np.float32))
    frames = np.empty((len(boxes), height, width, 3), np.uint8)
    for f in range(len(boxes)):
        m = np.array([[1, 0, boxes[f, 0]], [0, 1, boxes[f, 1]]], np.float32)
        warped = cv2.warpAffine(pattern, m, (width, height), flags=cv2.INTER_LINEAR)
        mask = cv2.warpAffine(np.ones(pattern.shape[:2], np.float32), m, (width, height), flags=cv2.INTER_LINEAR)
        mask *= visible[f]
        image = background * (1 - mask[..., None]) + warped * mask[..., None] + rng.normal(0, 3.0, background.shape)
        frames[f] = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return frames


def boxes_around(cx: np.ndarray, cy: np.ndarray, w: int = 44, h: int = 36) -> np.ndarray:
    """``(N, 4)`` 0-based xywh boxes of a ``w x h`` object centred at ``(cx[k], cy[k])``."""
    return np.stack([cx - w / 2, cy - h / 2, np.full(cx.shape, w), np.full(cx.shape, h)], axis=1)


def reappearing_clip(n_frames: int = 55, start: int = 20):
    """The object vanishes for GAP frames and reappears 2 object sizes away, beyond a fixed 10 px search."""
    k = np.arange(n_frames)
    cx = 90.0 + 1.5 * k + 90.0 * (k >= start + GAP)
    boxes = boxes_around(cx, 120.0 + 8.0 * np.sin(2 * np.pi * k / n_frames))
    visible = ~((k >= start) & (k < start + GAP))
    return render_clip(boxes, visible.astype(np.float32)), boxes, start + GAP


def jumping_clip(n_frames: int = 40, at: int = 20):
    """The object, always visible, jumps 120 px on frame ``at`` (a cut, a dropped stretch of video): far beyond a
    run's motion."""
    k = np.arange(n_frames)
    boxes = boxes_around(70.0 + 1.5 * k + 120.0 * (k >= at), 120.0 + 8.0 * np.sin(2 * np.pi * k / n_frames))
    return render_clip(boxes, np.ones(n_frames, np.float32)), boxes, at


def track_results(params, frames: np.ndarray, first_box: np.ndarray, seed: int = 0) -> list:
    """Every frame's result after the first of a tracker with ``params`` and ``seed`` started at ``first_box``."""
    tracker = Tracker(params, seed=seed)
    tracker.init(frames[0], first_box)
    return [tracker.update(frame) for frame in frames[1:]]

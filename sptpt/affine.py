"""The 6-parameter affine state of IVT and the warping of candidates into templates.

State order is IVT's ``(cx, cy, sc, th, ar, sk)``: centre (1-based pixels),
scale (box width / template width), rotation (rad), aspect ratio
(height / width) and skew (rad). The state is kept in the 1-based MATLAB
convention of the reference code so that its half-pixel conventions carry
over unchanged; boxes crossing this module's boundary are 0-based ``xywh``.
See ``docs/design/tracker.md``, "Affine state and boxes".
"""

from __future__ import annotations

import numba
import numpy as np

from sptpt._kernels.warp import warp_affine_batch

__all__ = [
    "STATE_NAMES",
    "state_from_box_xywh",
    "box_xywh_from_states",
    "affine_matrices",
    "warp_candidates",
    "template_offsets",
    "template_labels_to_frame",
]

STATE_NAMES = ("cx", "cy", "scale", "rotation", "aspect", "skew")


def state_from_box_xywh(box_xywh: np.ndarray, template_size: int) -> np.ndarray:
    """Affine state of an axis-aligned box (TPT initialisation).

    Parameters
    ----------
    box_xywh : (4,) array_like
        0-based ``x, y, w, h``.
    template_size : int
        Template side in pixels (32).

    Returns
    -------
    state : (6,) float64 ndarray
        ``(cx, cy, sc, th, ar, sk)`` with a 1-based centre
        ``x1 + (w - 1) / 2``, as OTB computes a box's centre (``docs/design/tracker.md``,
        "Affine state and boxes").
    """
    x, y, w, h = (float(v) for v in np.asarray(box_xywh, dtype=np.float64).reshape(4))
    return np.array([x + 1.0 + (w - 1.0) / 2.0, y + 1.0 + (h - 1.0) / 2.0, w / template_size, 0.0, h / w, 0.0])


def box_xywh_from_states(states: np.ndarray, template_size: int) -> np.ndarray:
    """Axis-aligned boxes of affine states (TPT ``Affine2Rect``; rotation and skew ignored).

    Parameters
    ----------
    states : (N, 6) or (6,) ndarray

    Returns
    -------
    boxes : (N, 4) or (4,) float64 ndarray
        0-based ``xywh``.
    """
    states = np.asarray(states, dtype=np.float64)
    single = states.ndim == 1
    states = np.atleast_2d(states)
    w = template_size * states[:, 2]
    h = states[:, 4] * w
    x = states[:, 0] - (w - 1.0) / 2.0 - 1.0
    y = states[:, 1] - (h - 1.0) / 2.0 - 1.0
    boxes = np.stack([x, y, w, h], axis=1)
    return boxes[0] if single else boxes


def affine_matrices(states: np.ndarray) -> np.ndarray:
    """IVT ``affparam2mat``: states to ``(cx, cy, A11, A12, A21, A22)``.

    ``A = sc * Rot(th) * Rot(-sk) * diag(1, ar) * Rot(sk)``.

    Parameters
    ----------
    states : (N, 6) ndarray

    Returns
    -------
    q : (N, 6) float64 ndarray
    """
    states = np.atleast_2d(np.asarray(states, dtype=np.float64))
    cx, cy, sc, th, ar, sk = states.T
    cos_t, sin_t = np.cos(th), np.sin(th)
    cos_s, sin_s = np.cos(sk), np.sin(sk)
    # diag(1, ar) conjugated by the skew rotation, then rotated by th.
    m11 = cos_s * cos_s + ar * sin_s * sin_s
    m12 = (ar - 1.0) * cos_s * sin_s
    m22 = sin_s * sin_s + ar * cos_s * cos_s
    a11 = sc * (cos_t * m11 - sin_t * m12)
    a12 = sc * (cos_t * m12 - sin_t * m22)
    a21 = sc * (sin_t * m11 + cos_t * m12)
    a22 = sc * (sin_t * m12 + cos_t * m22)
    return np.stack([cx, cy, a11, a12, a21, a22], axis=1)


def template_offsets(template_size: int) -> np.ndarray:
    """Template pixel offsets from the centre: ``j - T/2`` for 1-based ``j`` (IVT ``warpimg``).

    For 32 this is ``-15 .. 16``, asymmetric by half a pixel as in the reference code.

    Returns
    -------
    offsets : (T,) float64 ndarray
    """
    return np.arange(1, template_size + 1, dtype=np.float64) - template_size / 2.0


def warp_candidates(frame: np.ndarray, states: np.ndarray, template_size: int) -> np.ndarray:
    """Warp every candidate state into a ``T x T`` RGB template (bilinear, 0 outside the frame).

    Parameters
    ----------
    frame : (H, W, 3) uint8 ndarray
    states : (N, 6) ndarray
        Affine states, 1-based centres.
    template_size : int

    Returns
    -------
    templates : (N, T, T, 3) uint8 ndarray
        Rounded and clipped to uint8, as SNIC reads bytes.
    """
    frame = np.ascontiguousarray(frame, dtype=np.uint8)
    q = affine_matrices(states)
    # The kernel samples 0-based pixel positions; the state is 1-based.
    q[:, 0] -= 1.0
    q[:, 1] -= 1.0
    return warp_affine_batch(frame, np.ascontiguousarray(q), template_offsets(template_size), numba.get_num_threads())


def template_labels_to_frame(
    labels: np.ndarray, state: np.ndarray, frame_shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Map a candidate's template label map back onto frame pixels (nearest template pixel).

    Parameters
    ----------
    labels : (T, T) int ndarray
        Superpixel labels of the candidate's template.
    state : (6,) ndarray
        The candidate's affine state.
    frame_shape : (H, W)

    Returns
    -------
    frame_labels : (h, w) int32 ndarray
        Labels over the frame window covering the candidate; -1 where a frame
        pixel maps outside the template.
    origin_xy : (2,) int64 ndarray
        0-based frame column and row of ``frame_labels[0, 0]``.
    """
    size = labels.shape[0]
    cx, cy, a11, a12, a21, a22 = affine_matrices(state)[0]
    cx, cy = cx - 1.0, cy - 1.0
    offsets = template_offsets(size)
    corners = np.array([[offsets[0], offsets[0]], [offsets[-1], offsets[0]], [offsets[0], offsets[-1]],
                        [offsets[-1], offsets[-1]]])
    xs = cx + a11 * corners[:, 0] + a12 * corners[:, 1]
    ys = cy + a21 * corners[:, 0] + a22 * corners[:, 1]
    height, width = frame_shape
    x0 = int(np.clip(np.floor(xs.min()), 0, width - 1))
    x1 = int(np.clip(np.ceil(xs.max()), 0, width - 1))
    y0 = int(np.clip(np.floor(ys.min()), 0, height - 1))
    y1 = int(np.clip(np.ceil(ys.max()), 0, height - 1))
    px, py = np.meshgrid(np.arange(x0, x1 + 1, dtype=np.float64), np.arange(y0, y1 + 1, dtype=np.float64))
    det = a11 * a22 - a12 * a21
    if abs(det) < 1e-12:
        return np.full(px.shape, -1, dtype=np.int32), np.array([x0, y0], dtype=np.int64)
    dx, dy = px - cx, py - cy
    # Invert the 2x2 linear part to get template offsets, then the nearest template pixel.
    tx = (a22 * dx - a12 * dy) / det
    ty = (-a21 * dx + a11 * dy) / det
    col = np.rint(tx - offsets[0]).astype(np.int64)
    row = np.rint(ty - offsets[0]).astype(np.int64)
    inside = (col >= 0) & (col < size) & (row >= 0) & (row < size)
    frame_labels = np.full(px.shape, -1, dtype=np.int32)
    frame_labels[inside] = labels[row[inside], col[inside]]
    return frame_labels, np.array([x0, y0], dtype=np.int64)

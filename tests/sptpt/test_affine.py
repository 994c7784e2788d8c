"""Affine state, box round trips and the warp kernel against a slow reference."""

from __future__ import annotations

import numpy as np
import pytest

from sptpt.affine import (
    affine_matrices,
    box_xywh_from_states,
    state_from_box_xywh,
    template_labels_to_frame,
    template_offsets,
    warp_candidates,
)


def rot(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def reference_warp(frame: np.ndarray, state: np.ndarray, size: int) -> np.ndarray:
    """Per-pixel bilinear sampling (MATLAB interp2 + warpimg), from the formulas of ``docs/design/tracker.md``,
    "Affine state and boxes"."""
    cx, cy, a11, a12, a21, a22 = affine_matrices(state[None])[0]
    offsets = np.arange(1, size + 1) - size / 2
    height, width = frame.shape[:2]
    out = np.zeros((size, size, 3), np.uint8)
    for r in range(size):
        for c in range(size):
            x, y = offsets[c], offsets[r]
            X = cx + a11 * x + a12 * y  # 1-based sample position
            Y = cy + a21 * x + a22 * y
            if not (1 <= X <= width and 1 <= Y <= height):
                continue  # interp2 gives NaN, warpimg sets 0
            x0, y0 = int(np.floor(X)), int(np.floor(Y))
            fx, fy = X - x0, Y - y0
            for ch in range(3):
                def px(yy, xx, ch=ch):
                    return float(frame[min(yy, height) - 1, min(xx, width) - 1, ch])
                v = (px(y0, x0) * (1 - fx) + px(y0, x0 + 1) * fx) * (1 - fy) + (
                    px(y0 + 1, x0) * (1 - fx) + px(y0 + 1, x0 + 1) * fx
                ) * fy
                out[r, c, ch] = np.uint8(np.clip(np.rint(v), 0, 255))
    return out


def test_affparam2mat_axis_aligned_is_diagonal():
    q = affine_matrices(np.array([[10.0, 20.0, 1.5, 0.0, 0.8, 0.0]]))[0]
    np.testing.assert_allclose(q, [10.0, 20.0, 1.5, 0.0, 0.0, 1.2], atol=1e-15)


def test_affparam2mat_general_case_matches_rotation_product():
    sc, th, ar, sk = 1.3, 0.4, 0.7, -0.25
    expected = sc * rot(th) @ rot(-sk) @ np.diag([1.0, ar]) @ rot(sk)
    q = affine_matrices(np.array([[0.0, 0.0, sc, th, ar, sk]]))[0]
    np.testing.assert_allclose(q[2:].reshape(2, 2), expected, atol=1e-14)


@pytest.mark.parametrize("box", [(0, 0, 32, 32), (10.5, 3.25, 64, 48), (100, 80, 17, 51)])
def test_box_state_round_trip(box):
    state = state_from_box_xywh(np.array(box), 32)
    np.testing.assert_allclose(box_xywh_from_states(state, 32), box, atol=1e-12)
    np.testing.assert_allclose(box_xywh_from_states(state[None], 32), [box], atol=1e-12)


def test_state_centre_uses_one_based_otb_convention():
    state = state_from_box_xywh(np.array([0.0, 0.0, 32.0, 32.0]), 32)
    # 1-based x1 = 1, centre = x1 + (w - 1) / 2 = 16.5
    assert state[0] == 16.5 and state[1] == 16.5


def test_template_offsets_are_asymmetric_like_ivt():
    offsets = template_offsets(32)
    assert offsets[0] == -15 and offsets[-1] == 16


def test_unit_scale_warp_samples_whole_pixels_with_ivts_half_pixel_offset():
    rng = np.random.default_rng(1)
    frame = rng.integers(0, 256, (60, 70, 3), dtype=np.uint8)
    # Offsets run -15..16 around the centre x1 + (w - 1)/2, so a box at a
    # half-pixel position samples whole pixels: x = 5.5 samples columns 6..37.
    state = state_from_box_xywh(np.array([5.5, 7.5, 32.0, 32.0]), 32)
    template = warp_candidates(frame, state[None], 32)[0]
    np.testing.assert_array_equal(template, frame[8:40, 6:38])


@pytest.mark.parametrize("seed", range(4))
def test_warp_kernel_matches_reference(seed):
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (50, 64, 3), dtype=np.uint8)
    states = np.column_stack(
        [
            rng.uniform(-10, 74, 6),  # centres partly outside the frame
            rng.uniform(-10, 60, 6),
            rng.uniform(0.3, 2.5, 6),
            rng.uniform(-0.5, 0.5, 6),
            rng.uniform(0.5, 2.0, 6),
            rng.uniform(-0.3, 0.3, 6),
        ]
    )
    size = 16
    fast = warp_candidates(frame, states, size)
    for i, state in enumerate(states):
        np.testing.assert_array_equal(fast[i], reference_warp(frame, state, size))


def test_pixels_outside_the_frame_are_zero():
    frame = np.full((40, 40, 3), 200, np.uint8)
    state = state_from_box_xywh(np.array([-16.0, 0.0, 32.0, 32.0]), 32)
    template = warp_candidates(frame, state[None], 32)[0]
    assert (template[:, :15] == 0).all()
    assert (template[:, 17:] == 200).all()


def test_the_kernel_writes_every_pixel_whatever_its_output_held():
    """The output is not zero-filled beforehand: pixels outside the frame must be written as 0."""
    from sptpt._kernels.warp import _warp_range
    from sptpt.affine import affine_matrices, template_offsets

    frame = np.full((40, 40, 3), 200, np.uint8)
    state = state_from_box_xywh(np.array([-16.0, 0.0, 32.0, 32.0]), 32)
    q = affine_matrices(state[None])
    q[:, :2] -= 1.0
    out = np.full((1, 32, 32, 3), 77, np.uint8)
    _warp_range(frame, np.ascontiguousarray(q), template_offsets(32), out, 0, 1)
    np.testing.assert_array_equal(out[0], warp_candidates(frame, state[None], 32)[0])
    assert not (out == 77).any()


def test_labels_map_back_to_the_box_area():
    labels = np.repeat(np.arange(32, dtype=np.int32)[None, :], 32, axis=0)  # label = template column
    state = state_from_box_xywh(np.array([10.0, 20.0, 64.0, 32.0]), 32)
    frame_labels, origin = template_labels_to_frame(labels, state, (100, 100))
    x0, y0 = origin
    inside = frame_labels >= 0
    rows, cols = np.nonzero(inside)
    # The labelled window is the box, within half a template pixel of scale.
    assert abs((x0 + cols.min()) - 10) <= 1 and abs((x0 + cols.max()) - 73) <= 1
    assert abs((y0 + rows.min()) - 20) <= 1 and abs((y0 + rows.max()) - 51) <= 1
    # Columns increase left to right: a frame pixel 2 px right is at most one template column on.
    row = frame_labels[rows[0]]
    assert (np.diff(row[row >= 0]) >= 0).all()

"""The synthetic clip generator: its look-alike crosses in front of the object and changes nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from sptpt.boxes import iou_xywh
from sptpt_dev.synthetic import make_clip

KW = dict(size=(160, 120), object_size=(24, 20), seed=7, occlusion=None)


@pytest.fixture(scope="module")
def plain():
    return make_clip(40, **KW)


@pytest.fixture(scope="module")
def crossed():
    return make_clip(40, **KW, lookalike=0.5)


def _inside(box_xywh, shape, margin):
    """(H, W) bool mask of the pixels at least ``margin`` inside the box."""
    x, y, w, h = box_xywh
    rows, cols = np.mgrid[: shape[0], : shape[1]]
    return (cols >= x + margin) & (cols < x + w - margin) & (rows >= y + margin) & (rows < y + h - margin)


def test_no_lookalike_by_default(plain):
    assert plain.lookalike_xywh is None
    assert not plain.occluded.any()  # occlusion=None: no occluder


def test_lookalike_changes_only_the_pixels_it_covers(plain, crossed):
    np.testing.assert_array_equal(crossed.boxes_xywh, plain.boxes_xywh)
    assert crossed.lookalike_xywh.shape == (40, 4)
    for k in range(40):
        # Bilinear placement blurs its edge by a pixel; beyond that the frame is the plain clip's, noise included.
        away = ~_inside(crossed.lookalike_xywh[k], plain.frames.shape[1:3], -2)
        np.testing.assert_array_equal(crossed.frames[k][away], plain.frames[k][away])


def test_lookalike_covers_the_object_where_they_meet(plain, crossed):
    meet = round(0.5 * 39)
    overlap = iou_xywh(crossed.lookalike_xywh, crossed.boxes_xywh)
    assert overlap[meet] == pytest.approx(1.0)
    assert overlap.argmax() == meet
    assert overlap[0] < 0.1 and overlap[-1] < 0.1  # it crosses: apart at both ends
    # In front: inside the object's box the frame shows another pattern, not the object.
    inside = _inside(crossed.boxes_xywh[meet], plain.frames.shape[1:3], 2)
    diff = np.abs(crossed.frames[meet].astype(int) - plain.frames[meet].astype(int))[inside]
    assert diff.mean() > 20


def test_lookalike_crosses_at_right_angles_and_slower():
    clip = make_clip(40, **KW, lookalike=0.5)
    centre = clip.boxes_xywh[:, :2] + clip.boxes_xywh[:, 2:] / 2
    look = clip.lookalike_xywh[:, :2] + clip.lookalike_xywh[:, 2:] / 2
    meet = round(0.5 * 39)
    v_object = np.gradient(centre, axis=0)[meet]
    v_look = np.diff(look, axis=0)
    np.testing.assert_allclose(v_look, np.broadcast_to(v_look[0], v_look.shape))  # straight, constant speed
    assert np.dot(v_object, v_look[0]) == pytest.approx(0.0, abs=1e-9)
    assert np.linalg.norm(v_look[0]) == pytest.approx(0.8 * np.linalg.norm(v_object))


@pytest.mark.parametrize("value", [-0.1, 1.5])
def test_lookalike_outside_the_clip_is_refused(value):
    with pytest.raises(ValueError, match="lookalike must be a fraction"):
        make_clip(5, **KW, lookalike=value)

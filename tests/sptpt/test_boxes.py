"""sptpt.boxes: the one IoU, corner conversion and clipping of the tracker, the tool and the benchmarks, against
slow references."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sptpt.boxes import iou_xywh

coordinate = st.floats(-50, 50, allow_nan=False).map(lambda v: round(v * 4) / 4)
side = st.floats(-2, 40, allow_nan=False).map(lambda v: round(v * 4) / 4)  # some empty boxes (w or h <= 0)
box = st.tuples(coordinate, coordinate, side, side)


def reference_iou(a, b) -> float:
    """One pair, in plain Python: [x, x + w) x [y, y + h), an empty box (w or h <= 0) overlaps nothing."""
    if any(math.isnan(v) for v in (*a, *b)):
        return math.nan
    if min(a[2], a[3], b[2], b[3]) <= 0:
        return 0.0
    inter = (max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
             * max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])))
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


@settings(max_examples=200, deadline=None)
@given(pairs=st.lists(st.tuples(box, box), min_size=1, max_size=6))
def test_pairs_row_by_row_agree_with_the_reference(pairs):
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    got = iou_xywh(a, b)
    assert got.shape == (len(pairs),)
    np.testing.assert_allclose(got, [reference_iou(*p) for p in pairs], rtol=0, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(many=st.lists(box, min_size=1, max_size=6), one=box)
def test_many_against_one_is_each_pair(many, one):
    many = np.array(many)
    np.testing.assert_array_equal(iou_xywh(many, np.array(one)), iou_xywh(many, np.tile(one, (len(many), 1))))
    assert iou_xywh(many[0], np.array(one)).shape == ()  # one pair: a scalar


def test_identical_boxes_exactly_one_nan_is_nan_empty_is_zero():
    boxes = np.array([[0.1, 0.2, 30.3, 17.7], [5.0, 5.0, 0.0, 10.0], [np.nan, 0.0, 10.0, 10.0]])
    got = iou_xywh(boxes, boxes)
    assert got[0] == 1.0 and got[1] == 0.0 and np.isnan(got[2])
    assert iou_xywh([0, 0, 10, 10], [5, 0, 10, 10]) == 1 / 3


def test_mean_box_averages_centres_and_sizes_as_ratios():
    from sptpt.boxes import mean_box

    one = np.array([3.0, 4.0, 10.0, 20.0])
    np.testing.assert_array_equal(mean_box([one]), one)
    # Centres (5, 10) and (25, 30) average to (15, 20); widths 4 and 16 to 8, heights 10 and 40 to 20.
    got = mean_box([[3.0, 5.0, 4.0, 10.0], [17.0, 10.0, 16.0, 40.0]])
    np.testing.assert_allclose(got, [15.0 - 4.0, 20.0 - 10.0, 8.0, 20.0])
    # Order does not matter, and the same box twice is itself (to rounding: sizes go through log and exp).
    boxes = np.array([[0.0, 0.0, 2.0, 3.0], [1.0, 2.0, 5.0, 1.0], [4.0, -1.0, 3.0, 3.0]])
    np.testing.assert_allclose(mean_box(boxes), mean_box(boxes[::-1]))
    np.testing.assert_allclose(mean_box([one, one]), one)


# --------------------------------------------------------------------------- corners and clipping

finite_box = st.tuples(coordinate, coordinate, st.floats(0.25, 40).map(lambda v: round(v * 4) / 4),
                       st.floats(0.25, 40).map(lambda v: round(v * 4) / 4))


def reference_clip(box, width, height):
    """One box's part inside the frame, in plain Python: None when nothing of it is."""
    x, y, w, h = box
    left, top, right, bottom = max(x, 0.0), max(y, 0.0), min(x + w, width), min(y + h, height)
    if right <= left or bottom <= top:
        return None
    return (left, top, right - left, bottom - top)


@settings(max_examples=200, deadline=None)
@given(boxes=st.lists(box, min_size=1, max_size=6))
def test_corners_round_trip_and_match_the_layout(boxes):
    from sptpt.boxes import xywh_to_xyxy, xyxy_to_xywh

    xywh = np.array(boxes, dtype=np.float64)
    xyxy = xywh_to_xyxy(xywh)
    assert xyxy.shape == xywh.shape
    np.testing.assert_array_equal(xyxy, [[x, y, x + w, y + h] for x, y, w, h in boxes])
    np.testing.assert_array_equal(xyxy_to_xywh(xyxy), xywh)  # quarter-pixel values: exact both ways
    np.testing.assert_array_equal(xywh_to_xyxy(xywh[0]), xyxy[0])  # one box: shape (4,)


@settings(max_examples=300, deadline=None)
@given(one=finite_box, width=st.integers(1, 40), height=st.integers(1, 40))
def test_clip_agrees_with_the_reference_and_the_outside_test(one, width, height):
    from sptpt.boxes import clip_xywh, lies_outside

    got = clip_xywh(one, width, height)
    assert got == reference_clip(one, width, height)
    assert (got is None) == lies_outside(one, width, height)
    if got is not None:
        assert all(type(v) is float for v in got)  # plain floats: exporters format and compare them


@pytest.mark.parametrize(
    "box, expected",
    [
        ((-5.0, 2.0, 10.0, 3.0), (0.0, 2.0, 5.0, 3.0)),  # cut on the left
        ((15.0, 15.0, 10.0, 10.0), (15.0, 15.0, 5.0, 5.0)),  # cut on the right and the bottom
        ((20.0, 0.0, 5.0, 5.0), None),  # touches the right edge only: nothing inside
        ((0.0, -5.0, 5.0, 5.0), None),  # touches the top edge only
        ((np.nan, 0.0, 5.0, 5.0), None),
        ((0.0, 0.0, np.inf, 5.0), None),
    ],
)
def test_clip_xywh_cases(box, expected):
    from sptpt.boxes import clip_xywh

    assert clip_xywh(box, 20, 20) == expected


def test_clip_xywh_rounds_the_corners_before_the_size_and_the_emptiness_test():
    from sptpt.boxes import clip_xywh

    # Corners 0.12345 and 2.12394 round to 0.123 and 2.124: the width is their difference, 2.001 (not 2.000).
    assert clip_xywh((0.12345, 1.0, 2.00049, 3.0), 20, 20, decimals=3) == (0.123, 1.0, 2.001, 3.0)
    assert clip_xywh((19.9996, 1.0, 5.0, 5.0), 20, 20, decimals=3) is None  # 0.0004 px inside: rounded away
    assert clip_xywh((19.9996, 1.0, 5.0, 5.0), 20, 20) is not None


def test_clip_xyxy_keeps_the_corners_of_a_box_wholly_outside():
    from sptpt.boxes import clip_xyxy

    assert clip_xyxy((25.0, 2.0, 30.0, 4.0), 20, 10) == (25.0, 2.0, 20.0, 4.0)  # empty: x1 <= x0
    assert clip_xyxy((-3.0, -1.0, 5.0, 12.0), 20, 10) == (0.0, 0.0, 5.0, 10.0)
    assert np.isnan(clip_xyxy((np.nan, 0.0, 1.0, 1.0), 20, 10)[0])

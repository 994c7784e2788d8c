"""The NanoTrack guide (annotator/nanotrack.py): the shipped weights, its boxes, and a copy brought back."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
from _tracker_clips import jumping_clip

from annotator.nanotrack import NanoTrackGuide, _bgr, guide_for, nanotrack_weights
from sptpt.boxes import iou_xywh
from sptpt.params import get_preset


def test_the_weights_ship_with_their_licence_and_notice():
    backbone, head = map(Path, nanotrack_weights())
    folder = backbone.parent
    assert backbone.stat().st_size == 1_056_849 and head.stat().st_size == 726_198
    assert "Apache License" in (folder / "LICENSE").read_text()
    notice = (folder / "NOTICE").read_text()
    assert "HonglinChu/SiamTrackers" in notice and "248663fd" in notice


def test_it_follows_an_object_and_says_nothing_on_stderr(capfd):
    frames, boxes, at = jumping_clip()
    guide = NanoTrackGuide()
    guide.init(frames[0], boxes[0])
    found = np.array([guide.update(frame)[0] for frame in frames[1:at]])
    assert iou_xywh(found, boxes[1:at]).mean() >= 0.7
    assert capfd.readouterr().err == ""  # OpenCV's DNN warnings about its targets are silenced


def test_a_copy_caught_up_on_the_same_frames_goes_on_to_the_bit():
    frames, boxes, _ = jumping_clip()
    guide = NanoTrackGuide()
    guide.init(frames[0], boxes[0])
    for frame in frames[1:9]:
        guide.update(frame)
    copy = pickle.loads(pickle.dumps(guide))
    assert copy.behind == 9
    with pytest.raises(RuntimeError, match="catch_up"):
        copy.update(frames[9])
    for frame in frames[:9]:
        copy.catch_up(frame)
    assert copy.behind == 0
    for frame in frames[9:]:
        (a, score_a), (b, score_b) = guide.update(frame), copy.update(frame)
        np.testing.assert_array_equal(a, b)
        assert score_a == score_b
    with pytest.raises(RuntimeError, match="not behind"):
        copy.catch_up(frames[0])


def test_the_guide_sees_the_frame_s_own_pixels_in_opencv_s_channel_order():
    rgb = np.random.default_rng(0).integers(0, 256, (37, 53, 3), dtype=np.uint8)
    for frame in (rgb, rgb[3:30, 5:41]):  # a whole frame and a view into one
        bgr = _bgr(frame)
        assert bgr.shape == frame.shape and bgr.flags.c_contiguous
        np.testing.assert_array_equal(bgr, frame[:, :, ::-1])
    np.testing.assert_array_equal(_bgr(rgb[:, :, 1]), np.repeat(rgb[:, :, 1, None], 3, axis=2))


def test_only_presets_that_use_a_guide_get_one():
    assert guide_for(get_preset("robust")) is None and guide_for(get_preset("paper")) is None
    assert isinstance(guide_for(get_preset("fused")), NanoTrackGuide)


def test_the_fused_preset_is_a_valid_configuration():
    from annotator.config import resolve_config

    assert resolve_config(preset="fused").tracker.uses_guide  # its check builds a tracker with a guide

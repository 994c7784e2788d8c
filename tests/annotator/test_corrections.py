"""Corrections files: the CSV and COCO forms, and their checks against a run (file:line in every error)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from annotator.corrections import Correction, read_corrections, resolve_corrections
from annotator.errors import EXIT_INPUT, EXIT_VALUE, ToolError
from annotator.exports import write_coco
from annotator.tracks import TrackResult, VideoInfo


def write(tmp_path: Path, text: str, name: str = "fix.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# --------------------------------------------------------------------------- CSV


def test_csv_rows_header_comments_and_absent(tmp_path):
    path = write(tmp_path, "# reviewer: ana\nframe,x,y,w,h,track_id\n\n12, 10.5,20,30,40,2\n30,,,,,1\n40,1,2,3,4,\n")
    got = read_corrections(path)
    assert got == [
        Correction(12, (10.5, 20.0, 30.0, 40.0), 2, f"{path}:4"),
        Correction(30, None, 1, f"{path}:5"),
        Correction(40, (1.0, 2.0, 3.0, 4.0), None, f"{path}:6"),
    ]
    assert got[1].absent and not got[0].absent


def test_csv_without_header_or_track_column(tmp_path):
    path = write(tmp_path, "0,1,2,3,4\n5,-3,-2,10,10\n")
    assert [(c.frame, c.box_xywh, c.track_id) for c in read_corrections(path)] == [
        (0, (1.0, 2.0, 3.0, 4.0), None), (5, (-3.0, -2.0, 10.0, 10.0), None)]


@pytest.mark.parametrize(
    "text, line, fragment",
    [
        ("frame,x,y,w,h\n3,1,2,3\n", 2, "expected 5 or 6 fields"),
        ("3,1,2,3,4,1,9\n", 1, "expected 5 or 6 fields"),
        ("frame,x,y,w,h\n3.5,1,2,3,4\n", 2, "column 'frame' must be an integer"),
        ("1,1,2,3,4\n-1,1,2,3,4\n", 2, "must be an integer >= 0"),
        ("7,1,,3,4\n", 1, "all four empty"),
        ("7,1,2,0,4\n", 1, "zero or negative size"),
        ("7,1,2,3,abc\n", 1, "box '1,2,3,abc' is not four numbers x,y,w,h (h is 'abc')"),
        ("7,1,2,3,nan\n", 1, "(h is 'nan')"),
        ("7,1,2,3,4,0\n", 1, "column 'track_id' must be an integer >= 1"),
        ("frame,left,top,w,h\n7,1,2,3,4\n", 1, "expected the header"),
        ("# c\n\nx,y\n", 3, "expected the header"),
    ],
)
def test_csv_malformed_rows_name_file_and_line(tmp_path, text, line, fragment):
    path = write(tmp_path, text)
    with pytest.raises(ToolError) as info:
        read_corrections(path)
    assert info.value.exit_code == EXIT_VALUE
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: "), message
    assert fragment in message
    assert "\n" not in message


def test_csv_saved_as_utf16_by_windows_tools(tmp_path):
    path = tmp_path / "fixes.csv"
    path.write_bytes("frame,x,y,w,h\r\n12,10.5,20,30,40\r\n".encode("utf-16"))
    assert read_corrections(path) == [Correction(12, (10.5, 20.0, 30.0, 40.0), None, f"{path}:2")]


def test_binary_file_is_a_one_line_error(tmp_path):
    path = tmp_path / "fixes.csv"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(ToolError) as info:
        read_corrections(path)
    assert "is not text (UTF-8, or UTF-16 with a byte-order mark)" in str(info.value) and "\n" not in str(info.value)


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(ToolError) as info:
        read_corrections(tmp_path / "nope.csv")
    assert info.value.exit_code == EXIT_INPUT and "does not exist" in str(info.value)


# --------------------------------------------------------------------------- COCO


def _track(track_id: int, frames, keyframe_rows=(0,), outside_rows=()) -> TrackResult:
    n = len(frames)
    keyframe = np.zeros(n, bool)
    keyframe[list(keyframe_rows)] = True
    outside = np.zeros(n, bool)
    outside[list(outside_rows)] = True
    flagged = outside.copy()
    return TrackResult(
        track_id=track_id, label="object", frame_indices=np.asarray(frames),
        boxes_xywh=np.tile([10.0, 12.0, 20, 16], (n, 1)) + np.arange(n)[:, None], confidence=np.full(n, 0.8),
        log_likelihood=np.ones(n), accepted=np.ones(n, bool),
        flagged=flagged, reasons=tuple("outside" if o else "" for o in outside), keyframe=keyframe, outside=outside,
        seconds=np.zeros(n))


def test_coco_written_by_the_tool_yields_its_keyframes(tmp_path):
    video = VideoInfo(path="v.mp4", name="v", width=96, height=72, fps=25.0, frame_count=40)
    frames = [4, 6, 8, 10]
    write_coco(tmp_path / "a.json", video, [_track(1, frames), _track(2, frames, keyframe_rows=(0, 2))])
    got = read_corrections(tmp_path / "a.json")
    assert [(c.frame, c.track_id, c.box_xywh) for c in got] == [
        (4, 1, (10.0, 12.0, 20.0, 16.0)), (4, 2, (10.0, 12.0, 20.0, 16.0)), (8, 2, (12.0, 14.0, 22.0, 18.0))]
    # Each correction names the line of its annotation (one per line in the tool's layout).
    lines = (tmp_path / "a.json").read_text().splitlines()
    for c in got:
        number = int(c.where.rsplit(":", 1)[1])
        assert '"keyframe": true' in lines[number - 1]


def test_coco_outside_keyframe_is_an_absence(tmp_path):
    data = {"images": [{"id": 1, "frame_index": 9}], "annotations": [
        {"id": 1, "image_id": 1, "track_id": 3, "bbox": [0, 0, 0, 0],
         "attributes": {"keyframe": True, "outside": True}},
        {"id": 2, "image_id": 1, "instance_id": 4, "bbox": [1, 2, 3, 4], "attributes": {"keyframe": True}},
        {"id": 3, "image_id": 1, "track_id": 5, "bbox": [1, 2, 3, 4], "attributes": {"keyframe": False}},
    ]}
    path = write(tmp_path, json.dumps(data), "c.json")
    assert [(c.frame, c.track_id, c.box_xywh) for c in read_corrections(path)] == [
        (9, 3, None), (9, 4, (1.0, 2.0, 3.0, 4.0))]


@pytest.mark.parametrize(
    "text, line, fragment",
    [
        ('{"images": [\n{"id": 1, "frame_index": 0}\n], "annotations": [\n{"id": 1, "image_id": 1,}\n]}', 4,
         "not valid JSON"),
        ('{"images": [\n{"id": 1}\n],\n"annotations": [\n{"id": 1, "image_id": 1, "bbox": [1,2,3,4], '
         '"attributes": {"keyframe": true}}\n]}', 5, "no 'frame_index'"),
        ('{"images": [\n{"id": 1, "frame_index": 0}\n],\n"annotations": [\n{"id": 7, "image_id": 1},\n'
         '{"id": 8, "image_id": 1, "bbox": [1,2,3], "attributes": {"keyframe": true}}\n]}', 6,
         "bbox [1, 2, 3] is not four numbers"),
        ('{"images": [], "annotations": {}}', 1, "expected a COCO object"),
        ('{"images": [\n{"id": [1], "frame_index": 0}\n], "annotations": []}', 2, "an image 'id' must be"),
        ('{"images": [\n{"id": 1, "frame_index": 0}\n],\n"annotations": [\n{"id": 1, "image_id": [1], '
         '"bbox": [1,2,3,4], "attributes": {"keyframe": true}}\n]}', 5, "refers to image [1]"),
    ],
)
def test_coco_errors_name_file_and_line(tmp_path, text, line, fragment):
    path = write(tmp_path, text, "c.json")
    with pytest.raises(ToolError) as info:
        read_corrections(path)
    assert info.value.exit_code == EXIT_VALUE
    assert str(info.value).startswith(f"{path}:{line}: "), str(info.value)
    assert fragment in str(info.value)


# --------------------------------------------------------------------------- against a run


FRAMES = np.arange(2, 30, 2)  # a run with --start 2 --step 2


def resolve(corrections, track_ids=(1,)):
    return resolve_corrections(corrections, frame_indices=FRAMES, track_ids=track_ids, width=96, height=72)


def test_resolve_maps_source_frames_to_positions():
    got = resolve([Correction(2, (1, 2, 3, 4), None, "f:1"), Correction(10, None, None, "f:2")])
    assert got == {1: {0: ((1, 2, 3, 4), "f:1"), 4: (None, "f:2")}}
    got = resolve([Correction(6, (1, 2, 3, 4), 2, "f:1")], track_ids=(1, 2))
    assert got == {1: {}, 2: {2: ((1, 2, 3, 4), "f:1")}}


@pytest.mark.parametrize(
    "correction, track_ids, fragment",
    [
        (Correction(3, (1, 2, 3, 4), None, "fix.csv:7"), (1,), "frame 3 was not processed by the run (frames 2 to 28 "
                                                               "every 2)"),
        (Correction(40, (1, 2, 3, 4), None, "fix.csv:7"), (1,), "frame 40 was not processed"),
        (Correction(4, (1, 2, 3, 4), 3, "fix.csv:7"), (1, 2), "unknown track id 3: the run has tracks 1, 2"),
        (Correction(4, (1, 2, 3, 4), None, "fix.csv:7"), (1, 2), "no track_id given"),
        (Correction(4, (100, 2, 3, 4), None, "fix.csv:7"), (1,), "lies outside the 96x72 frame"),
        (Correction(4, (-10, 2, 10, 4), None, "fix.csv:7"), (1,), "lies outside the 96x72 frame"),
    ],
)
def test_resolve_rejects_what_does_not_fit_the_run(correction, track_ids, fragment):
    with pytest.raises(ToolError) as info:
        resolve([correction], track_ids=track_ids)
    assert info.value.exit_code == EXIT_VALUE
    assert str(info.value).startswith("fix.csv:7: ")
    assert fragment in str(info.value)


def test_resolve_rejects_a_frame_corrected_twice():
    with pytest.raises(ToolError, match=r"^f:5: frame 4 of track 1 is corrected twice \(also at f:2\)"):
        resolve([Correction(4, (1, 2, 3, 4), None, "f:2"), Correction(4, None, 1, "f:5")])


@pytest.mark.parametrize("text, kind", [
    ('<?xml version="1.0"?>\n<annotations><version>1.1</version></annotations>\n', "a CVAT XML export"),
    ('[{"data": {"video": "v.mp4"}, "annotations": []}]', "a Label Studio JSON export"),
])
def test_a_review_tool_export_points_to_retrack(tmp_path, text, kind):
    path = write(tmp_path, text, "export.txt")
    with pytest.raises(ToolError) as info:
        read_corrections(path)
    message = str(info.value)
    assert info.value.exit_code == EXIT_VALUE and "\n" not in message
    assert f"looks like {kind}" in message and f"retrack OUT --corrections {path}" in message

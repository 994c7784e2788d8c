"""Reviewers' fixes read back from CVAT and Label Studio exports as correction records (annotator.review.imports).

Round trips: export the run's file, change it as a reviewer would in the tool, read the corrections back.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from _export_cases import SHIFTED, VIDEO, edit_box, shifted_track

from annotator.corrections import Correction, resolve_corrections
from annotator.errors import EXIT_INPUT, EXIT_VALUE, ToolError
from annotator.exports.cvat import build_cvat_xml, write_cvat_xml
from annotator.exports.labelstudio import build_labelstudio_tasks
from annotator.review.imports import read_cvat_corrections, read_labelstudio_corrections
from annotator.tracks import TrackResult, VideoInfo

# --------------------------------------------------------------------------- corrections from CVAT


def test_cvat_round_trip_gives_exactly_the_moved_box(tmp_path):
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [shifted_track()], frames=SHIFTED)
    assert read_cvat_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED) == []

    # The reviewer moves the box of source frame 5 (an interpolated one): CVAT makes it a keyframe.
    path.write_text(edit_box(path.read_text(), 5, xtl="20.50", ytl="11.00", xbr="44.50", ybr="31.00", keyframe="1"))
    corrections = read_cvat_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert len(corrections) == 1
    (c,) = corrections
    assert (c.frame, c.track_id) == (5, 4)
    assert c.box_xywh == pytest.approx((20.5, 11.0, 24.0, 20.0))
    line = int(c.where.rsplit(":", 1)[1])
    assert '<box frame="5"' in path.read_text().splitlines()[line - 1]
    resolved = resolve_corrections(corrections, frame_indices=np.array(list(SHIFTED)), track_ids=[4], width=64,
                                   height=48)
    assert resolved == {4: {1: ((20.5, 11.0, 24.0, 20.0), c.where)}}


def test_cvat_outside_keyframe_is_an_absence_and_a_shown_box_a_return(tmp_path):
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [shifted_track()], frames=SHIFTED)
    text = edit_box(path.read_text(), 5, outside="1", keyframe="1")  # hide the object from 5 on
    text = edit_box(text, 7, outside="0", keyframe="1")  # ... and show it at 7, where the run had it absent
    path.write_text(text)
    corrections = read_cvat_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert [(c.frame, c.box_xywh) for c in corrections] == [(5, None), (7, (12.0, 10.0, 20.0, 20.0))]


def test_cvat_a_hidden_stretch_ends_at_the_next_shown_keyframe_even_with_the_runs_box(tmp_path):
    """A reviewer hides the object at 5 and it shows again at 9 with the run's own box (every box a keyframe, as
    CVAT dumps a track a reviewer stepped through): the return at 9 is a correction too, else the absence, which
    lasts until the next correction, would hide the object to the end."""
    track = TrackResult(**{**shifted_track().__dict__, "outside": np.zeros(4, bool),
                           "flagged": np.zeros(4, bool), "reasons": ("",) * 4})
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [track], frames=SHIFTED)
    text = path.read_text()
    for frame in SHIFTED:
        text = edit_box(text, frame, keyframe="1")
    path.write_text(edit_box(text, 5, outside="1"))
    corrections = read_cvat_corrections(path, video=VIDEO, tracks=[track], frames=SHIFTED)
    assert [(c.frame, c.box_xywh) for c in corrections] == [(5, None), (7, (14.0, 10.0, 20.0, 20.0))]
    # Unedited, the same all-keyframe file is no correction at all.
    path.write_text(text)
    assert read_cvat_corrections(path, video=VIDEO, tracks=[track], frames=SHIFTED) == []


def cvat_error(tmp_path, text: str) -> ToolError:
    path = tmp_path / "edited.xml"
    path.write_text(text)
    with pytest.raises(ToolError) as info:
        read_cvat_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    message = str(info.value)
    assert message.startswith(f"{path}:") and "\n" not in message
    return info.value


@pytest.mark.parametrize("edit, needle", [
    (lambda t: t.replace("<size>4</size>", "<size>40</size>"), "belongs to another task (40 frames of 64x48"),
    (lambda t: t.replace("<width>64</width>", "<width>640</width>"), "another task (4 frames of 640x48"),
    (lambda t: t.replace("<frame_filter>step=2</frame_filter>", "<frame_filter></frame_filter>"), "every 1"),
    (lambda t: t.replace("<start_frame>3</start_frame>", "<start_frame>0</start_frame>"), "from frame 0"),
    (lambda t: t.replace('label="person" source', 'label="car" source'), "has label 'car'"),
    (lambda t: t.replace("</annotations>", '<track id="9" label="person"></track>\n</annotations>'),
     "the file has 2 tracks, the run 1"),
    (lambda t: t.replace('xbr="30.00"', 'xbr="5.00"'), "zero or negative size"),
])
def test_cvat_rejects_other_tasks_and_bad_boxes(tmp_path, edit, needle):
    text = build_cvat_xml(VIDEO, [shifted_track()], frames=SHIFTED)
    error = cvat_error(tmp_path, edit(text))
    assert needle in str(error) and error.exit_code == EXIT_VALUE


def test_cvat_malformed_xml_names_the_line(tmp_path):
    text = build_cvat_xml(VIDEO, [shifted_track()], frames=SHIFTED).replace("</box>", "</bx>", 1)
    error = cvat_error(tmp_path, text)
    bad_line = next(n for n, line in enumerate(text.splitlines(), 1) if "</bx>" in line)
    assert str(error).startswith(f"{tmp_path / 'edited.xml'}:{bad_line}: not well-formed XML")


def test_cvat_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(ToolError) as info:
        read_cvat_corrections(tmp_path / "none.xml", video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert info.value.exit_code == EXIT_INPUT and "none.xml does not exist" in str(info.value)


# --------------------------------------------------------------------------- corrections from Label Studio


def reviewed_export(tasks: list[dict], edit) -> list[dict]:
    """What Label Studio exports after a reviewer accepted the predictions and edited the regions."""
    task = json.loads(json.dumps(tasks[0]))
    result = json.loads(json.dumps(task["predictions"][0]["result"]))
    for region in result:
        region["origin"] = "prediction-changed"
        edit(region["value"]["sequence"])
    task.update(id=17, annotations=[{"id": 1, "was_cancelled": False, "result": result}])
    return [task]


def test_labelstudio_round_trip(tmp_path):
    tasks = build_labelstudio_tasks(VIDEO, [shifted_track()], frames=SHIFTED)
    path = tmp_path / "export.json"
    path.write_text(json.dumps(reviewed_export(tasks, lambda seq: None)))
    assert read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED) == []

    def edit(sequence):
        sequence[0].update(x=50.0, y=25.0)  # move the first box (source frame 3) to x=32 px, y=12 px

    path.write_text(json.dumps(reviewed_export(tasks, edit), indent=2))
    corrections = read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert [(c.frame, c.track_id) for c in corrections] == [(3, 4)]
    assert corrections[0].box_xywh == pytest.approx((32.0, 12.0, 20.0, 20.0))


def test_labelstudio_enabled_false_is_an_absence_from_the_next_processed_frame(tmp_path):
    track = shifted_track().select(np.array([True, True, False, True]))  # the run saw the object at 3, 5, 9
    track = TrackResult(**{**track.__dict__, "flagged": np.zeros(3, bool), "reasons": ("", "", ""),
                           "outside": np.zeros(3, bool)})
    tasks = build_labelstudio_tasks(VIDEO, [track], frames=SHIFTED)

    def edit(sequence):
        sequence[0]["enabled"] = False  # hide after source frame 3: absent from 5 until the next keyframe

    path = tmp_path / "export.json"
    path.write_text(json.dumps(reviewed_export(tasks, edit)))
    corrections = read_labelstudio_corrections(path, video=VIDEO, tracks=[track], frames=SHIFTED)
    # Label Studio shows the object again at the next keyframe (9): its box, though the run's own, ends the
    # absence, which would otherwise last to the track's end (an absence lasts until the next correction).
    assert [c.frame for c in corrections] == [5, 9] and corrections[0].box_xywh is None
    assert corrections[1].box_xywh == pytest.approx((16.0, 10.0, 20.0, 20.0))
    resolved = resolve_corrections(corrections, frame_indices=np.array(list(SHIFTED)), track_ids=[4], width=64,
                                   height=48)
    assert sorted(resolved[4]) == [1, 3] and resolved[4][1][0] is None


def test_labelstudio_absence_to_the_end_needs_no_return(tmp_path):
    tasks = build_labelstudio_tasks(VIDEO, [shifted_track()], frames=SHIFTED)

    def edit(sequence):
        # Hide after the first keyframe and drop every later one: absent from 5 to the end.
        sequence[0]["enabled"] = False
        del sequence[1:]

    path = tmp_path / "export.json"
    path.write_text(json.dumps(reviewed_export(tasks, edit)))
    corrections = read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert [(c.frame, c.box_xywh) for c in corrections] == [(5, None)]


@pytest.mark.parametrize("content, needle", [
    ("[{\"data\": {\"video\": \"v.mp4\"}, \"annotations\": [{\"result\": []}]}]", "no task with video rectangles"),
    ("[{\"data\": {}}", "not valid JSON"),
])
def test_labelstudio_rejects_files_without_rectangles(tmp_path, content, needle):
    path = tmp_path / "export.json"
    path.write_text(content)
    with pytest.raises(ToolError) as info:
        read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert str(info.value).startswith(f"{path}:") and needle in str(info.value)
    assert info.value.exit_code == EXIT_VALUE and "\n" not in str(info.value)


def _mangled(change) -> list[dict]:
    tasks = reviewed_export(build_labelstudio_tasks(VIDEO, [shifted_track()], frames=SHIFTED), lambda seq: None)
    change(tasks[0])
    return tasks


@pytest.mark.parametrize("change, needle", [
    (lambda t: t.update(annotations=5, predictions=5), "no task with video rectangles"),
    (lambda t: t["annotations"][0].update(result={"a": 1}), None),  # falls back to the predictions
    (lambda t: t.update(data=["v.mp4"]), None),  # no sptpt record to check: read as is
    (lambda t: t["annotations"][0]["result"][0].update(value=[1, 2]), "has no 'value' object"),
    (lambda t: t["annotations"][0]["result"][0].update(id=["a"]), None),  # matched by count, as for other ids
    (lambda t: t["annotations"][0]["result"][0]["value"]["sequence"][0].update(frame="4"), None),
    (lambda t: t["annotations"][0]["result"][0]["value"]["sequence"][0].update(frame="four"),
     "needs an integer 'frame'"),
])
def test_labelstudio_foreign_shapes_are_read_or_refused_in_one_line(tmp_path, change, needle):
    path = tmp_path / "export.json"
    path.write_text(json.dumps(_mangled(change), indent=2))
    if needle is None:
        read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
        return
    with pytest.raises(ToolError) as info:
        read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert str(info.value).startswith(f"{path}:") and needle in str(info.value)
    assert info.value.exit_code == EXIT_VALUE and "\n" not in str(info.value)


def test_labelstudio_rejects_another_runs_task(tmp_path):
    other = VideoInfo(path="b.mp4", name="b", width=64, height=48, fps=25.0, frame_count=30)
    tasks = build_labelstudio_tasks(other, [shifted_track()], frames=SHIFTED)
    path = tmp_path / "export.json"
    path.write_text(json.dumps(reviewed_export(tasks, lambda seq: None), indent=2))
    with pytest.raises(ToolError) as info:
        read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    message = str(info.value)
    assert "belongs to another run (video 'b'" in message and "30 frames" in message
    line = int(message.split(":")[1])
    assert '"sptpt"' in path.read_text().splitlines()[line - 1]


def test_corrections_have_the_csv_record_type(tmp_path):
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [shifted_track()], frames=SHIFTED)
    path.write_text(edit_box(path.read_text(), 9, xtl="1.00"))
    (c,) = read_cvat_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert type(c) is Correction and c.box_xywh == (1.0, 10.0, 35.0, 20.0) and not c.absent


def test_a_box_wholly_outside_the_image_reads_back_as_the_runs_own_not_as_an_absence(tmp_path):
    """The exporters hide a box that lies outside the image (Label Studio: enabled false); read back unchanged,
    that is no correction (it used to give an absence, and with it a return where the box comes back)."""
    video = VideoInfo(path="walk.mp4", name="walk", width=64, height=48, fps=25.0, frame_count=8)
    boxes = np.array([[10, 10, 20, 20], [12, 10, 20, 20], [70, 10, 20, 20], [72, 10, 20, 20], [14, 10, 20, 20],
                      [16, 10, 20, 20], [18, 10, 20, 20], [20, 10, 20, 20]], float)
    n = len(boxes)
    track = TrackResult(track_id=1, label="object", frame_indices=np.arange(n), boxes_xywh=boxes,
                        confidence=np.full(n, 0.9), log_likelihood=np.zeros(n), accepted=np.ones(n, bool),
                        flagged=np.zeros(n, bool), reasons=("",) * n, keyframe=np.eye(n, dtype=bool)[0],
                        outside=np.zeros(n, bool), seconds=np.zeros(n))
    tasks = build_labelstudio_tasks(video, [track], frames=range(n))
    sequence = tasks[0]["predictions"][0]["result"][0]["value"]["sequence"]
    assert [(k["frame"], k["enabled"]) for k in sequence] == [(1, True), (2, False), (5, True), (8, True)]
    path = tmp_path / "export.json"
    path.write_text(json.dumps(tasks))
    assert read_labelstudio_corrections(path, video=video, tracks=[track], frames=range(n)) == []
    xml = write_cvat_xml(tmp_path / "cvat.xml", video, [track], frames=range(n))
    assert read_cvat_corrections(xml, video=video, tracks=[track], frames=range(n)) == []

"""A correction is what a person changed relative to what the tool gave them (issue #47).

Label Studio: against the prediction an annotation started from (its ``parent_prediction``, which the export
nests); CVAT: against the keyframes of the cvat.xml the run wrote (run.json's ``review_exports``). So the same
reviewer's file, read again after a re-track changed the run's own keyframes, gives the same corrections and no
more. And the files other programs write: FiftyOne's CVAT for video (an ``outside`` keyframe one frame past the
range), Datumaro's ``cvat`` (CVAT for images), a file without ``<original_size>``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from _export_cases import SHIFTED, VIDEO, edit_box, jittery_track, shifted_track
from _paths import DATA as TEST_DATA
from _runs import run_cli, snapshot

from annotator.errors import EXIT_VALUE, InputWarning, ToolError
from annotator.exports.cvat import build_cvat_xml, cvat_keyframes, write_cvat_xml
from annotator.exports.labelstudio import build_labelstudio_config, build_labelstudio_tasks, media_url_for
from annotator.review.imports import read_cvat_corrections, read_labelstudio_corrections, read_run_corrections
from annotator.tracks import TrackResult, VideoInfo

DATA = TEST_DATA / "review_tools"


def retracked(track: TrackResult) -> TrackResult:
    """The run after a re-track from a correction at source frame 5: the tracker's rows after it moved, and its
    own keyframe at 9 (the first frame after the flagged span) with them."""
    boxes = track.boxes_xywh.copy()
    boxes[1] = [20.5, 11.0, 24.0, 20.0]
    boxes[3] = [18.0, 12.0, 20.0, 20.0]
    keyframe = track.keyframe.copy()
    keyframe[1] = True
    keyframe[3] = False  # the tracker moved the box at 9: no human anchor there (a re-track never moves one)
    sources = list(track.keyframe_source)
    sources[1] = "reviewed.xml:40"
    sources[3] = ""
    return TrackResult(**{**track.__dict__, "boxes_xywh": boxes, "keyframe": keyframe,
                          "keyframe_source": tuple(sources)})


# --------------------------------------------------------------------------- CVAT


def test_cvat_same_file_twice_adds_nothing_the_second_time(tmp_path):
    before = shifted_track()
    given = [json.loads(json.dumps(cvat_keyframes(VIDEO, [before], frames=SHIFTED)))]
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [before], frames=SHIFTED)
    path.write_text(edit_box(path.read_text(), 5, xtl="20.50", ytl="11.00", xbr="44.50", ybr="31.00", keyframe="1"))
    first = read_cvat_corrections(path, video=VIDEO, tracks=[before], frames=SHIFTED, exported=given)
    assert [(c.frame, c.box_xywh) for c in first] == [(5, (20.5, 11.0, 24.0, 20.0))]

    # After the re-track the run's own keyframe at 9 differs from the file's: compared with the run it is a
    # "correction" (the bug); compared with what the file was given (the first version, which it matches
    # best) it is none. The reviewer's keyframe at 5, which the tool never gave, is compared with the run,
    # where it is in force already.
    after = retracked(before)
    given.append(json.loads(json.dumps(cvat_keyframes(VIDEO, [after], frames=SHIFTED))))
    assert [c.frame for c in read_cvat_corrections(path, video=VIDEO, tracks=[after], frames=SHIFTED)] == [9]
    assert read_cvat_corrections(path, video=VIDEO, tracks=[after], frames=SHIFTED, exported=given) == []

    # A file made from the re-tracked run's cvat.xml, unedited, is no correction either.
    path.write_text(build_cvat_xml(VIDEO, [after], frames=SHIFTED))
    assert read_cvat_corrections(path, video=VIDEO, tracks=[after], frames=SHIFTED, exported=given) == []


def test_cvat_a_changed_given_keyframe_is_a_correction_even_where_it_equals_the_run(tmp_path):
    """The reviewer moved the tool's keyframe at 9 onto what the re-tracked run now has: still their box."""
    before = shifted_track()
    given = [cvat_keyframes(VIDEO, [before], frames=SHIFTED)]
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [before], frames=SHIFTED)
    path.write_text(edit_box(path.read_text(), 9, xtl="18.00", ytl="12.00", xbr="38.00", ybr="32.00"))
    found = read_cvat_corrections(path, video=VIDEO, tracks=[retracked(before)], frames=SHIFTED, exported=given)
    assert [(c.frame, c.box_xywh) for c in found] == [(9, (18.0, 12.0, 20.0, 20.0))]


@pytest.mark.parametrize("with_record", [True, False])
def test_cvat_whole_pixel_rounding_is_no_correction_and_a_bigger_move_is(tmp_path, with_record):
    """FiftyOne writes every corner rounded to a whole pixel: up to 1 px on a width; a reviewer moves further."""

    track = jittery_track(100, seed=7)
    frames = range(0, 100)
    video = VideoInfo(path="v.mp4", name="v", width=320, height=240, fps=30.0, frame_count=100)
    given = [cvat_keyframes(video, [track], frames=frames)] if with_record else None
    text = build_cvat_xml(video, [track], frames=frames)
    rounded = re.sub(r'(xtl|ytl|xbr|ybr)="(-?[\d.]+)"', lambda m: f'{m.group(1)}="{round(float(m.group(2)))}"', text)
    path = tmp_path / "rounded.xml"
    path.write_text(rounded)
    assert read_cvat_corrections(path, video=video, tracks=[track], frames=frames, exported=given) == []
    box = re.search(r'<box frame="10"[^>]*>', rounded).group(0)
    moved = float(re.search(r'xtl="([\d.]+)"', box).group(1)) + 1.5
    path.write_text(edit_box(rounded, 10, xtl=f"{moved:g}", keyframe="1"))
    found = read_cvat_corrections(path, video=video, tracks=[track], frames=frames, exported=given)
    assert [c.frame for c in found] == [10]


def test_cvat_the_record_of_a_run_folder_is_read_through_run_corrections(tmp_path):
    before = shifted_track()
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, [before], frames=SHIFTED)
    record = {"cvat": [cvat_keyframes(VIDEO, [before], frames=SHIFTED)]}
    after = retracked(before)
    assert read_run_corrections(path, video=VIDEO, tracks=[after], frames=SHIFTED, exported=record) == []


def test_cvat_outside_keyframe_just_past_the_range_is_a_warning(tmp_path):
    """FiftyOne ends every track with an outside keyframe one frame after its last box (tests/data/review_tools/
    fiftyone_cvat_video.xml, written by FiftyOne 1.22.1: see README.md there)."""
    track = TrackResult(**{**shifted_track().__dict__, "outside": np.zeros(4, bool), "flagged": np.zeros(4, bool),
                           "reasons": ("",) * 4})
    text = build_cvat_xml(VIDEO, [track], frames=SHIFTED)
    extra = ('<box frame="10" xtl="16.00" ytl="10.00" xbr="36.00" ybr="30.00" outside="1" occluded="0" '
             'keyframe="1" z_order="0"></box>\n</track>')
    path = tmp_path / "fiftyone.xml"
    path.write_text(text.replace("</track>", extra))
    with pytest.warns(InputWarning, match=r"fiftyone\.xml:\d+: 1 outside keyframe just past .* frame 9"):
        assert read_cvat_corrections(path, video=VIDEO, tracks=[track], frames=SHIFTED) == []
    # Further past the range it is still refused.
    path.write_text(text.replace("</track>", extra.replace('frame="10"', 'frame="12"')))
    with pytest.raises(ToolError, match="frame 12 is not one of the run's processed frames"):
        read_cvat_corrections(path, video=VIDEO, tracks=[track], frames=SHIFTED)


def test_fiftyone_cvat_video_export_reads_with_one_warning():
    """The file FiftyOne 1.22.1 wrote (CVATVideoDataset) for a 12-frame 64x48 video with one tracked person."""
    path = DATA / "fiftyone_cvat_video.xml"
    if not path.exists():
        pytest.skip("no FiftyOne fixture")
    video = VideoInfo(path="walk.mp4", name="walk", width=64, height=48, fps=25.0, frame_count=12)
    frames = np.arange(12)
    track = TrackResult(
        track_id=1, label="person", frame_indices=frames,
        boxes_xywh=np.stack([10.0 + frames, np.full(12, 10.0), np.full(12, 20.0), np.full(12, 20.0)], axis=1),
        confidence=np.ones(12), log_likelihood=np.zeros(12), accepted=np.ones(12, bool),
        flagged=np.zeros(12, bool), reasons=("",) * 12, keyframe=frames == 0, outside=np.zeros(12, bool),
        seconds=np.zeros(12))
    with pytest.warns(InputWarning, match="just past the run's last processed frame 11"):
        corrections = read_cvat_corrections(path, video=video, tracks=[track], frames=range(12))
    assert corrections == []


def cvat_message(path: Path) -> str:
    with pytest.raises(ToolError) as info:
        read_cvat_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert info.value.exit_code == EXIT_VALUE
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
    return message


def test_datumaro_cvat_export_is_named_as_cvat_for_images():
    """Datumaro 1.13's "cvat" export of the run's cvat.xml (tests/data/review_tools/README.md)."""
    message = cvat_message(DATA / "datumaro_cvat_images.xml")
    assert '"CVAT for images"' in message and 'export "CVAT for video 1.1" from CVAT' in message
    assert "FiftyOne" in message and "Datumaro" not in message  # Datumaro has no CVAT for video exporter


def test_file_without_original_size_says_so(tmp_path):
    text = build_cvat_xml(VIDEO, [shifted_track()], frames=SHIFTED)
    start, end = text.index("<original_size>"), text.index("</original_size>") + len("</original_size>")
    path = tmp_path / "no_size.xml"
    path.write_text(text[:start] + text[end:])
    message = cvat_message(path)
    assert "has no <original_size>" in message and "<width>64</width><height>48</height>" in message


# --------------------------------------------------------------------------- Label Studio


def labelstudio_export(tasks: list[dict], edit, *, parent: bool = True) -> list[dict]:
    """Label Studio 1.23's JSON export after a reviewer accepted the prediction and edited it: the prediction
    nested under the annotation as ``prediction``, its id in ``parent_prediction``, the task's ``predictions``
    as ids (the layout tests/annotator/review/test_labelstudio_server.py gets from a real server)."""
    task = json.loads(json.dumps(tasks[0]))
    prediction = {**task["predictions"][0], "id": 7, "task": 17, "project": 1}
    result = json.loads(json.dumps(prediction["result"]))
    for region in result:
        edit(region["value"]["sequence"])
    annotation = {"id": 1, "was_cancelled": False, "result": result, "prediction": prediction if parent else {},
                  "parent_prediction": 7 if parent else None}
    task.update(id=17, annotations=[annotation], predictions=[7])
    return [task]


def test_labelstudio_same_export_twice_adds_nothing_the_second_time(tmp_path):
    before = shifted_track()
    tasks = build_labelstudio_tasks(VIDEO, [before], frames=SHIFTED)

    def move(sequence):
        assert sequence[1]["frame"] == 6  # source frame 5, the last the run saw before the absence at 7
        sequence[1].update(x=32.03125, y=22.916667)

    path = tmp_path / "export.json"
    path.write_text(json.dumps(labelstudio_export(tasks, move), indent=2))
    first = read_labelstudio_corrections(path, video=VIDEO, tracks=[before], frames=SHIFTED)
    assert [c.frame for c in first] == [5]
    assert first[0].box_xywh == pytest.approx((20.5, 11.0, 20.0, 20.0), abs=1e-4)
    after = retracked(before)
    again = read_labelstudio_corrections(path, video=VIDEO, tracks=[after], frames=SHIFTED)
    assert again == first
    # Without the parent prediction the run's boxes are all there is to compare with: the run's own keyframe at
    # 9, which the re-track moved, then counts as a correction (what the issue saw).
    path.write_text(json.dumps(labelstudio_export(tasks, move, parent=False), indent=2))
    assert [c.frame for c in read_labelstudio_corrections(path, video=VIDEO, tracks=[after], frames=SHIFTED)] == [5, 9]


def test_labelstudio_keyframe_added_without_moving_is_no_correction(tmp_path):
    """A keyframe added where Label Studio interpolated, with the box it showed there, changes nothing."""
    track = TrackResult(**{**shifted_track().__dict__, "outside": np.zeros(4, bool), "flagged": np.zeros(4, bool),
                           "reasons": ("",) * 4})
    tasks = build_labelstudio_tasks(VIDEO, [track], frames=SHIFTED, max_error_px=100.0)
    sequence = tasks[0]["predictions"][0]["result"][0]["value"]["sequence"]
    assert [k["frame"] for k in sequence] == [4, 10]

    def add(seq):
        a, b = seq
        t = (7 - a["frame"]) / (b["frame"] - a["frame"])
        seq.insert(1, {**a, "frame": 7, **{k: a[k] + t * (b[k] - a[k]) for k in ("x", "y", "width", "height")}})

    path = tmp_path / "export.json"
    path.write_text(json.dumps(labelstudio_export(tasks, add)))
    assert read_labelstudio_corrections(path, video=VIDEO, tracks=[retracked(track)], frames=SHIFTED) == []


def test_labelstudio_disabling_a_given_keyframe_is_an_absence(tmp_path):
    track = TrackResult(**{**shifted_track().__dict__, "outside": np.zeros(4, bool), "flagged": np.zeros(4, bool),
                           "reasons": ("",) * 4})
    tasks = build_labelstudio_tasks(VIDEO, [track], frames=SHIFTED, max_error_px=0.1)

    def hide(seq):
        # A keyframe at source frame 5 on the box shown there, hidden after: the object is gone from 7 on.
        seq.insert(1, {**seq[0], "frame": 6, "x": 18.75, "enabled": False})

    path = tmp_path / "export.json"
    path.write_text(json.dumps(labelstudio_export(tasks, hide)))
    found = read_labelstudio_corrections(path, video=VIDEO, tracks=[retracked(track)], frames=SHIFTED)
    assert [c.frame for c in found] == [7, 9] and found[0].box_xywh is None
    assert found[1].box_xywh == pytest.approx((16.0, 10.0, 20.0, 20.0))


def test_labelstudio_switching_a_given_keyframe_back_on_is_a_correction(tmp_path):
    """The prediction hid the object after source frame 5 (enabled: false); the reviewer switched it on."""
    tasks = build_labelstudio_tasks(VIDEO, [shifted_track()], frames=SHIFTED)

    def show(seq):
        assert seq[1]["frame"] == 6 and seq[1]["enabled"] is False
        seq[1]["enabled"] = True

    path = tmp_path / "export.json"
    path.write_text(json.dumps(labelstudio_export(tasks, show)))
    found = read_labelstudio_corrections(path, video=VIDEO, tracks=[shifted_track()], frames=SHIFTED)
    assert [c.frame for c in found] == [5] and found[0].box_xywh == pytest.approx((12.0, 10.0, 20.0, 20.0))


# --------------------------------------------------------------------------- what the task needs


def test_labelstudio_config_has_the_runs_labels_and_frame_rate():
    video = VideoInfo(path="v.mp4", name="v", width=64, height=48, fps=29.97, frame_count=12)
    config = build_labelstudio_config(video, [shifted_track()])
    assert '<Video name="video" value="$video" framerate="29.97"/>' in config
    assert '<Label value="person"/>' in config and '<VideoRectangle name="box" toName="video"/>' in config
    import xml.etree.ElementTree as ET

    ET.fromstring(config)  # well-formed


@pytest.mark.parametrize("url, expected", [
    (None, None), ("http://127.0.0.1:8081/walk.mp4", "http://127.0.0.1:8081/walk.mp4"),
    ("/data/local-files/?d=videos/", "/data/local-files/?d=videos/walk.mp4"),
    ("/data/local-files/?d=", "/data/local-files/?d=walk.mp4")])
def test_media_url(url, expected):
    assert media_url_for(url, "clips/walk.mp4") == expected
    tasks = build_labelstudio_tasks(VIDEO, [shifted_track()], frames=SHIFTED, video_url=media_url_for(url, VIDEO.path))
    assert tasks[0]["data"]["video"] == (expected or VIDEO.path)


# --------------------------------------------------------------------------- from the command line


@pytest.fixture(scope="module")
def cvat_run(tmp_path_factory):
    import cv2

    from sptpt_dev.synthetic import make_clip

    root = tmp_path_factory.mktemp("given")
    clip = make_clip(16, size=(96, 72), object_size=(24, 20))
    (root / "seq").mkdir()
    for k, frame in enumerate(clip.frames):
        cv2.imwrite(str(root / "seq" / f"{k:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    (root / "small.yaml").write_text("tracker:\n  n_particles: 60\n  n_negatives: 20\n")
    box = ",".join(f"{v:.2f}" for v in clip.boxes_xywh[0])
    code, output = run_cli(root / "seq", "--box", box, "--config", root / "small.yaml", "--formats",
                        "otb,flags,cvat,labelstudio", "--media-url", "http://127.0.0.1:8081/", "--out", root / "out",
                        "-q")
    assert code == 0, output
    return root / "out"


def test_cvat_file_used_twice_from_the_command_line_changes_nothing_the_second_time(cvat_run, tmp_path):
    """run.json keeps the keyframes of the cvat.xml it wrote; the second retrack with the same file is a no-op."""
    import shutil

    from annotator.track_store import STORE_NAME, read_store

    out = tmp_path / "out"
    shutil.copytree(cvat_run, out)
    assert len(json.loads((out / "run.json").read_text())["review_exports"]["cvat"]) == 1
    edited = tmp_path / "cvat_reviewed.xml"
    edited.write_text(edit_box((out / "cvat.xml").read_text(), 9, xtl="30.00", ytl="20.00", xbr="55.00",
                               ybr="41.00", keyframe="1"))
    code, output = run_cli("retrack", out, "--corrections", edited)
    assert code == 0 and "1 new or changed correction" in output, output
    assert len(json.loads((out / "run.json").read_text())["review_exports"]["cvat"]) == 2
    before = snapshot(out)
    code, output = run_cli("retrack", out, "--corrections", edited)
    assert code == 0 and "every correction is already applied" in output, output
    assert snapshot(out) == before
    assert int(read_store(out / STORE_NAME).tracks[0].keyframe.sum()) == 2


def test_media_url_and_labeling_config_survive_a_retrack(cvat_run, tmp_path):
    import shutil


    out = tmp_path / "out"
    shutil.copytree(cvat_run, out)
    outputs = json.loads((out / "run.json").read_text())["outputs"]["labelstudio"]
    assert sorted(outputs) == ["labelstudio.json", "labelstudio_config.xml"]
    assert json.loads((out / "labelstudio.json").read_text())[0]["data"]["video"] == "http://127.0.0.1:8081/seq"
    config = (out / "labelstudio_config.xml").read_text()
    code, output = run_cli("retrack", out, "--corrections", out / "cvat.xml", "--media-url",
                           "/data/local-files/?d=v.mp4", "-q")
    assert code == 0, output
    assert json.loads((out / "labelstudio.json").read_text())[0]["data"]["video"] == "/data/local-files/?d=v.mp4"
    assert json.loads((out / "run.json").read_text())["export_options"] == {"media_url": "/data/local-files/?d=v.mp4"}
    assert (out / "labelstudio_config.xml").read_text() == config


def test_trailing_outside_keyframe_is_one_warning_line_on_the_command_line(cvat_run, tmp_path):
    """A run's cvat.xml with FiftyOne's ending: an outside box one frame past the last processed frame."""
    import shutil


    out = tmp_path / "out"
    shutil.copytree(cvat_run, out)
    text = (out / "cvat.xml").read_text()
    last = text.rindex("<box frame=")
    trailing = re.sub(r'<box frame="\d+"', '<box frame="16"', text[last:text.index("</box>", last) + 6])
    trailing = re.sub(r'outside="0"', 'outside="1"', re.sub(r'keyframe="0"', 'keyframe="1"', trailing))
    fiftyone = tmp_path / "fiftyone.xml"
    fiftyone.write_text(text.replace("</track>", trailing + "\n  </track>"))
    before = snapshot(out)
    code, output = run_cli("retrack", out, "--corrections", fiftyone, "-q")
    assert code == 0, output
    lines = output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"sptpt-annotate: warning: {fiftyone}:"), output
    assert "just past the run's last processed frame 15" in lines[0]
    assert snapshot(out) == before


def test_batch_media_url_gives_each_video_its_url_and_is_part_of_what_a_rerun_keeps(tmp_path, capsys):
    from _runs import FAST, box_text, write_clip, write_jsonl

    from annotator.cli import main

    (tmp_path / "clips").mkdir()
    box = write_clip(tmp_path / "clips" / "v0.mp4", 5, seed=0)
    manifest = write_jsonl(tmp_path / "m.jsonl", [{"video": "clips/v0.mp4", "box": box_text(box)}])
    (tmp_path / "fast.yaml").write_text(FAST)
    out = tmp_path / "out"

    def batch(*extra):
        with pytest.raises(SystemExit) as info:
            main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--config", str(tmp_path / "fast.yaml"),
                  "--formats", "otb,labelstudio", "--no-render", "--quiet", *extra])
        summary_json = out / "summary.json"
        return info.value.code, json.loads(summary_json.read_text()) if summary_json.exists() else None

    code, summary = batch("--media-url", "/data/local-files/?d=videos/")
    assert code == 0
    url = "/data/local-files/?d=videos/v0.mp4"
    item = out / summary["items"][0]["id"]
    assert json.loads((item / "labelstudio.json").read_text())[0]["data"]["video"] == url
    assert (item / "labelstudio_config.xml").is_file()
    assert [t["data"]["video"] for t in json.loads((out / "labelstudio.json").read_text())] == [url]
    code, summary = batch("--media-url", "/data/local-files/?d=videos/")
    assert code == 0 and summary["counts"]["reused"] == 1
    code, summary = batch("--media-url", "http://127.0.0.1:8081/")
    assert code == 0 and summary["counts"]["reused"] == 0
    assert json.loads((item / "labelstudio.json").read_text())[0]["data"]["video"] == "http://127.0.0.1:8081/v0.mp4"
    capsys.readouterr()
    code, _ = batch("--media-url", "http://127.0.0.1:8081/v0.mp4")
    err = capsys.readouterr().err
    assert code == 4 and err.count("\n") == 1 and "end it with / or =" in err, err

"""The review loop through the reviewers' tools, from the command line: annotate with --formats cvat/labelstudio,
edit the file as a reviewer would, ``retrack --corrections`` it; bad files change nothing (issue #11)."""

from __future__ import annotations

import json
import re
import shutil

import cv2
import numpy as np
import pytest
from _export_cases import edit_box
from _runs import run_cli, snapshot

from annotator.errors import EXIT_VALUE
from annotator.track_store import STORE_NAME, read_store
from sptpt_dev.synthetic import make_clip

FORMATS = "otb,coco,flags,report,cvat,mot,labelstudio,yolo"
N = 16


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("tools")
    clip = make_clip(N, size=(96, 72), object_size=(24, 20))
    (root / "seq").mkdir()
    for k, frame in enumerate(clip.frames):
        cv2.imwrite(str(root / "seq" / f"{k:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    (root / "small.yaml").write_text("tracker:\n  n_particles: 60\n  n_negatives: 20\n")
    box = ",".join(f"{v:.2f}" for v in clip.boxes_xywh[0])
    code, output = run_cli(root / "seq", "--box", box, "--config", root / "small.yaml", "--formats", FORMATS,
                        "--out", root / "out", "-q")
    assert code == 0, output
    return root / "out"


@pytest.fixture()
def out(run_dir, tmp_path):
    copy = tmp_path / "out"
    shutil.copytree(run_dir, copy)
    return copy


def test_every_review_format_is_written_and_listed(run_dir):
    for name in ("cvat.xml", "labelstudio.json", "mot/gt/gt.txt", "mot/gt/labels.txt", "yolo/data.yaml",
                 "yolo/labels/0000.txt"):  # an image folder: labels named after its images (0000.png)
        assert (run_dir / name).is_file(), name
    info = json.loads((run_dir / "run.json").read_text())
    assert {"cvat", "mot", "labelstudio", "yolo"} <= set(info["outputs"])


def test_cvat_round_trip_from_the_command_line_keeps_the_moved_box(out, tmp_path):
    edited = tmp_path / "cvat_reviewed.xml"
    edited.write_text(edit_box((out / "cvat.xml").read_text(), 9, xtl="30.00", ytl="20.00", xbr="55.00",
                               ybr="41.00", keyframe="1"))
    code, output = run_cli("retrack", out, "--corrections", edited, "-q")
    assert code == 0, output
    track = read_store(out / STORE_NAME).tracks[0]
    assert track.keyframe[9] and track.keyframe_source[9].startswith(str(edited))
    np.testing.assert_array_equal(track.boxes_xywh[9], [30.0, 20.0, 25.0, 21.0])
    # Every view was rewritten from the new store, the CVAT file included: the box is a keyframe there now.
    assert re.search(r'<box frame="9"[^>]*xtl="30.00" ytl="20.00" xbr="55.00" ybr="41.00"[^>]*keyframe="1"',
                     (out / "cvat.xml").read_text())


def test_labelstudio_round_trip_from_the_command_line(out, tmp_path):
    tasks = json.loads((out / "labelstudio.json").read_text())
    region = tasks[0]["predictions"][0]["result"][0]
    sequence = region["value"]["sequence"]
    item = dict(sequence[0])
    item.update(frame=8, x=40.0, y=30.0, time=7 / 30)  # frame 8 is source frame 7, 1-based
    sequence.append(item)
    sequence.sort(key=lambda s: s["frame"])
    tasks[0]["annotations"] = [{"result": [region]}]
    exported = tmp_path / "ls_export.json"
    exported.write_text(json.dumps(tasks))
    code, output = run_cli("retrack", out, "--corrections", exported, "-q")
    assert code == 0, output
    track = read_store(out / STORE_NAME).tracks[0]
    assert track.keyframe[7]
    np.testing.assert_allclose(track.boxes_xywh[7, :2], [0.40 * 96, 0.30 * 72])


@pytest.mark.parametrize("kind, fragment", [
    ("other_task", "cvat_other.xml"), ("malformed", "cvat_broken.xml"), ("no_rectangles", "ls_empty.json")])
def test_bad_review_files_are_one_line_and_change_nothing(out, tmp_path, kind, fragment):
    text = (out / "cvat.xml").read_text()
    if kind == "other_task":
        (tmp_path / fragment).write_text(re.sub(r"<size>\d+</size>", "<size>99</size>", text))
    elif kind == "malformed":
        (tmp_path / fragment).write_text(text[: len(text) // 2])
    else:
        (tmp_path / fragment).write_text(json.dumps([{"data": {"video": "x.mp4"}, "annotations": [{"result": []}]}]))
    before = snapshot(out)
    code, output = run_cli("retrack", out, "--corrections", tmp_path / fragment, "-q")
    assert code == EXIT_VALUE, output
    lines = output.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], output
    assert snapshot(out) == before


def test_a_retrack_into_a_folder_in_use_stops_and_changes_nothing(out, tmp_path):
    pytest.importorskip("fcntl")
    from annotator.output_folder import folder_lock

    edited = tmp_path / "cvat_reviewed.xml"
    edited.write_text(edit_box((out / "cvat.xml").read_text(), 9, xtl="30.00", ytl="20.00", xbr="55.00",
                               ybr="41.00", keyframe="1"))
    before = snapshot(out)
    with folder_lock(out):  # as a run, a batch or another re-track in another process holds it
        code, output = run_cli("retrack", out, "--corrections", edited, "-q")
    assert code == 5 and output.count("\n") == 1 and f"output folder {out} is in use" in output, output
    assert snapshot(out) == before


def test_a_retrack_stages_inside_the_folder_and_clears_what_a_killed_one_left(out, tmp_path):
    # The same staging as a first run: a dead re-track's folder is removed under the lock, and nothing is left
    # beside the output folder or in it.
    dead = out / ".sptpt-run.killed.tmp"
    dead.mkdir()
    (dead / "tracks.npz").write_bytes(b"half")
    edited = tmp_path / "cvat_reviewed.xml"
    edited.write_text(edit_box((out / "cvat.xml").read_text(), 9, xtl="30.00", ytl="20.00", xbr="55.00",
                               ybr="41.00", keyframe="1"))
    beside = sorted(out.parent.iterdir())
    code, output = run_cli("retrack", out, "--corrections", edited, "-q")
    assert code == 0, output
    assert not dead.exists() and not list(out.glob(".sptpt-run.*"))
    assert sorted(out.parent.iterdir()) == beside

"""Review-tool exports (CVAT, MOT, Label Studio, YOLO): golden files, third-party readers, atomic writes.

Golden files live in ``tests/golden/exports/review/``; regenerate them after an
intended format change with ``UPDATE_GOLDEN=1 pytest tests/annotator/exports/test_exports_reviewtools.py``
and review the diff. Third-party readers (datumaro, motmetrics) run in
``tests/_reader_env`` (see ``_reader_env.py`` for why not in the project's own environment).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import _export_cases
import numpy as np
import pytest
import yaml
from _cvat_import import cvat_keyframe_count, cvat_worst_error
from _export_cases import VIDEO, jittery_track, make_tracks, shifted_track
from _labelstudio_import import interpolate_labelstudio
from _reader_env import run_check

from annotator import atomic
from annotator.exports.cvat import MAX_ERROR_PX, build_cvat_xml, write_cvat_xml
from annotator.exports.labelstudio import build_labelstudio_tasks, write_labelstudio
from annotator.exports.mot import write_mot
from annotator.exports.review_tools import MAX_KEYFRAME_GAP, REVIEW_SCORE_NAME, fewest_keyframes
from annotator.exports.yolo import write_yolo
from annotator.tracks import TrackResult, VideoInfo

GOLDEN = _export_cases.GOLDEN / "review"
FRAMES = range(0, 12, 2)  # make_tracks(): every other frame of the 12-frame video


def check_golden(path: Path, golden_name: str) -> None:
    _export_cases.check_golden(path, golden_name, root=GOLDEN)


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*"))


# --------------------------------------------------------------------------- CVAT


def test_cvat_golden_and_datumaro(tmp_path):
    path = write_cvat_xml(tmp_path / "cvat.xml", VIDEO, make_tracks(), frames=FRAMES)
    check_golden(path, "cvat.xml")
    text = path.read_text()
    # Keyframes: the first frame; 2, as the line from 0 to 4 passes 7 px from it; 4, the flagged span's start and
    # the last frame seen before the absence; 6, the absence and the span's end; 8, the correction; 10, the last.
    walker = re.search(r'<track id="0".*?</track>', text, re.S).group(0)
    assert re.findall(r'frame="(\d+)".*?keyframe="1"', walker) == ["0", "2", "4", "6", "8", "10"]
    assert cvat_worst_error(path, make_tracks(), FRAMES) <= MAX_ERROR_PX
    assert walker.count(f'<attribute name="{REVIEW_SCORE_NAME}">') == 6

    seen = run_check("datumaro_cvat", path=str(path))
    assert seen["labels"] == ["person", "car"]
    assert [item["frame"] for item in seen["items"]] == list(FRAMES)
    boxes = {(b["attributes"]["track_id"], item["frame"]): b for item in seen["items"] for b in item["boxes"]}
    walker_track, car = make_tracks()
    for i, frame in enumerate(walker_track.frame_indices):
        box = boxes[(0, int(frame))]
        assert box["label"] == "person" and box["attributes"]["outside"] == bool(walker_track.outside[i])
        if not walker_track.outside[i]:
            np.testing.assert_allclose(box["xywh"], walker_track.boxes_xywh[i])
    assert boxes[(0, 6)]["xywh"] == boxes[(0, 4)]["xywh"]  # absent: last known box, outside=1
    assert boxes[(1, 6)]["attributes"]["outside"] and boxes[(1, 10)]["attributes"]["outside"]  # NaN; track ended
    assert boxes[(0, 2)]["attributes"][REVIEW_SCORE_NAME] == pytest.approx(0.1)  # p_fail = 1 - confidence 0.9


def test_cvat_frames_are_source_indices_with_range_in_meta():
    track = shifted_track()
    text = build_cvat_xml(VIDEO, [track], frames=range(3, 10, 2))
    assert "<size>4</size>" in text and "<start_frame>3</start_frame>" in text
    assert "<stop_frame>9</stop_frame>" in text and "<frame_filter>step=2</frame_filter>" in text
    assert re.findall(r'<box frame="(\d+)"', text) == ["3", "5", "7", "9"]
    assert "<original_size>\n        <width>64</width>\n        <height>48</height>" in text


@pytest.mark.parametrize("hold_before_outside", [False, True], ids=["cvat-2.x", "cvat-1.x"])
@pytest.mark.parametrize("step", [1, 3])
def test_cvat_import_shows_every_tracked_box(tmp_path, step, hold_before_outside):
    """CVAT keeps only keyframes and interpolates between them: its import of our file shows every box of the run
    within MAX_ERROR_PX, hides the absent and NaN frames, and ends the track where the run ends it."""
    n = 100
    track = jittery_track(n, seed=step, step=step, start=2)
    frames = range(2, 2 + step * (n + 10), step)  # the range goes on after the track's last row
    video = VideoInfo(path="v.mp4", name="v", width=320, height=240, fps=30.0, frame_count=frames.stop + 1)
    path = write_cvat_xml(tmp_path / "cvat.xml", video, [track], frames=frames)
    assert cvat_worst_error(path, [track], frames, hold_before_outside=hold_before_outside) <= MAX_ERROR_PX
    keys = cvat_keyframe_count(path)
    assert keys < n  # fewer handles than boxes: the jitter is 0.4 px
    text = path.read_text()
    for bound in (20, 25, 50, 57, 40):  # flagged spans' first and last rows, the correction
        assert re.search(rf'<box frame="{2 + step * bound}"[^>]*keyframe="1"', text), bound


def test_cvat_file_of_a_jittery_track_with_a_bigger_error_is_what_cvat_drops():
    """The rule the test replays is CVAT's: the same boxes with keyframes only where the object leaves or comes back
    (as this exporter wrote them before) are far off."""
    track = jittery_track(100, seed=0)
    frames = range(0, 110)
    video = VideoInfo(path="v.mp4", name="v", width=320, height=240, fps=30.0, frame_count=120)
    text = build_cvat_xml(video, [track], frames=frames)
    kept = set(re.findall(r'<box frame="(\d+)"[^>]*keyframe="1"', text))
    bounds = ("0", "49", "50", "58", "69", "70", "71", "99", "100")  # absent 50-57 and 70 (NaN); ends at 99
    stripped = re.sub(r'(<box frame="(\d+)"[^>]*keyframe=")1"',
                      lambda m: m.group(1) + ("1" if m.group(2) in bounds else "0") + '"',
                      text)
    assert len(kept) > 5
    from tempfile import TemporaryDirectory

    with TemporaryDirectory() as folder:
        path = Path(folder) / "cvat.xml"
        path.write_text(stripped)
        assert cvat_worst_error(path, [track], frames) > 5 * MAX_ERROR_PX


def _brute_fewest(t, written, exact, required, max_error):
    """Fewest kept rows by trying every segment (quadratic in segments, cubic in all): the reference."""
    n = len(t)

    def fits(a, b):
        k = np.arange(a + 1, b)
        line = written[a] + (written[b] - written[a]) * ((t[k] - t[a]) / (t[b] - t[a]))[:, None]
        return len(k) == 0 or np.abs(line - exact[k]).max() <= max_error

    cost = [0] * n
    for i in range(n - 2, -1, -1):
        nxt = next(j for j in range(i + 1, n) if required[j] or j == n - 1)
        cost[i] = min(cost[j] + 1 for j in range(i + 1, nxt + 1) if fits(i, j))
    return cost[0] + 1, fits


@pytest.mark.parametrize("seed", range(6))
def test_fewest_keyframes_is_the_fewest_and_within_the_error(seed):
    rng = np.random.default_rng(seed)
    n = 120
    t = np.cumsum(rng.integers(1, 4, n)).astype(np.float64)
    exact = np.cumsum(rng.normal(0, rng.uniform(0.05, 0.6), (n, 4)), axis=0) + 100
    written = np.round(exact, 2)
    required = rng.random(n) < 0.04
    keep = fewest_keyframes(t, written, exact, required, 0.5)
    best, fits = _brute_fewest(t, written, exact, required, 0.5)
    rows = np.flatnonzero(keep)
    assert keep[0] and keep[-1] and keep[required].all()
    assert all(fits(a, b) for a, b in zip(rows[:-1], rows[1:]))
    assert keep.sum() == best


def test_fewest_keyframes_of_a_still_object_puts_one_every_max_gap_rows():
    n = 3 * MAX_KEYFRAME_GAP + 1
    exact = np.tile([10.0, 20.0, 60.0, 70.0], (n, 1))
    keep = fewest_keyframes(np.arange(n, dtype=np.float64), exact, exact, np.zeros(n, bool), 0.5)
    assert np.flatnonzero(keep).tolist() == [0, MAX_KEYFRAME_GAP, 2 * MAX_KEYFRAME_GAP, 3 * MAX_KEYFRAME_GAP]


# --------------------------------------------------------------------------- MOT


def test_mot_golden_motmetrics_and_datumaro(tmp_path):
    written = write_mot(tmp_path / "mot", VIDEO, make_tracks(), frames=FRAMES)
    assert written == [tmp_path / "mot" / "gt" / "gt.txt", tmp_path / "mot" / "gt" / "labels.txt"]
    check_golden(written[0], "mot/gt/gt.txt")
    check_golden(written[1], "mot/gt/labels.txt")

    walker, car = make_tracks()
    expected = {}  # (1-based position, track id) -> 0-based xywh, absent and NaN rows left out
    for track in (walker, car):
        for i, frame in enumerate(track.frame_indices):
            if not track.outside[i] and np.isfinite(track.boxes_xywh[i]).all():
                expected[(FRAMES.index(int(frame)) + 1, track.track_id)] = track.boxes_xywh[i]

    # MOTChallenge's evaluation reads bb_left, bb_top as 1-based and subtracts 1: it gets our 0-based boxes back.
    rows = run_check("motmetrics", path=str(written[0]))["rows"]
    assert sorted((f, t) for f, t, *_ in rows) == sorted(expected)
    for f, t, x, y, w, h, _ in rows:
        np.testing.assert_allclose([x, y, w, h], expected[(f, t)])

    # Datumaro's mot_seq (CVAT's "MOT 1.1") takes them as written: one pixel right and down, as documented.
    seen = run_check("datumaro_mot", path=str(tmp_path / "mot"))
    assert seen["labels"] == ["person", "car"]
    got = {(int(item["id"]), b["attributes"]["track_id"]): b for item in seen["items"] for b in item["boxes"]}
    assert sorted(got) == sorted(expected)
    for key, box in got.items():
        np.testing.assert_allclose(box["xywh"], expected[key] + np.array([1.0, 1.0, 0.0, 0.0]))
        assert box["label"] == ("person" if key[1] == 1 else "car")
    # origin=0 writes the unshifted pixels those readers want.
    write_mot(tmp_path / "mot0", VIDEO, make_tracks(), frames=FRAMES, origin=0)
    seen = run_check("datumaro_mot", path=str(tmp_path / "mot0"))
    for item in seen["items"]:
        for box in item["boxes"]:
            np.testing.assert_allclose(box["xywh"], expected[(int(item["id"]), box["attributes"]["track_id"])])


# --------------------------------------------------------------------------- Label Studio


def test_labelstudio_golden_and_layout(tmp_path):
    path = tmp_path / "labelstudio.json"
    tasks = write_labelstudio(path, VIDEO, make_tracks(), frames=FRAMES, video_url="/data/local-files/?d=walk.mp4")
    check_golden(path, "labelstudio.json")
    assert json.loads(path.read_text()) == tasks
    (task,) = tasks
    assert task["data"]["video"] == "/data/local-files/?d=walk.mp4"
    walker, car = task["predictions"][0]["result"]
    assert walker["type"] == "videorectangle" and walker["value"]["labels"] == ["person"]
    assert walker["value"]["framesCount"] == 12 and walker["value"]["duration"] == pytest.approx(12 / 25)
    sequence = walker["value"]["sequence"]
    # 1-based source frames; the object leaves after frame 4 (enabled: false there) and is back at the correction.
    assert [(k["frame"], k["enabled"]) for k in sequence] == [(1, True), (3, True), (5, False), (9, True), (11, True)]
    assert sequence[0] == {"frame": 1, "x": 15.625, "y": 25.0, "width": 31.25, "height": 62.5, "rotation": 0,
                           "enabled": True, "time": 0.04}
    assert sequence[2]["x"] == 0.0 and sequence[2]["width"] == 25.0  # clipped to the image
    # The car is seen once (its other boxes are NaN or off the image) and its track ends early: enabled false.
    assert [(k["frame"], k["enabled"]) for k in car["value"]["sequence"]] == [(5, False)]


def smooth_track(n: int = 60) -> TrackResult:
    t = np.arange(n, dtype=np.float64)
    boxes = np.stack([100 + 80 * np.sin(t / 9), 60 + 0.5 * t, 40 + 5 * np.cos(t / 5), 30 + 0 * t], axis=1)
    flagged = np.zeros(n, bool)
    flagged[30:34] = True
    outside = np.zeros(n, bool)
    outside[40:45] = True
    flagged[40:45] = True
    keyframe = np.zeros(n, bool)
    keyframe[[0, 45]] = True
    return TrackResult(
        track_id=3, label="object", frame_indices=np.arange(n), boxes_xywh=boxes, confidence=np.full(n, 0.8),
        log_likelihood=np.zeros(n), accepted=~flagged, flagged=flagged,
        reasons=tuple("check" if f else "" for f in flagged), keyframe=keyframe, outside=outside,
        seconds=np.zeros(n),
    )


@pytest.mark.parametrize("max_error_px", [0.5, 2.0, 10.0])
def test_labelstudio_interpolation_reproduces_the_track(max_error_px):
    video = VideoInfo(path="v.mp4", name="v", width=320, height=240, fps=30.0, frame_count=60)
    track = smooth_track()
    (result,) = build_labelstudio_tasks(video, [track], max_error_px=max_error_px)[0]["predictions"][0]["result"]
    sequence = result["value"]["sequence"]
    assert len(sequence) < len(track)
    for i, frame in enumerate(track.frame_indices):
        box, shown = interpolate_labelstudio(sequence, int(frame) + 1)
        assert shown == (not track.outside[i]), f"frame {frame}"
        if shown and not track.flagged[i]:
            pixels = np.array(box) * np.array([320, 240, 320, 240]) / 100
            assert np.abs(pixels - track.boxes_xywh[i]).max() <= max_error_px + 1e-6, f"frame {frame}"


# --------------------------------------------------------------------------- YOLO


def test_yolo_golden_and_layout(tmp_path):
    written = write_yolo(tmp_path / "yolo", VIDEO, make_tracks(), frames=FRAMES)
    names = [p.relative_to(tmp_path / "yolo").as_posix() for p in written]
    assert names == ["data.yaml", "frames.txt"] + [f"labels/{f:06d}.txt" for f in FRAMES]
    for name in names:
        check_golden(tmp_path / "yolo" / name, f"yolo/{name}")
    data = yaml.safe_load((tmp_path / "yolo" / "data.yaml").read_text())
    assert data == {"train": "frames.txt", "val": "frames.txt", "nc": 2, "names": {0: "person", 1: "car"}}
    assert (tmp_path / "yolo" / "labels" / "000006.txt").read_text() == ""  # absent walker, NaN car
    # Label stems are the COCO exporter's image names without folder and extension.
    from annotator.exports import build_coco

    coco_stems = [Path(image["file_name"]).stem for image in build_coco(VIDEO, make_tracks())["images"]]
    assert coco_stems == [Path(n).stem for n in names[2:]]
    for line in (tmp_path / "yolo" / "labels" / "000004.txt").read_text().splitlines():
        cls, *values = line.split()
        assert cls in ("0", "1") and all(0.0 <= float(v) <= 1.0 for v in values)


def test_yolo_labels_of_an_image_folder_are_named_after_its_images(tmp_path):
    import dataclasses

    files = tuple(f"Seq/img/{k + 1}.jpg" for k in range(12))  # unpadded names, numbered from 1
    folder = dataclasses.replace(VIDEO, frame_files=files)
    written = write_yolo(tmp_path / "yolo", folder, make_tracks(), frames=FRAMES)
    assert [p.name for p in written[2:]] == [f"{f + 1}.txt" for f in FRAMES]
    assert (tmp_path / "yolo" / "frames.txt").read_text().splitlines() == [f"./images/{f + 1}.jpg" for f in FRAMES]
    assert '("Seq/img", as named in frames.txt) into images/' in (tmp_path / "yolo" / "data.yaml").read_text()
    # The labels are the video's, frame for frame, under the image's name.
    for f in FRAMES:
        assert (tmp_path / "yolo" / "labels" / f"{f + 1}.txt").read_text() == \
            (GOLDEN / "yolo" / "labels" / f"{f:06d}.txt").read_text()
    # Two images with one stem cannot both have a label file: the index names, as for a video.
    clash = dataclasses.replace(VIDEO, frame_files=("Seq/a.jpg", files[1], "Seq/a.png", *files[3:]))
    written = write_yolo(tmp_path / "clash", clash, make_tracks(), frames=FRAMES)
    assert [p.name for p in written[2:]] == [f"{f:06d}.txt" for f in FRAMES]
    assert "named by frame index" in (tmp_path / "clash" / "data.yaml").read_text()


# --------------------------------------------------------------------------- atomic writes


WRITERS = {
    "cvat": lambda out: write_cvat_xml(out / "cvat.xml", VIDEO, make_tracks(), frames=FRAMES),
    "mot": lambda out: write_mot(out / "mot", VIDEO, make_tracks(), frames=FRAMES),
    "labelstudio": lambda out: write_labelstudio(out / "labelstudio.json", VIDEO, make_tracks(), frames=FRAMES),
    "yolo": lambda out: write_yolo(out / "yolo", VIDEO, make_tracks(), frames=FRAMES),
}
TARGET = {"cvat": "cvat.xml", "mot": "mot/gt/gt.txt", "labelstudio": "labelstudio.json", "yolo": "yolo/data.yaml"}


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_writers_never_leave_a_partial_file(tmp_path, monkeypatch, fmt):
    target = tmp_path / TARGET[fmt]
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("previous\n")
    real_fsync = atomic.os.fsync

    def failing_fsync(fd):  # the first file's data is written; only making it durable fails
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(atomic.os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="simulated"):
        WRITERS[fmt](tmp_path)
    assert target.read_text() == "previous\n" and leftovers(tmp_path) == []
    monkeypatch.setattr(atomic.os, "fsync", real_fsync)
    WRITERS[fmt](tmp_path)
    assert target.read_text() != "previous\n" and leftovers(tmp_path) == []

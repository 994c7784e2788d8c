"""Exporters: golden files, readers that must load them (pycocotools), id offsets and merging, atomicity.

Golden files live in ``tests/golden/exports/`` and are compared as text. After
an intended format change, regenerate them with::

    UPDATE_GOLDEN=1 pytest tests/annotator/exports/test_exports.py

and review the diff before committing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _export_cases import VIDEO, check_golden, make_tracks

from annotator.exports import (
    build_coco,
    merge_coco,
    read_flags_csv,
    save_coco,
    write_coco,
    write_flags_csv,
    write_otb_results,
)
from annotator.exports import flags as flags_module
from annotator.otb_format import read_otb_boxes
from annotator.tracks import TrackRecorder, TrackResult, VideoInfo

# --------------------------------------------------------------------------- OTB


def test_otb_single_track_golden(tmp_path):
    walker = make_tracks()[0]
    written = write_otb_results(tmp_path, "walk", [walker])
    assert written == [tmp_path / "walk.txt", tmp_path / "times" / "walk_time.txt"]
    check_golden(tmp_path / "walk.txt", "otb/walk.txt")
    check_golden(tmp_path / "times" / "walk_time.txt", "otb/times/walk_time.txt")
    # One row per processed frame, absent frame included; 1-based on disk, 0-based after reading.
    boxes = read_otb_boxes(tmp_path / "walk.txt")
    np.testing.assert_allclose(boxes, walker.boxes_xywh)
    assert (tmp_path / "walk.txt").read_text().splitlines()[0] == "11.000,13.000,20.000,30.000"


def test_otb_multi_target_names(tmp_path):
    written = write_otb_results(tmp_path, "walk", make_tracks())
    names = sorted(p.relative_to(tmp_path).as_posix() for p in written)
    assert names == ["times/walk.1_time.txt", "times/walk.2_time.txt", "walk.1.txt", "walk.2.txt"]
    check_golden(tmp_path / "walk.2.txt", "otb/walk.2.txt")
    assert (tmp_path / "walk.2.txt").read_text().splitlines()[1] == "nan,nan,nan,nan"


# --------------------------------------------------------------------------- COCO


def test_coco_golden_and_pycocotools(tmp_path):
    from pycocotools.coco import COCO

    path = tmp_path / "annotations.json"
    dataset = write_coco(path, VIDEO, make_tracks())
    check_golden(path, "annotations.json")
    assert json.loads(path.read_text()) == dataset

    coco = COCO(str(path))
    images = coco.loadImgs(sorted(coco.getImgIds()))
    assert [im["frame_id"] for im in images] == list(range(len(images)))  # contiguous, 0-based
    assert [im["frame_index"] for im in images] == [0, 2, 4, 6, 8, 10]
    assert images[1]["file_name"] == "walk/000002.jpg"
    assert [c["name"] for c in coco.loadCats(coco.getCatIds())] == ["person", "car"]
    by_frame = {im["frame_index"]: im["id"] for im in images}

    # Frame 6: the walker is outside and the car lost (NaN): no annotations, the image stays.
    assert coco.getAnnIds(imgIds=[by_frame[6]]) == []
    # Frame 4: the walker's box is clipped at the left edge and the bottom.
    (ann,) = coco.loadAnns(coco.getAnnIds(imgIds=[by_frame[4]], catIds=coco.getCatIds(catNms=["person"])))
    assert ann["bbox"] == [0.0, 30.0, 16.0, 18.0] and ann["area"] == 288.0
    assert ann["track_id"] == ann["instance_id"] == ann["attributes"]["track_id"] == 1
    assert ann["attributes"]["needs_review"] is True and ann["attributes"]["outside"] is False
    assert ann["score"] == ann["attributes"]["score"] == 0.42
    # Frame 8: the car lies wholly right of the 64-pixel-wide image: omitted; the corrected walker is a keyframe.
    (ann,) = coco.loadAnns(coco.getAnnIds(imgIds=[by_frame[8]]))
    assert ann["attributes"]["keyframe"] is True and ann["category_id"] == 1
    assert dataset["videos"] == [{"id": 1, "name": "walk", "width": 64, "height": 48, "fps": 25.0, "length": 12}]
    assert dataset["tracks"] == [{"id": 1, "category_id": 1, "video_id": 1}, {"id": 2, "category_id": 2, "video_id": 1}]
    for ann in dataset["annotations"]:
        x, y, w, h = ann["bbox"]
        assert 0 <= x and 0 <= y and x + w <= 64 and y + h <= 48 and w > 0 and h > 0


def test_coco_ids_are_offsettable():
    dataset = build_coco(
        VIDEO, make_tracks(), video_id=3, first_image_id=100, first_annotation_id=500, first_track_id=7
    )
    assert [im["id"] for im in dataset["images"]] == list(range(100, 106))
    assert {im["video_id"] for im in dataset["images"]} == {3}
    assert [a["id"] for a in dataset["annotations"]] == list(range(500, 500 + len(dataset["annotations"])))
    assert [t["id"] for t in dataset["tracks"]] == [7, 8]
    assert {a["track_id"] for a in dataset["annotations"]} == {7, 8}
    assert all(100 <= a["image_id"] < 106 for a in dataset["annotations"])


def test_coco_without_tracks_and_fixed_categories():
    empty = build_coco(VIDEO, [])
    assert empty["categories"] == [{"id": 1, "name": "object", "supercategory": "object"}]
    assert empty["images"] == [] and empty["annotations"] == []
    fixed = build_coco(VIDEO, make_tracks(), categories=["car", "person", "dog"])
    assert [(c["id"], c["name"]) for c in fixed["categories"]] == [(1, "car"), (2, "person"), (3, "dog")]
    assert fixed["tracks"][0]["category_id"] == 2
    with pytest.raises(ValueError, match="not among categories"):
        build_coco(VIDEO, make_tracks(), categories=["car"])


def test_coco_rejects_tracks_from_another_video():
    short = VideoInfo(path="x.mp4", name="x", width=64, height=48, fps=25.0, frame_count=5)
    with pytest.raises(ValueError, match="frame index 10 but 'x' has 5 frames"):
        build_coco(short, make_tracks())


def test_merge_gives_unique_ids_and_consistent_references(tmp_path):
    from pycocotools.coco import COCO

    other_video = VideoInfo(path="run.mp4", name="run", width=64, height=48, fps=30.0, frame_count=12)
    other = make_tracks()[1:]  # only a car: its category must map onto the merged "car"
    parts = [build_coco(VIDEO, make_tracks()), build_coco(other_video, other)]  # both number from 1
    merged = merge_coco(parts)
    for key in ("videos", "images", "tracks", "annotations"):
        ids = [item["id"] for item in merged[key]]
        assert ids == list(range(1, len(ids) + 1)), key
    assert len(merged["images"]) == 6 + 3 and len(merged["tracks"]) == 3
    assert [c["name"] for c in merged["categories"]] == ["person", "car"]
    images = {im["id"]: im for im in merged["images"]}
    tracks = {t["id"]: t for t in merged["tracks"]}
    for ann in merged["annotations"]:
        image = images[ann["image_id"]]
        assert ann["video_id"] == image["video_id"] == tracks[ann["track_id"]]["video_id"]
        assert ann["category_id"] == tracks[ann["track_id"]]["category_id"]
        assert ann["instance_id"] == ann["attributes"]["track_id"] == ann["track_id"]
    run_annotations = [a for a in merged["annotations"] if a["video_id"] == 2]
    assert {a["category_id"] for a in run_annotations} == {2} and {a["track_id"] for a in run_annotations} == {3}
    path = tmp_path / "merged.json"
    save_coco(path, merged)
    assert len(COCO(str(path)).getAnnIds()) == len(merged["annotations"])

    with pytest.raises(ValueError, match="unique names"):
        merge_coco([parts[0], parts[0]])


# --------------------------------------------------------------------------- flags CSV


def test_flags_golden_and_round_trip(tmp_path):
    tracks = make_tracks()
    path = tmp_path / "flags.csv"
    write_flags_csv(path, tracks)
    check_golden(path, "flags.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == "frame,track,confidence,log_likelihood,accepted,flagged,reason"
    assert '"outside, lost"' in lines[5]  # a comma in a reason is quoted

    table = read_flags_csv(path)
    assert len(table) == 9
    order = list(zip(table.frame.tolist(), table.track.tolist()))
    assert order == sorted(order)  # by frame, then track
    for track in tracks:
        rows = table.for_track(track.track_id)
        assert rows.frame.tolist() == track.frame_indices.tolist()
        np.testing.assert_allclose(rows.confidence, track.confidence, atol=1e-6)
        np.testing.assert_allclose(rows.log_likelihood, track.log_likelihood, rtol=1e-5)  # inf and nan survive
        assert rows.accepted.tolist() == track.accepted.tolist()
        assert rows.flagged.tolist() == track.flagged.tolist()
        assert rows.reason == track.reasons


@pytest.mark.parametrize(
    "text, needle",
    [
        ("frame,track\n1,2\n", "expected the header"),
        ("frame,track,confidence,log_likelihood,accepted,flagged,reason\n1,1,x,0,1,0,\n", ":2:"),
    ],
)
def test_flags_reader_errors_name_file_and_line(tmp_path, text, needle):
    path = tmp_path / "flags.csv"
    path.write_text(text)
    with pytest.raises(flags_module.FlagsFormatError, match=needle) as caught:
        read_flags_csv(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


# --------------------------------------------------------------------------- atomicity


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_flags_writer_failing_midway_leaves_no_file(tmp_path, monkeypatch):
    real_rows = flags_module._rows

    def failing_rows(*args):
        for n, row in enumerate(real_rows(*args)):
            if n == 3:
                raise OSError("disk full (simulated)")
            yield row

    monkeypatch.setattr(flags_module, "_rows", failing_rows)
    path = tmp_path / "flags.csv"
    with pytest.raises(OSError, match="simulated"):
        write_flags_csv(path, make_tracks())
    assert not path.exists() and leftovers(tmp_path) == []

    path.write_text("previous\n")
    with pytest.raises(OSError):
        write_flags_csv(path, make_tracks())
    assert path.read_text() == "previous\n" and leftovers(tmp_path) == []


def test_coco_writer_refuses_nan_and_leaves_no_file(tmp_path):
    dataset = build_coco(VIDEO, make_tracks())
    dataset["annotations"][0]["score"] = float("nan")  # not valid JSON
    path = tmp_path / "annotations.json"
    with pytest.raises(ValueError):
        save_coco(path, dataset)
    assert not path.exists() and leftovers(tmp_path) == []


# --------------------------------------------------------------------------- records


def test_recorder_builds_the_same_track():
    walker = make_tracks()[0]
    recorder = TrackRecorder(track_id=1, label="person")
    for i in range(len(walker)):
        recorder.append(
            walker.frame_indices[i], walker.boxes_xywh[i], confidence=walker.confidence[i],
            log_likelihood=walker.log_likelihood[i], accepted=walker.accepted[i], seconds=walker.seconds[i],
            keyframe=walker.keyframe[i], outside=walker.outside[i],
            flagged=walker.outside[i], reason="outside, lost" if walker.outside[i] else "",
        )  # fmt: skip
    recorder.set_flag(2, True, "rejected")  # decided later, by position, as OnlineFlagger does
    built = recorder.to_result()
    for key in ("frame_indices", "boxes_xywh", "confidence", "log_likelihood", "accepted", "flagged",
                "keyframe", "outside", "seconds", "occluded"):  # fmt: skip
        np.testing.assert_array_equal(getattr(built, key), getattr(walker, key), err_msg=key)
    assert built.reasons == walker.reasons
    kept = built.up_to(5)  # e.g. a DecodeError's last good frame
    assert kept.frame_indices.tolist() == [0, 2, 4] and len(TrackRecorder().to_result()) == 0


def _recorded(n: int = 6) -> TrackRecorder:
    """A recorder of ``n`` rows whose signals start on row 2 and whose failures and flags come later."""
    recorder = TrackRecorder(track_id=3, label="car")
    for i in range(n):
        recorder.append(10 + i, [i, 2.5 * i, 30, 20], confidence=0.5, log_likelihood=-i / 3, accepted=i % 2 == 0,
                        seconds=0.01 * i, keyframe=i == 0, signals={"ncc_first": i / 7} if i >= 2 else None)
    for i in range(n - 2):
        recorder.set_failure(i, i / 10)
    recorder.set_flag(1, True, "doubt:guide")
    return recorder


def test_recorder_columns_pad_late_signals_and_take_later_failures():
    track = _recorded().to_result()
    np.testing.assert_array_equal(track.signals["ncc_first"], [np.nan, np.nan, 2 / 7, 3 / 7, 4 / 7, 5 / 7])
    np.testing.assert_array_equal(track.signals["p_fail"], [0.0, 0.1, 0.2, 0.3, np.nan, np.nan])
    np.testing.assert_array_equal(track.confidence, [1.0, 0.9, 0.8, 0.7, 0.5, 0.5])
    assert track.flagged.tolist() == [False, True, False, False, False, False]
    assert track.reasons[1] == "doubt:guide" and track.scoring[:2] == ("init", "subspace")
    assert track.frame_indices.dtype == np.int64 and track.boxes_xywh.shape == (6, 4)
    assert track.boxes_xywh[3].tolist() == [3.0, 7.5, 30.0, 20.0]


def test_recorder_pickles_as_checkpoints_keep_it_and_reads_rows_of_older_checkpoints():
    import pickle

    recorder = _recorded()
    assert pickle.loads(pickle.dumps(recorder)).to_result().equals(recorder.to_result())
    # A checkpoint written before the columns held one tuple per row and lists of floats.
    track = recorder.to_result()
    old = TrackRecorder.__new__(TrackRecorder)
    old.__dict__.update(track_id=3, label="car", _signals={k: v.tolist() for k, v in track.signals.items()}, _rows=[
        (int(track.frame_indices[i]), track.boxes_xywh[i], float(track.confidence[i]), float(track.log_likelihood[i]),
         bool(track.accepted[i]), bool(track.flagged[i]), track.reasons[i], bool(track.keyframe[i]),
         bool(track.outside[i]), float(track.seconds[i]), bool(track.occluded[i]), track.scoring[i],
         track.keyframe_source[i]) for i in range(len(track))])
    resumed = pickle.loads(pickle.dumps(old))
    assert resumed.to_result().equals(track)
    resumed.append(99, [1, 1, 5, 5], confidence=1.0, log_likelihood=0.0, accepted=True, seconds=0.0,
                   signals={"ncc_first": 0.5})
    assert len(resumed) == 7 and np.isnan(resumed.to_result().signals["p_fail"][-1])


def _walker_fields(**changes):
    walker = make_tracks()[0]
    fields = {k: getattr(walker, k) for k in walker.__dataclass_fields__}
    fields.update(changes)
    return fields


@pytest.mark.parametrize(
    "changes, needle",
    [
        ({"boxes_xywh": np.zeros((5, 4))}, "boxes_xywh must have shape (6, 4)"),
        ({"frame_indices": np.array([0, 2, 2, 6, 8, 10])}, "strictly increasing"),
        ({"confidence": np.array([1.0, 0.9, 1.5, 0.1, 1.0, 0.5])}, "confidence must lie in [0, 1]"),
        ({"reasons": ("", "", "", "outside, lost", "", "")}, "needs a reason"),
        ({"flagged": np.array([False, False, True, False, False, False]), "reasons": ("", "", "rejected", "", "", "")},
         "outside (object absent) but not flagged"),
        ({"track_id": 0}, "track_id must be an integer >= 1"),
        ({"accepted": np.ones(6)}, "accepted must be a (6,) bool array"),
    ],
)
def test_track_result_validation(changes, needle):
    with pytest.raises(ValueError) as caught:
        TrackResult(**_walker_fields(**changes))
    assert needle in str(caught.value) and "\n" not in str(caught.value)


def test_track_result_is_read_only():
    walker = make_tracks()[0]
    with pytest.raises(ValueError):
        walker.boxes_xywh[0, 0] = 5.0


def test_coco_file_name_of_an_image_folder_is_the_real_image_path(tmp_path):
    from pycocotools.coco import COCO

    files = tuple(f"walk/img/{k + 1:04d}.jpg" for k in range(VIDEO.frame_count))
    video = VideoInfo(**{**VIDEO.__dict__, "frame_files": files})
    path = tmp_path / "annotations.json"
    dataset = write_coco(path, video, make_tracks())
    assert [im["file_name"] for im in dataset["images"]] == [files[f] for f in (0, 2, 4, 6, 8, 10)]
    coco = COCO(str(path))
    assert coco.loadImgs(coco.getImgIds())[1]["file_name"] == "walk/img/0003.jpg"
    # Everything else is as for a video.
    plain = write_coco(tmp_path / "video.json", VIDEO, make_tracks())
    assert {**dataset, "images": []} == {**plain, "images": []}
    assert [{**im, "file_name": ""} for im in dataset["images"]] == [{**im, "file_name": ""} for im in plain["images"]]


def test_video_info_frame_files_must_cover_every_frame():
    with pytest.raises(ValueError, match="frame_files"):
        VideoInfo(**{**VIDEO.__dict__, "frame_files": ("a.jpg",)})

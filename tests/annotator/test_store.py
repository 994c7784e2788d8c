"""The track store: exact round trips, exports as views of it, and what a damaged or foreign store gets.

The exports' golden files are those of ``tests/annotator/exports/test_exports.py``: written from
a store read back from disk, every export must come out byte for byte the same.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import typer
from _export_cases import GOLDEN, VIDEO, make_tracks
from _runs import CONFIG, GT, csv_row, snapshot, write_frames
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from annotator.commands.retrack import retrack_command
from annotator.errors import EXIT_INPUT
from annotator.exports import FILE_EXPORTS, write_exports
from annotator.review import load_run
from annotator.run import annotate
from annotator.track_store import SCHEMA_VERSION, STORE_NAME, RunStore, StoreError, read_store, write_store
from annotator.tracks import Target, TrackResult, VideoInfo
from sptpt_dev.synthetic import make_clip

# --------------------------------------------------------------------------- round trips

_floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
_text = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\n\r\0"), max_size=12)


@st.composite
def tracks(draw) -> list[TrackResult]:
    n = draw(st.integers(0, 30))
    frames = np.cumsum(draw(st.lists(st.integers(1, 4), min_size=n, max_size=n))).astype(np.int64)
    out = []
    for tid in draw(st.lists(st.integers(1, 99), min_size=1, max_size=3, unique=True)):
        boxes = np.array(draw(st.lists(st.tuples(*[st.floats(-1e6, 1e6, width=64)] * 2,
                                                  *[st.floats(0, 1e6, width=64)] * 2),
                                       min_size=n, max_size=n)), dtype=np.float64).reshape(n, 4)
        absent = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool)
        boxes[absent] = np.nan  # NaN boxes for frames without an estimate
        keyframe = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool)
        flagged = absent | np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool)
        reasons = tuple((draw(_text) or "x") if f else "" for f in flagged)
        sources = tuple((draw(_text) or "given") if k else "" for k in keyframe)
        signals = {name: np.array(draw(st.lists(_floats, min_size=n, max_size=n)), dtype=np.float64)
                   for name in draw(st.lists(st.sampled_from(["p_fail", "fb_error", "spread"]), unique=True))}
        out.append(TrackResult(
            track_id=tid, label=draw(_text.filter(str.strip)) if draw(st.booleans()) else "object",
            frame_indices=frames, boxes_xywh=boxes,
            confidence=np.array(draw(st.lists(st.floats(0, 1), min_size=n, max_size=n)), dtype=np.float64),
            log_likelihood=np.array(draw(st.lists(_floats, min_size=n, max_size=n)), dtype=np.float64),
            accepted=np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool),
            flagged=flagged, reasons=reasons, keyframe=keyframe, keyframe_source=sources, outside=absent,
            occluded=np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool),
            scoring=tuple(draw(st.lists(st.sampled_from(["init", "bootstrap", "subspace", "none"]),
                                        min_size=n, max_size=n))),
            seconds=np.array(draw(st.lists(st.floats(0, 1e3), min_size=n, max_size=n)), dtype=np.float64),
            signals=signals,
        ))
    return out


@settings(max_examples=40, deadline=None)
@given(tracks())
def test_round_trip_is_exact(tmp_path_factory, drawn):
    path = tmp_path_factory.mktemp("store") / STORE_NAME
    store = RunStore(video=VIDEO, start=0, stop=200, step=1, tracks=drawn)
    write_store(path, store)
    back = read_store(path)
    assert back.video == VIDEO and (back.start, back.stop, back.step) == (0, 200, 1)
    assert len(back.tracks) == len(drawn)
    for a, b in zip(drawn, back.tracks):
        assert a.equals(b)
        # float64 bit for bit, NaN payloads included
        assert a.boxes_xywh.tobytes() == b.boxes_xywh.tobytes()
        assert a.log_likelihood.tobytes() == b.log_likelihood.tobytes()


def test_equals_sees_a_one_ulp_change():
    track = make_tracks()[0]
    boxes = track.boxes_xywh.copy()
    boxes[1, 0] = np.nextafter(boxes[1, 0], np.inf)
    moved = TrackResult(**{**{k: getattr(track, k) for k in track.__dataclass_fields__}, "boxes_xywh": boxes})
    assert track.equals(track) and not track.equals(moved)


def test_the_store_is_readable_with_numpy_alone(tmp_path):
    write_store(tmp_path / STORE_NAME, RunStore(video=VIDEO, start=0, stop=12, step=2, tracks=make_tracks()))
    with np.load(tmp_path / STORE_NAME, allow_pickle=False) as data:
        header = json.loads(str(data["header"]))
        assert header["schema_version"] == SCHEMA_VERSION and header["range"] == {"start": 0, "stop": 12, "step": 2}
        assert data["t1.frame_index"].tolist() == [0, 2, 4, 6, 8, 10]
        assert data["t1.reason"].tolist()[3] == "outside, lost"


# --------------------------------------------------------------------------- exports are views of the store

@pytest.mark.parametrize("name, n_tracks, golden", [
    ("otb", 1, ["walk.txt", "times/walk_time.txt"]), ("otb", 2, ["walk.2.txt"]),
    ("coco", 2, ["annotations.json"]), ("flags", 2, ["flags.csv"])])
def test_every_export_from_the_store_equals_its_golden_file(tmp_path, name, n_tracks, golden):
    store = RunStore(video=VIDEO, start=0, stop=12, step=2, tracks=make_tracks()[:n_tracks])
    write_store(tmp_path / STORE_NAME, store)
    (tmp_path / "out").mkdir()
    written = write_exports(tmp_path / "out", read_store(tmp_path / STORE_NAME), [name])
    assert set(written) == {name}
    for rel in golden:
        expected = GOLDEN / ("otb/" + rel if name == "otb" else rel)
        assert (tmp_path / "out" / rel).read_text(encoding="utf-8") == expected.read_text(encoding="utf-8"), rel


def test_every_file_format_is_a_view():
    from annotator.output_files import ALL_FORMATS

    assert set(FILE_EXPORTS) == set(ALL_FORMATS) - {"overlay", "report"}


# --------------------------------------------------------------------------- runs read the store, never an export

@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("storerun")
    frames = write_frames(root / "seq", 20)
    annotate(frames, [Target(tuple(GT[0]), 1)], CONFIG, out_dir=root / "out", show_progress=False,
             formats=("otb", "coco", "flags", "report"))
    return root / "out"


@pytest.fixture()
def out(run_dir, tmp_path):
    copy = tmp_path / "out"
    shutil.copytree(run_dir, copy)
    return copy


def _retrack(out: Path, fix: Path):
    app = typer.Typer()
    app.command()(retrack_command)
    return CliRunner().invoke(app, [str(out), "--corrections", str(fix), "--quiet"])


def test_the_store_is_written_whatever_the_formats(tmp_path):
    frames = write_frames(tmp_path / "seq", 6)
    annotate(frames, [Target(tuple(GT[0]), 1)], CONFIG, out_dir=tmp_path / "out", show_progress=False,
             formats=("otb",))
    store = read_store(tmp_path / "out" / STORE_NAME)
    assert len(store.frame_indices) == 6 and store.tracks[0].scoring[0] == "init"
    assert store.tracks[0].keyframe_source[0] == "given"
    assert "store" in json.loads((tmp_path / "out" / "run.json").read_text())["outputs"]


def test_the_store_holds_what_the_exports_hold_at_full_precision(run_dir):
    from annotator.exports import read_flags_csv
    from annotator.otb_format import read_otb_boxes

    track = load_run(run_dir).tracks[0]
    np.testing.assert_allclose(track.boxes_xywh, read_otb_boxes(run_dir / "seq.txt"), atol=5e-4)
    np.testing.assert_allclose(track.confidence, read_flags_csv(run_dir / "flags.csv").confidence, atol=5e-7)


def test_retrack_with_every_export_deleted_writes_them_again(out):
    for name in ("seq.txt", "times/seq_time.txt", "annotations.json", "flags.csv", "report.html"):
        (out / name).unlink()
    (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
    result = _retrack(out, out.parent / "fix.csv")
    assert result.exit_code == 0, result.output
    for name in ("seq.txt", "times/seq_time.txt", "annotations.json", "flags.csv", "report.html", STORE_NAME):
        assert (out / name).is_file(), name
    track = read_store(out / STORE_NAME).tracks[0]
    position = 12
    assert track.keyframe[position] and track.keyframe_source[position].endswith("fix.csv:1")
    np.testing.assert_array_equal(track.boxes_xywh[position], np.round(GT[12], 3))


def _bump_version(path: Path) -> None:
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    header = json.loads(str(arrays["header"]))
    header["schema_version"] = 99
    arrays["header"] = np.asarray(json.dumps(header))
    with open(path, "wb") as handle:
        np.savez_compressed(handle, **arrays)


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _foreign(path: Path) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("header.npy", b"not numpy")


@pytest.mark.parametrize("damage, fragment", [(_bump_version, "schema version 99"), (_truncate, "truncated or damaged"),
                                              (_foreign, STORE_NAME), (Path.unlink, "holds no tracks.npz")])
def test_a_bad_store_is_one_line_exit_3_and_nothing_changes(out, damage, fragment):
    damage(out / STORE_NAME)
    before = snapshot(out)
    (out.parent / "fix.csv").write_text(csv_row(12, GT[12]))
    result = _retrack(out, out.parent / "fix.csv")
    assert result.exit_code == EXIT_INPUT, result.output
    message = result.output.strip()
    assert "\n" not in message and fragment in message and STORE_NAME in message, message
    assert "--force" in message
    assert snapshot(out) == before


def test_read_store_errors_name_the_file(tmp_path):
    with pytest.raises(StoreError, match=str(tmp_path / "missing.npz")):
        read_store(tmp_path / "missing.npz")
    (tmp_path / "plain.npz").write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(StoreError, match="plain.npz"):
        read_store(tmp_path / "plain.npz")


def test_store_range_is_validated():
    with pytest.raises(ValueError, match="step >= 1"):
        RunStore(video=VIDEO, start=0, stop=4, step=0, tracks=())
    track = make_tracks()[0]
    with pytest.raises(ValueError, match="unique"):
        RunStore(video=VideoInfo(path="a", name="a", width=4, height=4, fps=1.0, frame_count=1), start=0, stop=1,
                 step=1, tracks=(track, track))


# --------------------------------------------------------------------------- image folders: real image names


def test_frame_files_round_trip_and_older_stores_read_without_them(tmp_path):
    files = tuple(f"walk/img/{k + 1:04d}.jpg" for k in range(VIDEO.frame_count))
    video = VideoInfo(**{**VIDEO.__dict__, "frame_files": files})
    path = write_store(tmp_path / STORE_NAME, RunStore(video=video, start=0, stop=12, step=2, tracks=make_tracks()))
    assert read_store(path).video == video and read_store(path).video.frame_files == files
    # A store written before frame_files existed: its header has no such key.
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    header = json.loads(str(arrays["header"]))
    del header["video"]["frame_files"]
    arrays["header"] = np.array(json.dumps(header))
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    assert read_store(old).video == VIDEO and read_store(old).video.frame_files is None


def test_coco_of_an_otb_folder_names_the_real_images(tmp_path):
    from pycocotools.coco import COCO

    frames = write_frames(tmp_path / "img", 5)
    otb = tmp_path / "Coke"
    otb.mkdir()
    frames.rename(otb / "img")
    annotate(otb, [Target(tuple(make_clip(5, size=(96, 72), object_size=(24, 20)).boxes_xywh[0]), 1)], CONFIG,
             out_dir=tmp_path / "out", step=2, show_progress=False)
    coco = COCO(str(tmp_path / "out" / "annotations.json"))
    images = coco.loadImgs(sorted(coco.getImgIds()))
    assert [im["file_name"] for im in images] == ["Coke/img/0000.png", "Coke/img/0002.png", "Coke/img/0004.png"]
    assert all((tmp_path / im["file_name"]).is_file() for im in images)  # image root: the sequence's parent
    assert read_store(tmp_path / "out" / STORE_NAME).video.frame_files[1] == "Coke/img/0001.png"

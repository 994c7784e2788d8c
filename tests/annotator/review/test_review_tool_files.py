"""Real runs' review files, read by the consuming tools' own rules, not by our reader (issue #68).

* ``cvat.xml``: CVAT's import rule replayed (``_cvat_import.py``, written from CVAT's code) must show every
  box of ``tracks.npz`` within 0.5 px, on the README's sample and on a batch item with three tracks.
* An untouched review in FiftyOne (its real export of the sample's ``cvat.xml``, which rounds to whole pixels)
  is no correction: ``retrack`` changes no file.
* ``mot/gt/gt.txt``: motmetrics, as MOTChallenge's evaluation reads it, gets ``tracks.npz``'s boxes.
* ``annotations.json``: pycocotools' ``COCO`` gets each frame's box, clipped to the image, 0-based.
* ``yolo/``: Ultralytics' rule (``img2label_paths``: the image path with its last ``/images/`` made
  ``/labels/`` and its extension ``.txt``; rows ``class cx cy w h`` normalised) finds each listed frame's
  label file and gets its boxes.
* ``labelstudio.json``: Label Studio's interpolation (``VideoRectangleRegion``, replayed in
  ``_labelstudio_import.interpolate_labelstudio``) shows each unflagged box within the exporter's 2 px.
"""

from __future__ import annotations

import hashlib
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from _cvat_import import cvat_keyframe_count, cvat_worst_error
from _labelstudio_import import interpolate_labelstudio
from _paths import DATA as TEST_DATA
from _paths import ROOT
from _reader_env import run_check
from _runs import FAST, box_text, write_clip
from typer.testing import CliRunner

from annotator.cli import _with_default_command, app
from annotator.exports.cvat import MAX_ERROR_PX
from annotator.track_store import STORE_NAME, read_store
from sptpt.boxes import clip_xywh

DATA = TEST_DATA / "review_tools"
FORMATS = "otb,coco,flags,cvat,mot,labelstudio,yolo"


def _run(*args) -> tuple[int, str]:
    result = CliRunner().invoke(app, _with_default_command([str(a) for a in args]))
    return result.exit_code, result.stdout + result.stderr


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sample") / "run"
    box = (ROOT / "samples" / "clip_box.txt").read_text().strip()
    # robust: the run of the README's review round, which loses the object to a look-alike and so has a flagged
    # span (its bounds must be CVAT keyframes); the FiftyOne file below was exported from this run.
    code, output = _run(ROOT / "samples" / "clip.mp4", "--box", box, "--preset", "robust", "--formats", FORMATS,
                        "--no-render", "--out", out, "-q")
    assert code == 0, output
    return out


@pytest.fixture(scope="module")
def batch_item(tmp_path_factory) -> Path:
    """One batch item with three tracks: the synthetic object and two patches of background."""
    root = tmp_path_factory.mktemp("three")
    first = write_clip(root / "three.mp4", 30, seed=3)
    (root / "fast.yaml").write_text(FAST)
    boxes = "|".join([box_text(first), "4,4,20,16", "70,50,20,16"])
    (root / "items.csv").write_text(f'video,boxes,id\nthree.mp4,"{boxes}",three\n')
    code, output = _run("batch", root / "items.csv", "--out", root / "labels", "--config", root / "fast.yaml",
                        "--formats", FORMATS, "--no-render", "--workers", "1", "-q")
    assert code == 0, output
    return root / "labels" / "three"


def _frames(out: Path):
    store = read_store(out / STORE_NAME)
    return store, range(store.start, store.stop, store.step)


@pytest.mark.parametrize("hold_before_outside", [False, True], ids=["cvat-2.x", "cvat-1.x"])
def test_cvat_import_of_the_sample_shows_every_tracked_box(sample_run, hold_before_outside):
    store, frames = _frames(sample_run)
    assert cvat_worst_error(sample_run / "cvat.xml", store.tracks, frames,
                            hold_before_outside=hold_before_outside) <= MAX_ERROR_PX
    (track,) = store.tracks
    assert track.flagged.any(), "the sample has a flagged span: its bounds must be keyframes"
    text = (sample_run / "cvat.xml").read_text()
    spans = np.flatnonzero(np.diff(np.concatenate([[0], track.flagged.astype(int), [0]])))
    for row in (spans[0::2].tolist() + (spans[1::2] - 1).tolist()):
        assert re.search(rf'<box frame="{int(track.frame_indices[row])}"[^>]*keyframe="1"', text), row
    assert cvat_keyframe_count(sample_run / "cvat.xml") < len(track) // 2


def test_cvat_import_of_a_three_track_batch_item_shows_every_tracked_box(batch_item):
    store, frames = _frames(batch_item)
    assert len(store.tracks) == 3
    for hold in (False, True):
        assert cvat_worst_error(batch_item / "cvat.xml", store.tracks, frames, hold_before_outside=hold) \
            <= MAX_ERROR_PX


def _hashes(folder: Path) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_an_untouched_fiftyone_review_of_the_sample_is_no_correction(sample_run, tmp_path):
    """FiftyOne 1.22.1 imported the sample run's cvat.xml and exported it with no edit, rounding every corner to
    a whole pixel (tests/data/review_tools/README.md): nothing is a correction, and no file of the run changes."""
    given = DATA / "fiftyone_sample_untouched.xml"
    keyframes = re.compile(r'<box frame="(\d+)"[^>]*keyframe="1"')
    past_end = ["100"]  # FiftyOne ends each track with an outside box one frame past its last
    ours = keyframes.findall((sample_run / "cvat.xml").read_text())
    assert keyframes.findall(given.read_text()) == ours + past_end, \
        "the sample's keyframes changed: make the FiftyOne file again (tests/data/review_tools/README.md)"
    assert re.search(r'xtl="\d+" ytl="\d+" xbr="\d+" ybr="\d+"', given.read_text())  # FiftyOne's whole pixels
    out = tmp_path / "run"
    shutil.copytree(sample_run, out)
    before = _hashes(out)
    code, output = _run("retrack", out, "--corrections", given)
    assert code == 0, output
    assert "every correction is already applied" in output and "new or changed correction" not in output, output
    assert _hashes(out) == before


@pytest.mark.parametrize("which", ["sample", "batch item"])
def test_motmetrics_reads_gt_txt_as_tracks_npz(sample_run, batch_item, which):
    out = sample_run if which == "sample" else batch_item
    store, frames = _frames(out)
    rows = run_check("motmetrics", path=str(out / "mot" / "gt" / "gt.txt"))["rows"]
    expected = {}
    for track in store.tracks:
        for i, frame in enumerate(track.frame_indices):
            if not track.outside[i] and np.isfinite(track.boxes_xywh[i]).all():
                expected[(frames.index(int(frame)) + 1, track.track_id)] = track.boxes_xywh[i]
    assert sorted((f, t) for f, t, *_ in rows) == sorted(expected)
    for f, t, x, y, w, h, _ in rows:
        np.testing.assert_allclose([x, y, w, h], expected[(f, t)], atol=5e-4)  # written with 3 decimals


def _clipped(store, track, i):
    """The box at row ``i`` as a file that clips to the image holds it, None where it has none."""
    if track.outside[i] or not np.isfinite(track.boxes_xywh[i]).all():
        return None
    return clip_xywh(track.boxes_xywh[i], store.video.width, store.video.height)


def test_pycocotools_reads_the_sample_boxes_as_tracks_npz(sample_run):
    from pycocotools.coco import COCO

    store, frames = _frames(sample_run)
    (track,) = store.tracks
    coco = COCO(str(sample_run / "annotations.json"))
    by_frame = {coco.imgs[a["image_id"]]["frame_index"]: a["bbox"] for a in coco.dataset["annotations"]}
    for i, frame in enumerate(track.frame_indices):
        box = _clipped(store, track, i)
        assert (int(frame) in by_frame) == (box is not None)
        if box is not None:
            np.testing.assert_allclose(by_frame[int(frame)], box, atol=1.001e-3)  # corners at 3 decimals


def test_ultralytics_finds_and_reads_the_sample_yolo_labels(sample_run):
    store, frames = _frames(sample_run)
    (track,) = store.tracks
    folder = sample_run / "yolo"
    images = (folder / "frames.txt").read_text().split()
    assert len(images) == len(frames)
    w, h = store.video.width, store.video.height
    for i, image in enumerate(images):
        path = (folder / image).as_posix()
        label = Path("/labels/".join(path.rsplit("/images/", 1)).rsplit(".", 1)[0] + ".txt")
        rows = [line.split() for line in label.read_text().splitlines()]
        box = _clipped(store, track, i)
        if box is None:
            assert rows == []
            continue
        ((cls, cx, cy, bw, bh),) = rows
        got = [(float(cx) - float(bw) / 2) * w, (float(cy) - float(bh) / 2) * h, float(bw) * w, float(bh) * h]
        assert cls == "0"
        np.testing.assert_allclose(got, box, atol=1e-3)


def test_label_studio_shows_the_sample_unflagged_boxes_within_two_pixels(sample_run):
    import json

    store, frames = _frames(sample_run)
    (track,) = store.tracks
    (task,) = json.loads((sample_run / "labelstudio.json").read_text())
    sequence = task["predictions"][0]["result"][0]["value"]["sequence"]
    scale = np.array([store.video.width, store.video.height] * 2) / 100.0
    for i, frame in enumerate(track.frame_indices):
        box, shown = interpolate_labelstudio(sequence, int(frame) + 1)  # Label Studio's frames are 1-based
        expected = _clipped(store, track, i)
        assert shown == (expected is not None), frame
        if shown and not track.flagged[i]:
            assert np.abs(np.array(box) * scale - expected).max() <= 2.0 + 1e-6, frame

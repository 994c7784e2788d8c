"""Batch manifests: the same items from CSV, JSON Lines and YAML; every bad row named by file, line and field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from annotator.manifest import (
    RESERVED_IDS,
    BatchItem,
    InvalidManifestError,
    ManifestError,
    items_from_otb_root,
    read_manifest,
    safe_item_id,
)
from annotator.pipeline import Target


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def errors_of(path: Path) -> list[ManifestError]:
    with pytest.raises(InvalidManifestError) as info:
        read_manifest(path)
    return info.value.errors


# The same three items in each format: a minimal one, one with two labelled boxes, range and params,
# and one whose id defaults to a duplicate stem.
SAME_ITEMS = {
    "m.csv": (
        "video,box,boxes,label,start,stop,id,params\n"
        "clips/a.mp4,\"10,20,30,40\",,,,,,\n"
        "b.mp4,,\"1,2,3,4|5,6,7,8\",cat|dog,2,9,bee,\"{n_particles: 60, threshold: 0.4}\"\n"
        "other/a.mp4,\"1.5,2.5,3,4\",,,,,,\n"
    ),
    "m.jsonl": (
        '{"video": "clips/a.mp4", "box": "10,20,30,40"}\n'
        "\n"
        '{"video": "b.mp4", "boxes": ["1,2,3,4", [5, 6, 7, 8]], "label": "cat|dog", "start": 2, "stop": 9, '
        '"id": "bee", "params": {"n_particles": 60, "flags": {"threshold": 0.4}}}\n'
        '{"video": "other/a.mp4", "box": [1.5, 2.5, 3, 4]}\n'
    ),
    "m.yaml": (
        "items:\n"
        "  - video: clips/a.mp4\n"
        "    box: \"10,20,30,40\"\n"
        "  - video: b.mp4\n"
        "    boxes:\n"
        "      - {box: \"1,2,3,4\", label: cat}\n"
        "      - {box: [5, 6, 7, 8], label: dog}\n"
        "    start: 2\n"
        "    stop: 9\n"
        "    id: bee\n"
        "    params: {tracker: {n_particles: 60}, threshold: 0.4}\n"
        "  - {video: other/a.mp4, box: [1.5, 2.5, 3, 4]}\n"
    ),
}
EXPECTED_LINES = {"m.csv": [2, 3, 4], "m.jsonl": [1, 3, 4], "m.yaml": [2, 4, 12]}


@pytest.mark.parametrize("name", sorted(SAME_ITEMS))
def test_three_formats_give_the_same_items(tmp_path, name):
    items = read_manifest(write(tmp_path, name, SAME_ITEMS[name]))
    assert [i.id for i in items] == ["a", "bee", "a-2"]
    assert [i.line for i in items] == EXPECTED_LINES[name]
    assert all(i.source == str(tmp_path / name) for i in items)
    a, bee, a2 = items
    assert a.input_path == tmp_path / "clips" / "a.mp4"  # relative to the manifest's folder
    assert a.targets == (Target((10.0, 20.0, 30.0, 40.0), track_id=1, label="object"),)
    assert (a.start, a.stop, a.step, a.params) == (None, None, None, {})
    assert bee.targets == (Target((1.0, 2.0, 3.0, 4.0), 1, "cat"), Target((5.0, 6.0, 7.0, 8.0), 2, "dog"))
    assert (bee.start, bee.stop) == (2, 9)
    assert bee.params == {"tracker": {"n_particles": 60}, "flags": {"threshold": 0.4}}
    assert a2.input_path == tmp_path / "other" / "a.mp4"
    assert a2.targets[0].box_xywh == (1.5, 2.5, 3.0, 4.0)


@pytest.mark.parametrize("name", sorted(SAME_ITEMS))
def test_a_manifest_saved_as_utf16_reads_the_same(tmp_path, name):
    utf8 = read_manifest(write(tmp_path, name, SAME_ITEMS[name]))
    other = tmp_path / "utf16"
    other.mkdir()
    (other / name).write_bytes(SAME_ITEMS[name].replace("\n", "\r\n").encode("utf-16"))
    utf16 = read_manifest(other / name)
    strip = lambda items: [(i.id, i.line, i.targets, i.start, i.stop, i.params) for i in items]  # noqa: E731
    assert strip(utf16) == strip(utf8)


def test_minimal_items_are_the_same_in_every_format(tmp_path):
    csv_items = read_manifest(write(tmp_path, "x.csv", "video,box\na.mp4,\"10,20,30,40\"\n"))
    jsonl_items = read_manifest(write(tmp_path, "x.jsonl", '{"video": "a.mp4", "box": "10,20,30,40"}\n'))
    yaml_items = read_manifest(write(tmp_path, "x.yaml", "- video: a.mp4\n  box: 10,20,30,40\n"))
    strip = lambda items: [(i.id, i.input_path, i.targets, i.params) for i in items]  # noqa: E731
    assert strip(csv_items) == strip(jsonl_items) == strip(yaml_items)


def test_box_origin_1_reads_otb_style_boxes_per_item_or_for_the_batch(tmp_path):
    """An OTB box pasted with box_origin 1 is the 0-based box one pixel up and left; items that say win."""
    for name, text in (("o.csv", "video,box,box_origin\na.mp4,\"11,21,30,40\",1\nb.mp4,\"10,20,30,40\",\n"),
                       ("o.jsonl", '{"video": "a.mp4", "box": "11,21,30,40", "box_origin": 1}\n'
                                   '{"video": "b.mp4", "box": "10,20,30,40"}\n'),
                       ("o.yaml", "- {video: a.mp4, boxes: ['11,21,30,40', [2, 2, 5, 5]], box_origin: 1}\n"
                                  "- {video: b.mp4, box: '10,20,30,40'}\n")):
        items = read_manifest(write(tmp_path, name, text))
        assert items[0].targets[0].box_xywh == (10.0, 20.0, 30.0, 40.0), name
        assert items[1].targets[0].box_xywh == (10.0, 20.0, 30.0, 40.0), name
    items = read_manifest(write(tmp_path, "o.yaml", text), box_origin=1)
    assert items[0].targets[1].box_xywh == (1.0, 1.0, 5.0, 5.0)
    assert items[1].targets[0].box_xywh == (9.0, 19.0, 30.0, 40.0)  # no field: the batch's origin
    explicit = read_manifest(write(tmp_path, "z.jsonl", '{"video": "a.mp4", "box": "10,20,30,40", "box_origin": 0}\n'),
                             box_origin=1)
    assert explicit[0].targets[0].box_xywh == (10.0, 20.0, 30.0, 40.0)


def test_csv_params_columns_and_track_ids(tmp_path):
    path = write(tmp_path, "p.csv", "video,box,params.n_particles,params.threshold\n"
                                    "a.mp4,\"1,2,3,4\",80,0.3\nb.mp4,\"1,2,3,4\",,\n")
    a, b = read_manifest(path)
    assert a.params == {"tracker": {"n_particles": 80}, "flags": {"threshold": 0.3}}
    assert b.params == {}
    items = read_manifest(write(tmp_path, "t.yaml", "- video: v.mp4\n  boxes:\n    - {box: '1,2,3,4', track_id: 7}\n"
                                                     "    - '5,6,7,8'\n"))
    assert [t.track_id for t in items[0].targets] == [7, 2]


@pytest.mark.parametrize(
    "name, text, expected",
    [
        # CSV: a header line, then items from line 2.
        ("bad.csv", "video,box,lable\na.mp4,\"1,2,3,4\",red\n", [(1, "lable", "did you mean 'label'")]),
        ("bad.csv", "video,box\na.mp4,\"1,2,3\"\nb.mp4,\"1,2,0,4\"\nc.mp4,\n,\"1,2,3,4\"\n",
         [(2, "box", "not four numbers"), (3, "box", "zero or negative size"), (4, "box", "no box given"),
          (5, "video", "no video given")]),
        ("bad.csv", "video,box\na.mp4,1,2,3,4\n", [(2, "", "quote cells that hold commas")]),
        ("bad.csv", "video,box,start,stop\na.mp4,\"1,2,3,4\",x,\nb.mp4,\"1,2,3,4\",5,5\nc.mp4,\"1,2,3,4\",-1,\n",
         [(2, "start", "not an integer"), (3, "stop", "not after start"), (4, "start", "below 0")]),
        ("bad.csv", "video,box,params\na.mp4,\"1,2,3,4\",\"{n_particle: 5}\"\n"
                    "b.mp4,\"1,2,3,4\",\"{n_particles: -3}\"\n",
         [(2, "params", "did you mean 'n_particles'"), (3, "params", "n_particles")]),
        ("bad.csv", "video,boxes,label\na.mp4,\"1,2,3,4|5,6,7,8\",x|y|z\n", [(2, "label", "3 labels for 2 boxes")]),
        ("bad.csv", "", [(0, "", "empty")]),
        # JSON Lines: the line of the object.
        ("bad.jsonl", '{"video": "a.mp4", "box": "1,2,3,4"}\n{"video": "b.mp4", "box": "1,2,3,4",}\n[1, 2]\n',
         [(2, "", "not valid JSON"), (3, "", "is not an item")]),
        ("bad.jsonl", '{"video": "a.mp4", "box": "1,2,3,4", "boxes": ["1,2,3,4"]}\n'
                      '{"vidoe": "a.mp4", "box": "1,2,3,4"}\n',
         [(1, "boxes", "both box and boxes"), (2, "vidoe", "did you mean 'video'"), (2, "video", "no video given")]),
        ("bad.jsonl", '{"video": "a.mp4", "box": "1,2,3,4", "id": "x/y"}\n'
                      '{"video": "a.mp4", "box": "1,2,3,4", "params": {"seed": 3}}\n',
         [(1, "id", "not a safe name"), (2, "params", "seed cannot be set per item")]),
        ("bad.jsonl", '{"video": "a.mp4", "box": "1,2,3,4", "id": "same"}\n'
                      '{"video": "b.mp4", "box": "1,2,3,4", "id": "SAME"}\n',
         [(2, "id", "already used by the item at line 1")]),
        ("bad.jsonl", '{"video": "a.mp4", "box": "1,2,3,4", "id": "summary.json"}\n',
         [(1, "id", "batch-level output")]),
        ("bad.jsonl", '{"video": "a.mp4", "boxes": [{"box": "1,2,3,4", "track_id": 2}, '
                      '{"box": "1,2,3,4", "track_id": 2}]}\n',
         [(1, "boxes[1]", "track id 2, already used")]),
        # YAML: the line of the field where known.
        ("bad.yaml", "- video: a.mp4\n  box: '1,2,3,4'\n- video: b.mp4\n  box: [1, 2, 3]\n  stop: 0\n",
         [(4, "box", "not four numbers"), (5, "stop", "below 1")]),
        ("bad.yaml", "items:\n  - video: a.mp4\n    box: 1,2,3,4\n   - bad indent\n", [(4, "", "not valid YAML")]),
        ("bad.yaml", "things: []\n", [(1, "things", "not known"), (1, "items", "no 'items' key")]),
        ("bad.yaml", "- just a string\n", [(1, "", "not a mapping")]),
        ("bad.yaml", "- video: a.mp4\n  box: 1,2,3,4\n  params: {preset: nope}\n", [(3, "params", "unknown preset")]),
        ("bad.txt", "video,box\n", [(0, "", "extension '.txt' is not known")]),
        ("bad.jsonl", '{"video": "a.mp4", "box": "1,2,3,4", "box_origin": 2}\n', [(1, "box_origin", "not 0 or 1")]),
        ("bad.csv", "video,box,box_origin\na.mp4,\"1,2,3,4\",one\n", [(2, "box_origin", "not 0 or 1")]),
    ],
)
def test_bad_rows_are_reported_with_file_line_and_field(tmp_path, name, text, expected):
    path = write(tmp_path, name, text)
    errors = errors_of(path)
    got = [(e.line, e.field) for e in errors]
    assert got == [(line, field) for line, field, _ in expected], [str(e) for e in errors]
    for error, (line, _, needle) in zip(errors, expected):
        assert needle in str(error)
        assert str(error).startswith(f"{path}:{line}: " if line else f"{path}: ")
        assert "\n" not in str(error)


def test_every_problem_of_a_manifest_is_reported_at_once(tmp_path):
    rows = ['{"video": "a.mp4", "box": "1,2,3"}', '{"video": "b.mp4", "box": "1,2,3,4"}', '{"box": "1,2,3,4"}']
    errors = errors_of(write(tmp_path, "m.jsonl", "\n".join(rows) + "\n"))
    assert [e.line for e in errors] == [1, 3]


def test_missing_manifest_file(tmp_path):
    errors = errors_of(tmp_path / "none.csv")
    assert "does not exist" in str(errors[0])


def test_default_ids_are_deterministic_safe_and_unique(tmp_path):
    rows = [{"video": v, "box": "1,2,3,4"} for v in
            ["a b.mp4", "a_b.mp4", "x/a b.mp4", "seq/img", ".hidden.mp4", "summary.mp4", "A_B.avi"]]
    rows.insert(1, {"video": "z.mp4", "box": "1,2,3,4", "id": "a_b-2"})
    path = write(tmp_path, "m.jsonl", "".join(json.dumps(r) + "\n" for r in rows))
    ids = [i.id for i in read_manifest(path)]
    assert ids == ["a_b", "a_b-2", "a_b-3", "a_b-4", "seq", "hidden", "summary", "A_B-5"]


@given(st.lists(st.text(min_size=0, max_size=30), min_size=1, max_size=12))
def test_safe_ids_are_file_name_safe(names):
    for name in names:
        item_id = safe_item_id(name)
        assert 1 <= len(item_id) <= 100
        assert item_id[0].isascii() and item_id[0].isalnum()
        assert all(c.isascii() and (c.isalnum() or c in "._-") for c in item_id)


def make_otb_root(root: Path) -> None:
    for name, files in {"Alpha": {"groundtruth_rect.txt": "11,21,30,40\n12,22,30,40\n"},
                        "Pair": {"groundtruth_rect.1.txt": "1\t2\t3\t4\n",
                                 "groundtruth_rect.2.txt": "5,6,7,8\n"}}.items():
        (root / name / "img").mkdir(parents=True)
        for file, text in files.items():
            (root / name / file).write_text(text)


def test_items_from_otb_root(tmp_path):
    make_otb_root(tmp_path)
    items = items_from_otb_root(tmp_path)
    assert [i.id for i in items] == ["Alpha", "Pair.1", "Pair.2"]
    alpha = items[0]
    assert alpha.targets == (Target((10.0, 20.0, 30.0, 40.0), 1, "object"),)  # 1-based ground truth -> 0-based
    assert alpha.input_path == tmp_path / "Alpha"
    assert alpha.line == 1 and alpha.source.endswith("groundtruth_rect.txt")
    assert items[1].input_path == items[2].input_path == tmp_path / "Pair"
    assert items[1].targets[0].box_xywh == (0.0, 1.0, 3.0, 4.0)


def test_otb_root_errors(tmp_path):
    with pytest.raises(InvalidManifestError, match="no sequence found"):
        items_from_otb_root(tmp_path)
    (tmp_path / "Bad" / "img").mkdir(parents=True)
    (tmp_path / "Bad" / "groundtruth_rect.txt").write_text("0,0,0,5\n")
    with pytest.raises(InvalidManifestError) as info:
        items_from_otb_root(tmp_path)
    assert info.value.errors[0].line == 1 and "zero or negative size" in str(info.value)


def test_reserved_ids_cover_the_batch_outputs():
    from annotator.batch import BATCH_FILES

    assert set(RESERVED_IDS) == set(BATCH_FILES)
    assert BatchItem("x", Path("/v.mp4"), ()).where == ""

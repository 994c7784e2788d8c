"""One box parser: ``--box``, a manifest's ``box``, a corrections file's ``x,y,w,h`` and a COCO ``bbox`` agree.

Each entry point reads the same box to the same numbers, and refuses the same box with the same message (behind
its own name for the box, and the file and line where there is one).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from annotator.box_input import BoxError, parse_box
from annotator.cli import main
from annotator.corrections import read_corrections
from annotator.errors import EXIT_VALUE, ToolError
from annotator.manifest import InvalidManifestError, read_manifest

# --------------------------------------------------------------------------- the parser


@pytest.mark.parametrize(
    "value, origin, expected",
    [
        ("10,20,30,40", 0, (10.0, 20.0, 30.0, 40.0)),
        (" 10, 20 ,30,40 ", 0, (10.0, 20.0, 30.0, 40.0)),
        ("10;20;30;40", 0, (10.0, 20.0, 30.0, 40.0)),
        ("10 20 30 40", 0, (10.0, 20.0, 30.0, 40.0)),
        ("10\t20\t30\t40", 0, (10.0, 20.0, 30.0, 40.0)),
        ("10.5,20.25,30,40", 0, (10.5, 20.25, 30.0, 40.0)),
        ("-5,-5,30,40", 0, (-5.0, -5.0, 30.0, 40.0)),  # partly outside is allowed
        ("11,21,30,40", 1, (10.0, 20.0, 30.0, 40.0)),  # OTB 1-based
        ([10, 20, 30.5, 40], 0, (10.0, 20.0, 30.5, 40.0)),
        ((10, 20, 30, 40), 0, (10.0, 20.0, 30.0, 40.0)),
        (np.array([10.0, 20.0, 30.0, 40.0]), 0, (10.0, 20.0, 30.0, 40.0)),
    ],
)
def test_parse_box(value, origin, expected):
    got = parse_box(value, name="--box", origin=origin)
    assert got == expected and all(type(v) is float for v in got)


@pytest.mark.parametrize(
    "value, message",
    [
        ("10,20,30", "box '10,20,30' is not four numbers x,y,w,h (it has 3 values): give e.g. 120,80,40,60"),
        ("10,20,30,40,50",
         "box '10,20,30,40,50' is not four numbers x,y,w,h (it has 5 values): give e.g. 120,80,40,60"),
        ("10,,20,30", "box '10,,20,30' is not four numbers x,y,w,h (y is ''): give e.g. 120,80,40,60"),
        ("10 20 30", "box '10 20 30' is not four numbers x,y,w,h (it has 3 values): give e.g. 120,80,40,60"),
        ("a,b,c,d", "box 'a,b,c,d' is not four numbers x,y,w,h (x is 'a'): give e.g. 120,80,40,60"),
        ("", "box '' is not four numbers x,y,w,h: give e.g. 120,80,40,60"),
        ("nan,1,2,3", "box 'nan,1,2,3' is not four numbers x,y,w,h (x is 'nan'): give e.g. 120,80,40,60"),
        ("1,2,inf,3", "box '1,2,inf,3' is not four numbers x,y,w,h (w is 'inf'): give e.g. 120,80,40,60"),
        ("10,20,0,40", "box '10,20,0,40' has zero or negative size (w=0, h=40): width and height must be > 0"),
        ("10,20,30,-1", "box '10,20,30,-1' has zero or negative size (w=30, h=-1): width and height must be > 0"),
        ([1, 2, 3], "box [1, 2, 3] is not four numbers x,y,w,h (it has 3 values): give e.g. [120, 80, 40, 60]"),
        ([1, 2, True, 4], "box [1, 2, True, 4] is not four numbers x,y,w,h (w is True): give e.g. [120, 80, 40, 60]"),
        ([1, 2, "3", 4], "box [1, 2, '3', 4] is not four numbers x,y,w,h (w is '3'): give e.g. [120, 80, 40, 60]"),
        (None, "box None is not four numbers x,y,w,h: give e.g. [120, 80, 40, 60]"),
        ({"x": 1}, "box {'x': 1} is not four numbers x,y,w,h: give e.g. [120, 80, 40, 60]"),
    ],
)
def test_parse_box_errors_say_what_is_wrong_in_one_line(value, message):
    with pytest.raises(BoxError) as caught:
        parse_box(value, name="box")
    assert str(caught.value) == message
    assert isinstance(caught.value, ToolError) and caught.value.exit_code == EXIT_VALUE
    assert isinstance(caught.value, ValueError)


# --------------------------------------------------------------------------- every entry point agrees

# Four comma-separated values, the one form every entry point can hold (a corrections row has four columns).
AS_TYPED = ["10,20,30,40", "10.5, 20.25, 30, 40", "10,20,0,40", "10,20,30,-1", "10,20,abc,40", "nan,20,30,40",
            "10,,30,40"]


def reference(text: str, name: str):
    """What the parser makes of ``text`` under ``name``: the box, or the message."""
    try:
        return parse_box(text, name=name)
    except BoxError as exc:
        return str(exc)


@pytest.mark.parametrize("text", [*AS_TYPED, "10;20;30;40", "10 20 30 40", "1,2,3"])
def test_the_command_line_reads_a_box_as_the_parser_does(text, tmp_path, monkeypatch, capsys):
    import annotator.run

    got = []

    def capture(input_path, targets, *args, **kwargs):
        got.extend(t.box_xywh for t in targets)
        raise SystemExit(0)

    monkeypatch.setattr(annotator.run, "annotate", capture)
    with pytest.raises(SystemExit) as caught:
        main([str(tmp_path / "clip.mp4"), "--box", text, "--quiet"])
    expected = reference(text, "--box")
    if isinstance(expected, tuple):
        assert got == [expected]
    else:
        assert caught.value.code == EXIT_VALUE
        assert capsys.readouterr().err == f"sptpt-annotate: error: {expected}\n"


@pytest.mark.parametrize("text", [*AS_TYPED, "10;20;30;40", "10 20 30 40", "1,2,3"])
def test_a_manifest_reads_a_box_as_the_parser_does(text, tmp_path):
    manifest = tmp_path / "m.csv"
    manifest.write_text(f'video,box\na.mp4,"{text}"\n', encoding="utf-8")
    expected = reference(text, "box")
    if isinstance(expected, tuple):
        assert read_manifest(manifest)[0].targets[0].box_xywh == expected
    else:
        with pytest.raises(InvalidManifestError) as caught:
            read_manifest(manifest)
        assert [(e.line, e.field, e.problem) for e in caught.value.errors] == [(2, "box", expected)]


@pytest.mark.parametrize("value", [[10, 20, 30, 40], [10, 20, 0, 40], [10, 20, 30], [10, 20, True, 40]])
def test_a_manifest_list_and_a_coco_bbox_read_as_the_parser_does(value, tmp_path):
    manifest = tmp_path / "m.jsonl"
    manifest.write_text(json.dumps({"video": "a.mp4", "box": value}) + "\n", encoding="utf-8")
    coco = tmp_path / "fix.json"
    coco.write_text(json.dumps({
        "images": [{"id": 1, "frame_index": 3}],
        "annotations": [{"id": 1, "image_id": 1, "bbox": value, "attributes": {"keyframe": True}}]}))
    try:
        expected = parse_box(value, name="box")
    except BoxError as exc:
        with pytest.raises(InvalidManifestError) as caught:
            read_manifest(manifest)
        assert caught.value.errors[0].problem == str(exc)
        with pytest.raises(ToolError) as caught:
            read_corrections(coco)
        assert str(caught.value) == (f"{coco}:1: {reference(value, 'bbox')}; set attributes.outside to true to mark "
                                     "the object absent")
    else:
        assert read_manifest(manifest)[0].targets[0].box_xywh == expected
        assert read_corrections(coco)[0].box_xywh == expected


# Some columns empty is the corrections file's own error (all four empty says the object is absent):
# tests/annotator/test_corrections.py.
@pytest.mark.parametrize("text", [t for t in AS_TYPED if t != "10,,30,40"])
def test_a_corrections_row_reads_a_box_as_the_parser_does(text, tmp_path):
    path = tmp_path / "fix.csv"
    path.write_text(f"frame,x,y,w,h\n3,{text}\n", encoding="utf-8")
    columns = ",".join(part.strip() for part in text.split(","))  # the CSV reader strips each field
    expected = reference(columns, "box")
    if isinstance(expected, tuple):
        assert read_corrections(path)[0].box_xywh == expected
    else:
        with pytest.raises(ToolError) as caught:
            read_corrections(path)
        assert str(caught.value) == f"{path}:2: {expected}; leave x,y,w,h all empty to mark the object absent"


@pytest.mark.parametrize("text", [*AS_TYPED, "10;20;30;40", "1,2,3"])
def test_the_python_api_reads_a_box_as_the_parser_does(text, tmp_path):
    from annotator import annotate
    from annotator.errors import EXIT_INPUT

    expected = reference(text, "box")
    with pytest.raises(ToolError) as caught:
        annotate(tmp_path / "missing.mp4", text, show_progress=False)
    if isinstance(expected, tuple):
        assert caught.value.exit_code == EXIT_INPUT and "no such file" in str(caught.value)  # the box is taken
    else:
        assert str(caught.value) == expected


@pytest.mark.parametrize(
    "given, boxes",
    [
        ((1, 2, 3, 4), [(1.0, 2.0, 3.0, 4.0)]),
        ("1 2 3 4", [(1.0, 2.0, 3.0, 4.0)]),
        (np.array([1.0, 2.0, 3.0, 4.0]), [(1.0, 2.0, 3.0, 4.0)]),
        ([(1, 2, 3, 4), "5,6,7,8"], [(1.0, 2.0, 3.0, 4.0), (5.0, 6.0, 7.0, 8.0)]),
        (np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]]), [(1.0, 2.0, 3.0, 4.0), (5.0, 6.0, 7.0, 8.0)]),
    ],
)
def test_annotate_takes_one_box_or_a_list_of_them(given, boxes):
    from annotator.run import _as_targets
    from annotator.tracks import Target

    assert _as_targets(given) == [Target(box, track_id=i, label="object") for i, box in enumerate(boxes, start=1)]
    mine = Target((1.0, 2.0, 3.0, 4.0), track_id=7, label="car")
    assert _as_targets(mine) == [mine] and _as_targets([mine]) == [mine]

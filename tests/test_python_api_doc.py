"""docs/python-api.md's examples, run as written: the public API does what the page says.

Every ```python block of the page runs, in order and in one namespace, from a folder holding a copy of the
project's ``samples/`` (as from the repository's folder, without touching it).
"""

from __future__ import annotations

import contextlib
import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "python-api.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.S | re.M)


@pytest.fixture(scope="module")
def ran(tmp_path_factory) -> dict:
    """The page's blocks run in a copy of samples/: the namespace after each, and what each printed."""
    work = tmp_path_factory.mktemp("python_api")
    shutil.copytree(ROOT / "samples", work / "samples", ignore=shutil.ignore_patterns("clip_sptpt"))
    blocks = python_blocks(PAGE.read_text(encoding="utf-8"))
    namespace: dict = {"__name__": "python_api_doc"}
    printed, after = [], []
    with contextlib.chdir(work):
        for number, block in enumerate(blocks, start=1):
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                exec(compile(block, f"{PAGE.name}, python block {number}", "exec"), namespace)
            printed.append(out.getvalue())
            after.append(dict(namespace))
    return {"after": after, "printed": printed, "work": work}


def test_every_block_of_the_page_runs(ran):
    assert len(ran["printed"]) == len(python_blocks(PAGE.read_text(encoding="utf-8"))) >= 6


def test_annotate_takes_a_video_and_a_box_and_gives_the_outputs_and_the_store(ran):
    result = ran["after"][0]["result"]
    assert result.exit_code == 0 and result.out_dir == Path("clip_out")  # as given, relative to the folder
    assert {"store", "otb", "coco", "flags", "overlay", "report", "provenance"} <= set(result.outputs)
    track = result.store.track(1)
    assert len(track) == 20 and track.label == "object"
    np.testing.assert_array_equal(track.boxes_xywh[0], [136, 129, 48, 40])  # the given box, as given
    assert ran["printed"][0].startswith("0 clip_out [")


def test_targets_and_a_config_of_your_own(ran):
    fast = ran["after"][1]["fast"]
    assert fast.store.track(1).label == "toy" and set(fast.outputs) >= {"otb", "coco"}
    assert "overlay" not in fast.outputs and ran["printed"][1] == "toy ['annotations.json']\n"


def test_the_correction_is_applied_and_the_store_read_back_has_it(ran):
    assert ran["after"][2]["review"].changed
    track = ran["after"][3]["store"].track(1)
    row = int(np.flatnonzero(track.frame_indices == 15)[0])
    np.testing.assert_allclose(track.boxes_xywh[row], [190.8, 147.4, 53.6, 44.6])
    assert track.keyframe[row]


def test_the_tracker_alone(ran):
    namespace = ran["after"][-2]
    assert namespace["index"] == 9 and len(ran["printed"][-2].splitlines()) == 10
    from sptpt import FrameResult, Tracker, TrackerParams, preset

    assert isinstance(namespace["tracker"], Tracker) and isinstance(namespace["result"], FrameResult)
    assert isinstance(preset("robust"), TrackerParams)


def test_frames_submitted_ahead_give_update_s_boxes(ran):
    assert ran["printed"][-1] == "10 True\n"
    assert ran["after"][-1]["ahead"].submitted == 0


def test_each_package_names_its_public_api():
    import annotator
    import sptpt

    for package in (annotator, sptpt):
        for name in package.__all__:
            assert getattr(package, name) is not None, name
        with pytest.raises(AttributeError):
            _ = package.not_a_name
    from annotator.run import annotate

    assert annotator.annotate is annotate  # the command line's own function, not a second one


def _tool_classes(hint) -> set[type]:
    """The classes of the tool or the tracker inside a type hint (``RunConfig | None``, ``list[TrackResult]``)."""
    import typing

    found = set()
    if isinstance(hint, type) and hint.__module__.split(".")[0] in ("annotator", "sptpt"):
        found.add(hint)
    for arg in typing.get_args(hint):
        found |= _tool_classes(arg)
    return found


def test_what_annotate_and_apply_corrections_take_and_return_is_public():
    """A caller can name every type they touch: the parameters and returns of the public functions, and the
    fields of the results they return, each a public name of ``annotator`` or ``sptpt``."""
    import dataclasses
    import typing

    import annotator
    import sptpt

    public = {id(getattr(package, name)) for package in (annotator, sptpt) for name in package.__all__}
    todo = [annotator.annotate, annotator.apply_corrections]
    seen: set = set()
    missing = []
    while todo:
        thing = todo.pop()
        if thing in seen:
            continue
        seen.add(thing)
        hints = typing.get_type_hints(thing)
        if dataclasses.is_dataclass(thing):  # its fields, not its private ones
            hints = {f.name: hints[f.name] for f in dataclasses.fields(thing) if not f.name.startswith("_")}
        for hint in hints.values():
            for cls in _tool_classes(hint):
                if id(cls) not in public:
                    missing.append(f"{getattr(thing, '__qualname__', thing)}: {cls.__module__}.{cls.__qualname__}")
                elif dataclasses.is_dataclass(cls) and cls.__module__.startswith("annotator"):
                    todo.append(cls)
    assert not missing
    assert {annotator.AnnotateResult, annotator.RunConfig, annotator.RunStore, annotator.TrackingRun,
            annotator.ReviewResult, annotator.RetrackResult, annotator.TrackResult} <= seen


def test_the_page_imports_only_public_names():
    import annotator
    import sptpt

    text = PAGE.read_text(encoding="utf-8")
    for module, names in re.findall(r"^from (annotator\S*|sptpt\S*) import (.+)$", text, flags=re.M):
        assert module in ("annotator", "sptpt"), f"the page imports from {module}: only package names are public"
        package = annotator if module == "annotator" else sptpt
        for name in (n.strip() for n in names.split(",")):
            assert name in package.__all__, name
    for name in re.findall(r"`((?:annotator|sptpt)\.[a-z_.]+)", text):
        assert name.count(".") == 1 and name.split(".")[1] in (annotator if name.startswith("a") else sptpt).__all__ \
            or name == "sptpt.boxes", f"the page names {name}, not a public name"

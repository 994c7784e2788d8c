"""annotator.publish.move_into_place: the one way a first run and a re-track move their files into place."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from annotator.publish import MoveError, move_into_place


def _staged(tmp_path: Path, names) -> Path:
    staging = tmp_path / "staging"
    for name in names:
        (staging / name).parent.mkdir(parents=True, exist_ok=True)
        (staging / name).write_text(f"new {name}")
    return staging


def _folder(tmp_path: Path, files: dict[str, str]) -> Path:
    out = tmp_path / "out"
    out.mkdir()
    for name, text in files.items():
        (out / name).write_text(text)
    return out


def _failing_replace(monkeypatch, fails, error: OSError) -> None:
    """os.replace raises ``error`` where ``fails(source, target)``, and works elsewhere."""
    replace = os.replace

    def patched(source, target):
        if fails(Path(source), Path(target)):
            raise error
        replace(source, target)

    monkeypatch.setattr(os, "replace", patched)


def test_the_store_goes_next_to_last_and_run_json_last(tmp_path, monkeypatch):
    names = ["run.json", "tracks.npz", "flags.csv", "mot/gt/gt.txt"]
    staging, out = _staged(tmp_path, names), _folder(tmp_path, {"run.json": "old"})
    order, replace = [], os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: (order.append(Path(b).relative_to(out).as_posix()), replace(a, b)))
    placed = move_into_place(staging, out, names)
    assert order == ["flags.csv", "mot/gt/gt.txt", "tracks.npz", "run.json"]
    assert placed == [out / name for name in order] and (out / "run.json").read_text() == "new run.json"


def test_retired_files_go_only_once_everything_is_in_place(tmp_path):
    staging = _staged(tmp_path, ["run.json", "tracks.npz"])
    out = _folder(tmp_path, {"run.json": "old", "overlay.mp4": "old video", "notes.txt": "mine"})
    move_into_place(staging, out, ["run.json", "tracks.npz"], retire=["overlay.mp4", "cvat.xml"])
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "run.json", "tracks.npz"]


def test_a_retired_file_that_cannot_be_moved_changes_nothing(tmp_path, monkeypatch):
    staging = _staged(tmp_path, ["run.json", "flags.csv"])
    out = _folder(tmp_path, {"run.json": "old", "flags.csv": "old flags", "overlay.mp4": "open in a player"})
    _failing_replace(monkeypatch, lambda source, _: source.name == "overlay.mp4",
                     PermissionError(errno.EACCES, "Permission denied"))
    with pytest.raises(MoveError) as info:
        move_into_place(staging, out, ["run.json", "flags.csv"], retire=["overlay.mp4"], unmark_first=True)
    assert info.value.blocked == out / "overlay.mp4" and info.value.moved == []
    assert {p.name: p.read_text() for p in out.iterdir()} == {
        "run.json": "old", "flags.csv": "old flags", "overlay.mp4": "open in a player"}


def test_a_failed_move_puts_the_retired_files_back_and_says_what_moved(tmp_path, monkeypatch):
    staging = _staged(tmp_path, ["run.json", "tracks.npz", "flags.csv"])
    out = _folder(tmp_path, {"run.json": "old", "overlay.mp4": "old video"})
    _failing_replace(monkeypatch, lambda _, target: target.name == "tracks.npz",
                     OSError(errno.ENOSPC, "No space left on device"))
    with pytest.raises(MoveError) as info:
        move_into_place(staging, out, ["run.json", "tracks.npz", "flags.csv"], retire=["overlay.mp4"])
    assert info.value.moved == [Path("flags.csv")] and info.value.cause.errno == errno.ENOSPC
    # The re-track's rule: run.json still describes the earlier state, and the overlay is back.
    assert (out / "run.json").read_text() == "old" and (out / "overlay.mp4").read_text() == "old video"
    assert not list(out.glob(".*.stale"))


def test_unmark_first_leaves_no_run_json_when_a_move_fails(tmp_path, monkeypatch):
    staging = _staged(tmp_path, ["run.json", "tracks.npz"])
    out = _folder(tmp_path, {"run.json": "old", "tracks.npz": "old store"})
    _failing_replace(monkeypatch, lambda _, target: target.name == "tracks.npz", OSError(errno.EIO, "I/O error"))
    with pytest.raises(MoveError):
        move_into_place(staging, out, ["run.json", "tracks.npz"], unmark_first=True)
    assert not (out / "run.json").exists()  # a first run cut short here: the folder holds no finished run

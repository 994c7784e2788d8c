"""An interrupted run goes on from its last checkpoint with the boxes of a run never interrupted (issue #69).

Interruptions are made where a Ctrl-C makes them: the frame loop is asked to stop between frames (its
``stop_request``), after a chosen number of frames; checkpoints every 7 frames instead of 100 keep the clip short.
"""

from __future__ import annotations

import contextlib
import pickle
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotator import pipeline
from annotator import run as job
from annotator.checkpoint import CHECKPOINT_NAME, read_checkpoint
from annotator.cli import _with_default_command, app
from annotator.config import resolve_config
from annotator.errors import EXIT_INPUT, EXIT_INTERRUPTED, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, ToolError
from annotator.nanotrack import NanoTrackGuide
from annotator.track_store import STORE_NAME, read_store
from annotator.tracks import Target
from sptpt_dev.synthetic import make_clip

N = 30
EVERY = 7
FORMATS = ["otb", "flags", "overlay", "report"]


class _StopAfter(dict):
    """A stop request that turns true once the loop has asked ``frames + 1`` times (after ``frames`` frames)."""

    def __init__(self, frames: int) -> None:
        super().__init__()
        self.left = frames

    def __getitem__(self, key):
        self.left -= 1
        return self.left < 0


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory) -> tuple[Path, Target]:
    root = tmp_path_factory.mktemp("resume")
    clip = make_clip(N, size=(96, 72), object_size=(24, 20), seed=4)
    (root / "seq").mkdir()
    for k, frame in enumerate(clip.frames):
        cv2.imwrite(str(root / "seq" / f"{k:03d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    return root / "seq", Target(tuple(float(v) for v in clip.boxes_xywh[0]), track_id=1)


# fused: its NanoTrack guide must come back from a checkpoint too (it is replayed the frames before it).
CONFIG = resolve_config(preset="fused", tracker_overrides={"n_particles": 60, "n_negatives": 20}, seed=3)


@pytest.fixture(autouse=True)
def short_checkpoints(monkeypatch):
    monkeypatch.setattr(pipeline, "CHECKPOINT_EVERY", EVERY)


@pytest.fixture(scope="module")
def whole(clip_dir, tmp_path_factory):
    """The run never interrupted (also with checkpoints every 7 frames, which change no box)."""
    seq, target = clip_dir
    out = tmp_path_factory.mktemp("whole") / "out"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(pipeline, "CHECKPOINT_EVERY", EVERY)
        assert job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False).exit_code == 0
    return out


def _interrupted_run(seq, target, out, frames, monkeypatch):
    @contextlib.contextmanager
    def stop_after():
        yield _StopAfter(frames)

    monkeypatch.setattr(pipeline, "_deferred_interrupt", stop_after)
    result = job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False)
    monkeypatch.undo()
    monkeypatch.setattr(pipeline, "CHECKPOINT_EVERY", EVERY)
    return result


def _same_run(a: Path, b: Path) -> None:
    first, second = read_store(a / STORE_NAME).tracks[0], read_store(b / STORE_NAME).tracks[0]
    for name in ("frame_indices", "boxes_xywh", "confidence", "log_likelihood", "accepted", "flagged", "outside",
                 "p_fail"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name), err_msg=name)
    assert first.reasons == second.reasons
    assert (a / "flags.csv").read_text() == (b / "flags.csv").read_text()


@pytest.mark.parametrize("stop", [1, EVERY - 1, EVERY, 17, N - 1])
def test_a_run_resumed_after_an_interruption_at_any_frame_has_the_boxes_of_one_never_interrupted(
        clip_dir, whole, tmp_path, monkeypatch, stop):
    seq, target = clip_dir
    out = tmp_path / "out"
    cut = _interrupted_run(seq, target, out, stop, monkeypatch)
    assert cut.exit_code == EXIT_INTERRUPTED and cut.run.frames_processed == stop
    checkpoint = read_checkpoint(out)
    assert (checkpoint is None) == (stop < EVERY)
    if checkpoint is not None:
        assert checkpoint.frames_tracked == stop // EVERY * EVERY
        # fused's NanoTrack comes back behind: the resumed run replays the frames before the checkpoint to it.
        (tracker,) = checkpoint.trackers.values()
        assert isinstance(tracker.guide, NanoTrackGuide) and tracker.guide.behind == checkpoint.frames_tracked
    with pytest.raises(ToolError) as refused:
        job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False)
    assert str(refused.value) == (f"output folder {out} holds a run interrupted at frame {stop} of {N}: --resume to "
                                  "continue, --force to start again")
    assert refused.value.exit_code == EXIT_OUTPUT
    resumed = job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, resume=True)
    assert resumed.exit_code == EXIT_OK and resumed.run.frames_processed == N
    _same_run(whole, out)
    assert not (out / CHECKPOINT_NAME).exists()
    assert (out / "overlay.mp4").stat().st_size > 0 and "<html" in (out / "report.html").read_text()


def test_a_run_interrupted_twice_resumes_twice(clip_dir, whole, tmp_path, monkeypatch):
    seq, target = clip_dir
    out = tmp_path / "out"
    _interrupted_run(seq, target, out, 9, monkeypatch)

    @contextlib.contextmanager
    def stop_after():
        yield _StopAfter(10)  # 10 more frames after the checkpoint at 7

    monkeypatch.setattr(pipeline, "_deferred_interrupt", stop_after)
    again = job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, resume=True)
    monkeypatch.undo()
    monkeypatch.setattr(pipeline, "CHECKPOINT_EVERY", EVERY)
    assert again.exit_code == EXIT_INTERRUPTED and again.run.frames_processed == 17
    assert read_checkpoint(out).frames_tracked == 14
    job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, resume=True)
    _same_run(whole, out)


def test_resume_refuses_a_finished_run_and_another_runs_checkpoint(clip_dir, whole, tmp_path, monkeypatch):
    seq, target = clip_dir
    with pytest.raises(ToolError, match="holds a finished run: there is nothing to resume; pass --force"):
        job.annotate(seq, [target], CONFIG, out_dir=whole, formats=FORMATS, show_progress=False, resume=True)
    out = tmp_path / "out"
    _interrupted_run(seq, target, out, 9, monkeypatch)
    moved = Target((target.box_xywh[0] + 2, *target.box_xywh[1:]), track_id=1)
    with pytest.raises(ToolError, match=r"checkpoint in .* is of another run \(its boxes or labels differs\)"):
        job.annotate(seq, [moved], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, resume=True)
    # --force starts again and leaves no stale checkpoint behind.
    done = job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, force=True)
    assert done.exit_code == EXIT_OK and not (out / CHECKPOINT_NAME).exists()
    _same_run(whole, out)


def test_a_killed_run_leaves_its_checkpoint_and_resumes(clip_dir, whole, tmp_path, monkeypatch):
    """kill -9 leaves no run.json: the checkpoint alone says a run was cut short."""
    seq, target = clip_dir
    out = tmp_path / "out"
    _interrupted_run(seq, target, out, 16, monkeypatch)
    for path in out.iterdir():
        if path.name != CHECKPOINT_NAME:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    with pytest.raises(ToolError, match="holds a run stopped before it finished .*: --resume to continue"):
        job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False)
    job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, resume=True)
    _same_run(whole, out)


def test_a_damaged_checkpoint_is_refused_in_one_line(clip_dir, tmp_path, monkeypatch):
    seq, target = clip_dir
    out = tmp_path / "out"
    _interrupted_run(seq, target, out, 9, monkeypatch)
    (out / CHECKPOINT_NAME).write_bytes(b"sptpt-annotate checkpoint 1\n" + pickle.dumps("not a checkpoint"))
    with pytest.raises(ToolError, match=r"the checkpoint cannot be read \(not a checkpoint of this tool\): pass "
                                         r"--force to start the run again"):
        job.annotate(seq, [target], CONFIG, out_dir=out, formats=FORMATS, show_progress=False, resume=True)


def test_resume_and_force_together_are_a_usage_error(clip_dir, tmp_path):
    seq, target = clip_dir
    box = ",".join(f"{v:g}" for v in target.box_xywh)
    result = CliRunner().invoke(app, _with_default_command(
        [str(seq), "--box", box, "--out", str(tmp_path / "out"), "--resume", "--force"]))
    assert result.exit_code == EXIT_USAGE
    assert "--resume goes on with the run in the output folder and --force discards it" in result.stderr
    assert not (tmp_path / "out").exists()


def test_an_interrupted_batch_item_resumes_on_the_rerun(clip_dir, tmp_path, monkeypatch):
    """What a batch worker runs (run_item): an item cut short goes on from its checkpoint on the rerun, with the
    boxes of the item run whole; the batch asks for that unless --force."""
    import dataclasses

    from annotator.batch.plan import BatchRequest, plan_batch
    from annotator.batch.runner import _schedule
    from annotator.batch.workers import run_item
    from annotator.manifest import BatchItem

    seq, target = clip_dir
    item = BatchItem(id="clip", input_path=seq, targets=(target,), start=None, stop=None, step=None, params={},
                     source="m.csv", line=2)
    request = BatchRequest(config_values={"tracker": {"n_particles": 60, "n_negatives": 20}}, formats=FORMATS)
    (plan,) = plan_batch([item], request, out_dir=tmp_path / "labels")
    assert [p.job.resume for p in _schedule([plan], force=False, n_workers=1, scheduler=None)[0]] == [True]
    job_ = plan.job
    whole = run_item(dataclasses.replace(job_, folder=str(tmp_path / "whole")))
    assert whole.status == "done"

    @contextlib.contextmanager
    def stop_after():
        yield _StopAfter(16)

    monkeypatch.setattr(pipeline, "_deferred_interrupt", stop_after)
    cut = run_item(job_)
    monkeypatch.undo()
    monkeypatch.setattr(pipeline, "CHECKPOINT_EVERY", EVERY)
    assert cut.status == "partial" and cut.frames == 16
    assert read_checkpoint(Path(job_.folder)).frames_tracked == 14
    asked = []
    real = job.annotate

    def recording(*args, **kwargs):
        asked.append(kwargs.get("resume"))
        return real(*args, **kwargs)

    monkeypatch.setattr(job, "annotate", recording)
    again = run_item(dataclasses.replace(job_, resume=True))
    assert again.status == "done" and asked == [True]
    _same_run(tmp_path / "whole", Path(job_.folder))
    # --force: the item starts afresh (resume False), whatever checkpoint its folder holds.
    assert [p.job.resume for p in _schedule([plan], force=True, n_workers=1, scheduler=None)[0]] == [False]
    asked.clear()
    assert run_item(dataclasses.replace(job_, resume=False)).status == "done" and asked == [False]
    assert not (Path(job_.folder) / CHECKPOINT_NAME).exists()


class _Frames:
    """A frame source of blank frames with the given indices."""

    path = Path("walk.mp4")

    def __init__(self, indices) -> None:
        self.indices = list(indices)

    def __iter__(self):
        return ((i, np.zeros((4, 4, 3), np.uint8)) for i in self.indices)


class _BehindGuide:
    """A restored guide that needs ``behind`` more frames (NanoTrackGuide's catch-up protocol)."""

    def __init__(self, behind: int) -> None:
        self.behind, self.caught = behind, []

    def catch_up(self, frame) -> None:
        self.caught.append(frame)
        self.behind -= 1


def _trackers(*guides):
    return [type("T", (), {"guide": g})() for g in guides]


def test_resuming_replays_the_frames_before_the_checkpoint_to_a_guide_and_yields_the_rest():
    guide = _BehindGuide(5)
    out = [i for i, _ in pipeline._skipped_to(_Frames(range(10)), 5, _trackers(guide, None))]
    assert out == [6, 7, 8, 9] and guide.behind == 0 and len(guide.caught) == 5
    # A checkpoint on the last frame leaves nothing to track, and that is no error.
    assert list(pipeline._skipped_to(_Frames(range(6)), 5, _trackers(None))) == []


@pytest.mark.parametrize("indices, last, guide, fragment", [
    (range(4), 5, None, "walk.mp4: the video ends before frame 5, where the checkpoint stopped"),
    (range(10), 5, 8, "walk.mp4: the checkpoint's learned tracker saw more frames before frame 6"),
])
def test_a_video_that_changed_since_the_checkpoint_is_refused_in_one_line(indices, last, guide, fragment):
    trackers = _trackers(None if guide is None else _BehindGuide(guide))
    with pytest.raises(ToolError) as err:
        list(pipeline._skipped_to(_Frames(indices), last, trackers))
    assert err.value.exit_code == EXIT_INPUT and fragment in str(err.value) and "--force" in str(err.value)
    assert "\n" not in str(err.value)

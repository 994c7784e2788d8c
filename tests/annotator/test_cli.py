"""``sptpt-annotate VIDEO --box x,y,w,h`` with the real tracker: through typer's runner and as the console script.

The tracker is slow (a few frames per second), so each expensive invocation
runs once per module on a tiny synthetic clip with a cut-down tracker
(60 particles, 20 negatives, from a ``--config`` file) and many tests look at
its outputs. Bad inputs fail before any tracking and are cheap.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from _report_page import parse, seek_seconds, shows_frame
from pycocotools.coco import COCO
from typer.testing import CliRunner

import annotator
from annotator.cli import app, main
from annotator.exports import read_flags_csv
from annotator.flagging import FlagParams
from annotator.frame_sources import open_frames
from annotator.otb_format import read_otb_boxes
from sptpt_dev.synthetic import make_clip

N_FRAMES, SIZE, FPS = 16, (96, 72), 25.0
TRACKER_YAML = "seed: 1\ntracker:\n  n_particles: 60\n  n_negatives: 20\n"
RESULT_NAMES = {"run.json", "tracks.npz", "annotations.json", "flags.csv", "overlay.mp4", "report.html"}


def write_clip(path: Path, n: int = N_FRAMES, *, faststart: bool = False) -> Path:
    clip = make_clip(n, size=SIZE, object_size=(24, 20))
    extra = ["-movflags", "+faststart"] if faststart else []
    writer = imageio_ffmpeg.write_frames(str(path), SIZE, fps=FPS, codec="libx264", macro_block_size=1,
                                         ffmpeg_log_level="error", output_params=["-g", "4", *extra])
    writer.send(None)
    for frame in clip.frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    return path


def box_text(box) -> str:
    return ",".join(f"{v:.0f}" for v in box)


BOXES = make_clip(N_FRAMES, size=SIZE, object_size=(24, 20)).boxes_xywh
BOX0 = box_text(BOXES[0])  # "36,29,24,20"


def invoke(*args: str):
    """Run the CLI in-process; stderr is kept apart from stdout."""
    return CliRunner().invoke(app, ["track", *map(str, args)])


def console_script() -> list[str]:
    """The console script installed with the Python running the tests (not the first one on PATH, which may
    belong to another environment), else the module."""
    exe = Path(sys.executable).with_name("sptpt-annotate")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "annotator.cli"]


def run_script(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*console_script(), *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          timeout=300, stdin=subprocess.DEVNULL)


def no_temporaries(folder: Path) -> None:
    if folder.exists():
        leftovers = [p for p in folder.rglob("*") if ".tmp" in p.name]
        assert not leftovers, leftovers


def check_complete_outputs(out: Path, name: str, frames: list[int], tracks: int = 1) -> None:
    """Every output that exists parses completely and has one entry per processed frame."""
    no_temporaries(out)
    otb = [out / f"{name}.txt"] if tracks == 1 else [out / f"{name}.{t}.txt" for t in range(1, tracks + 1)]
    for path in otb:
        if path.exists():
            assert len(read_otb_boxes(path)) == len(frames)
    if (out / "flags.csv").exists():
        table = read_flags_csv(out / "flags.csv")
        for track in range(1, tracks + 1):
            assert table.for_track(track).frame.tolist() == frames
    if (out / "annotations.json").exists():
        coco = COCO(str(out / "annotations.json"))
        images = sorted(coco.dataset["images"], key=lambda im: im["id"])
        assert [im["frame_id"] for im in images] == list(range(len(frames)))
        assert [im["frame_index"] for im in images] == frames
    if (out / "overlay.mp4").exists():
        assert open_frames(out / "overlay.mp4").frame_count == len(frames)
    if (out / "report.html").exists():
        assert (out / "report.html").read_text(encoding="utf-8").rstrip().endswith("</html>")
    info = json.loads((out / "run.json").read_text())
    assert info["frames_processed"] == len(frames)


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cli")


@pytest.fixture(scope="module")
def clip(work) -> Path:
    return write_clip(work / "clip.mp4")


@pytest.fixture(scope="module")
def config_file(work) -> Path:
    path = work / "small.yaml"
    path.write_text(TRACKER_YAML, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def strict_config_file(work) -> Path:
    """The small tracker, and flags on every frame with p_fail above 1e-9, so that the report has spans to list
    (on this easy clip the shipped model puts p_fail far below 0.001)."""
    path = work / "strict.yaml"
    path.write_text(TRACKER_YAML + "flags:\n  threshold: 1.0e-9\n  merge_gap: 0\n  min_span: 1\n", encoding="utf-8")
    return path


MAIN_START, MAIN_STOP, MAIN_STEP = 1, 15, 2
MAIN_FRAMES = list(range(MAIN_START, MAIN_STOP, MAIN_STEP))  # 1, 3, ..., 13


@pytest.fixture(scope="module")
def main_run(clip, strict_config_file, work):
    """Two objects (the second a patch of background), a sub-sampled range, every output."""
    out = work / "main"
    result = invoke(clip, "--box", box_text(BOXES[MAIN_START]), "--box", "4,4,20,16", "--label", "thing",
                    "--start", MAIN_START, "--stop", MAIN_STOP, "--step", MAIN_STEP, "--config", strict_config_file,
                    "--out", out)
    return result, out


@pytest.fixture(scope="module")
def script_run(clip, config_file, work):
    """The console script, default output folder, --quiet, the seed of the file overridden by --seed,
    and the box given OTB-style (1-based)."""
    one_based = ",".join(str(v + 1) if i < 2 else str(v) for i, v in enumerate(map(int, BOX0.split(","))))
    done = run_script(clip, "--box", one_based, "--box-origin", "1", "--config", config_file, "--seed", 3, "--quiet")
    return done, clip.parent / "clip_sptpt"


@pytest.fixture(scope="module")
def runner_run(clip, config_file, work):
    """The same run as ``script_run`` in-process, box 0-based: must give the same boxes."""
    out = work / "again"
    return invoke(clip, "--box", BOX0, "--config", config_file, "--seed", 3, "--out", out), out


# --------------------------------------------------------------------------- a full run


def test_main_run_succeeds_and_says_so(main_run):
    result, out = main_run
    assert result.exit_code == 0, result.output
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert lines[-1].startswith(f"{len(MAIN_FRAMES)} frames tracked in ") and str(out) in lines[-1]
    assert f"frames {len(MAIN_FRAMES)}/{len(MAIN_FRAMES)}" in result.stderr  # progress
    assert "Traceback" not in result.output
    assert RESULT_NAMES <= {p.name for p in out.iterdir()}
    check_complete_outputs(out, "clip", MAIN_FRAMES, tracks=2)


def test_main_run_otb_rows_equal_processed_frames(main_run):
    _, out = main_run
    for track in (1, 2):
        boxes = read_otb_boxes(out / f"clip.{track}.txt")
        assert boxes.shape == (len(MAIN_FRAMES), 4) and np.isfinite(boxes).all()
        times = (out / "times" / f"clip.{track}_time.txt").read_text().split()
        assert len(times) == len(MAIN_FRAMES)
    # The first row is the given box (1-based in the file).
    assert read_otb_boxes(out / "clip.2.txt")[0].tolist() == [4.0, 4.0, 20.0, 16.0]
    assert not (out / "clip.txt").exists()


def test_main_run_coco_loads_with_contiguous_frame_ids_and_two_tracks(main_run):
    _, out = main_run
    coco = COCO(str(out / "annotations.json"))
    images = sorted(coco.dataset["images"], key=lambda im: im["id"])
    assert [im["frame_id"] for im in images] == list(range(len(MAIN_FRAMES)))
    assert [im["frame_index"] for im in images] == MAIN_FRAMES  # source indices
    assert [(t["id"], t["category_id"]) for t in coco.dataset["tracks"]] == [(1, 1), (2, 1)]
    assert coco.dataset["categories"][0]["name"] == "thing"  # one --label for all boxes
    assert coco.dataset["videos"][0]["length"] == N_FRAMES and coco.dataset["videos"][0]["fps"] == FPS
    first = [a for a in coco.dataset["annotations"] if coco.imgs[a["image_id"]]["frame_id"] == 0]
    assert {a["track_id"]: a["bbox"] for a in first}[2] == [4.0, 4.0, 20.0, 16.0]
    assert all(a["attributes"]["keyframe"] for a in first)
    for ann in coco.dataset["annotations"]:
        assert ann["track_id"] == ann["instance_id"] == ann["attributes"]["track_id"]
        assert 0.0 <= ann["score"] <= 1.0


def test_main_run_overlay_has_the_processed_frames(main_run):
    _, out = main_run
    overlay = open_frames(out / "overlay.mp4")
    assert (overlay.frame_count, overlay.width, overlay.height, overlay.fps) == (len(MAIN_FRAMES), *SIZE, FPS)


def spans_of(table) -> list[tuple[int, int, int]]:
    """(track, first frame, last frame) of each run of flagged rows, per track in processed order."""
    spans = []
    for track in sorted(set(table.track.tolist())):
        rows = table.for_track(track)
        start = None
        for i, flagged in enumerate([*rows.flagged.tolist(), False]):
            if flagged and start is None:
                start = i
            elif not flagged and start is not None:
                spans.append((track, int(rows.frame[start]), int(rows.frame[i - 1])))
                start = None
    return spans


def test_main_run_report_has_one_row_per_flagged_span_of_flags_csv(main_run):
    _, out = main_run
    table = read_flags_csv(out / "flags.csv")
    expected = spans_of(table)
    assert expected, "the strict flag settings should flag some frames"
    parsed = parse((out / "report.html").read_text(encoding="utf-8"))
    got = sorted((int(r["cells"][0]), *map(int, r["cells"][1].split("\u2013"))) for r in parsed.rows)
    assert got == sorted(expected)
    for row in parsed.rows:
        first = int(row["cells"][1].split("\u2013")[0])
        assert shows_frame(seek_seconds(row["seek"]), MAIN_FRAMES.index(first), FPS)
        assert row["img"]  # a thumbnail of the span's worst overlay frame


def test_main_run_json(main_run, clip):
    _, out = main_run
    info = json.loads((out / "run.json").read_text())
    assert info["tool_version"] == annotator.__version__
    assert info["input"]["path"] == str(clip.resolve()) and info["input"]["content_hash"].startswith("sha256:")
    assert (info["input"]["frame_count"], info["input"]["fps"]) == (N_FRAMES, FPS)
    assert info["range"] == {"start": MAIN_START, "stop": MAIN_STOP, "step": MAIN_STEP}
    assert info["frames_processed"] == len(MAIN_FRAMES) and info["complete"] is True
    config = info["config"]
    assert config["seed"] == 1  # from the file
    assert config["tracker"]["n_particles"] == 60 and config["tracker"]["n_negatives"] == 20
    # From the file, then the defaults.
    assert config["flags"]["threshold"] == 1e-9 and config["flags"]["review_budget"] == FlagParams().review_budget
    assert config["tracker"]["n_superpixels"] == 30 and config["preset"] == "fused"  # full parameters
    assert [(t["track_id"], t["label"]) for t in info["targets"]] == [(1, "thing"), (2, "thing")]
    assert set(info["timings"]) >= {"seconds_total", "seconds_tracking", "frames_per_second"}


# --------------------------------------------------------------------------- the console script


def test_console_script_quiet_run_prints_nothing(script_run):
    done, out = script_run
    assert done.returncode == 0, done.stderr
    assert done.stderr == "" and done.stdout == ""
    assert RESULT_NAMES <= {p.name for p in out.iterdir()}  # default folder beside the input
    check_complete_outputs(out, "clip", list(range(N_FRAMES)))


def test_seed_flag_overrides_the_config_file(script_run):
    _, out = script_run
    info = json.loads((out / "run.json").read_text())
    assert info["config"]["seed"] == 3 and info["config"]["tracker"]["n_particles"] == 60


def test_box_origin_one_is_shifted_to_zero_based(script_run):
    _, out = script_run
    info = json.loads((out / "run.json").read_text())
    assert info["targets"][0]["box_xywh"] == [float(v) for v in BOX0.split(",")]
    coco = json.loads((out / "annotations.json").read_text())
    assert coco["annotations"][0]["bbox"] == [float(v) for v in BOX0.split(",")]
    # The OTB file is 1-based again: its first row is the box as given.
    first = (out / "clip.txt").read_text().splitlines()[0]
    assert [float(v) for v in first.split(",")][:2] == [float(v) + 1 for v in BOX0.split(",")[:2]]


def test_same_seed_gives_identical_otb_file(script_run, runner_run):
    """In another process, with the box given 0-based: the same seed gives the same boxes, byte for byte."""
    (_, out_a), (result, out_b) = script_run, runner_run
    assert result.exit_code == 0, result.output
    assert (out_a / "clip.txt").read_bytes() == (out_b / "clip.txt").read_bytes()
    table_a, table_b = read_flags_csv(out_a / "flags.csv"), read_flags_csv(out_b / "flags.csv")
    assert np.array_equal(table_a.log_likelihood, table_b.log_likelihood)


def test_console_script_default_command_and_version(clip):
    assert run_script("--version").stdout.strip() == f"sptpt-annotate {annotator.__version__}"
    usage = run_script(clip)  # no --box: a usage error from the default 'track' command
    assert usage.returncode == 2 and "--box" in usage.stderr and "Traceback" not in usage.stderr


def test_debug_shows_the_traceback_and_keeps_the_exit_code(work):
    missing = work / "missing.mp4"
    plain = run_script(missing, "--box", "1,2,3,4")
    assert plain.returncode == 3 and "Traceback" not in plain.stderr
    assert plain.stderr == f"sptpt-annotate: error: {missing}: no such file or folder; expected a video file, " \
                           "a folder of images or an OTB sequence folder - check the path\n"
    debug = run_script(missing, "--box", "1,2,3,4", "--debug")
    assert debug.returncode == 3 and "Traceback" in debug.stderr and "ToolError" in debug.stderr


@pytest.mark.parametrize("error, code, needle", [
    (OSError(28, "No space left on device", "/data/out/overlay.mp4"), 5,
     "sptpt-annotate: error: no space left on the disk while writing /data/out/overlay.mp4 (No space left on "
     "device): free space, or write the results elsewhere with --out\n"),
    (OSError(5, "Input/output error"), 1, "sptpt-annotate: internal error: OSError: [Errno 5] Input/output error"),
])
def test_a_full_disk_is_an_output_error_not_a_bug(clip, monkeypatch, capsys, error, code, needle):
    import annotator.run

    def full(*args, **kwargs):
        raise error

    monkeypatch.setattr(annotator.run, "annotate", full)
    with pytest.raises(SystemExit) as caught:
        main([str(clip), "--box", "1,2,3,4", "--quiet"])
    assert caught.value.code == code
    err = capsys.readouterr().err
    assert err.startswith(needle) and err.count("\n") == 1


def interrupt_after_two_frames(*args) -> str:
    """Run the console script and send it SIGINT once its progress shows tracking; its stderr after that."""
    proc = subprocess.Popen([*console_script(), *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True)
    try:
        for line in proc.stderr:
            done = re.match(r"frames (\d+)/", line)
            if done and int(done.group(1)) >= 2:  # tracking is under way
                proc.send_signal(signal.SIGINT)
                break
        rest = proc.stderr.read()
        assert proc.wait(timeout=120) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in rest
    return rest


def test_ctrl_c_exits_130_and_leaves_no_half_written_file(config_file, work):
    """SIGINT to the console script mid-run (once its progress shows tracking): exit 130, no temporary file,
    and the frames tracked so far written completely."""
    clip = write_clip(work / "long.mp4", 40)
    out = work / "interrupted"
    rest = interrupt_after_two_frames(clip, "--box", BOX0, "--config", config_file, "--out", out)
    assert "interrupted after" in rest
    no_temporaries(out)
    # Nothing computed is lost: the frames tracked before Ctrl-C are written, marked incomplete.
    run = json.loads((out / "run.json").read_text())
    assert run["interrupted"] is True and run["complete"] is False
    assert 2 <= run["frames_processed"] < 40
    check_complete_outputs(out, "long", list(range(run["frames_processed"])))
    assert not (out / "incomplete").exists()


def test_ctrl_c_during_force_keeps_the_earlier_finished_run(config_file, work):
    """--force replaces a finished run only with a finished one: Ctrl-C leaves the earlier run byte for byte,
    and the frames tracked so far go to incomplete/, a run folder of their own."""
    clip = write_clip(work / "again.mp4", 40)
    out = work / "forced"
    first = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 6, "--quiet")
    assert first.exit_code == 0, first.output
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    rest = interrupt_after_two_frames(clip, "--box", BOX0, "--config", config_file, "--out", out, "--force")
    assert f"the earlier finished run in {out} is kept" in rest and str(out / "incomplete") in rest
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*")
            if p.is_file() and "incomplete" not in p.parts} == before
    no_temporaries(out)
    partial = json.loads((out / "incomplete" / "run.json").read_text())
    assert partial["interrupted"] is True and 2 <= partial["frames_processed"] < 40
    check_complete_outputs(out / "incomplete", "again", list(range(partial["frames_processed"])))


def test_a_second_run_into_a_folder_in_use_stops_with_one_line(clip, config_file, work):
    from annotator.output_folder import folder_lock

    out = work / "busy"
    out.mkdir()
    with folder_lock(out):  # as a run in another process holds it
        busy = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 3)
    assert busy.exit_code == 5 and busy.stderr.count("\n") == 1
    assert f"output folder {out} is in use by another sptpt-annotate run" in busy.stderr
    assert list(out.iterdir()) == []
    done = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 3, "--quiet")
    assert done.exit_code == 0, done.output


def test_results_reach_a_subfolder_on_another_file_system_and_a_failed_move_keeps_them(clip, config_file, work,
                                                                                          monkeypatch):
    import errno

    out = work / "moved"
    replace = os.replace

    def cross_device(source, target):  # as when mot/ is a symlink to another disk
        if ".sptpt-run." in str(source) and ".sptpt-run." not in str(target) and "mot" in Path(target).parts:
            raise OSError(errno.EXDEV, "Invalid cross-device link")
        replace(source, target)

    monkeypatch.setattr(os, "replace", cross_device)
    moved = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 3, "--quiet",
                   "--formats", "otb,mot")
    assert moved.exit_code == 0, moved.output
    assert (out / "mot" / "gt" / "gt.txt").is_file() and not list(out.glob(".sptpt-run.*"))
    monkeypatch.setattr(os, "replace", replace)

    def full_disk(source, target):  # moving the track store out of the staging folder
        if Path(target).name == "tracks.npz" and ".sptpt-run." in str(source) and ".sptpt-run." not in str(target):
            raise OSError(errno.ENOSPC, "No space left on device", str(target))
        replace(source, target)

    monkeypatch.setattr(os, "replace", full_disk)
    failed = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 3, "--force",
                    "--formats", "otb", "--quiet")
    assert failed.exit_code == 5 and failed.stderr.count("\n") == 1, failed.stderr
    staging = re.search(r"results are in (\S+):", failed.stderr).group(1)
    assert "No space left on device" in failed.stderr and Path(staging).parent == out
    assert json.loads((Path(staging) / "run.json").read_text())["complete"] is True


# --------------------------------------------------------------------------- options that choose outputs


def test_formats_subset_writes_only_those_files(clip, config_file, work):
    out = work / "subset"
    result = invoke(clip, "--box", BOX0, "--config", config_file, "--stop", 4, "--formats", "otb,flags", "--out", out)
    assert result.exit_code == 0, result.output
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "clip.txt", "flags.csv", "passes.npz", "run.json", "times", "times/clip_time.txt", "tracks.npz",
    ]  # fmt: skip
    check_complete_outputs(out, "clip", [0, 1, 2, 3])
    assert json.loads((out / "run.json").read_text())["formats"] == ["otb", "flags"]


def test_no_render_skips_the_overlay(clip, config_file, work):
    out = work / "norender"
    result = invoke(clip, "--box", BOX0, "--config", config_file, "--stop", 4, "--no-render", "--out", out, "-q")
    assert result.exit_code == 0, result.output
    assert result.stderr == ""
    names = {p.name for p in out.iterdir()}
    assert "overlay.mp4" not in names and {"report.html", "annotations.json", "flags.csv", "run.json"} <= names
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "No overlay video in this folder" in page and "<video" not in page
    check_complete_outputs(out, "clip", [0, 1, 2, 3])


def test_existing_results_are_refused_unless_force(clip, config_file, work):
    out = work / "existing"
    out.mkdir()
    (out / "run.json").write_text('{"old": true}\n')
    refused = invoke(clip, "--box", BOX0, "--config", config_file, "--stop", 3, "--out", out)
    assert refused.exit_code == 5
    assert "already holds results (run.json)" in refused.stderr and "--force" in refused.stderr
    assert (out / "run.json").read_text() == '{"old": true}\n' and sorted(p.name for p in out.iterdir()) == ["run.json"]
    forced = invoke(clip, "--box", BOX0, "--config", config_file, "--stop", 3, "--out", out, "--force", "-q")
    assert forced.exit_code == 0, forced.output
    check_complete_outputs(out, "clip", [0, 1, 2])
    assert RESULT_NAMES <= {p.name for p in out.iterdir()}
    # Forced again with other outputs: nothing of the earlier run is left to contradict the new run.json.
    again = invoke(clip, "--box", BOX0, "--box", "4,4,20,16", "--config", config_file, "--stop", 3, "--out", out,
                   "--force", "--formats", "otb", "-q")
    assert again.exit_code == 0, again.output
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "clip.1.txt", "clip.2.txt", "passes.npz", "run.json", "times", "times/clip.1_time.txt",
        "times/clip.2_time.txt", "tracks.npz",
    ]  # fmt: skip


def test_decode_error_part_way_exits_6_with_valid_results(config_file, work):
    full = write_clip(work / "full.mp4", 24, faststart=True)
    cut = work / "cut.mp4"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size * 6 // 10])
    good = open_frames(cut).frame_count
    assert 1 < good < 24
    out = work / "cut_out"
    result = invoke(cut, "--box", BOX0, "--config", config_file, "--out", out, "--quiet")
    assert result.exit_code == 6
    message = result.stderr.strip()
    assert "\n" not in message and message.startswith("sptpt-annotate: warning: ")
    assert f"decoding stopped after frame {good - 1}" in message and str(out) in message
    check_complete_outputs(out, "cut", list(range(good)))
    info = json.loads((out / "run.json").read_text())
    assert info["complete"] is False and f"frame {good - 1}" in info["decode_error"]
    # Forced over a finished run, a run cut short by a decode error goes beside it, not over it; the next finished
    # run replaces both.
    finished = invoke(full, "--box", BOX0, "--config", config_file, "--out", out, "--quiet", "--force",
                      "--formats", "otb,flags")
    assert finished.exit_code == 0, finished.output
    kept = (out / "full.txt").read_bytes()
    fixes = work / "cut_fixes.csv"
    fixes.write_text("frame,x,y,w,h\n1,30,25,24,20\n")
    again = invoke(cut, "--box", BOX0, "--config", config_file, "--out", out, "--quiet", "--force",
                   "--corrections", fixes)
    assert again.exit_code == 6 and f"the earlier finished run in {out} is kept" in again.stderr
    # The corrections are applied only to a whole run; the message says how to apply them to this one.
    assert f"'sptpt-annotate retrack {out / 'incomplete'} --corrections {fixes}'" in again.stderr
    assert (out / "full.txt").read_bytes() == kept and json.loads((out / "run.json").read_text())["complete"]
    check_complete_outputs(out / "incomplete", "cut", list(range(good)))
    (out / ".sptpt-run.k9.tmp").mkdir()  # the staging folder of a run killed with kill -9
    last = invoke(full, "--box", BOX0, "--config", config_file, "--out", out, "--quiet", "--force", "--stop", 5)
    assert last.exit_code == 0, last.output
    assert not (out / "incomplete").exists() and not (out / ".sptpt-run.k9.tmp").exists()
    check_complete_outputs(out, "full", list(range(5)))


# --------------------------------------------------------------------------- bad input


@pytest.fixture(scope="module")
def bad_inputs(work, clip) -> dict[str, Path]:
    folder = work / "bad"
    folder.mkdir()
    (folder / "text.mp4").write_text("this is not a video\n" * 20)
    (folder / "empty.mp4").write_bytes(b"")
    (folder / "no_images").mkdir()
    (folder / "no_images" / "notes.txt").write_text("hello")
    (folder / "cut_header.mp4").write_bytes(clip.read_bytes()[: clip.stat().st_size // 2])  # moov atom lost
    (folder / "a_file").write_text("not a folder")
    (folder / "unknown_key.yaml").write_text("tracker:\n  n_particle: 60\n")
    (folder / "bad_flag.yaml").write_text("flags:\n  min_span: 0\n")
    (folder / "bad_ranks.yaml").write_text("tracker:\n  ranks: [40, 30, 40]\n")
    (folder / "results").mkdir()
    (folder / "results" / "annotations.json").write_text("{}")
    (folder / "fix_past_stop.csv").write_text("frame,x,y,w,h\n12,5,5,10,10\n")
    (folder / "fix_empty.csv").write_text("frame,x,y,w,h,track_id\n")
    return {"clip": clip, **{p.name: p for p in folder.iterdir()}}


BAD = [
    # id, input, arguments (@name: a file of the bad-inputs folder; a --box is added if none), exit code, message words
    ("missing-file", "nope.mp4", [], 3, ["nope.mp4", "no such file", "check the path"]),
    ("text-as-mp4", "text.mp4", [], 3, ["text.mp4", "not a readable video"]),
    ("empty-file", "empty.mp4", [], 3, ["empty.mp4", "empty"]),
    ("truncated-header", "cut_header.mp4", [], 3, ["cut_header.mp4", "moov atom not found"]),
    ("folder-no-images", "no_images", [], 3, ["no_images", "no images"]),
    ("box-three-numbers", "clip", ["--box", "1,2,3"], 4, ["--box '1,2,3' is not four numbers"]),
    ("box-words", "clip", ["--box", "a,b,c,d"], 4, ["not four numbers"]),
    ("box-five-numbers", "clip", ["--box", "1,2,3,4,5"], 4, ["not four numbers"]),
    ("box-zero-width", "clip", ["--box", "10,10,0,5"], 4, ["zero or negative size", "w=0"]),
    ("box-negative-height", "clip", ["--box", "10,10,5,-5"], 4, ["zero or negative size"]),
    ("box-right-of-frame", "clip", ["--box", "96,10,10,10"], 4, ["lies outside the 96x72 first frame"]),
    ("box-above-frame", "clip", ["--box", "10,-30,10,10"], 4, ["lies outside"]),
    ("box-origin-two", "clip", ["--box-origin", "2"], 4, ["--box-origin 2 is invalid"]),
    ("second-box-bad", "clip", ["--box", "5,5,10,10", "--box", "1,2,3"], 4, ["--box '1,2,3' is not four numbers"]),
    ("empty-label", "clip", ["--box", "5,5,10,10", "--label", " "], 4, ["--label ' ' of box 1 is empty"]),
    ("labels-mismatch", "clip", ["--box", "5,5,10,10", "--box", "6,6,10,10", "--label", "a", "--label", "b",
                                 "--label", "c"], 4, ["--label given 3 times for 2 boxes"]),
    ("empty-range", "clip", ["--start", "5", "--stop", "5"], 4, ["stop=5 <= start=5 selects no frame"]),
    ("start-past-end", "clip", ["--start", "100"], 4, ["start=100 is past the last frame", "0 <= start < 16"]),
    ("step-zero", "clip", ["--step", "0"], 4, ["step=0 selects no frame"]),
    ("negative-start", "clip", ["--start", "-1"], 4, ["start=-1 is negative"]),
    ("unknown-format", "clip", ["--formats", "otb,xml"], 4, ["--formats xml is not known"]),
    ("config-unknown-key", "clip", ["--config", "@unknown_key.yaml"], 4,
     ["unknown_key.yaml", "unknown tracker parameter 'n_particle'", "did you mean 'n_particles'?"]),
    ("config-bad-value", "clip", ["--config", "@bad_flag.yaml"], 4, ["bad_flag.yaml", "min_span=0 is invalid"]),
    ("config-tracker-rejects", "clip", ["--config", "@bad_ranks.yaml"], 4, ["bad_ranks.yaml", "superpixel rank 30"]),
    ("config-missing", "clip", ["--config", "nope.yaml"], 3, ["nope.yaml does not exist"]),
    # Corrections are checked against the range before any tracking (nothing is written).
    ("corrections-past-stop", "clip", ["--stop", "8", "--corrections", "@fix_past_stop.csv"], 4,
     ["fix_past_stop.csv:2", "frame 12 was not processed"]),
    ("corrections-empty", "clip", ["--corrections", "@fix_empty.csv"], 4, ["fix_empty.csv is empty"]),
    ("unknown-preset", "clip", ["--preset", "turbo"], 4, ["unknown preset 'turbo'"]),
    ("negative-seed", "clip", ["--seed", "-1"], 4, ["seed must be a non-negative integer"]),
    ("out-is-a-file", "clip", ["--out", "@a_file"], 5, ["a_file is a file"]),
    ("out-under-a-file", "clip", ["--out", "@a_file/sub"], 5, ["cannot be written", "writable --out"]),
    ("out-holds-results", "clip", ["--out", "@results"], 5, ["already holds results (annotations.json)", "--force"]),
]


@pytest.mark.parametrize("input_name, extra, code, needles", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_exit_code_and_one_line_message(bad_inputs, work, tmp_path, input_name, extra, code, needles):
    source = bad_inputs.get(input_name, work / "bad" / input_name)
    extra = [str(work / "bad" / e[1:]) if e.startswith("@") else e for e in extra]
    if "--box" not in extra:
        extra = ["--box", "5,5,10,10", *extra]
    out = tmp_path / "out"
    if "--out" not in extra:
        extra += ["--out", str(out)]
    before = {p: p.stat().st_mtime_ns for p in (work / "bad").rglob("*")}
    result = invoke(source, *extra)
    assert result.exit_code == code, result.output
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("sptpt-annotate: error: "), result.stderr
    for needle in needles:
        assert needle in lines[0]
    assert "Traceback" not in result.output
    # Nothing was written, half or whole: no output folder, no temporary file, inputs untouched.
    assert not out.exists() or not any(out.iterdir())
    assert {p: p.stat().st_mtime_ns for p in (work / "bad").rglob("*")} == before
    no_temporaries(work / "bad")


@pytest.mark.parametrize(
    "args, needles",
    [
        ([], ["Missing option '--box'"]),
        # click's wording of an unknown option changes with the typer and click versions ("No such option:
        # --frobnicate", "No such option '--frobnicate'."): the promise is that the message names it.
        (["--box", "1,2,3,4", "--frobnicate"], ["No such option", "--frobnicate"]),
        (["--box", "1,2,3,4", "--start", "one"], ["Invalid value for '--start'"]),
    ],
)
def test_usage_errors_exit_2_in_one_line(clip, args, needles, capsys):
    with pytest.raises(SystemExit) as info:
        main([str(clip), *args])
    out, err = capsys.readouterr()
    assert info.value.code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("sptpt-annotate: error: ")
    assert all(needle in err for needle in needles), err
    assert "(see 'sptpt-annotate track --help')" in err


@pytest.mark.parametrize("argv, code, first, named", [
    (["evall", "a", "b"], 2, "sptpt-annotate: error: 'evall' is neither a command nor an existing video or folder: "
                             "did you mean 'sptpt-annotate eval'?", ""),
    # The rest of the line is click's wording, which changes with the typer and click versions.
    (["batch", "--bogus"], 2, "sptpt-annotate: error: No such option", "--bogus"),
    ([], 2, "Usage: sptpt-annotate", ""),
    (["--help"], 0, "Usage: sptpt-annotate", ""),
])
def test_mistyped_commands_and_help(argv, code, first, named, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    out, err = capsys.readouterr()
    assert info.value.code == code and (out + err).startswith(first) and named in (out + err).splitlines()[0]


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder_exits_5(clip, tmp_path):
    out = tmp_path / "locked"
    out.mkdir()
    out.chmod(0o500)
    try:
        result = invoke(clip, "--box", BOX0, "--out", out)
        assert result.exit_code == 5 and "cannot be written" in result.stderr
        assert list(out.iterdir()) == []
    finally:
        out.chmod(0o700)


# --------------------------------------------------------------------------- what a new user trips over (issue #14)


@pytest.mark.parametrize("box, needle", [("30,30,1,1", "is only 1x1 px"), ("-30,40,40,40", "80% outside the 96x72")])
def test_doubtful_boxes_are_tracked_with_a_one_line_warning(clip, config_file, tmp_path, box, needle):
    result = invoke(clip, "--box", box, "--stop", 3, "--config", config_file, "--out", tmp_path / "o", "-q",
                    "--no-render")
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if line.startswith("sptpt-annotate: warning: ")]
    assert len(warnings) == 1 and needle in warnings[0], result.stderr


def test_a_good_box_gets_no_warning(clip, config_file, tmp_path):
    result = invoke(clip, "--box", BOX0, "--stop", 3, "--config", config_file, "--out", tmp_path / "o", "-q",
                    "--no-render")
    assert result.exit_code == 0 and "warning" not in result.stderr


def test_help_names_the_box_layout_and_the_default_preset():
    text = CliRunner().invoke(app, ["track", "--help"], terminal_width=200).stdout
    assert "--box X,Y,W,H" in text and "list[str]" not in text
    assert "[default: fused" in text


def test_a_folder_that_holds_results_is_refused_before_the_video_is_counted(clip, config_file, work, monkeypatch):
    """Opening a video decodes it all to count its frames (minutes for a long one): a refusal comes first."""
    import annotator.frame_sources

    out = work / "refused_early"
    done = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 3, "--quiet")
    assert done.exit_code == 0, done.output

    def counted(*args, **kwargs):
        raise AssertionError("the video was counted before the refusal")

    monkeypatch.setattr(annotator.frame_sources, "_count_video_frames", counted)
    again = invoke(clip, "--box", BOX0, "--config", config_file, "--out", out, "--stop", 3)
    assert again.exit_code == 5 and "already holds results" in again.stderr, again.output
    missing = invoke(work / "missing.mp4", "--box", BOX0, "--out", out)  # a missing input is still named first
    assert missing.exit_code == 3 and "no such file" in missing.stderr

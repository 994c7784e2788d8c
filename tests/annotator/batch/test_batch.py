"""Batch runs on tiny synthetic videos: isolated failures, dataset outputs, resume after kill -9, worker
deaths, no process left running after kill -9 of the main process, the same outputs with 1 and 2 workers and
through a Dask LocalCluster.

Items are 10-20 frames of 96x72 tracked with 60 particles, so that the whole file runs in well under a minute.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _runs import FAST, OBJECT, SIZE, box_text, write_clip, write_jsonl

from annotator.batch import BatchRequest, ItemJob, is_item_finished, item_seed, plan_batch, read_run_json, run_batch
from annotator.cli import main
from annotator.config import load_config_file
from annotator.frame_sources import open_frames
from annotator.manifest import read_manifest
from sptpt_dev.synthetic import make_clip

GOOD = ("v0", "v1", "v2")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Three good clips, a corrupt file, a missing file, a box outside the frame and a truncated clip."""
    root = tmp_path_factory.mktemp("dataset")
    (root / "clips").mkdir()
    rows = []
    for k, name in enumerate(GOOD):
        box = write_clip(root / "clips" / f"{name}.mp4", 10, seed=k)
        rows.append({"video": f"clips/{name}.mp4", "box": box_text(box)})
    (root / "clips" / "corrupt.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + os.urandom(2000))
    write_clip(root / "full.mp4", 12, seed=5, faststart=True)
    data = (root / "full.mp4").read_bytes()
    # Decodes some of 12 frames (how many depends on the ffmpeg), then damage.
    (root / "clips" / "cut.mp4").write_bytes(data[: int(len(data) * 0.8)])
    rows += [
        {"video": "clips/corrupt.mp4", "box": "10,10,20,20"},
        {"video": "clips/missing.mp4", "box": "10,10,20,20"},
        {"video": "clips/v0.mp4", "box": "500,500,10,10", "id": "offframe"},
        {"video": "clips/cut.mp4", "box": box_text(make_clip(12, size=SIZE, object_size=OBJECT, seed=5).boxes_xywh[0])},
    ]
    write_jsonl(root / "all.jsonl", rows)
    write_jsonl(root / "good.jsonl", rows[:3])
    (root / "fast.yaml").write_text(FAST, encoding="utf-8")
    return root


@pytest.fixture(scope="module")
def first_run(dataset):
    """The whole manifest through the CLI with 2 workers."""
    out = dataset / "out2"
    with pytest.raises(SystemExit) as info:
        main(["batch", str(dataset / "all.jsonl"), "--out", str(out), "--workers", "2", "--config",
              str(dataset / "fast.yaml"), "--quiet"])
    return out, info.value.code


def item_outputs(folder: Path) -> dict[str, bytes]:
    """The outputs that must not depend on timing: OTB boxes, COCO, flags."""
    names = [p.name for p in folder.glob("*.txt")] + ["annotations.json", "flags.csv"]
    return {name: (folder / name).read_bytes() for name in sorted(names)}


def test_failures_are_isolated_and_reported(first_run, dataset):
    out, code = first_run
    assert code == 7  # EXIT_BATCH_FAILURES
    summary = json.loads((out / "summary.json").read_text())
    status = {r["id"]: r["status"] for r in summary["items"]}
    assert status == {"v0": "done", "v1": "done", "v2": "done", "corrupt": "failed", "missing": "failed",
                      "offframe": "failed", "cut": "partial"}
    assert summary["counts"] == {"items": 7, "done": 3, "partial": 1, "failed": 3, "pending": 0, "reused": 0}
    failures = [json.loads(line) for line in (out / "failures.jsonl").read_text().splitlines()]
    by_id = {f["id"]: f for f in failures}
    assert set(by_id) == {"corrupt", "missing", "offframe", "cut"}
    assert by_id["corrupt"]["exit_code"] == 3 and "corrupt.mp4" in by_id["corrupt"]["error"]
    assert by_id["missing"]["exit_code"] == 3 and "no such file" in by_id["missing"]["error"]
    assert by_id["offframe"]["exit_code"] == 4 and "outside" in by_id["offframe"]["error"]
    assert by_id["cut"]["exit_code"] == 6 and "decoding stopped" in by_id["cut"]["error"]
    assert by_id["missing"]["manifest"] == f"{dataset / 'all.jsonl'}:5"
    for name in GOOD:
        assert (out / name / "run.json").is_file() and (out / name / f"{name}.txt").is_file()
        assert (out / name / "overlay.mp4").is_file() and (out / name / "report.html").is_file()
    # What decodes of a damaged file depends on the ffmpeg imageio-ffmpeg brings (6 frames with 7.x, 7 with 9.x):
    # the promise is that every frame that decoded is kept, and that the run says it is partial.
    run = read_run_json(out / "cut")
    assert run["complete"] is False and 1 <= run["frames_processed"] < 12
    boxes = (out / "cut" / "cut.txt").read_text().splitlines()
    assert len(boxes) == run["frames_processed"]
    # Seeds derive from the base seed (0) and the id, not from the order items ran in.
    assert all(r["seed"] == item_seed(0, r["id"]) for r in summary["items"])
    assert read_run_json(out / "v1")["config"]["seed"] == item_seed(0, "v1")


def test_merged_coco_has_unique_ids_and_one_video_per_item(first_run):
    from pycocotools.coco import COCO

    out, _ = first_run
    merged = json.loads((out / "annotations.json").read_text())
    assert [v["name"] for v in merged["videos"]] == ["v0", "v1", "v2", "cut"]  # manifest order; partial kept
    for key in ("videos", "images", "annotations", "tracks"):
        ids = [x["id"] for x in merged[key]]
        assert ids == list(range(1, len(ids) + 1))
    cut = read_run_json(out / "cut")["frames_processed"]  # how many decoded depends on the ffmpeg
    assert len(merged["images"]) == 10 + 10 + 10 + cut
    assert {im["file_name"].split("/")[0] for im in merged["images"]} == {"v0", "v1", "v2", "cut"}
    singles = sum(len(json.loads((out / n / "annotations.json").read_text())["annotations"]) for n in (*GOOD, "cut"))
    assert len(merged["annotations"]) == singles
    coco = COCO(str(out / "annotations.json"))
    assert len(coco.getImgIds()) == 30 + cut


def test_index_report_links_every_item_and_sorts(first_run):
    out, _ = first_run
    page = (out / "report.html").read_text()
    for name in GOOD:
        assert f'<a href="{name}/report.html">{name}</a>' in page
    for name in ("corrupt", "missing", "offframe", "cut"):
        assert f'data-sort="{name}"' in page
    assert page.count("<tr>") == 1 + 7  # header + one row per item
    assert "sortBy" in page and "aria-sort" in page
    assert "no such file" in page  # the reason is shown


def test_one_and_two_workers_give_identical_outputs_and_reruns_skip(first_run, dataset):
    out2, _ = first_run
    out1 = dataset / "out1"
    items = read_manifest(dataset / "good.jsonl")
    config = load_config_file(dataset / "fast.yaml")
    result = run_batch(items, BatchRequest(config_values=config), out_dir=out1, workers=1, show_progress=False)
    assert result.exit_code == 0 and result.counts["done"] == 3
    for name in GOOD:
        assert item_outputs(out1 / name) == item_outputs(out2 / name), name
    merged1 = json.loads((out1 / "annotations.json").read_text())
    merged2 = json.loads((out2 / "annotations.json").read_text())
    assert merged1["annotations"] == [a for a in merged2["annotations"] if a["video_id"] <= 3]

    # A rerun keeps every finished item untouched.
    stamps = {name: (out1 / name / "run.json").stat().st_mtime_ns for name in GOOD}
    again = run_batch(items, BatchRequest(config_values=config), out_dir=out1, workers=1, show_progress=False)
    assert again.exit_code == 0 and again.counts["reused"] == 3 and again.frames_this_run == 0
    assert {name: (out1 / name / "run.json").stat().st_mtime_ns for name in GOOD} == stamps
    assert json.loads((out1 / "annotations.json").read_text()) == merged1

    # Changed params, a changed input or --force make an item's outputs stale; nothing else does.
    def reuse(force=False, **kwargs):
        request = BatchRequest(config_values=kwargs.pop("config", config), **kwargs)
        plans = plan_batch(items, request, out_dir=out1, force=force)
        return {p.item.id: p.reuse for p in plans}

    assert reuse() == {"v0": True, "v1": True, "v2": True}
    assert reuse(force=True) == {"v0": False, "v1": False, "v2": False}
    assert reuse(seed=1) == {"v0": False, "v1": False, "v2": False}
    assert reuse(stop=5) == {"v0": False, "v1": False, "v2": False}
    assert reuse(formats=["otb", "coco"]) == {"v0": False, "v1": False, "v2": False}
    assert reuse(config={"tracker": {"n_particles": 61, "n_negatives": 20}})["v0"] is False
    edited = [*items]
    edited[1] = type(items[1])(**{**items[1].__dict__, "params": {"flags": {"merge_gap": 2}}})
    plans = plan_batch(edited, BatchRequest(config_values=config), out_dir=out1)
    assert [p.reuse for p in plans] == [True, False, True]
    job: ItemJob = plans[0].job
    run = read_run_json(out1 / "v0")
    assert is_item_finished(job, run)
    assert not is_item_finished(job, {**run, "complete": False})
    assert not is_item_finished(job, {**run, "input": {**run["input"], "content_hash": "sha256:0"}})
    # An image folder tracked before EXIF orientations were applied is redone (its boxes may be sideways).
    from annotator.provenance import content_hash

    images = dataset / "as_images"
    images.mkdir(exist_ok=True)
    (images / "0001.jpg").write_bytes(b"not decoded here")
    folder_job = dataclasses.replace(job, input_path=str(images))
    recorded = {**run["input"], "path": str(images.resolve()), "content_hash": content_hash(images)}
    assert not is_item_finished(folder_job, {**run, "input": recorded})
    assert is_item_finished(folder_job, {**run, "input": {**recorded, "exif_orientation": "applied"}})


def in_progress(out: Path) -> tuple[list[Path], list[Path]]:
    """Item folders with a run.json, and those being written (files, temporary or final, but no run.json yet).

    Final files count too: between two atomic renames an item in progress can hold no temporary file.
    """
    folders = [d for d in out.iterdir() if d.is_dir()] if out.is_dir() else []
    finished = [d for d in folders if (d / "run.json").is_file()]
    running = [d for d in folders if not (d / "run.json").exists() and any(d.iterdir())]
    return finished, running


def start_batch(manifest: Path, out: Path, config: Path, workers: int = 1) -> subprocess.Popen:
    command = [sys.executable, "-m", "annotator.cli", "batch", str(manifest), "--out", str(out), "--workers",
               str(workers), "--config", str(config), "--quiet"]
    return subprocess.Popen(command, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def wait_until(condition, proc: subprocess.Popen, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if proc.poll() is not None:
            pytest.fail(f"batch ended (exit {proc.returncode}) before the moment to kill it: {proc.stdout.read()!r}")
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    pytest.fail("the batch never reached the moment to kill it")


def wait_for_group_to_exit(group: int, timeout: float = 10.0) -> None:
    """Wait until no process of the process group is left (an unreaped orphan counts as left: then the timeout)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return
        time.sleep(0.02)


def check_every_output_parses(out: Path) -> None:
    assert not list(out.rglob(".*.tmp*")), "temporary files left behind"
    for path in out.rglob("*.json"):
        json.loads(path.read_text())
    for line in (out / "failures.jsonl").read_text().splitlines():
        json.loads(line)
    for folder in (d for d in out.iterdir() if d.is_dir()):
        run = read_run_json(folder)
        frames = run["frames_processed"]
        with open(folder / "flags.csv", newline="") as handle:
            assert len(list(csv.DictReader(handle))) == frames
        assert len((folder / f"{folder.name}.txt").read_text().splitlines()) == frames
        assert open_frames(folder / "overlay.mp4").frame_count == frames


@pytest.fixture(scope="module")
def longer(dataset) -> Path:
    """Three 20-frame clips, so that a run can be caught with one item finished and the next in progress."""
    rows = []
    for k in range(3):
        box = write_clip(dataset / f"long{k}.mp4", 20, seed=10 + k)
        rows.append({"video": f"long{k}.mp4", "box": box_text(box)})
    return write_jsonl(dataset / "long.jsonl", rows)


def test_kill_9_mid_item_then_rerun_finishes_the_rest_without_redoing(dataset, longer):
    out = dataset / "killed"
    proc = start_batch(longer, out, dataset / "fast.yaml")
    wait_until(lambda: all(in_progress(out)), proc)
    os.killpg(proc.pid, signal.SIGKILL)  # the parent, its fork server and its worker, all at once
    proc.wait(10)
    # The worker dies a moment after its parent: until then it holds its item folder's lock, and a rerun started
    # at once finds that item "in use by another run" (a person reruns after the kill, not during it).
    wait_for_group_to_exit(proc.pid)
    finished, running = in_progress(out)
    assert finished and running
    kept = {d.name: ((d / "run.json").read_bytes(), (d / "run.json").stat().st_mtime_ns) for d in finished}

    result = run_batch(read_manifest(longer), BatchRequest(config_values=load_config_file(dataset / "fast.yaml")),
                       out_dir=out, workers=1, show_progress=False)
    assert result.exit_code == 0 and result.counts["done"] == 3
    assert {r["id"] for r in result.rows if r["reused"]} == set(kept)
    for name, (content, mtime) in kept.items():
        assert (out / name / "run.json").read_bytes() == content
        assert (out / name / "run.json").stat().st_mtime_ns == mtime
    check_every_output_parses(out)


def test_a_worker_killed_mid_item_is_replaced_and_its_item_retried(dataset, longer):
    psutil = pytest.importorskip("psutil")
    out = dataset / "worker-killed"
    proc = start_batch(longer, out, dataset / "fast.yaml")

    def running_worker():
        if not in_progress(out)[1]:
            return None
        servers = [p for p in psutil.Process(proc.pid).children() if "forkserver" in " ".join(p.cmdline())]
        workers = [w for s in servers for w in s.children()]
        return workers[0] if workers else None

    worker = wait_until(running_worker, proc)
    victim = in_progress(out)[1][0].name
    worker.kill()
    if proc.wait(90) != 0:  # pytest would cut the batch's output short in the assertion's message; say all of it
        pytest.fail(f"batch exit {proc.returncode}: {proc.stdout.read().decode(errors='replace')}\n"
                    f"summary: {(out / 'summary.json').read_text() if (out / 'summary.json').is_file() else 'none'}")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"]["done"] == 3
    row = next(r for r in summary["items"] if r["id"] == victim)
    assert row["status"] == "done" and row["worker_pid"] != worker.pid
    check_every_output_parses(out)


def test_kill_9_of_the_main_process_alone_stops_its_workers_and_fork_server(dataset, longer):
    psutil = pytest.importorskip("psutil")
    out = dataset / "main-killed"
    proc = start_batch(longer, out, dataset / "fast.yaml", workers=2)

    def run_processes():
        """Every descendant (fork server, resource tracker, workers, their ffmpeg), once a worker is mid-item."""
        if not in_progress(out)[1]:
            return None
        try:
            descendants = psutil.Process(proc.pid).children(recursive=True)
            servers = [p for p in descendants if "forkserver" in " ".join(p.cmdline())]
            return set(descendants) if any(s.children() for s in servers) else None
        except psutil.Error:  # a process ended while being looked at: look again
            return None

    processes = wait_until(run_processes, proc)
    os.kill(proc.pid, signal.SIGKILL)  # the main process only: the rest must follow it by themselves
    proc.wait(10)

    def alive():
        running = []
        for process in list(processes):
            with contextlib.suppress(psutil.Error):
                # A dead orphan may stay a zombie until init reaps it: it runs nothing and holds no memory.
                if process.is_running() and process.status() != psutil.STATUS_ZOMBIE:
                    running.append(process)
                    processes.update(process.children())  # started after the first look
        return running

    deadline = time.monotonic() + 10.0
    while alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    left = []
    for process in alive():
        with contextlib.suppress(psutil.Error):
            left.append(f"{process.pid} {' '.join(process.cmdline())[:80]}")
            process.kill()  # not left behind for the rest of the suite
    assert not left, f"still running 10 s after the main process died: {left}"


def test_dask_local_cluster_gives_the_same_outputs(first_run, dataset):
    distributed = pytest.importorskip("distributed")
    out2, _ = first_run
    out = dataset / "dask"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        result = run_batch(read_manifest(dataset / "good.jsonl"),
                           BatchRequest(config_values=load_config_file(dataset / "fast.yaml")), out_dir=out,
                           scheduler=cluster.scheduler_address, show_progress=False)
    assert result.exit_code == 0 and result.counts["done"] == 3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["scheduler"].startswith("tcp://127.0.0.1:")
    for name in GOOD:
        assert item_outputs(out / name) == item_outputs(out2 / name), name


def test_manifest_errors_stop_the_batch_before_any_work(tmp_path, capsys):
    manifest = tmp_path / "m.csv"
    manifest.write_text('video,box\na.mp4,"1,2,3"\nb.mp4,"1,2,3,4"\n,"1,2,3,4"\n')
    with pytest.raises(SystemExit) as info:
        main(["batch", str(manifest), "--out", str(tmp_path / "out")])
    assert info.value.code == 4
    err = capsys.readouterr().err.splitlines()
    assert err == [f"sptpt-annotate: error: {manifest}:2: box '1,2,3' is not four numbers x,y,w,h (it has 3 values): "
                   "give e.g. 120,80,40,60",
                   f"sptpt-annotate: error: {manifest}:4: no video given: give the path of a video file or image "
                   "folder as video"]
    assert not (tmp_path / "out").exists()


def test_batch_box_origin_is_checked_in_one_line_before_any_work(tmp_path, capsys):
    manifest = tmp_path / "m.csv"
    manifest.write_text('video,box\na.mp4,"1,2,3,4"\n')
    (tmp_path / "otb").mkdir()
    for argv, code, needle in (
            (["batch", str(manifest), "--box-origin", "2"], 4, "--box-origin 2 is invalid: expected 0 (default) or 1"),
            (["batch", "--otb-root", str(tmp_path / "otb"), "--box-origin", "1"], 2, "drop --box-origin")):
        with pytest.raises(SystemExit) as info:
            main([*argv, "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err.splitlines()
        assert info.value.code == code and len(err) == 1 and needle in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_missing_manifest_exits_3_and_an_otb_root_without_sequences_4(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    for argv, code, needle in ((["batch", str(tmp_path / "none.csv")], 3, "manifest file does not exist"),
                               (["batch", str(tmp_path / "none")], 3, "manifest file does not exist"),
                               (["batch", "--otb-root", str(tmp_path / "empty")], 4, "no sequence found")):
        with pytest.raises(SystemExit) as info:
            main([*argv, "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert info.value.code == code and err.count("\n") == 1 and needle in err, (argv, err)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv, needle", [
    (["batch", "--out", "x"], "give either a MANIFEST file or --otb-root"),
    (["batch", "m.csv", "--otb-root", "r", "--out", "x"], "give either a MANIFEST file or --otb-root"),
])
def test_usage_errors(argv, needle, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2 and needle in capsys.readouterr().err


def test_bad_batch_settings_exit_4(tmp_path, capsys):
    manifest = write_jsonl(tmp_path / "m.jsonl", [{"video": "a.mp4", "box": "1,2,3,4"}])
    for extra, needle in ((["--workers", "0"], "--workers 0"), (["--formats", "otb,gif"], "--formats gif"),
                          (["--preset", "nope"], "unknown preset"), (["--start", "-1"], "--start -1"),
                          (["--start", "5", "--stop", "5"], "--stop 5"),
                          (["--scheduler", "hello world"], "is not a Dask scheduler address")):
        with pytest.raises(SystemExit) as info:
            main(["batch", str(manifest), "--out", str(tmp_path / "out"), *extra])
        err = capsys.readouterr().err
        assert info.value.code == 4 and needle in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def _tiny_otb_root(root: Path) -> Path:
    import cv2

    clip = make_clip(3, size=SIZE, object_size=OBJECT, seed=30)
    (root / "Alpha" / "img").mkdir(parents=True)
    for i, frame in enumerate(clip.frames):
        cv2.imwrite(str(root / "Alpha" / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    x, y, w, h = clip.boxes_xywh[0]
    (root / "Alpha" / "groundtruth_rect.txt").write_text(f"{x + 1},{y + 1},{w},{h}\n" * 3)
    return root


def test_an_out_folder_that_is_the_input_root_is_refused_and_nothing_is_touched(tmp_path, capsys):
    root = _tiny_otb_root(tmp_path / "otb")
    before = sorted(str(p.relative_to(root)) for p in root.rglob("*"))
    with pytest.raises(SystemExit) as info:
        main(["batch", "--otb-root", str(root), "--out", str(root), "--workers", "1", "--no-render", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 5
    assert len(err) == 1 and "would write into the input folder" in err[0] and "outside the input" in err[0]
    assert sorted(str(p.relative_to(root)) for p in root.rglob("*")) == before


def test_an_out_folder_holding_a_single_video_run_is_refused(tmp_path, capsys):
    manifest = write_jsonl(tmp_path / "m.jsonl", [{"video": "a.mp4", "box": "1,2,3,4"}])
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}")
    (run / "annotations.json").write_text("{}")
    with pytest.raises(SystemExit) as info:
        main(["batch", str(manifest), "--out", str(run), "--force", "--quiet"])
    assert info.value.code == 5 and "single-video run" in capsys.readouterr().err
    assert (run / "annotations.json").read_text() == "{}" and sorted(p.name for p in run.iterdir()) == [
        "annotations.json", "run.json"]


def test_redoing_an_item_removes_only_what_its_earlier_run_wrote(tmp_path):
    from annotator.batch.workers import _clear_item_folder

    folder = tmp_path / "Alpha"
    (folder / "times").mkdir(parents=True)
    (folder / "yolo").mkdir()
    outputs = {"otb": ["Alpha.txt", "times/Alpha_time.txt"], "flags": ["flags.csv"], "yolo": ["yolo/frames.txt"]}
    (folder / "run.json").write_text(json.dumps({"outputs": outputs}))
    (folder / ".sptpt-run.x1y2.tmp" / "mot").mkdir(parents=True)  # the staging folder of a killed run
    for name in ("Alpha.txt", "times/Alpha_time.txt", "flags.csv", "tracks.npz", ".flags.csv.123.tmp",
                 "yolo/frames.txt", "groundtruth_rect.txt", "notes.txt", "times/mine.txt",
                 ".sptpt-run.x1y2.tmp/flags.csv", ".sptpt-run.x1y2.tmp/mot/gt.txt"):
        (folder / name).write_text("x")
    _clear_item_folder(folder, "Alpha")
    assert sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()) == [
        "groundtruth_rect.txt", "notes.txt", "times/mine.txt"]
    assert not (folder / ".sptpt-run.x1y2.tmp").exists()


def test_a_killed_runs_otb_files_go_and_a_symlinked_subfolder_is_not_followed(tmp_path):
    from annotator.batch.workers import _clear_item_folder

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious.txt").write_text("keep")
    folder = tmp_path / "item7"  # an item id other than the video's name
    folder.mkdir()
    (folder / "times").symlink_to(elsewhere, target_is_directory=True)
    (folder / "run.json").write_text(json.dumps({"outputs": {"otb": ["times/precious.txt"]}}))
    _clear_item_folder(folder, "Alpha")
    assert (elsewhere / "precious.txt").read_text() == "keep"
    (folder / "times").unlink()
    (folder / "times").mkdir()
    for name in ("Alpha.txt", "Alpha.2.txt", "times/Alpha_time.txt", "Beta.txt"):  # no run.json: killed before it
        (folder / name).write_text("x")
    _clear_item_folder(folder, "Alpha")
    assert sorted(p.name for p in folder.rglob("*") if p.is_file()) == ["Beta.txt"]


def test_the_out_check_compares_every_item_folder_with_every_input_folder(tmp_path):
    from annotator.batch.runner import _refuse_unsafe_out_dir
    from annotator.errors import ToolError
    from annotator.manifest import BatchItem
    from annotator.tracks import Target

    out = tmp_path / "out"
    (out / "frames").mkdir(parents=True)  # another item's input image folder, where item 'frames' would write
    (out / "clip").mkdir()
    (out / "clip" / "clip.mp4").write_bytes(b"")  # a video inside its own item folder: harmless
    target = (Target((1, 2, 3, 4), 1),)
    items = [BatchItem("frames", out / "clip" / "clip.mp4", target), BatchItem("other", out / "frames", target)]
    planned = plan_batch(items, out_dir=out, force=True)
    with pytest.raises(ToolError, match="item 'frames' would write into the input folder"):
        _refuse_unsafe_out_dir(out, planned)
    _refuse_unsafe_out_dir(out, plan_batch([BatchItem("clip", out / "clip" / "clip.mp4", target)], out_dir=out,
                                           force=True))


def test_a_missing_otb_root_is_named_once(tmp_path, capsys):
    root = tmp_path / "nope"
    with pytest.raises(SystemExit) as info:
        main(["batch", "--otb-root", str(root), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert info.value.code == 3 and err.count(str(root)) == 1 and "pass an OTB-layout root" in err


def test_a_second_run_on_the_same_folder_is_refused(tmp_path):
    pytest.importorskip("fcntl")
    from annotator.errors import ToolError
    from annotator.manifest import BatchItem
    from annotator.output_folder import folder_lock
    from annotator.tracks import Target

    out = tmp_path / "out"
    out.mkdir()
    with folder_lock(out):  # as a run or a batch in another process holds it: one lock for every writer
        with pytest.raises(ToolError, match="in use by another sptpt-annotate run") as info:
            run_batch([BatchItem("a", tmp_path / "a.mp4", (Target((1, 2, 3, 4), 1),))], out_dir=out,
                      show_progress=False)
    assert info.value.exit_code == 5
    assert list(out.iterdir()) == []  # the lock is on the folder: no lock file among the results


def test_item_seed_is_stable_and_depends_on_base_seed_and_id():
    assert item_seed(0, "v0") == item_seed(0, "v0") == 277254542094830  # golden: same on every machine
    assert len({item_seed(0, "v0"), item_seed(1, "v0"), item_seed(0, "v1")}) == 3
    assert 0 <= item_seed(2**40, "x" * 100) < 2**48


def test_an_otb_root_is_a_batch_that_eval_scores(tmp_path, capsys):
    import cv2

    root = tmp_path / "otb"
    for k, name in enumerate(("Alpha", "Beta")):
        clip = make_clip(8, size=SIZE, object_size=OBJECT, seed=20 + k)
        (root / name / "img").mkdir(parents=True)
        for i, frame in enumerate(clip.frames):
            cv2.imwrite(str(root / name / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        rows = [f"{x + 1:.2f},{y + 1:.2f},{w:.2f},{h:.2f}" for x, y, w, h in clip.boxes_xywh]  # OTB: 1-based
        (root / name / "groundtruth_rect.txt").write_text("\n".join(rows) + "\n")
    config = tmp_path / "fast.yaml"
    config.write_text(FAST)
    out = tmp_path / "out"
    main_exit = None
    try:
        main(["batch", "--otb-root", str(root), "--out", str(out), "--workers", "2", "--config", str(config),
              "--no-render", "--quiet"])
    except SystemExit as exc:
        main_exit = exc.code
    assert main_exit in (None, 0), capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["Alpha", "Beta"]
    assert not (out / "Alpha" / "overlay.mp4").exists()
    with pytest.raises(SystemExit) as info:
        main(["eval", str(out), str(root)])
    assert info.value.code in (None, 0)
    table = capsys.readouterr().out
    assert "Alpha" in table and "Beta" in table


def test_merged_coco_from_the_stores_keeps_real_image_paths_and_renames_frame_dumps(tmp_path):
    from annotator.batch.outputs import _item_stores
    from annotator.exports import write_dataset_exports
    from annotator.track_store import STORE_NAME, RunStore, write_store
    from annotator.tracks import TrackRecorder, VideoInfo

    recorder = TrackRecorder(1, "object")
    for k in range(2):
        recorder.append(k, [1.0, 2.0, 3.0, 4.0], confidence=0.9, log_likelihood=0.0, accepted=True, seconds=0.0)
    track = recorder.to_result()
    folder = tmp_path / "data" / "Coke"
    (folder / "img").mkdir(parents=True)
    videos = {
        "item-a": (VideoInfo(path=str(folder), name="Coke", width=8, height=8, fps=30.0, frame_count=2,
                             frame_files=("Coke/img/0001.jpg", "Coke/img/0002.jpg")), str(folder)),
        "item-b": (VideoInfo(path="clip.mp4", name="clip", width=8, height=8, fps=30.0, frame_count=2),
                   str(tmp_path / "clip.mp4")),
    }
    rows = []
    for item, (video, source) in videos.items():
        (tmp_path / "out" / item).mkdir(parents=True)
        write_store(tmp_path / "out" / item / STORE_NAME, RunStore(video=video, start=0, stop=2, step=1,
                                                                  tracks=[track]))
        rows.append({"id": item, "status": "done", "input": source})
    written = write_dataset_exports(tmp_path / "out", _item_stores(tmp_path / "out", rows), ["coco", "flags"])
    assert list(written) == ["coco"]  # flags are one file per video: they stay in the items' folders
    merged = json.loads(written["coco"][0].read_text(encoding="utf-8"))
    assert [v["name"] for v in merged["videos"]] == ["item-a", "item-b"]
    assert [im["file_name"] for im in merged["images"]] == [
        "Coke/img/0001.jpg", "Coke/img/0002.jpg", "item-b/000000.jpg", "item-b/000001.jpg"]


def test_an_item_whose_track_asks_for_keyframes_is_marked_in_the_summary_index_and_output(dataset, tmp_path, capsys):
    """Its flags are few (every 3rd frame here), so its flagged share would look good: the row counts the keyframes
    asked for, the index marks them, and the command line names the item."""
    config = tmp_path / "lost.yaml"
    config.write_text(FAST + "flags:\n  lost_threshold: 0.0001\n  keyframe_every: 3\n", encoding="utf-8")
    manifest = tmp_path / "one.jsonl"
    row = json.loads((dataset / "good.jsonl").read_text().splitlines()[0])
    row["video"] = str(dataset / row["video"])
    write_jsonl(manifest, [row])
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--config", str(config)])
    assert info.value.code == 0
    (item,) = json.loads((out / "summary.json").read_text())["items"]
    assert item["keyframes_asked"] == 3  # of 10 frames: positions 3, 6, 9 (9 is also the last)
    assert item["flagged"] == 3
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "<th class=\"num\" data-type=\"num\">Keyframes asked</th>" in page
    assert re.search(r'<td class="num warn" data-sort="3" title="a track looks lost: box these frames, then '
                     r'retrack">3</td>', page)
    err = capsys.readouterr().err
    assert f"1 item with a track that looks lost and asks for keyframes (box them, then retrack the item's folder; " \
           f"see its report.html): {item['id']}" in err

"""The frame-size, long-video and contrast-cost benchmarks' own parts: the resized sequence's ground truth, the memory
probe, the contrast table."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from _benchmark_scripts import load_script, run_benchmark
from _paths import ROOT


def test_a_resized_sequence_keeps_its_ground_truth_on_the_object(tmp_path, monkeypatch):
    sizes = load_script("video_sizes")
    source = tmp_path / "otb" / "Seq"
    (source / "img").mkdir(parents=True)
    for k in range(3):
        frame = np.zeros((60, 80, 3), np.uint8)
        frame[20 + k:30 + k, 10:30] = 255  # a white box at 1-based x 11, y 21 + k, 20 x 10
        cv2.imwrite(str(source / "img" / f"{k + 1:04d}.png"), frame)
    (source / "groundtruth_rect.txt").write_text("".join(f"11,{21 + k},20,10\n" for k in range(3)))
    monkeypatch.setattr(sizes, "SHARED", tmp_path / "otb")
    folder, box = sizes.make_sized("Seq", 2, (160, 90), tmp_path / "work")
    assert box == [20.0, 30.0, 40.0, 15.0]  # 0-based, x doubled, y 1.5 times
    assert len(list((folder / "img").iterdir())) == 2
    rows = (folder / "groundtruth_rect.txt").read_text().splitlines()
    assert rows == ["21.000,31.000,40.000,15.000", "21.000,32.500,40.000,15.000"]
    image = cv2.imread(str(folder / "img" / "0002.jpg"), cv2.IMREAD_GRAYSCALE)
    assert image.shape == (90, 160)
    x, y, w, h = 20, int(round(31.5)), 40, 15  # the second frame's box, 0-based
    assert image[y + 2:y + h - 2, x + 2:x + w - 2].mean() > 200 and image[:y - 3].mean() < 30


def test_a_row_takes_the_median_of_its_rounds_and_of_each_round_s_ratio(tmp_path, monkeypatch):
    sizes = load_script("video_sizes")
    folder = tmp_path / "Seq"
    (folder / "img").mkdir(parents=True)
    for k in range(10):
        (folder / "img" / f"{k:04d}.jpg").touch()
    monkeypatch.setattr(sizes, "make_sized", lambda *args: (folder, [1.0, 2.0, 3.0, 4.0]))
    monkeypatch.setattr(sizes, "_auc", lambda out, folder: 0.5)
    # Three rounds of (ours plain, ours with the overlay, CSRT): the second round's machine is twice as slow.
    times = iter([(10, 300), (12, 320), (5, 100), (20, 310), (24, 330), (10, 100), (11, 290), (14, 340), (4, 100)])
    commands = []

    def timed(command):
        commands.append(command)
        if "--out" in command and "--no-render" not in command:
            out = Path(command[command.index("--out") + 1])
            out.mkdir(parents=True, exist_ok=True)
            (out / "overlay.mp4").write_bytes(b"x" * 2**20)
        return next(times)

    monkeypatch.setattr(sizes, "_timed", timed)
    row = sizes.measure("Seq", 10, (160, 90), tmp_path / "work", Path("python"), repeats=3)
    assert len(commands) == 9 and all("--force" in c for c in commands[0::3] + commands[1::3])
    assert row["seconds"] == 11 and row["fps"] == 10 / 11 and row["csrt_seconds"] == 5
    assert row["ratio_csrt"] == 0.5 and row["ratio_range"] == (4 / 11, 0.5)  # each round's own ratio
    assert row["overlay_seconds"] == 3 and row["peak_mib"] == 300 and row["full_peak_mib"] == 330
    assert row["overlay_mib"] == 1.0


def test_bad_sizes_and_repeats_get_one_line_and_exit_code_2():
    for args, words in ((["--sizes", "320x240,320x"], "'320x' is not a frame size"),
                        (["--sizes", "1x5"], "'1x5' is not a frame size"), (["--repeats", "0"], "at least 1, got 0")):
        done = run_benchmark("video_sizes", *args)
        assert done.returncode == 2 and words in done.stderr.splitlines()[-1], args
    assert load_script("video_sizes").parse_size("1920x1080", print) == (1920, 1080)


def test_the_memory_probe_reads_this_process():
    long_video = load_script("long_video")
    assert 10 < long_video._tree_rss_mib(os.getpid()) < 100_000


def test_the_memory_probe_tells_the_decoder_from_the_encoder():
    """Issue #69 needs each process's share: the children are told apart by their command lines, as
    imageio-ffmpeg and the frame counter start them."""
    long_video = load_script("long_video")
    ffmpeg = "/site-packages/imageio_ffmpeg/binaries/ffmpeg-linux-x86_64-v9.0.2"
    decoder = [ffmpeg, "-threads", "1", "-i", "in.mp4", "-map", "0:v:0", "-f", "image2pipe", "-pix_fmt", "rgb24",
               "-vcodec", "rawvideo", "-"]
    encoder = [ffmpeg, "-y", "-f", "rawvideo", "-vcodec", "rawvideo", "-s", "1920x1080", "-pix_fmt", "rgb24", "-i",
               "-", "-vcodec", "libx264", "-pix_fmt", "yuv420p", "overlay.mp4"]
    counter = [ffmpeg, "-nostdin", "-i", "in.mp4", "-map", "0:v:0", "-f", "null", "-progress", "pipe:1", "-"]
    compile_child = ["/usr/bin/python3", "-c", "from sptpt import compile_kernels"]
    assert [long_video._role(c) for c in (decoder, encoder, counter, compile_child, [])] == [
        "decoder", "encoder", "other", "other", "other"]
    mine = long_video._rss_by_process(os.getpid())
    assert set(mine) == set(long_video.ROLES) and mine["tool"] > 10


def test_the_contrast_cost_benchmark_times_every_box_size():
    done = run_benchmark("contrast_cost", "--calls", "1", "--rounds", "1")
    assert done.returncode == 0, done.stderr
    rows = [line.split("|") for line in done.stdout.splitlines() if line.startswith("| ") and "x" in line[:12]]
    boxes = [cells[1].strip() for cells in rows if cells[1].strip() != "box"]
    assert boxes == [f"{w}x{h}" for w, h in load_script("contrast_cost").BOXES]
    assert all(float(cells[3]) > 0 for cells in rows if cells[1].strip() != "box")


def test_the_contrast_cost_benchmark_counts_the_calls_of_a_run_of_the_tool():
    box = (ROOT / "samples" / "clip_box.txt").read_text().strip()
    done = run_benchmark("contrast_cost", "--video", str(ROOT / "samples" / "clip.mp4"), "--box", box, "--stop", "4",
                         timeout=300)
    assert done.returncode == 0, done.stderr
    calls = int(done.stdout.split(" calls in 4 frames")[0].split()[-1])
    assert calls >= 3  # the failure signal's at least, on frames 1-3, and the tracker's own

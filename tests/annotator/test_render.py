"""Overlay renderer (exact pixels on synthetic frames) and the streaming MP4 writer (decoded back)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import pytest

from annotator.render import (
    DEFAULT_PALETTE,
    OverlayItem,
    OverlayRenderer,
    OverlayWriter,
    _encoder_environment,
    _text_colour,
    i420_to_rgb,
    items_from_tracks,
    label_text,
    rgb_to_i420,
)  # fmt: skip
from annotator.tracks import KEYFRAME_GIVEN, TrackResult
from sptpt.results import FrameResult

H, W = 60, 80
GRAY = 100


def gray_frame(height: int = H, width: int = W) -> np.ndarray:
    return np.full((height, width, 3), GRAY, dtype=np.uint8)


def plain(**kwargs) -> OverlayRenderer:
    """A renderer with every layer off except those asked for."""
    layers = dict(draw_particles=False, draw_superpixels=False, draw_boxes=False, draw_labels=False, draw_flags=False)
    layers.update(kwargs)
    return OverlayRenderer(**layers)


def test_annotate_returns_a_new_frame_and_leaves_the_input():
    frame = gray_frame()
    before = frame.copy()
    item = OverlayItem(box_xywh=[10, 10, 30, 20], track_id=1, confidence=0.87, flagged=True)
    out = OverlayRenderer().annotate(frame, [item])
    assert out is not frame and out.shape == frame.shape and out.dtype == np.uint8 and out.flags.c_contiguous
    assert np.array_equal(frame, before)
    assert not np.array_equal(out, frame)


def test_all_layers_off_draws_nothing():
    frame = gray_frame()
    item = OverlayItem(box_xywh=[10, 10, 30, 20], track_id=1, confidence=0.5, flagged=True, keyframe_source="c.txt:3")
    assert np.array_equal(plain().annotate(frame, [item]), frame)
    assert np.array_equal(OverlayRenderer().annotate(frame, []), frame)


def test_box_is_drawn_on_its_edges_in_the_track_colour():
    out = plain(draw_boxes=True, thickness=1, outline_color=None).annotate(gray_frame(),
                                                                           [OverlayItem([20, 15, 30, 25], 1, 0.9)])
    colour = DEFAULT_PALETTE[0]
    # Box covers columns 20..49 and rows 15..39.
    assert tuple(out[15, 35]) == colour and tuple(out[39, 35]) == colour
    assert tuple(out[27, 20]) == colour and tuple(out[27, 49]) == colour
    assert tuple(out[27, 35]) == (GRAY,) * 3 and tuple(out[5, 5]) == (GRAY,) * 3
    second = plain(draw_boxes=True, thickness=1, outline_color=None).annotate(gray_frame(),
                                                                              [OverlayItem([20, 15, 30, 25], 2, 0.9)])
    assert tuple(second[15, 35]) == DEFAULT_PALETTE[1]


def test_box_outline_is_dark_on_both_sides_of_the_line():
    out = plain(draw_boxes=True, thickness=1).annotate(gray_frame(), [OverlayItem([20, 15, 30, 25], 1, 0.9)])
    assert tuple(out[27, 20]) == DEFAULT_PALETTE[0]
    assert tuple(out[27, 19]) == (0, 0, 0) and tuple(out[27, 21]) == (0, 0, 0)
    assert tuple(out[27, 22]) == (GRAY,) * 3


def test_corrected_box_has_its_own_colour_and_label():
    renderer = plain(draw_boxes=True, draw_labels=True, thickness=1, corrected_color=(0, 220, 0))
    out = renderer.annotate(gray_frame(), [OverlayItem([20, 25, 30, 25], 1, 0.9, keyframe_source="fix.json:7")])
    assert tuple(out[49, 35]) == (0, 220, 0)  # bottom edge, away from the label
    tracker = renderer.annotate(gray_frame(), [OverlayItem([20, 25, 30, 25], 1, 0.9)])
    assert not np.array_equal(out, tracker)


@pytest.mark.parametrize(
    ("source", "given", "corrected", "text"),
    [
        (KEYFRAME_GIVEN, True, False, "id 4 given"),
        ("fix.json:7", False, True, "id 4 corrected"),
        ("", False, False, "id 4 0.87"),
    ],
)
def test_first_frame_box_is_labelled_given_and_a_correction_corrected(source, given, corrected, text):
    item = OverlayItem([20, 25, 30, 25], 4, 0.87, keyframe_source=source)
    assert (item.given, item.corrected, label_text(item)) == (given, corrected, text)


def test_given_box_keeps_the_track_colour_and_is_thicker():
    renderer = plain(draw_boxes=True, thickness=1, outline_color=None, corrected_color=(0, 220, 0))
    out = renderer.annotate(gray_frame(), [OverlayItem([20, 25, 30, 25], 1, 1.0, keyframe_source=KEYFRAME_GIVEN)])
    assert tuple(out[49, 35]) == DEFAULT_PALETTE[0]
    tracker = renderer.annotate(gray_frame(), [OverlayItem([20, 25, 30, 25], 1, 1.0)])
    assert np.count_nonzero(np.any(out != GRAY, axis=-1)) > np.count_nonzero(np.any(tracker != GRAY, axis=-1))


@pytest.mark.parametrize(
    ("background", "text"),
    [((0, 220, 0), (0, 0, 0)), (DEFAULT_PALETTE[0], (255, 255, 255)), ((255, 127, 14), (0, 0, 0)),
     ((0, 0, 0), (255, 255, 255)), ((255, 255, 255), (0, 0, 0))],
)
def test_label_text_colour_is_the_more_contrasting_of_black_and_white(background, text):
    assert _text_colour(background) == text


def test_keyframe_source_must_be_a_string():
    with pytest.raises(ValueError, match="keyframe_source"):
        OverlayItem([0, 0, 1, 1], 1, 0.5, keyframe_source=True)


@pytest.mark.parametrize(
    ("size", "thickness", "radius"),
    [((240, 320), 2, 0), ((480, 640), 2, 0), ((720, 1280), 3, 1), ((1080, 1920), 4, 2)],
)
def test_mark_sizes_scale_with_the_frame(size, thickness, radius):
    sizes = OverlayRenderer().sizes_for(*size)
    assert (sizes.thickness, sizes.particle_radius) == (thickness, radius)
    assert sizes.font_scale >= 0.4


def test_line_width_and_label_grow_with_the_frame():
    renderer = plain(draw_boxes=True, draw_labels=True, outline_color=None)
    small = renderer.annotate(gray_frame(240, 320), [OverlayItem([100, 100, 60, 50], 1, 0.9)])
    large = renderer.annotate(gray_frame(720, 1280), [OverlayItem([300, 300, 180, 150], 1, 0.9)])
    # The left edge's width, measured on a row below the label.
    width = lambda out, row, x: int(np.count_nonzero(np.all(out[row, x - 5 : x + 6] == DEFAULT_PALETTE[0], -1)))  # noqa: E731
    assert width(small, 130, 100) == 2 and width(large, 400, 300) == 3
    label_rows = lambda out: int(np.count_nonzero(np.any(np.all(out == DEFAULT_PALETTE[0], -1), axis=1)))  # noqa: E731
    assert label_rows(large) > label_rows(small)


def test_label_goes_below_a_box_at_the_top_of_the_frame():
    out = plain(draw_labels=True, outline_color=None).annotate(gray_frame(), [OverlayItem([20, 0, 30, 20], 1, 0.87)])
    assert np.array_equal(out[:20], gray_frame()[:20])  # the object is left clear
    assert np.any(np.all(out[20:] == DEFAULT_PALETTE[0], axis=-1))


def test_drawing_is_deterministic():
    rng = np.random.default_rng(0)
    particles = np.column_stack([rng.uniform(0, 70, (200, 2)), np.full((200, 2), 4.0)])
    item = OverlayItem([10, 10, 30, 20], 1, 0.5, particles_xywh=particles, particle_scores=rng.normal(size=200),
                       superpixel_labels=rng.integers(0, 4, (20, 30)), superpixel_origin_xy=[5, 5])
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    renderer = OverlayRenderer(particle_radius=2)
    assert np.array_equal(renderer.annotate(frame, [item]), renderer.annotate(frame.copy(), [item]))


def test_label_sits_above_the_box():
    out = plain(draw_labels=True).annotate(gray_frame(), [OverlayItem([20, 30, 30, 20], 1, 0.87)])
    above = out[:30, 20:]
    assert np.any(np.all(above == DEFAULT_PALETTE[0], axis=-1))  # the label's background
    assert np.array_equal(out[30:], gray_frame()[30:])


def test_flagged_frame_gets_a_red_border_and_review_tag():
    out = plain(draw_flags=True, flag_color=(230, 25, 25)).annotate(
        gray_frame(), [OverlayItem([20, 20, 10, 10], 1, 0.2, flagged=True)]
    )
    for y, x in [(0, 0), (H - 1, W - 1), (H // 2, 0), (0, W // 2), (H - 1, W // 2)]:
        assert tuple(out[y, x]) == (230, 25, 25)
    assert tuple(out[H // 2, W // 2]) == (GRAY,) * 3
    unflagged = plain(draw_flags=True).annotate(gray_frame(), [OverlayItem([20, 20, 10, 10], 1, 0.9)])
    assert np.array_equal(unflagged, gray_frame())


def test_nan_box_draws_nothing_but_keeps_the_review_mark():
    out = OverlayRenderer().annotate(gray_frame(), [OverlayItem([np.nan] * 4, 1, 0.1, flagged=True)])
    assert tuple(out[0, 0]) != (GRAY,) * 3 and tuple(out[H // 2, W // 2]) == (GRAY,) * 3


def test_particles_are_shaded_by_score_within_the_frame():
    renderer = plain(draw_particles=True, particle_radius=0, particle_min_alpha=1.0)
    particles = np.array([[10, 10, 4, 4], [30, 20, 6, 2], [50, 40, 2, 2]], dtype=float)
    scores = np.array([-3.0, 7.0, 2.0])
    item = OverlayItem([0, 0, 1, 1], 1, 0.5, particles_xywh=particles, particle_scores=scores)
    out = renderer.annotate(gray_frame(), [item])
    lut = renderer._lut.astype(np.uint8)
    assert tuple(out[12, 12]) == tuple(lut[0])  # worst: dark end of the colormap
    assert tuple(out[21, 33]) == tuple(lut[255])  # best: bright end
    assert tuple(out[41, 51]) == tuple(lut[round(5 / 10 * 255)])
    assert np.count_nonzero(np.any(out != GRAY, axis=-1)) == 3
    # Shading is relative to the frame: scaling all scores changes nothing.
    scaled = OverlayItem([0, 0, 1, 1], 1, 0.5, particles_xywh=particles, particle_scores=scores * 10)
    again = renderer.annotate(gray_frame(), [scaled])
    assert np.array_equal(out, again)


def test_worse_particles_are_fainter():
    renderer = plain(draw_particles=True, particle_radius=0, particle_min_alpha=0.25)
    particles = np.array([[10, 10, 4, 4], [30, 20, 6, 2]], dtype=float)
    item = OverlayItem([0, 0, 1, 1], 1, 0.5, particles_xywh=particles, particle_scores=np.array([0.0, 1.0]))
    out = renderer.annotate(gray_frame(), [item])
    lut = renderer._lut
    assert tuple(out[12, 12]) == tuple(np.round(GRAY * 0.75 + lut[0] * 0.25).astype(np.uint8))
    assert tuple(out[21, 33]) == tuple(lut[255].astype(np.uint8))


def test_superpixel_boundaries_inside_the_labelled_area():
    renderer = plain(draw_superpixels=True, superpixel_color=(255, 255, 255), superpixel_alpha=0.5)
    labels = np.full((10, 12), -1, dtype=np.int32)
    labels[1:9, 1:11] = 0
    labels[1:9, 6:11] = 1  # two superpixels side by side, split between window columns 5 and 6
    item = OverlayItem([0, 0, 1, 1], 1, 0.5, superpixel_labels=labels, superpixel_origin_xy=[30, 20])
    out = renderer.annotate(gray_frame(), [item])
    blended = round(GRAY * 0.5 + 255 * 0.5)
    changed = np.argwhere(np.any(out != GRAY, axis=-1))
    # Exactly the left pixel of each differing pair, rows 1..8 of the window: frame column 35, rows 21..28.
    assert changed.tolist() == [[20 + r, 35] for r in range(1, 9)]
    assert tuple(out[21, 35]) == (blended,) * 3


def test_superpixel_window_partly_outside_the_frame():
    labels = np.arange(20 * 20, dtype=np.int32).reshape(20, 20) // 7
    item = OverlayItem([0, 0, 1, 1], 1, 0.5, superpixel_labels=labels, superpixel_origin_xy=[-10, H - 5])
    out = plain(draw_superpixels=True).annotate(gray_frame(), [item])
    assert out.shape == (H, W, 3) and np.any(out != GRAY)


def test_items_from_frame_result_and_tracks():
    result = FrameResult(
        box_xywh=np.array([5.0, 6.0, 7.0, 8.0]), log_likelihood=1.0, confidence=0.7, accepted=True, scoring="subspace",
        particles_xywh=np.zeros((3, 4)), particle_scores=np.zeros(3),
    )  # fmt: skip
    item = OverlayItem.from_frame_result(result, track_id=3, flagged=True)
    assert item.track_id == 3 and item.flagged and item.particles_xywh.shape == (3, 4)
    track = TrackResult(
        track_id=2, label="object", frame_indices=np.array([0, 5]), boxes_xywh=np.array([[1, 2, 3, 4], [5, 6, 7, 8.0]]),
        confidence=np.array([1.0, 0.2]), log_likelihood=np.array([0.0, -1.0]), accepted=np.array([True, False]),
        flagged=np.array([False, True]), reasons=("", "absent"), keyframe=np.array([True, False]),
        outside=np.array([False, True]), seconds=np.zeros(2),
    )  # fmt: skip
    assert items_from_tracks([track], 3) == []
    (first,) = items_from_tracks([track], 0)
    assert first.given and not first.corrected and first.box_xywh.tolist() == [1, 2, 3, 4]
    (absent,) = items_from_tracks([track], 5)
    assert absent.flagged and np.isnan(absent.box_xywh).all()


@pytest.mark.parametrize(
    "bad", [np.zeros((H, W), np.uint8), np.zeros((H, W, 3), np.float32), np.zeros((H, W, 4), np.uint8)]
)
def test_annotate_rejects_non_rgb_uint8(bad):
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        OverlayRenderer().annotate(bad, [])


# --------------------------------------------------------------------------- writer


def decode(path: Path) -> tuple[dict, list[np.ndarray]]:
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    frames = [np.frombuffer(b, np.uint8).reshape(height, width, 3) for b in reader]
    return meta, frames


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_overlay_video_decodes_to_the_same_frames_with_marks_visible(tmp_path):
    height, width, n = 73, 97, 12  # odd on purpose: yuv420p needs even sizes
    renderer = OverlayRenderer(thickness=3, draw_labels=False)
    path = tmp_path / "overlay.mp4"
    with OverlayWriter(path, fps=25, width=width, height=height) as writer:
        assert writer.padded_size == (98, 74)
        for k in range(n):
            item = OverlayItem([10 + k, 30, 30, 24], 1, 0.9, flagged=(k == 5))
            writer.write(renderer.annotate(gray_frame(height, width), [item]))
    assert writer.frames_written == n and leftovers(tmp_path) == []
    data = path.read_bytes()
    assert data.find(b"moov") < data.find(b"mdat")  # faststart: the index comes first

    meta, frames = decode(path)
    assert len(frames) == n and meta["size"] == (98, 74) and meta["codec"] == "h264"
    assert meta["pix_fmt"].startswith("yuv420p(tv, smpte170m")  # BT.601, as converted: players need not guess
    blue = np.array(DEFAULT_PALETTE[0], float)
    for k, frame in enumerate(frames):
        frame = frame[:height, :width].astype(float)
        # Middle of the box's top and bottom edges (3 rows centred on rows 30 and 30 + 24 - 1).
        assert np.abs(frame[30, 25 + k] - blue).max() < 40, k
        assert np.abs(frame[53, 25 + k] - blue).max() < 40, k
        assert np.abs(frame[42, 25 + k] - GRAY).max() < 12, k  # inside the box: untouched background
        red_border = frame[1, width // 2][0] > 180 and frame[1, width // 2][1] < 80
        assert red_border == (k == 5), k


def running_command(pid: int) -> tuple[list[str], list[str]]:
    """A running process's arguments and environment, once /proc shows both (briefly empty after its start)."""
    for _ in range(500):
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
        environment = Path(f"/proc/{pid}/environ").read_bytes()
        if command and environment:
            return command.decode().split("\0"), environment.decode().split("\0")
        time.sleep(0.01)
    raise AssertionError(f"process {pid} shows no command line or environment")


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="reads the encoder's command line from /proc")
def test_writer_launches_the_encoder_with_bounded_memory(tmp_path, monkeypatch):
    """The overlay's encoder runs beside the tracker for the whole run (issue #69): ``ultrafast`` on one thread
    keeps it near 100 MiB at 1080p instead of 290 MiB, and glibc's fixed mmap threshold returns each frame's buffers
    (70 MiB). Read from the running ffmpeg itself. The options given still win."""
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    for kwargs, preset in (({"fps": 30000 / 1001}, "ultrafast"), ({"fps": 10, "preset": "veryfast"}, "veryfast")):
        with OverlayWriter(tmp_path / "overlay.mp4", width=32, height=32, **kwargs) as writer:
            writer.write(gray_frame(32, 32))
            options, environment = running_command(writer._encoder.pid)
        assert options[options.index("-preset") + 1] == preset
        assert options[options.index("-threads") + 1] == "1"
        assert options[options.index("-crf") + 1] == "23"
        assert options[options.index("-pix_fmt") + 1] == "rgb24"  # what is drawn gets ffmpeg's own 4:2:0 conversion
        assert options[options.index("-r") + 1] == ("30000/1001" if preset == "ultrafast" else "10")
        assert "GLIBC_TUNABLES=glibc.malloc.mmap_threshold=131072" in environment
    assert "GLIBC_TUNABLES" not in os.environ  # the tool's own environment is untouched


@pytest.mark.parametrize("given, expected", [
    (None, "glibc.malloc.mmap_threshold=131072"),
    ("glibc.malloc.arena_max=2", "glibc.malloc.arena_max=2:glibc.malloc.mmap_threshold=131072"),
    ("glibc.malloc.mmap_threshold=65536", "glibc.malloc.mmap_threshold=65536"),  # the user's own wins
])
def test_encoder_malloc_setting_joins_the_users_own(monkeypatch, given, expected):
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    if given is None:
        monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    else:
        monkeypatch.setenv("GLIBC_TUNABLES", given)
    assert _encoder_environment()["GLIBC_TUNABLES"] == expected
    assert os.environ.get("GLIBC_TUNABLES") == given
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "65536")  # glibc's older spelling of the same setting
    assert _encoder_environment().get("GLIBC_TUNABLES") == given


@pytest.mark.skipif(not hasattr(os, "getpgid"), reason="POSIX process groups")
@pytest.mark.parametrize("switch, own_group", [(None, True), ("1", False), ("0", True)])
def test_the_encoder_leaves_the_tools_process_group_unless_imageio_ffmpegs_switch_says_not(
        tmp_path, monkeypatch, switch, own_group):
    """Like imageio-ffmpeg's ffmpeg processes: a group of its own spares it a terminal's Ctrl-C, which the tool
    handles; batch pool workers set IMAGEIO_FFMPEG_NO_PREVENT_SIGINT to keep it in the run's group, which a
    ``kill -9 -PGID`` of the run must reach."""
    if switch is None:
        monkeypatch.delenv("IMAGEIO_FFMPEG_NO_PREVENT_SIGINT", raising=False)
    else:
        monkeypatch.setenv("IMAGEIO_FFMPEG_NO_PREVENT_SIGINT", switch)
    with OverlayWriter(tmp_path / "overlay.mp4", fps=10, width=32, height=32) as writer:
        writer.write(gray_frame(32, 32))
        pid, group = writer._encoder.pid, os.getpgid(writer._encoder.pid)
    assert group == (pid if own_group else os.getpgrp())  # a group of its own is led by ffmpeg itself


def test_ctrl_c_inside_the_block_stops_ffmpeg_and_leaves_no_file(tmp_path):
    path = tmp_path / "overlay.mp4"
    with pytest.raises(KeyboardInterrupt):
        with OverlayWriter(path, fps=10, width=32, height=32) as writer:
            writer.write(gray_frame(32, 32))
            encoder = writer._encoder
            raise KeyboardInterrupt
    assert encoder.returncode is not None  # killed and reaped, not left finishing the file
    assert not path.exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize("frames, needle", [(1, r"ffmpeg failed \(exit status [1-9]"),
                                            (50, "ffmpeg stopped taking frames after")])
def test_writer_reports_a_failing_encoder_and_leaves_no_file(tmp_path, frames, needle):
    """ffmpeg that stops (here: x264 refuses the preset) is an error naming the file: at the end when its pipe
    took every frame (one frame fits in it), while frames are written when it did not; the target keeps its old
    content."""
    path = tmp_path / "overlay.mp4"
    path.write_bytes(b"previous overlay")
    with pytest.raises(OSError, match=r"overlay\.mp4: " + needle):
        with OverlayWriter(path, fps=10, width=32, height=32, preset="no-such-preset") as writer:
            for _ in range(frames):
                writer.write(gray_frame(32, 32))
    assert path.read_bytes() == b"previous overlay" and leftovers(tmp_path) == []


def reference_i420(rgb: np.ndarray) -> np.ndarray:
    """BT.601 limited-range YUV 4:2:0 by its definition (ITU-R BT.601, 8-bit: Y in 16..235, U and V in 16..240),
    the chroma of each 2x2 block the mean of its four pixels' chroma; planes stacked as I420."""
    r, g, b = (rgb[..., c].astype(float) for c in range(3))
    y = 16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255
    u = 128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255
    v = 128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255
    h, w = rgb.shape[:2]
    half = [c.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)) for c in (u, v)]
    return np.concatenate([y.ravel(), half[0].ravel(), half[1].ravel()])


@pytest.mark.parametrize("height, width", [(48, 64), (37, 51)])
def test_i420_planes_follow_bt601_and_come_back_to_the_frame(height, width):
    """The overlay's frames are held and encoded as I420 (issue #69): BT.601 limited range as FFmpeg converts RGB
    by default, an odd frame padded by its last row and column, and back to RGB within the 4:2:0 rounding."""
    rng = np.random.default_rng(3)
    coarse = rng.integers(40, 216, (height // 12 + 2, width // 12 + 2, 3)).astype(np.uint8)
    rgb = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)  # smooth, as frames are
    rgb[:, 5] = (255, 0, 0)  # 1-pixel colour lines at odd places keep their share of their blocks' colour
    rgb[7, :] = (0, 255, 0)
    planes = rgb_to_i420(rgb)
    even_h, even_w = height + height % 2, width + width % 2
    assert planes.dtype == np.uint8 and planes.shape == (even_h * 3 // 2, even_w)
    padded = np.pad(rgb, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
    expected = reference_i420(padded)
    luma = even_h * even_w
    assert np.abs(planes.ravel()[:luma].astype(float) - expected[:luma]).max() <= 1.0
    assert np.abs(planes.ravel()[luma:].astype(float) - expected[luma:]).max() <= 1.0
    smooth = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    back = i420_to_rgb(rgb_to_i420(smooth), width, height)
    assert back.shape == smooth.shape and back.dtype == np.uint8 and back.flags.c_contiguous
    error = back.astype(float) - smooth
    assert 10 * np.log10(255 ** 2 / (error ** 2).mean()) > 28  # 31 dB here (strong colour gradients)


def test_writer_error_inside_block_leaves_no_file(tmp_path):
    path = tmp_path / "overlay.mp4"
    with pytest.raises(RuntimeError, match="tracking failed"):
        with OverlayWriter(path, fps=10, width=32, height=32) as writer:
            for _ in range(3):
                writer.write(gray_frame(32, 32))
            raise RuntimeError("tracking failed")
    assert not path.exists() and leftovers(tmp_path) == []

    path.write_bytes(b"previous overlay")
    with pytest.raises(ValueError, match=r"\(32, 32, 3\) uint8"):
        with OverlayWriter(path, fps=10, width=32, height=32) as writer:
            writer.write(gray_frame(32, 32))
            writer.write(gray_frame(30, 32))  # wrong size
    assert path.read_bytes() == b"previous overlay" and leftovers(tmp_path) == []


def test_writer_with_no_frames_is_an_error_and_leaves_no_file(tmp_path):
    path = tmp_path / "overlay.mp4"
    with pytest.raises(ValueError, match="no frame was written"):
        with OverlayWriter(path, fps=10, width=32, height=32):
            pass
    assert not path.exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize("kwargs, needle", [({"fps": 0}, "fps"), ({"width": 0}, "width"), ({"crf": 60}, "crf")])
def test_writer_argument_errors(tmp_path, kwargs, needle):
    args = {"fps": 25.0, "width": 32, "height": 32, **kwargs}
    with pytest.raises(ValueError, match=needle):
        OverlayWriter(tmp_path / "x.mp4", **args)


@pytest.mark.parametrize("make", [
    lambda **kw: OverlayItem(**{"box_xywh": (1, 2, 3, 4), "track_id": 1, "confidence": 0.5, **kw}),
    lambda **kw: FrameResult(**{"box_xywh": (1, 2, 3, 4), "log_likelihood": 0.0, "confidence": 0.5,
                                "accepted": True, "scoring": "subspace", **kw}),
])
def test_frame_results_and_overlay_items_check_their_particles_alike(make):
    item = make(particles_xywh=[[0, 0, 2, 2], [1, 1, 2, 2]], particle_scores=[0.1, 0.2])
    assert item.particles_xywh.dtype == np.float64 and item.particle_scores.shape == (2,)
    with pytest.raises(ValueError, match="particles_xywh and particle_scores come together or not at all"):
        make(particles_xywh=[[0, 0, 2, 2]])
    with pytest.raises(ValueError, match=r"particles_xywh must be \(N, 4\) and particle_scores \(N,\), "
                                         r"got \(1, 4\) and \(2,\)"):
        make(particles_xywh=[[0, 0, 2, 2]], particle_scores=[0.1, 0.2])
    with pytest.raises(ValueError, match=r"box_xywh must have shape \(4,\), got \(3,\)"):
        make(box_xywh=(1, 2, 3))

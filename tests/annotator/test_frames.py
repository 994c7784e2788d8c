"""Frame sources: decoded frame k is frame k, for videos and image folders, and every error says what to do.

Synthetic sources carry their frame index as 8 black/white 16x16 blocks (one
bit each), large enough to survive H.264, so a test can read back which frame
it got.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from annotator import frame_sources
from annotator.frame_sources import (
    DEFAULT_FOLDER_FPS,
    DecodeError,
    FrameRangeError,
    FrameSizeMismatchError,
    FrameSourceError,
    NoImagesError,
    SourceNotFoundError,
    UnreadableSourceError,
    natural_sort_key,
    open_frames,
)

WIDTH, HEIGHT, BLOCK, BITS = 128, 48, 16, 8
N_FRAMES = 30
FPS = 25.0


def index_frame(k: int, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """An RGB frame whose top row of blocks spells ``k`` in binary; the rest a k-dependent colour."""
    frame = np.empty((height, width, 3), dtype=np.uint8)
    frame[:] = (40 + 5 * (k % 20), 90, 160)
    for bit in range(BITS):
        frame[:BLOCK, bit * BLOCK : (bit + 1) * BLOCK] = 255 if (k >> bit) & 1 else 0
    return frame


def read_index(frame: np.ndarray) -> int:
    """The index spelled by :func:`index_frame`, tolerant to compression."""
    value = 0
    for bit in range(BITS):
        block = frame[2 : BLOCK - 2, bit * BLOCK + 2 : (bit + 1) * BLOCK - 2]
        if block.mean() > 128:
            value |= 1 << bit
    return value


def write_video(path, n: int = N_FRAMES, *, faststart: bool = False, fps: float = FPS) -> None:
    extra = ["-movflags", "+faststart"] if faststart else []
    writer = imageio_ffmpeg.write_frames(
        str(path), (WIDTH, HEIGHT), fps=fps, codec="libx264", macro_block_size=1,
        ffmpeg_log_level="error", output_params=["-g", "10", *extra],
    )  # fmt: skip
    writer.send(None)
    for k in range(n):
        writer.send(index_frame(k))
    writer.close()


def with_timestamps(video, out, setpts: str):
    """``video`` re-encoded with every frame kept and its timestamps set by the ``setpts`` expression."""
    subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(video), "-vf", f"setpts='{setpts}'",
         "-fps_mode", "passthrough", "-c:v", "libx264", "-g", "10", str(out)],
        check=True,
    )  # fmt: skip
    return out


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "clip.mp4"
    write_video(path)
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """``frame1.png .. frame12.png``: lexical order would put frame10 before frame2."""
    root = tmp_path_factory.mktemp("folder") / "seq"
    root.mkdir()
    for k in range(12):
        cv2.imwrite(str(root / f"frame{k + 1}.png"), cv2.cvtColor(index_frame(k), cv2.COLOR_RGB2BGR))
    (root / "groundtruth_rect.txt").write_text("1,2,3,4\n")  # not an image: ignored
    (root / ".frame0.png").write_bytes(b"macOS resource fork")  # hidden: ignored
    return root


# --------------------------------------------------------------------------- videos


def test_video_frame_k_is_decoded_frame_k(video):
    source = open_frames(video)
    assert (source.name, source.width, source.height, source.fps, source.frame_count) == (
        "clip", WIDTH, HEIGHT, FPS, N_FRAMES,
    )  # fmt: skip
    assert source.kind == "video" and source.damage is None and len(source) == N_FRAMES
    seen = []
    for index, frame in source:
        assert frame.shape == (HEIGHT, WIDTH, 3) and frame.dtype == np.uint8
        assert frame.flags.c_contiguous and frame.flags.writeable
        assert read_index(frame) == index
        seen.append(index)
    assert seen == list(range(N_FRAMES))
    info = source.info
    assert (info.name, info.width, info.height, info.fps, info.frame_count) == ("clip", WIDTH, HEIGHT, FPS, N_FRAMES)


def test_variable_frame_rate_video_is_not_resampled(video, tmp_path):
    """A timestamp jump must not make ffmpeg insert duplicates: frame k stays frame k."""
    vfr = with_timestamps(video, tmp_path / "vfr.mp4", "N/(25*TB)+if(gte(N,10),1.0/TB,0)")
    source = open_frames(vfr)
    assert source.frame_count == N_FRAMES
    assert [read_index(frame) for _, frame in source] == list(range(N_FRAMES))


RANGES = [
    # start, stop, step, expected source indices (N_FRAMES = 30)
    (0, None, 1, list(range(30))),
    (5, 12, 1, list(range(5, 12))),
    (3, None, 7, [3, 10, 17, 24]),
    (0, 100, 10, [0, 10, 20]),  # stop past the end is clipped, like a slice
    (29, None, 1, [29]),
]


@pytest.mark.parametrize("start, stop, step, expected", RANGES)
def test_video_range_selection(video, start, stop, step, expected):
    source = open_frames(video, start=start, stop=stop, step=step)
    assert source.indices.tolist() == expected and source.indices.dtype == np.int64
    assert len(source) == len(expected)
    got = [(index, read_index(frame)) for index, frame in source]
    assert got == [(k, k) for k in expected]


@pytest.mark.parametrize("start, stop, step", [(5, 12, 1), (3, None, 7), (11, 30, 4)])
def test_a_selection_delivers_the_frames_of_a_full_decode_bit_for_bit(video, start, stop, step):
    """ffmpeg skips the frames outside a selection itself; the frames it delivers are those a full decode gives."""
    full = dict(open_frames(video))
    selected = list(open_frames(video, start=start, stop=stop, step=step))
    assert [index for index, _ in selected] == list(range(start, stop or N_FRAMES, step))
    for index, frame in selected:
        np.testing.assert_array_equal(frame, full[index])


@pytest.mark.parametrize("kind", ["video", "folder"])
@pytest.mark.parametrize("start, stop, step", [(0, None, 1), (3, 11, 2)])
def test_frames_from_a_position_are_the_tail_of_the_iteration(video, folder, kind, start, stop, step):
    source = open_frames(video if kind == "video" else folder, start=start, stop=stop, step=step)
    everything = list(source)
    for position in (0, 1, len(source) - 1, len(source)):
        tail = list(source.frames_from(position))
        assert [index for index, _ in tail] == [index for index, _ in everything[position:]]
        for (_, got), (_, expected) in zip(tail, everything[position:]):
            np.testing.assert_array_equal(got, expected)
    for position in (-1, len(source) + 1):
        with pytest.raises(IndexError, match="outside the"):
            source.frames_from(position)


def test_a_selection_of_joined_clips_of_two_sizes_is_the_full_decode(tmp_path):
    """ffmpeg rebuilds its filters where the frame size changes part-way (joined camera clips); the selection
    filter's frame number must not start again there."""
    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    parts = []
    for part, (width, height) in enumerate([(WIDTH, HEIGHT), (2 * WIDTH, 2 * HEIGHT)]):
        path = tmp_path / f"part{part}.ts"
        writer = imageio_ffmpeg.write_frames(str(path), (width, height), fps=FPS, codec="libx264", macro_block_size=1,
                                             ffmpeg_log_level="error", output_params=["-g", "5", "-f", "mpegts"])
        writer.send(None)
        for k in range(10 * part, 10 * part + 10):
            writer.send(index_frame(k, width, height))
        writer.close()
        parts.append(path)
    listing = tmp_path / "parts.txt"
    listing.write_text("".join(f"file '{p.name}'\n" for p in parts))
    joined = tmp_path / "joined.ts"
    subprocess.run([ffmpeg, "-v", "error", "-f", "concat", "-safe", "0", "-i", str(listing), "-c", "copy", str(joined)],
                   check=True)
    full = dict(open_frames(joined))
    assert len(full) == 20
    for selection in (dict(start=0, step=3), dict(start=5, stop=15), dict(start=12), dict(start=1, step=4)):
        got = list(open_frames(joined, **selection))
        expected = list(range(selection.get("start", 0), selection.get("stop", 20), selection.get("step", 1)))
        assert [index for index, _ in got] == expected, selection
        for index, frame in got:
            np.testing.assert_array_equal(frame, full[index])


@pytest.fixture()
def reader_calls(monkeypatch):
    """The keyword arguments of every ``imageio_ffmpeg.read_frames`` call the test makes, in order."""
    calls = []
    real = imageio_ffmpeg.read_frames

    def spy(path, **kwargs):
        calls.append(kwargs)
        return real(path, **kwargs)

    monkeypatch.setattr(imageio_ffmpeg, "read_frames", spy)
    return calls


def test_a_selection_has_ffmpeg_write_at_once_and_stop_at_its_last_frame(video, reader_calls):
    """imageio-ffmpeg waits only 10 s for ffmpeg's output header, written with the first frame out, so frame 0
    always goes out (and is dropped); and the filter holds back its last frames until the end of the file unless
    ffmpeg stops after them. Both are too slow to show on a test clip: the options are checked."""
    got = [index for index, _ in open_frames(video, start=20, stop=26, step=2)]
    assert got == [20, 22, 24]
    options = reader_calls[-1]["output_params"]
    assert options[options.index("-frames:v") + 1] == "4"  # frame 0 and the three selected
    assert options[options.index("-vf") + 1].startswith("select=eq(n\\,0)+")
    assert "scale=" not in options[options.index("-vf") + 1]  # a small clip: ffmpeg's RGB
    assert reader_calls[-1]["input_params"][-2:] == ["-reinit_filter", "0"]


def ffmpeg_rgb(path) -> list[np.ndarray]:
    """Every frame of ``path`` as ffmpeg itself turns it into RGB (its own choice of threads and queues)."""
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    return [np.frombuffer(b, np.uint8).reshape(height, width, 3) for b in reader]


def assert_ffmpegs_colours(got: list[np.ndarray], expected: list[np.ndarray], mean: float = 1.5) -> None:
    """The frames are ffmpeg's RGB up to the rounding of a 4:2:0 conversion of its own (about one level)."""
    assert len(got) == len(expected) and all(g.shape == e.shape for g, e in zip(got, expected))
    error = np.abs(np.stack(got).astype(int) - np.stack(expected))
    assert error.mean() <= mean and np.percentile(error, 99) <= 16, (error.mean(), np.percentile(error, 99))


@pytest.fixture
def yuv_from_any_size(monkeypatch):
    """Small test clips piped as YUV as an HD video is."""
    monkeypatch.setattr(frame_sources, "_PIPE_YUV_MIN_PIXELS", 0)


@pytest.fixture(params=["rgb24", "yuv420p"])
def piped_as(request):
    """A test twice: small clips piped as RGB, as they are, and as YUV 4:2:0, as an HD video's frames are."""
    if request.param == "yuv420p":
        request.getfixturevalue("yuv_from_any_size")
    return request.param


def test_the_reading_decoder_runs_with_bounded_memory_and_gives_ffmpegs_frames(video, reader_calls,
                                                                                yuv_from_any_size):
    """The decoder that runs beside the tracker has one thread, queues at most one frame and pipes an HD 4:2:0
    video as YUV 4:2:0 (issue #69: at 1080p 197 MiB as ffmpeg chooses, 122 MiB with one thread and one queued
    frame, 79 MiB with YUV too); its frames are ffmpeg's RGB within rounding, writable, in order."""
    got = [frame for _, frame in open_frames(video)]
    call = reader_calls[-1]
    inputs, outputs = call["input_params"], call["output_params"]
    assert inputs[inputs.index("-threads") + 1] == "1"
    assert outputs[outputs.index("-thread_queue_size") + 1] == "1"
    assert call["pix_fmt"] == "yuv420p" and call["bits_per_pixel"] == 12
    assert outputs[outputs.index("-vf") + 1] == "scale=out_color_matrix=bt601:out_range=tv"
    assert "-reinit_filter" not in inputs  # only a selection needs it
    assert [read_index(f) for f in got] == list(range(N_FRAMES))
    assert all(f.flags.writeable and f.dtype == np.uint8 for f in got)
    assert_ffmpegs_colours(got, ffmpeg_rgb(video))


@pytest.fixture(scope="module")
def tagged_videos(tmp_path_factory):
    """Colourful 64x48 clips with the tags of HD and phone video, and a 4:4:4 one, which keeps ffmpeg's RGB. (No
    odd-sized 4:2:0 clip: ffmpeg's own 4:2:0 filters round the size down to even.)"""
    root = tmp_path_factory.mktemp("tagged")
    exe = imageio_ffmpeg.get_ffmpeg_exe()
    made = {}
    for name, size, pix_fmt, tags, codec in (
            ("bt709", "64x48", "yuv420p", ["-colorspace", "bt709", "-color_range", "tv"], ["libx264", "-crf", "10"]),
            ("bt709_full", "64x48", "yuvj420p", ["-colorspace", "bt709", "-color_range", "pc"],
             ["libx264", "-crf", "10"]),
            ("yuv444", "64x48", "yuv444p", [], ["libx264", "-crf", "10"])):
        matrix = "bt709" if tags else "bt601"
        full = "pc" if "pc" in tags else "tv"
        path = root / f"{name}.mp4"
        subprocess.run(
            [exe, "-v", "error", "-f", "lavfi", "-i", f"testsrc2=size={size}:rate=10", "-frames:v", "6", "-vf",
             f"scale=out_color_matrix={matrix}:out_range={full},format={pix_fmt}", "-c:v", *codec, *tags, str(path)],
            check=True,
        )  # fmt: skip
        made[name] = path
    return made


@pytest.mark.parametrize("name", ["bt709", "bt709_full"])
def test_a_piped_yuv_video_keeps_its_own_colours(tagged_videos, name, yuv_from_any_size):
    """A BT.709 video (most HD video), full range too (some phones): ffmpeg first brings it to the BT.601
    limited range OpenCV's conversion assumes, so its frames are ffmpeg's RGB within rounding (without that step
    they are 3.8 levels off on average on the full-range clip, against 0.8)."""
    source = open_frames(tagged_videos[name])
    assert source.pipes_yuv
    assert_ffmpegs_colours([f for _, f in source], ffmpeg_rgb(tagged_videos[name]))


def test_a_selection_of_a_piped_yuv_video_converts_only_the_frames_selected(video, reader_calls, yuv_from_any_size):
    got = [(index, read_index(frame)) for index, frame in open_frames(video, start=20, stop=26, step=2)]
    assert got == [(20, 20), (22, 22), (24, 24)]
    chain = reader_calls[-1]["output_params"][reader_calls[-1]["output_params"].index("-vf") + 1]
    assert chain.startswith("select=eq(n\\,0)+") and chain.endswith(",scale=out_color_matrix=bt601:out_range=tv")


def test_small_frames_keep_ffmpegs_rgb_to_the_bit(video):
    """Below HD the decoder's buffers are small: the frames stay ffmpeg's own RGB."""
    source = open_frames(video)
    assert not source.pipes_yuv
    for (_, frame), want in zip(source, ffmpeg_rgb(video)):
        np.testing.assert_array_equal(frame, want)


def test_a_444_video_keeps_ffmpegs_rgb(tagged_videos, yuv_from_any_size):
    """A 4:4:4 video would lose colour in 4:2:0: ffmpeg's RGB, to the bit."""
    name = "yuv444"
    source = open_frames(tagged_videos[name])
    assert not source.pipes_yuv
    got = [f for _, f in source]
    expected = ffmpeg_rgb(tagged_videos[name])
    assert len(got) == len(expected) == 6
    for frame, want in zip(got, expected):
        np.testing.assert_array_equal(frame, want)


def test_a_selection_of_a_variable_frame_rate_video_counts_frames_not_time(video, tmp_path):
    """Frame k of a selection is the k-th decoded frame even where the timestamps jump."""
    vfr = with_timestamps(video, tmp_path / "vfr.mp4", "N/(25*TB)+if(gte(N,10),1.0/TB,0)+if(gte(N,20),2.5/TB,0)")
    got = [(index, read_index(frame)) for index, frame in open_frames(vfr, start=8, stop=26, step=3)]
    assert got == [(k, k) for k in range(8, 26, 3)]


def test_breaking_out_early_then_iterating_again(video):
    source = open_frames(video)
    for index, _ in source:
        if index == 3:
            break
    assert [index for index, _ in source][:5] == [0, 1, 2, 3, 4]


def test_truncated_faststart_mp4_raises_decode_error_after_last_good_frame(tmp_path, piped_as):
    """An MP4 with its index first, cut in half: ffmpeg decodes the head, then reports a partial file. Alike
    whether the frames come piped as RGB or, as an HD video's do, as YUV 4:2:0 (frames of 1.5 bytes a pixel)."""
    full = tmp_path / "full.mp4"
    write_video(full, n=60, faststart=True)
    data = full.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])

    source = open_frames(cut)
    assert source.pipes_yuv == (piped_as == "yuv420p")
    assert 0 < source.frame_count < 60 and source.damage
    assert source.declared_frame_count == 60
    delivered = []
    with pytest.raises(DecodeError) as caught:
        for index, frame in source:
            assert read_index(frame) == index  # every frame delivered is at its true index
            delivered.append(index)
    error = caught.value
    assert delivered == list(range(source.frame_count))
    assert error.last_good_index == delivered[-1]
    assert isinstance(error, FrameSourceError) and error.path == cut
    message = str(error)
    assert "\n" not in message and str(cut) in message and f"frame {delivered[-1]}" in message
    assert "re-copy" in message  # says how to fix it

    # A range that ends before the damage decodes cleanly.
    head = open_frames(cut, stop=5)
    assert [index for index, _ in head] == [0, 1, 2, 3, 4]
    # A selection that reaches the damage stops at its last good selected frame.
    tail = open_frames(cut, start=2, step=3)
    delivered = []
    with pytest.raises(DecodeError) as caught:
        for index, frame in tail:
            assert read_index(frame) == index
            delivered.append(index)
    assert delivered == list(range(2, source.frame_count, 3))
    # The last frame ffmpeg decoded, selected or not: what the message says decoding stopped after.
    assert caught.value.last_good_index == source.frame_count - 1
    assert f"after frame {source.frame_count - 1}" in str(caught.value)
    # So does a tail of it.
    got = []
    with pytest.raises(DecodeError) as caught:
        for index, _ in tail.frames_from(2):
            got.append(index)
    assert got == delivered[2:] and caught.value.last_good_index == source.frame_count - 1


def test_truncated_plain_mp4_is_unreadable_at_open(tmp_path):
    """Without faststart the index (moov) is at the end; half a file has none and nothing can be decoded."""
    full = tmp_path / "full.mp4"
    write_video(full, n=60)
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.raises(UnreadableSourceError, match="moov atom not found") as caught:
        open_frames(cut)
    assert str(cut) in str(caught.value) and "faststart" in str(caught.value)


# --------------------------------------------------------------------------- image folders


def test_folder_natural_order_and_default_fps(folder):
    source = open_frames(folder)
    assert source.kind == "images" and source.name == "seq"
    assert (source.width, source.height, source.frame_count, source.fps) == (WIDTH, HEIGHT, 12, DEFAULT_FOLDER_FPS)
    assert [f.name for f in source.files][:3] == ["frame1.png", "frame2.png", "frame3.png"]
    frames = list(source)
    assert [index for index, _ in frames] == list(range(12))
    for index, frame in frames:
        assert np.array_equal(frame, index_frame(index))  # PNG is lossless: exact RGB, not BGR
        assert frame.flags.c_contiguous and frame.flags.writeable


@pytest.mark.parametrize(
    "start, stop, step, expected", [(2, 9, 3, [2, 5, 8]), (10, None, 1, [10, 11]), (0, 50, 5, [0, 5, 10])]
)
def test_folder_range_selection(folder, start, stop, step, expected):
    source = open_frames(folder, start=start, stop=stop, step=step, fps=12.5)
    assert source.fps == 12.5
    assert [(index, read_index(frame)) for index, frame in source] == [(k, k) for k in expected]


def test_otb_sequence_folder_and_grayscale_images(tmp_path):
    img = tmp_path / "Basketball" / "img"
    img.mkdir(parents=True)
    for k in range(3):
        gray = cv2.cvtColor(index_frame(k), cv2.COLOR_RGB2GRAY)
        cv2.imwrite(str(img / f"{k + 1:04d}.jpg"), gray, [cv2.IMWRITE_JPEG_QUALITY, 98])
    (tmp_path / "Basketball" / "groundtruth_rect.txt").write_text("1,1,2,2\n" * 3)
    for path in (tmp_path / "Basketball", img):
        source = open_frames(path)
        assert source.name == "Basketball" and source.frame_count == 3
        for index, frame in source:
            assert frame.shape == (HEIGHT, WIDTH, 3)
            assert np.array_equal(frame[..., 0], frame[..., 1]) and np.array_equal(frame[..., 1], frame[..., 2])
            assert read_index(frame) == index
        # Image paths relative to the sequence folder's parent, whichever of the two folders was given.
        assert source.frame_files == ("Basketball/img/0001.jpg", "Basketball/img/0002.jpg", "Basketball/img/0003.jpg")
        assert source.info.frame_files == source.frame_files


def test_a_cut_short_jpeg_is_named_in_a_warning_and_whole_ones_are_not(tmp_path):
    import warnings

    from annotator.errors import InputWarning

    noise = np.random.default_rng(0).integers(0, 256, (5, HEIGHT, WIDTH, 3), dtype=np.uint8)  # data, not tables
    for k in range(5):
        cv2.imwrite(str(tmp_path / f"{k:04d}.jpg"), noise[k])
    frame = {k: tmp_path / f"{k:04d}.jpg" for k in range(5)}
    frame[0].write_bytes(frame[0].read_bytes() + b"\x00" * 100)  # padding after the image is fine
    trailer = np.random.default_rng(1).integers(0, 256, 10_000, dtype=np.uint8).tobytes().replace(b"\xff", b"")
    frame[2].write_bytes(frame[2].read_bytes() + trailer)  # a "motion photo": a video after the image, fine
    whole = frame[1].read_bytes()
    frame[1].write_bytes(whole[: len(whole) * 3 // 4])
    # Cut short, with an end marker before its scan (as an EXIF thumbnail has): still cut short.
    thumbnail = b"\xff\xe1" + (2 + 6).to_bytes(2, "big") + b"ab\xff\xd9cd"
    whole = frame[3].read_bytes()
    frame[3].write_bytes(whole[:2] + thumbnail + whole[2: len(whole) * 3 // 4])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(open_frames(tmp_path))
    assert [index for index, _ in frames] == [0, 1, 2, 3, 4]
    messages = [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
    assert [m.split(": ")[0] for m in messages] == [str(frame[1]), str(frame[3])]
    assert all(": JPEG file is cut short" in m for m in messages)


def test_folder_frame_files_are_relative_to_its_parent(folder, monkeypatch):
    source = open_frames(folder)
    assert source.frame_files == tuple(f"seq/{f.name}" for f in source.files)
    assert all((folder.parent / name).is_file() for name in source.frame_files)
    monkeypatch.chdir(folder)
    assert open_frames(Path(".")).frame_files == source.frame_files


def test_video_has_no_frame_files(tmp_path):
    path = tmp_path / "clip.mp4"
    write_video(path, n=3)
    source = open_frames(path)
    assert source.frame_files is None and source.info.frame_files is None


@given(st.lists(st.integers(min_value=0, max_value=10**6), min_size=1, max_size=30, unique=True))
def test_natural_sort_orders_numbers_by_value(numbers):
    names = [f"frame{n}.jpg" for n in numbers]
    assert sorted(names, key=natural_sort_key) == [f"frame{n}.jpg" for n in sorted(numbers)]


# --------------------------------------------------------------------------- errors


def one_line(error: BaseException, *needles: str) -> str:
    message = str(error)
    assert "\n" not in message
    for needle in needles:
        assert needle in message
    return message


def test_missing_path(tmp_path):
    path = tmp_path / "nope.mp4"
    with pytest.raises(SourceNotFoundError) as caught:
        open_frames(path)
    assert isinstance(caught.value, FrameSourceError) and isinstance(caught.value, FileNotFoundError)
    one_line(caught.value, str(path), "check the path")


@pytest.mark.parametrize(
    "content, needle",
    [(b"this is not a video\n" * 20, "not a readable video"), (b"", "empty")],
    ids=["text-renamed-mp4", "empty-file"],
)
def test_not_a_video(tmp_path, content, needle):
    path = tmp_path / "fake.mp4"
    path.write_bytes(content)
    with pytest.raises(UnreadableSourceError) as caught:
        open_frames(path)
    one_line(caught.value, str(path), needle, "expected")


@pytest.mark.parametrize("name", ["notes.txt", "groundtruth_rect.txt"])
def test_a_text_file_is_not_a_video_though_ffmpeg_draws_it(tmp_path, name):
    """ffmpeg's tty demuxer turns any text file of a few kB into frames of ANSI art; the tool must refuse it."""
    path = tmp_path / name
    path.write_text("".join(f"{10 + k},{20 + k},30,40\n" for k in range(400)))
    with pytest.raises(UnreadableSourceError) as caught:
        open_frames(path)
    one_line(caught.value, str(path), "a text file", "expected a video file")


def test_a_single_image_opens_as_one_frame_with_a_warning_that_names_its_folder(tmp_path):
    from annotator.errors import InputWarning

    (tmp_path / "img").mkdir()
    path = tmp_path / "img" / "0001.jpg"
    cv2.imwrite(str(path), np.full((48, 64, 3), 120, np.uint8))
    with pytest.warns(InputWarning, match=r"0001.jpg is a single image, .* give their folder \(.*img\)"):
        source = open_frames(path)
    assert source.frame_count == 1 and (source.width, source.height) == (64, 48)


def test_folder_without_images(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(NoImagesError) as caught:
        open_frames(tmp_path)
    one_line(caught.value, str(tmp_path), "no images", "jpg")


def test_images_of_different_sizes_name_the_first_odd_file(tmp_path):
    for k in range(4):
        size = (WIDTH, HEIGHT) if k != 2 else (WIDTH // 2, HEIGHT)
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.zeros((size[1], size[0], 3), np.uint8))
    with pytest.raises(FrameSizeMismatchError) as caught:
        open_frames(tmp_path)
    one_line(caught.value, "f2.png", f"{WIDTH // 2}x{HEIGHT}", f"expected {WIDTH}x{HEIGHT}", "f0.png")


def test_corrupt_image_in_folder_raises_decode_error_during_iteration(tmp_path):
    for k in range(4):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), cv2.cvtColor(index_frame(k), cv2.COLOR_RGB2BGR))
    data = (tmp_path / "f2.png").read_bytes()
    (tmp_path / "f2.png").write_bytes(data[:100])  # header intact (size readable), pixels gone
    source = open_frames(tmp_path)
    seen = []
    with pytest.raises(DecodeError) as caught:
        for index, _ in source:
            seen.append(index)
    assert seen == [0, 1] and caught.value.last_good_index == 1
    one_line(caught.value, "f2.png")


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        ({"start": N_FRAMES}, "past the last frame"),
        ({"start": 100}, f"0 <= start < {N_FRAMES}"),
        ({"start": 5, "stop": 5}, "stop=5 <= start=5"),
        ({"start": 5, "stop": 2}, "stop > start"),
        ({"step": 0}, "step >= 1"),
        ({"step": -2}, "step >= 1"),
        ({"start": -1}, "negative"),
        ({"start": 1.5}, "integers"),
    ],
)
def test_bad_ranges(video, kwargs, needle):
    with pytest.raises(FrameRangeError) as caught:
        open_frames(video, **kwargs)
    assert isinstance(caught.value, ValueError)
    one_line(caught.value, str(video), needle)


def test_bad_range_on_folder(folder):
    with pytest.raises(FrameRangeError, match="0 <= start < 12"):
        open_frames(folder, start=12)


def test_a_rotated_phone_video_is_read_upright_without_a_size_warning(tmp_path, caplog, piped_as):
    """ffmpeg applies a video's display rotation, so frames come upright, as players show them; imageio-ffmpeg's
    note that the read size differs from the stored one is noise on every portrait phone video. Alike whether the
    frames come piped as RGB or, as an HD video's do, as YUV 4:2:0, whose planes have the upright size."""
    flat = tmp_path / "flat.mp4"
    write_video(flat, 4)
    rotated = tmp_path / "rotated.mp4"
    made = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-display_rotation", "90", "-i", str(flat),
                           "-c", "copy", str(rotated)], capture_output=True, text=True)
    if made.returncode != 0:
        pytest.skip(f"this ffmpeg cannot write a display rotation: {made.stderr.strip()[:100]}")
    with caplog.at_level("WARNING"):
        source = open_frames(rotated)
        frames = list(source)
        later = list(open_frames(rotated, start=1, step=2))  # the selection filter runs after the rotation
    assert source.pipes_yuv == (piped_as == "yuv420p")
    assert (source.width, source.height) == (HEIGHT, WIDTH) and len(frames) == 4
    assert [read_index(np.rot90(frame, -1)) for _, frame in frames] == [0, 1, 2, 3]  # shown turned a quarter left
    assert all(frame.shape == (WIDTH, HEIGHT, 3) for _, frame in frames)
    assert [index for index, _ in later] == [1, 3]
    for index, frame in later:
        np.testing.assert_array_equal(frame, frames[index][1])
    assert not [r for r in caplog.records if r.name.startswith("imageio")], caplog.text


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_is_applied_as_viewers_apply_it(tmp_path, orientation):
    """Phone photos: the frames are the upright images (Pillow's exif_transpose, as viewers, CVAT and Label Studio
    show them), and the folder's frame size is the upright one."""
    from PIL import Image, ImageOps

    stored = np.random.default_rng(orientation).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    for k in range(2):
        image = Image.fromarray(stored)
        exif = image.getexif()
        exif[274] = orientation
        image.save(tmp_path / f"{k}.png", exif=exif)  # PNG: lossless, so the pixels compare exactly
    with Image.open(tmp_path / "0.png") as image:
        expected = np.asarray(ImageOps.exif_transpose(image).convert("RGB"))
    source = open_frames(tmp_path)
    assert (source.height, source.width) == expected.shape[:2]
    for _, frame in source:
        assert np.array_equal(frame, expected)


def test_the_count_of_a_video_reports_its_progress(video):
    from annotator.frame_sources import _count_video_frames

    seen: list[int] = []
    count, damage = _count_video_frames(Path(video), seen.append)
    assert (count, damage) == (N_FRAMES, None)
    assert seen and seen[-1] == N_FRAMES and seen == sorted(seen)
    source = open_frames(video, counting=seen.append)
    assert source.frame_count == N_FRAMES and seen[-1] == N_FRAMES


@pytest.mark.parametrize("orientation", range(1, 5))
def test_tiff_frames_are_turned_once(tmp_path, orientation):
    """OpenCV's TIFF reader applies the orientation itself (2-4; it cannot decode 5-8): not turned again.

    The upright image is written out from the EXIF meaning of each orientation, not taken from Pillow's
    exif_transpose: up to Pillow 10.0 that turns a TIFF a second time, after its decoder has turned it once.
    """
    from PIL import Image

    stored = np.random.default_rng(orientation).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    image = Image.fromarray(stored)
    exif = image.getexif()
    exif[274] = orientation
    image.save(tmp_path / "0.tif", exif=exif)
    # 1: as stored; 2: mirrored left-right; 3: turned 180 degrees; 4: mirrored top-bottom.
    expected = {1: stored, 2: stored[:, ::-1], 3: stored[::-1, ::-1], 4: stored[::-1]}[orientation]
    [(_, frame)] = list(open_frames(tmp_path))
    assert np.array_equal(frame, expected)


def test_mixed_orientations_name_the_exif_orientation(tmp_path):
    from PIL import Image

    from annotator.frame_sources import FrameSizeMismatchError

    stored = np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)
    for k, orientation in enumerate((1, 6)):
        image = Image.fromarray(stored)
        exif = image.getexif()
        exif[274] = orientation
        image.save(tmp_path / f"{k}.png", exif=exif)
    with pytest.raises(FrameSizeMismatchError, match="turned upright as its EXIF orientation 6 says"):
        open_frames(tmp_path)


def test_ctrl_c_during_the_count_stops_ffmpeg(video, monkeypatch):
    from annotator.frame_sources import _count_video_frames

    killed = []

    class Recording(subprocess.Popen):
        def kill(self):
            killed.append(self.args[0])
            super().kill()

    monkeypatch.setattr(subprocess, "Popen", Recording)

    def interrupted(frames):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _count_video_frames(Path(video), interrupted)
    assert killed == [imageio_ffmpeg.get_ffmpeg_exe()]

"""Frame sources: one sequential decoder for a video file or a folder of images.

Every consumer (tracking, rendering, exports) sees frames through
:func:`open_frames`, so that frame ``k`` of the overlay and row ``k`` of an
export are the frame the tracker saw as ``k`` (FORMATS.md, "Frame indexing").

Frame indices are 0-based positions in decode order:

* **Video.** Decoded by the ffmpeg bundled with imageio-ffmpeg through
  :func:`imageio_ffmpeg.read_frames`, first video stream (an HD 4:2:0 video piped
  as ``yuv420p`` and turned into RGB here; see ``_PIPE_YUV_SOURCES`` below), with
  ``-fps_mode passthrough``: every decoded frame is delivered once, none is
  duplicated or dropped to fit a constant rate. Without it ffmpeg's raw pipe
  output resamples variable-frame-rate video to the nominal rate, and frame
  ``k`` is no longer the ``k``-th frame of the file. A ``start``/``step``
  selection is applied by ffmpeg's ``select`` filter on the decoded frame
  number, so skipped frames are decoded but not converted or piped.
* **Image folder.** Position in natural sort order of the file names
  (``frame2`` before ``frame10``); the numbers inside the names are not used,
  so an OTB sequence whose ``img/`` starts at ``0001.jpg`` has source index 0
  for ``0001.jpg``.

Frame count of a video
----------------------
Container metadata (``nb_frames``, or duration x fps) is an estimate: it is
wrong for variable frame rate, edit lists and truncated files. At open time
the whole video is decoded once by ffmpeg into a null sink, with the same
options as the reading pass (``-map 0:v:0 -fps_mode passthrough -xerror``),
and the frames it delivers are counted. This is what
:func:`imageio_ffmpeg.count_frames_and_secs` does, but here ffmpeg's error
log and exit status are kept too, which is how damage is detected. The pass
costs one extra decode (about 0.4 s for 300 frames at 640x480 on 2 cores,
3.7 s for 1800 at 1920x1080), small next to tracking. ``retrack`` skips it
(``known_count``) once the file's content hash shows the bytes the run counted.

Damaged videos (the rule)
-------------------------
Both passes run ffmpeg with ``-xerror``: decoding stops at the first error
the demuxer or decoder reports. Without it ffmpeg skips an undecodable packet
and carries on, so every later frame would arrive one index early; with it,
every frame delivered is at its true index. Hence:

* If the open-time pass exits with an error after decoding ``n > 0`` frames,
  the source opens with ``frame_count = n`` and ``damage`` set to ffmpeg's
  message. Iteration yields the good frames of the selected range and, if
  the range reaches the damage, raises :class:`DecodeError` carrying
  ``last_good_index = n - 1`` after the last good frame. The caller keeps
  everything computed so far.
* If the reading pass delivers fewer frames than the open-time pass counted,
  or a partial frame, iteration raises :class:`DecodeError` at that point.
* An MP4 cut before its index (``moov`` atom) was written cannot be decoded
  at all: that is an :class:`UnreadableSourceError` at open time. An MP4
  written with ``-movflags +faststart`` (index first), MKV and MPEG-TS keep
  their decodable head when truncated and take the ``DecodeError`` path.

An error in the first frame is an :class:`UnreadableSourceError`: nothing
can be kept.
"""

from __future__ import annotations

import contextlib
import logging
import operator
import os
import re
import subprocess
import tempfile
import warnings
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Callable, Iterator, Sequence

import cv2
import imageio_ffmpeg
import numpy as np

from annotator.errors import InputWarning
from annotator.tracks import VideoInfo

__all__ = [
    "DEFAULT_FOLDER_FPS",
    "IMAGE_SUFFIXES",
    "DecodeError",
    "FrameRangeError",
    "FrameSizeMismatchError",
    "FrameSource",
    "FrameSourceError",
    "ImageFolderSource",
    "NoImagesError",
    "SourceNotFoundError",
    "UnreadableSourceError",
    "VideoSource",
    "natural_sort_key",
    "open_frames",
]

#: Frame rate given to image folders, which carry none. 30 fps is the rate of
#: the OTB and GOT-10k sequences' source videos and of most cameras; pass
#: ``fps=`` to :func:`open_frames` when it is known.
DEFAULT_FOLDER_FPS = 30.0

#: File suffixes (lower case) read from image folders.
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")

# ffmpeg options shared by the counting pass and the reading pass; they must
# be identical so that both see the same frames (module docstring).
_DECODE_OPTIONS = ["-map", "0:v:0", "-fps_mode", "passthrough", "-xerror"]

# Reading pass only: options that bound the decoder's memory while the tool tracks (issue #69). The pass runs
# beside the tracker for the whole run, so its memory is part of the run's peak; one decoded frame takes 8 ms of
# CPU at 1920x1080, far below a tracked frame's 100 ms, so neither option slows the run. Measured at 1080p with a
# reader taking 10-20 frames/s: 197 MiB as ffmpeg chooses, 122 MiB with both.
# ``-threads 1`` (input): one decoding thread instead of frame threading (one decoding context and its frames per
# core). It changes no frame: FFmpeg's frame-threaded H.264 decoding is bit-exact, and on a file damaged part-way
# the same number of frames arrived before ``-xerror`` stopped ffmpeg in every trial (the counting pass, where
# memory does not matter and speed does, keeps its threads).
_READ_INPUT_OPTIONS = ["-threads", "1"]
# ``-thread_queue_size 1`` (output, ffmpeg >= 6; imageio-ffmpeg >= 0.8 bundles 9): at most one raw frame queued to
# the pipe's muxer instead of ffmpeg's 8, which at 1080p RGB is 6 MiB a frame. The pipe and the queued frame still
# keep the next frame ready before the tracker asks for it.
_READ_OUTPUT_OPTIONS = ["-thread_queue_size", "1"]

# Reading pass of an 8-bit 4:2:0 video of even size and at least HD's pixels (nearly every camera and phone video of
# today): ffmpeg pipes its frames as YUV 4:2:0, half the bytes of RGB, and the tool turns them into RGB (OpenCV, BT.601
# limited range, chroma repeated over each 2x2 block as ffmpeg's own conversion does). Its buffers then hold half-size
# frames: at 1920x1080 the decoder holds 79 MiB instead of 121 (issue #69). The filter first brings every video's
# colours to what OpenCV's conversion assumes, BT.601 limited range, from its own tags (BT.709 for most HD video, full
# range for some phones), so the RGB is ffmpeg's own within rounding: 0.9-1.0 levels on average, 3-5 at most, on an
# untagged, a BT.709 and a full-range BT.709 1080p clip. Other sources (4:2:2, 4:4:4, more than 8 bits, odd sizes) stay
# on ffmpeg's RGB, which loses none of their colour; so do smaller frames, whose decoder buffers are small (about 3 MiB
# of RGB at 320x240) and whose RGB then stays ffmpeg's own to the bit.
_PIPE_YUV_SOURCES = frozenset({"yuv420p", "yuvj420p"})
_PIPE_YUV_MIN_PIXELS = 1280 * 720
_PIPE_YUV_FILTER = "scale=out_color_matrix=bt601:out_range=tv"

_REPAIR_HINT = (
    "re-copy the complete file, or re-encode it with `ffmpeg -i IN -c:v libx264 OUT.mp4` "
    "(which skips damaged frames, so later frame numbers shift)"
)


# --------------------------------------------------------------------------- errors


class FrameSourceError(Exception):
    """A video or image folder that cannot be read; the message is one line that says how to fix it."""


class SourceNotFoundError(FrameSourceError, FileNotFoundError):
    """The input path does not exist."""


class UnreadableSourceError(FrameSourceError):
    """The input exists but is not a decodable video or image (wrong format, empty, truncated header)."""


class NoImagesError(FrameSourceError):
    """A folder that holds no image files."""


class FrameSizeMismatchError(FrameSourceError):
    """An image folder whose images do not all have the same size."""


class FrameRangeError(FrameSourceError, ValueError):
    """A ``start``/``stop``/``step`` selection that selects no frame or is malformed."""


class DecodeError(FrameSourceError):
    """Decoding stopped in the middle of the source; raised during iteration.

    Attributes
    ----------
    path : Path
        The source.
    last_good_index : int
        Source index of the last frame decoded correctly; -1 when none was.
        Every frame yielded before the error has an index <= this one and is
        correct, so results computed on them can be kept.
    reason : str
        What went wrong, from ffmpeg or OpenCV.
    """

    def __init__(self, path: str | os.PathLike, last_good_index: int, reason: str) -> None:
        self.path = Path(path)
        self.last_good_index = int(last_good_index)
        self.reason = reason
        if self.last_good_index >= 0:
            kept = f"results up to frame {self.last_good_index} are valid"
        else:
            kept = "no frame could be decoded"
        super().__init__(
            f"{self.path}: decoding stopped after frame {self.last_good_index} ({reason}); "
            f"expected a complete file - {kept}; to process the rest, {_REPAIR_HINT}"
        )


# --------------------------------------------------------------------------- helpers


def natural_sort_key(name: str) -> tuple:
    """Sort key that orders digit runs by value: ``frame2`` < ``frame10``.

    Case is ignored; the name itself breaks ties so that the order is total.
    """
    parts = re.split(r"(\d+)", name)
    key = tuple((0, int(p), "") if p.isdigit() else (1, 0, p.lower()) for p in parts if p)
    return (key, name)


def _check_range(path: Path, frame_count: int, start: int, stop: int | None, step: int, damage: str | None) -> range:
    """Validate a selection against ``frame_count`` and return the selected source indices."""
    try:
        start = operator.index(start)
        step = operator.index(step)
        stop = None if stop is None else operator.index(stop)
    except TypeError:
        raise FrameRangeError(
            f"{path}: start, stop and step must be integers, got start={start!r}, stop={stop!r}, step={step!r}"
        ) from None
    if step < 1:
        raise FrameRangeError(f"{path}: step={step} selects no frame; expected step >= 1 (1 = every frame)")
    if start < 0:
        raise FrameRangeError(
            f"{path}: start={start} is negative; expected a 0-based frame index 0 <= start < {frame_count}"
        )
    if stop is not None and stop <= start:
        raise FrameRangeError(
            f"{path}: stop={stop} <= start={start} selects no frame; expected stop > start (stop is exclusive)"
        )
    if start >= frame_count:
        extra = f" (decoding fails after frame {frame_count - 1}: {damage})" if damage else ""
        raise FrameRangeError(
            f"{path}: start={start} is past the last frame; expected 0 <= start < {frame_count}, "
            f"the number of decodable frames{extra}"
        )
    # ``stop`` beyond the end is clipped, as Python slices are.
    end = frame_count if stop is None else min(stop, frame_count)
    return range(start, end, step)


def _ffmpeg_reason(stderr: str, path: Path | None = None) -> str:
    """The most telling line of an ffmpeg error log, without the ``[demuxer @ 0x...]`` prefixes.

    Lines that quote ``path`` are ffmpeg's generic summaries ("Error opening
    input file PATH"); they are skipped, also so that a path containing a word
    like "truncated" is not mistaken for a diagnosis.
    """
    lines = []
    for line in stderr.splitlines():
        if path is not None and str(path) in line:
            continue
        line = re.sub(r"^(\[[^\]]*\]\s*)+", "", line).strip()
        if line and not line.startswith("Last message repeated"):
            lines.append(line)
    if not lines:
        return "ffmpeg gave no reason"
    # A demuxer's verdict on the file says more than the decoder's complaint about one packet.
    for line in lines:
        if re.search(r"partial file|truncat|corrupt", line, flags=re.IGNORECASE):
            return line.rstrip(".")
    # ffmpeg ends with generic summaries ("Error opening input files: ..."); the first line is the cause.
    return lines[0].rstrip(".")


# --------------------------------------------------------------------------- sources


class FrameSource(ABC):
    """A selected range of frames of a video or image folder, decoded sequentially on iteration.

    Iterating yields ``(source_index, frame)`` for every selected frame, in
    order, where ``frame`` is a fresh, writeable, C-contiguous
    ``(height, width, 3) uint8`` RGB array. Each iteration decodes the source
    again from its start; memory use does not depend on the source's length.

    Parameters
    ----------
    path : Path
        The video file or image folder.
    name : str
        Its sequence name.
    width, height, frame_count : int
        Frame size and the number of frames of the whole source.
    fps : float
        Frames per second.
    selection : range
        The selected source indices (``start``, ``stop``, ``step``).

    Attributes
    ----------
    path : Path
        The video file or image folder as given.
    name : str
        Sequence name used for output files: the video's stem, the folder's
        name, or for an OTB ``Name/img`` folder ``Name``.
    width, height : int
        Frame size in pixels.
    fps : float
        Frames per second: the container's nominal rate for videos,
        :data:`DEFAULT_FOLDER_FPS` for image folders, or the ``fps=`` given.
    frame_count : int
        Number of frames of the whole source as decoded (for a damaged video,
        the frames before the first error).
    indices : (F,) int64 ndarray
        Source indices of the selected frames.
    start, stop, step : int
        The selection, with ``stop`` clipped to ``frame_count``.

    """

    kind: str = ""
    #: Image folders: every frame's file relative to the sequence folder's parent (see VideoInfo.frame_files).
    frame_files: tuple[str, ...] | None = None

    def __init__(
        self,
        path: Path,
        name: str,
        width: int,
        height: int,
        fps: float,
        frame_count: int,
        selection: range,
    ) -> None:
        self.path = path
        self.name = name
        self.width = int(width)
        self.height = int(height)
        self.fps = float(fps)
        self.frame_count = int(frame_count)
        self._selection = selection

    @property
    def start(self) -> int:
        return self._selection.start

    @property
    def stop(self) -> int:
        return self._selection.stop

    @property
    def step(self) -> int:
        return self._selection.step

    @property
    def indices(self) -> np.ndarray:
        return np.arange(self.start, self.stop, self.step, dtype=np.int64)

    @property
    def info(self) -> VideoInfo:
        """The source's :class:`~annotator.tracks.VideoInfo`, for exporters and reports."""
        return VideoInfo(
            path=str(self.path),
            name=self.name,
            width=self.width,
            height=self.height,
            fps=self.fps,
            frame_count=self.frame_count,
            frame_files=self.frame_files,
        )

    def __len__(self) -> int:
        return len(self._selection)

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        return self._frames(self._selection)

    def frames_from(self, position: int) -> Iterator[tuple[int, np.ndarray]]:
        """The selected frames from the ``position``-th on (``0 <= position <= len(self)``), as iteration yields them.

        Cheaper than iterating from the start and dropping frames: an image folder reads only the images
        wanted, a video has ffmpeg skip the frames before (decoded, not converted or piped).
        """
        if not 0 <= position <= len(self._selection):
            raise IndexError(f"position {position} is outside the {len(self._selection)} selected frames")
        return self._frames(self._selection[position:])

    @abstractmethod
    def _frames(self, wanted: range) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(source_index, frame)`` for every index of ``wanted``, a tail of the selection."""

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({str(self.path)!r}, {self.width}x{self.height}, fps={self.fps:g}, "
            f"frame_count={self.frame_count}, range({self.start}, {self.stop}, {self.step}))"
        )


class VideoSource(FrameSource):
    """Frames of a video file, decoded by ffmpeg (see the module docstring for counting and damage).

    Attributes
    ----------
    damage : str or None
        ffmpeg's message when the open-time pass stopped on an error;
        iteration raises :class:`DecodeError` if the selection reaches it.
    declared_frame_count : int or None
        Frame count the container claims (duration x nominal fps, rounded);
        an estimate, used only to say how much of a damaged file is lost.
    codec : str
        Codec name reported by ffmpeg, e.g. ``"h264"``.
    """

    kind = "video"

    def __init__(self, path: Path, *, start: int, stop: int | None, step: int, fps: float | None,
                 counting: Callable[[int], None] | None = None,
                 known_count: tuple[int, str | None] | None = None) -> None:
        if known_count is None:
            frame_count, damage = _count_video_frames(path, counting)
        else:
            frame_count, damage = int(known_count[0]), known_count[1]
        meta = _video_meta(path)
        width, height = (int(v) for v in meta["size"])
        source_format = str(meta.get("pix_fmt", "")).split("(")[0].strip()
        self.pipes_yuv = (source_format in _PIPE_YUV_SOURCES and width % 2 == 0 and height % 2 == 0
                          and width * height >= _PIPE_YUV_MIN_PIXELS)
        nominal = float(meta.get("fps") or 0.0)
        duration = float(meta.get("duration") or 0.0)
        self.codec = str(meta.get("codec", ""))
        self.damage = damage
        self.declared_frame_count = int(round(duration * nominal)) if duration > 0 and nominal > 0 else None
        if fps is None:
            # A stream with no rate in its header (rare: some raw or broken files) gets the
            # average rate over its duration, and failing that the folder default.
            if nominal > 0:
                fps = nominal
            elif duration > 0:
                fps = frame_count / duration
            else:
                fps = DEFAULT_FOLDER_FPS
        selection = _check_range(path, frame_count, start, stop, step, damage)
        super().__init__(path, path.stem, width, height, fps, frame_count, selection)

    def _frames(self, wanted: range) -> Iterator[tuple[int, np.ndarray]]:
        if len(wanted) == 0:
            return
        shape = (self.height * 3 // 2, self.width) if self.pipes_yuv else (self.height, self.width, 3)
        frame_bytes = int(np.prod(shape))
        selecting, filtering, head = _selection_filter(wanted, _PIPE_YUV_FILTER if self.pipes_yuv else None)
        reader = imageio_ffmpeg.read_frames(
            str(self.path), pix_fmt="yuv420p" if self.pipes_yuv else "rgb24",
            bits_per_pixel=12 if self.pipes_yuv else 24,
            input_params=[*_READ_INPUT_OPTIONS, *selecting],
            output_params=[*_DECODE_OPTIONS, *_READ_OUTPUT_OPTIONS, *filtering],
        )
        delivered = 0  # frames received after ``head`` (the k-th is source frame wanted[k])
        last_good = -1
        try:
            try:
                with _rotation_note_silenced():
                    meta = next(reader)
            except (OSError, RuntimeError) as err:
                raise DecodeError(self.path, -1, f"ffmpeg could not restart: {_ffmpeg_reason(str(err))}") from err
            if tuple(meta["size"]) != (self.width, self.height):
                raise DecodeError(
                    self.path, -1, f"frame size changed from {self.width}x{self.height} to {meta['size']} since open"
                )
            while delivered < len(wanted):
                try:
                    buffer = next(reader)
                except StopIteration:
                    break
                except RuntimeError as err:  # imageio-ffmpeg: a partial frame, i.e. ffmpeg died mid-frame
                    stderr = str(err).split("=== stderr ===")[-1]
                    raise DecodeError(self.path, last_good, _ffmpeg_reason(stderr, self.path)) from err
                if head:
                    head -= 1
                    continue
                index = wanted[delivered]
                if len(buffer) != frame_bytes:  # pragma: no cover - imageio-ffmpeg guarantees full frames
                    reason = f"frame {index} has {len(buffer)} bytes, expected {frame_bytes}"
                    raise DecodeError(self.path, last_good, reason)
                delivered += 1
                last_good = index
                piped = np.frombuffer(buffer, dtype=np.uint8).reshape(shape)
                # A new array either way: frombuffer over ``bytes`` is read-only, and callers draw on frames.
                yield index, cv2.cvtColor(piped, cv2.COLOR_YUV2RGB_I420) if self.pipes_yuv else piped.copy()
        finally:
            reader.close()  # stops ffmpeg when the caller breaks out early
        if delivered < len(wanted):
            raise DecodeError(
                self.path,
                last_good,
                f"ffmpeg delivered {delivered} of the {len(wanted)} selected frames "
                f"(frames {wanted.start}..{wanted[-1]}, every {wanted.step}); the open-time count was "
                f"{self.frame_count}",
            )
        if self.damage is not None and self.stop == self.frame_count:
            last_good = self.frame_count - 1  # decoded up to there, selected or not
            lost = ""
            if self.declared_frame_count is not None and self.declared_frame_count > self.frame_count:
                missing = self.declared_frame_count - self.frame_count
                lost = f", about {missing} of ~{self.declared_frame_count} frames lost"
            raise DecodeError(self.path, last_good, f"ffmpeg: {self.damage}{lost}")


class ImageFolderSource(FrameSource):
    """Frames from a folder of images (or an OTB sequence's ``img/`` folder), read with OpenCV.

    Files are ordered by :func:`natural_sort_key`; hidden files (``._0001.jpg``
    left by macOS) are skipped. Grayscale and palette images become 3-channel
    RGB, alpha is dropped, 16-bit images are scaled to 8 bits (OpenCV's
    ``IMREAD_COLOR``). An EXIF orientation tag (phone photos) is applied, so
    frames, boxes and exports are upright, as image viewers, browsers, CVAT and
    Label Studio show the same images; frame sizes are the upright ones.

    Attributes
    ----------
    files : tuple of Path
        All images of the folder in frame order (not only the selected ones).
    """

    kind = "images"

    def __init__(self, path: Path, *, start: int, stop: int | None, step: int, fps: float | None) -> None:
        folder, name = _image_folder(path)
        candidates = (p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
        files = tuple(sorted((p for p in candidates if p.is_file()), key=lambda p: natural_sort_key(p.name)))
        if not files:
            raise NoImagesError(
                f"{path}: folder holds no images; expected a video file, a folder of "
                f"{'/'.join(s.lstrip('.') for s in IMAGE_SUFFIXES)} frames, or an OTB sequence folder with img/"
            )
        width, height, first_orientation = _image_header(files[0])
        orientations = [first_orientation]
        for file in files[1:]:
            *size, orientation = _image_header(file)
            orientations.append(orientation)
            if tuple(size) != (width, height):
                turned = (f" (turned upright as its EXIF orientation {orientation} says)" if orientation != 1 else
                          f" ({files[0].name} turned upright as its EXIF orientation {first_orientation} says)"
                          if first_orientation != 1 else "")
                raise FrameSizeMismatchError(
                    f"{file}: image is {size[0]}x{size[1]}{turned}, expected {width}x{height} like {files[0].name}; "
                    f"all frames of a sequence must have one size - resize or remove the odd ones"
                )
        self.files = files
        #: The EXIF orientation applied to each file's decoded image (1: none), read with its size at open.
        self.orientations = tuple(orientations)
        self.frame_files = _relative_frame_files(path, folder, files)
        if fps is None:
            fps = DEFAULT_FOLDER_FPS
        selection = _check_range(path, len(files), start, stop, step, None)
        super().__init__(path, name, width, height, fps, len(files), selection)

    @property
    def oriented(self) -> int:
        """How many of the images carry an EXIF orientation the frames are turned by."""
        return sum(o != 1 for o in self.orientations)

    def _frames(self, wanted: range) -> Iterator[tuple[int, np.ndarray]]:
        last_good = -1
        for index in wanted:
            file = self.files[index]
            bgr = cv2.imread(str(file), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
            if bgr is None:
                raise DecodeError(self.path, last_good, f"OpenCV cannot decode {file.name}")
            bgr = upright(bgr, self.orientations[index])
            if bgr.shape[:2] != (self.height, self.width):
                raise DecodeError(
                    self.path,
                    last_good,
                    f"{file.name} decodes to {bgr.shape[1]}x{bgr.shape[0]}, expected {self.width}x{self.height}",
                )
            if file.suffix.lower() in JPEG_SUFFIXES and not _jpeg_has_end_marker(file):
                # libjpeg says only "Premature end of JPEG file", without the file's name.
                warnings.warn(f"{file}: JPEG file is cut short (no end marker); its missing part decodes as grey and "
                              "the tracker sees it as the image - re-export the frame or remove it", InputWarning,
                              stacklevel=2)
            # cvtColor returns a new C-contiguous array; nothing else holds it.
            yield index, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            last_good = index


JPEG_SUFFIXES = (".jpg", ".jpeg", ".jpe")


def _jpeg_has_end_marker(file: Path) -> bool:
    """Whether a JPEG file holds the end-of-image marker (FF D9) of its image, data after it allowed.

    Compressed data never holds FF D9 (a data byte FF is written FF 00), so a file cut inside its data has
    none after its first scan. The last 4 KiB decide almost always; a file with more after its image (a
    phone's "motion photo" appends a video) is walked segment by segment to its first scan and searched
    from there, so that an EXIF thumbnail's own end marker, before the scan, does not count.
    """
    try:
        with open(file, "rb") as handle:
            handle.seek(max(0, os.fstat(handle.fileno()).st_size - 4096))
            if b"\xff\xd9" in handle.read():
                return True
            handle.seek(0)
            data = handle.read()
    except OSError:
        return True  # unreadable files are reported by the decoder
    at = 2  # after SOI
    while at + 4 <= len(data) and data[at] == 0xFF:
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
            continue
        if marker == 0xDA:  # start of scan: the compressed data follows its header
            return data.find(b"\xff\xd9", at) >= 0
        at += 2 + int.from_bytes(data[at + 2:at + 4], "big")
    return True  # not a layout this check knows: leave it to the decoder


# --------------------------------------------------------------------------- probing


def _count_video_frames(path: Path, progress: Callable[[int], None] | None = None) -> tuple[int, str | None]:
    """Decode the whole video into a null sink and count its frames; ``progress(frames so far)`` as ffmpeg reports.

    Returns
    -------
    frame_count : int
        Frames delivered before the end or the first error.
    damage : str or None
        ffmpeg's message when it stopped on an error after at least one frame.

    Raises
    ------
    UnreadableSourceError
        ffmpeg cannot open the file, finds no video stream, or cannot decode its first frame.
    """
    command = [
        imageio_ffmpeg.get_ffmpeg_exe(),
        "-nostdin", "-hide_banner", "-nostats", "-v", "error",
        "-i", str(path),
        *_DECODE_OPTIONS,
        "-f", "null", "-progress", "pipe:1", "-",
    ]  # fmt: skip
    # stdout carries only ``-progress`` key=value lines (a block about every 0.5 s), read as they come so that
    # ``progress`` can show a long count; stderr, only error lines, goes to a file so it can never fill a pipe.
    counts: list[int] = []
    with tempfile.TemporaryFile(mode="w+", encoding="utf-8", errors="replace") as errors:
        with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=errors, stdin=subprocess.DEVNULL, text=True,
                              errors="replace") as process:
            assert process.stdout is not None  # stdout=PIPE
            try:
                for line in process.stdout:
                    found = re.match(r"frame=(\d+)\s*$", line)
                    if found:
                        counts.append(int(found.group(1)))
                        if progress is not None:
                            progress(counts[-1])
            except BaseException:
                process.kill()  # Ctrl-C (or a failing callback): stop decoding now, as subprocess.run did
                raise
        returncode = process.returncode
        errors.seek(0)
        stderr = errors.read()
    frame_count = counts[-1] if counts else 0
    reason = _ffmpeg_reason(stderr, path)
    if returncode == 0 and frame_count > 0:
        return frame_count, None
    if frame_count > 0:
        return frame_count, reason
    raise UnreadableSourceError(_unreadable_message(path, reason, opened=bool(counts)))


def _unreadable_message(path: Path, reason: str, *, opened: bool) -> str:
    size = path.stat().st_size
    if size == 0:
        return f"{path}: file is empty (0 bytes); expected a video file - re-copy or re-export it"
    if "matches no streams" in reason:
        return f"{path}: has no video stream (audio only?); expected a file with video - check the input"
    with open(path, "rb") as handle:
        head = handle.read(12)
    is_mp4 = head[4:8] == b"ftyp"
    if is_mp4 and "moov atom not found" in reason:
        return (
            f"{path}: MP4 without its index (ffmpeg: moov atom not found), i.e. cut short or still being "
            f"written; expected a complete MP4 - re-copy the complete file, or record with "
            f"`-movflags +faststart` or to MKV so that a truncated file keeps its frames"
        )
    if not is_mp4 and "moov atom not found" in reason:
        # ffmpeg guessed MP4 from the suffix alone; its complaint about a missing index would mislead.
        reason = "no known video format inside"
    if opened:
        return (
            f"{path}: the first frame cannot be decoded (ffmpeg: {reason}); expected a decodable video - "
            f"re-encode it with `ffmpeg -i IN -c:v libx264 OUT.mp4`"
        )
    return (
        f"{path}: not a readable video (ffmpeg: {reason}); expected a video file (mp4, mkv, avi, mov, ...), "
        f"a folder of images, or an OTB sequence folder - check that the file is a complete video"
    )


@contextlib.contextmanager
def _rotation_note_silenced() -> Iterator[None]:
    """Hide imageio-ffmpeg's warning that the frame size differs from the stream's.

    ffmpeg turns a phone video's rotation into upright frames (as players show them), so a portrait video
    stored as 1920x1080 is read as 1080x1920; imageio-ffmpeg logs that difference as a warning, on every
    open, although the frames are right.
    """
    logger = logging.getLogger("imageio_ffmpeg")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


#: Input options with a selection filter: ffmpeg rebuilds its filters when the frames' size or colour range changes
#: part-way (joined camera clips), which would restart the filter's frame number ``n`` from 0.
_SELECTION_INPUT_OPTIONS = ["-reinit_filter", "0"]


def _selection_filter(wanted: range, then: str | None = None) -> tuple[list[str], list[str], int]:
    """ffmpeg's input and output options that deliver only the frames of ``wanted``, and how many frames before
    them to drop; the filter ``then`` (if any) applied to the frames delivered.

    No options for every frame from the first. Frames before ``start``, and between steps, are still decoded (a
    video cannot be cut at an arbitrary frame without decoding from the keyframe before it, and seeking by time is
    not frame-exact on variable frame rates), but no longer converted to RGB and piped to Python: about half the
    cost of skipping them. ``n`` counts the decoded frames, as the open-time count does; ``-fps_mode passthrough``
    keeps ffmpeg from filling the gaps the filter leaves with duplicates. Frame 0 always goes through (and is
    dropped by the reader): ffmpeg writes its output header, which imageio-ffmpeg waits for only 10 s, when the
    first frame arrives. ``-frames:v`` ends ffmpeg at the last selected frame, which the filter would otherwise
    hold back until the end of the file.
    """
    if wanted.start == 0 and wanted.step == 1:
        return [], ([] if then is None else ["-vf", then]), 0
    keep = f"between(n\\,{wanted.start}\\,{wanted[-1]})"
    if wanted.step > 1:
        keep += f"*not(mod(n-{wanted.start}\\,{wanted.step}))"
    head = 1 if wanted.start > 0 else 0
    if head:
        keep = f"eq(n\\,0)+{keep}"
    chain = f"select={keep}" if then is None else f"select={keep},{then}"
    return list(_SELECTION_INPUT_OPTIONS), ["-vf", chain, "-frames:v", str(len(wanted) + head)], head


#: ffmpeg codecs that render text as images (its ``tty``, ``bin``, ``xbin`` and ``idf`` demuxers read any text
#: file as "ANSI art"): such an input is a text file given by mistake, not a video.
TEXT_ART_CODECS = frozenset({"ansi", "bintext", "xbin", "idf"})


def _video_meta(path: Path) -> dict:
    """Size, nominal fps, duration and codec from ffmpeg's header, via imageio-ffmpeg's reader."""
    reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24", output_params=list(_DECODE_OPTIONS))
    try:
        with _rotation_note_silenced():
            meta = next(reader)
    except (OSError, RuntimeError, StopIteration) as err:
        raise UnreadableSourceError(
            f"{path}: ffmpeg decodes it but its header cannot be parsed ({_ffmpeg_reason(str(err))}); "
            f"expected a standard video - re-encode it with `ffmpeg -i IN -c:v libx264 OUT.mp4`"
        ) from err
    finally:
        reader.close()
    if str(meta.get("codec", "")).split(",")[0].strip() in TEXT_ART_CODECS:
        raise UnreadableSourceError(
            f"{path}: a text file (ffmpeg would draw its characters as frames); expected a video file, a folder of "
            "images or an OTB sequence folder - a box or ground-truth file goes to --box, --corrections or eval")
    return meta


def _image_folder(path: Path) -> tuple[Path, str]:
    """The folder holding the frames and the sequence name (OTB: ``Name/img`` -> ``Name``)."""
    img = path / "img"
    if img.is_dir() and any(p.suffix.lower() in IMAGE_SUFFIXES for p in img.iterdir()):
        return img, path.resolve().name
    if path.name == "img":
        return path, path.resolve().parent.name
    return path, path.resolve().name


def _relative_frame_files(path: Path, folder: Path, files: Sequence[Path]) -> tuple[str, ...]:
    """Image paths relative to the parent of the sequence folder: ``Coke/img/0001.jpg``, ``seq/0001.png``.

    The sequence folder is the one that names the sequence (``Coke`` for
    ``Coke/`` and ``Coke/img/``), so a COCO reader pointed at its parent
    finds the images. Paths are made absolute without resolving symlinks, so
    a linked image keeps the name it has in the folder.
    """
    given = Path(os.path.abspath(path))
    if Path(os.path.abspath(folder)) != given or given.name != "img":
        root = given
    else:
        root = given.parent
    base = root.parent
    return tuple(Path(os.path.relpath(os.path.abspath(f), base)).as_posix() for f in files)


def _image_header(file: Path) -> tuple[int, int, int]:
    """Upright ``(width, height)`` of an image and the EXIF orientation this tool applies to it (1: none).

    From the header where Pillow can read it, else by decoding.
    """
    try:
        from PIL import Image  # imageio depends on Pillow; header-only reads keep open() fast

        with Image.open(file) as image:
            width, height = image.size
            orientation = _applied_orientation(file, image)
    except Exception:  # noqa: BLE001 - any Pillow failure falls back to OpenCV, which decides
        pass
    else:
        return (height, width, orientation) if orientation in _SWAPS_SIDES else (width, height, orientation)
    bgr = cv2.imread(str(file), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if bgr is None:
        raise UnreadableSourceError(
            f"{file}: image cannot be decoded; expected a valid "
            f"{'/'.join(s.lstrip('.') for s in IMAGE_SUFFIXES)} file - re-export or remove it"
        )
    return bgr.shape[1], bgr.shape[0], 1


#: EXIF orientations (tag 274) whose upright image is the stored one turned a quarter: width and height swap.
_SWAPS_SIDES = (5, 6, 7, 8)


def _applied_orientation(file: Path, image) -> int:
    """The EXIF orientation (1-8) :func:`upright` applies to ``file``'s decoded image, from its open Pillow
    ``image``; 1 (as stored) when absent, not valid or unreadable.

    TIFF: OpenCV's TIFF reader applies the orientation itself, ``IMREAD_IGNORE_ORIENTATION`` or not, so the
    decoded image is already upright (orientations 2-4; it cannot decode 5-8 at all).
    """
    if file.suffix.lower() in (".tif", ".tiff"):
        return 1
    try:
        value = image.getexif().get(274, 1)
    except Exception:  # noqa: BLE001 - a header Pillow reads but whose EXIF it cannot (a cut-short PNG)
        return 1
    return value if isinstance(value, int) and 1 <= value <= 8 else 1


def upright(image: np.ndarray, orientation: int) -> np.ndarray:
    """The stored image ``(H, W, ...)`` turned as its EXIF ``orientation`` says (Pillow's ``exif_transpose``)."""
    if orientation == 2:
        image = image[:, ::-1]
    elif orientation == 3:
        image = image[::-1, ::-1]
    elif orientation == 4:
        image = image[::-1]
    elif orientation == 5:
        image = image.swapaxes(0, 1)
    elif orientation == 6:
        image = image.swapaxes(0, 1)[:, ::-1]
    elif orientation == 7:
        image = image.swapaxes(0, 1)[::-1, ::-1]
    elif orientation == 8:
        image = image.swapaxes(0, 1)[::-1]
    return np.ascontiguousarray(image)


# --------------------------------------------------------------------------- entry point


def open_frames(
    path: str | os.PathLike,
    *,
    start: int = 0,
    stop: int | None = None,
    step: int = 1,
    fps: float | None = None,
    counting: Callable[[int], None] | None = None,
    known_count: tuple[int, str | None] | None = None,
) -> FrameSource:
    """Open a video file or image folder and select a range of its frames.

    Parameters
    ----------
    path : path-like
        A video file (anything ffmpeg decodes), a folder of images, or an OTB
        sequence folder ``Name/`` holding ``img/``.
    start : int
        First source frame, 0-based.
    stop : int or None
        End of the range, exclusive, clipped to the number of frames; None
        for the end of the source.
    step : int
        Take every ``step``-th frame from ``start``.
    fps : float or None
        Frame rate to record; None uses the container's rate for videos and
        :data:`DEFAULT_FOLDER_FPS` (30) for image folders.
    counting : callable, optional
        For a video, ``counting(frames so far)`` about every half second of
        the open-time pass that decodes it all to count its frames (a long
        video takes minutes: worth showing).
    known_count : (int, str or None), optional
        For a video, ``(frame_count, damage)`` of an earlier open of the very
        same bytes: the open-time pass is skipped. The caller vouches for the
        bytes (``retrack`` has just checked the file's content hash); ignored
        for image folders, whose count costs nothing.

    Returns
    -------
    FrameSource
        Iterate it for ``(source_index, (H, W, 3) uint8 RGB)`` pairs.

    Raises
    ------
    SourceNotFoundError
        ``path`` does not exist.
    UnreadableSourceError
        Not a decodable video or image (text file, empty file, MP4 cut before
        its index, no video stream, undecodable first frame).
    NoImagesError
        A folder with no image files.
    FrameSizeMismatchError
        Images of different sizes in one folder.
    FrameRangeError
        ``step < 1``, ``start < 0``, ``stop <= start`` or ``start`` past the last frame.

    Notes
    -----
    Iteration may raise :class:`DecodeError` after the last good frame of a
    truncated or corrupt source; see the module docstring.

    Examples
    --------
    >>> from annotator import open_frames
    >>> source = open_frames("samples/clip.mp4", start=10, stop=16, step=2)
    >>> source.width, source.height, source.indices.tolist()
    (320, 240, [10, 12, 14])
    >>> [(int(index), frame.shape) for index, frame in source]
    [(10, (240, 320, 3)), (12, (240, 320, 3)), (14, (240, 320, 3))]
    """
    path = Path(path)
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}; or None for the default")
    if not path.exists():
        raise SourceNotFoundError(
            f"{path}: no such file or folder; expected a video file, a folder of images or an OTB sequence folder "
            f"- check the path"
        )
    if path.is_dir():
        return ImageFolderSource(path, start=start, stop=stop, step=step, fps=fps)
    source = VideoSource(path, start=start, stop=stop, step=step, fps=fps, counting=counting, known_count=known_count)
    if source.frame_count == 1 and path.suffix.lower() in IMAGE_SUFFIXES:
        # ffmpeg reads one image as a one-frame video; the user most likely meant the folder of frames.
        warnings.warn(f"{path} is a single image, so there is nothing to track after its first frame; to track a "
                      f"sequence of images give their folder ({path.parent})", InputWarning, stacklevel=2)
    return source

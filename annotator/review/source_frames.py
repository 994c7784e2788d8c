"""Frames for re-tracking, decoded again from the input that ``run.json`` records."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from annotator.errors import EXIT_INPUT, ToolError
from annotator.frame_sources import FrameSource, FrameSourceError, open_frames
from annotator.provenance import content_hash
from annotator.review.loaded_run import RUN_JSON, LoadedRun

__all__ = ["BUFFER_BYTES", "SourceFrames", "checks_content_hash", "open_run_source"]

#: Memory a backward pass may spend on buffered frames; longer spans are re-read in chunks of this size
#: (see :mod:`annotator.review.retrack`). 512 MiB is ~580 frames of 640x480, ~85 of 1080p.
BUFFER_BYTES = 512 * 2**20


class SourceFrames:
    """A :class:`~annotator.review.FrameProvider` over a run's frame source, decoding sequentially.

    Reading forward continues the live decoder (a video is decoded once for
    all the segments of a re-track); reading backwards, or far ahead in an
    image folder, starts the source again at the first frame wanted
    (:meth:`~annotator.frame_sources.FrameSource.frames_from`: for a video, ffmpeg
    decodes again from the start of the file but hands over only the frames
    from there on).
    """

    def __init__(self, source: FrameSource, frame_indices: np.ndarray) -> None:
        self.source = source
        self.frame_indices = np.asarray(frame_indices, dtype=np.int64)
        self._live: Iterator | None = None
        self._next = 0

    def _open(self, lo: int) -> None:
        self.close()
        self._live, self._next = self.source.frames_from(lo), lo

    def close(self) -> None:
        if self._live is not None and hasattr(self._live, "close"):
            self._live.close()
        self._live = None

    def frames(self, lo: int, hi: int) -> Iterator[tuple[int, np.ndarray]]:
        if lo >= hi:
            return
        images = getattr(self.source, "kind", "") == "images"
        if self._live is None or self._next > lo or (images and lo - self._next > 8):
            self._open(lo)
        assert self._live is not None  # opened just above if it was not
        while self._next < hi:
            try:
                index, frame = next(self._live)
            except StopIteration:
                raise ToolError(f"{self.source.path}: ended before frame {int(self.frame_indices[self._next])} "
                                "that the run processed; the input changed - re-run the annotation",
                                EXIT_INPUT) from None
            position = self._next
            if index != self.frame_indices[position]:
                raise ToolError(f"{self.source.path}: decoded frame {index} where the run had frame "
                                f"{int(self.frame_indices[position])}; the input changed - re-run the annotation",
                                EXIT_INPUT)
            self._next = position + 1
            if position >= lo:
                yield position, frame


def open_run_source(run: LoadedRun, *, verify_input: bool, input_path: str | os.PathLike | None = None,
                    input_checked: bool = False) -> FrameSource:
    """Open the run's input over its recorded range and check it is the input the run saw.

    ``input_path`` replaces the recorded path (the input was moved or copied);
    its content hash must then equal the recorded one, whatever ``verify_input`` says.
    ``input_checked``: the caller has just hashed the input into run.json, so
    its recorded frame count stands without decoding it again.
    """
    source_info, rng = run.info["input"], run.info["range"]
    moved = input_path is not None
    path = Path(input_path) if input_path is not None else Path(source_info["path"])
    verify = checks_content_hash(run, verify_input=verify_input, input_path=input_path)
    # A video file's hash is checked before opening it, so that the count can be taken from the run; an image
    # folder's count costs nothing.
    same_bytes = False
    if verify and path.is_file():
        with contextlib.suppress(OSError):  # unreadable: open_frames below says why
            same_bytes = _check_content_hash(path, source_info["content_hash"], run, moved=moved)
    # The same bytes decode to the same frames: a video need not be decoded once more just to count them.
    trusted = same_bytes or (input_checked and not moved)
    known = (int(source_info["frame_count"]), source_info["damage"]) if trusted and "damage" in source_info else None
    try:
        source = open_frames(path, start=int(rng["start"]), stop=int(rng["stop"]), step=int(rng["step"]),
                             known_count=known)
    except FrameSourceError as exc:
        where = "given with --input" if moved else (f"the input recorded in {run.out_dir / RUN_JSON}; if it moved, "
                                                     "give its new path with --input PATH")
        raise ToolError(f"{exc} ({where})", EXIT_INPUT) from None
    if (source.width, source.height, source.frame_count) != (run.video.width, run.video.height, run.video.frame_count):
        raise ToolError(f"{path} is now {source.width}x{source.height} with {source.frame_count} frames, the run had "
                        f"{run.video.width}x{run.video.height} with {run.video.frame_count}: the input changed - "
                        "re-run the annotation", EXIT_INPUT)
    oriented = getattr(source, "oriented", 0)
    if oriented and source_info.get("exif_orientation") != "applied":
        raise ToolError(f"{path}: {oriented} of its images carry an EXIF orientation, which this version applies "
                        f"(frames upright, as viewers show them) and the version that made the run in {run.out_dir} "
                        "ignored, so the run's boxes are in the images as stored: re-run the annotation", EXIT_INPUT)
    if not np.array_equal(source.indices[: len(run.frame_indices)], run.frame_indices):
        raise ToolError(f"{path}: the frames of the recorded range do not match the run's track store: re-run the "
                        "annotation", EXIT_INPUT)
    if verify and not same_bytes:
        _check_content_hash(path, source_info["content_hash"], run, moved=moved)  # opened, so let a read error out
    return source


def checks_content_hash(run: LoadedRun, *, verify_input: bool, input_path: str | os.PathLike | None) -> bool:
    """Whether :func:`open_run_source` checks the input's bytes against run.json: when asked, always for an input
    given with ``--input``, and only where the run recorded a content hash."""
    return bool((verify_input or input_path is not None) and run.info["input"].get("content_hash"))


def _check_content_hash(path: Path, recorded: str, run: LoadedRun, *, moved: bool) -> bool:
    """True if ``path`` holds the bytes the run was made on, else a one-line error (``OSError`` if unreadable)."""
    if content_hash(path) != recorded:
        if moved:
            raise ToolError(f"--input {path} is not the input of this run (its content hash differs from the one "
                            f"recorded in {run.out_dir / RUN_JSON}): give the file or folder the run was made on",
                            EXIT_INPUT)
        raise ToolError(f"{path} changed since the run (its content hash differs from run.json): corrections "
                        "refer to the frames the run saw - re-run the annotation on the new input", EXIT_INPUT)
    return True

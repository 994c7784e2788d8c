"""The OTB box text format: one ``x,y,w,h`` row per frame.

OTB ground truth and the result files read by the got10k and pysot toolkits
are 1-based (MATLAB heritage). Everything inside this project is 0-based
``xywh``; this module is the only place where the origin changes.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from annotator.atomic import atomic_open
from annotator.text_input import TEXT_ENCODINGS, read_text

__all__ = ["OTBFormatError", "read_otb_boxes", "write_otb_boxes", "write_otb_times"]

# Ground-truth files mix separators: commas in most, tabs or runs of spaces in some.
_SEPARATOR = re.compile(r"[,\t ]+")


class OTBFormatError(ValueError):
    """A box file that cannot be parsed; the message names the file and the line."""


def read_otb_boxes(path: str | os.PathLike, *, origin: int = 1) -> np.ndarray:
    """Read an OTB box file into 0-based ``xywh`` boxes.

    Parameters
    ----------
    path : path-like
        Text file with one ``x,y,w,h`` row per frame, separated by commas,
        tabs or spaces.
    origin : {1, 0}
        Pixel origin of the file. OTB ground truth and OTB result files are 1-based.

    Returns
    -------
    boxes : (N, 4) float64 ndarray
        0-based ``xywh``. Empty rows and rows holding ``NaN`` become a row
        of NaN: the toolkits score those frames as failures, and so do we.

    Raises
    ------
    OTBFormatError
        A row that does not hold four numbers, naming the file and line.
    FileNotFoundError
        The file does not exist.
    """
    if origin not in (0, 1):
        raise ValueError(f"origin must be 0 or 1, got {origin!r}")
    path = Path(path)
    rows: list[list[float]] = []
    try:
        lines = read_text(path).splitlines()
    except UnicodeDecodeError:
        raise OTBFormatError(f"{path} is not text ({TEXT_ENCODINGS}): expected one 'x,y,w,h' row per frame "
                             "(an OTB box file); check the path") from None
    # A trailing empty line is a file ending, not a frame.
    while lines and not lines[-1].strip():
        lines.pop()
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text:
            rows.append([np.nan] * 4)
            continue
        fields = [f for f in _SEPARATOR.split(text) if f]
        if len(fields) != 4:
            raise OTBFormatError(
                f"{path}:{number}: expected 4 numbers 'x,y,w,h', got {len(fields)} fields in {text!r}"
            )
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise OTBFormatError(f"{path}:{number}: expected 4 numbers 'x,y,w,h', got {text!r}") from None
    boxes = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    boxes[:, :2] -= origin
    return boxes


def write_otb_boxes(path: str | os.PathLike, boxes_xywh: np.ndarray, *, origin: int = 1) -> None:
    """Write 0-based ``xywh`` boxes as an OTB result file, atomically.

    One row per box, ``%.3f`` comma-separated as got10k writes them; a NaN
    box is written as ``nan,nan,nan,nan`` so that the row count always equals
    the frame count (the toolkits assert it).
    """
    if origin not in (0, 1):
        raise ValueError(f"origin must be 0 or 1, got {origin!r}")
    boxes = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4).copy()
    boxes[:, :2] += origin
    with atomic_open(path, "w", encoding="utf-8", newline="\n") as handle:
        for x, y, w, h in boxes:
            handle.write(f"{x:.3f},{y:.3f},{w:.3f},{h:.3f}\n")


def write_otb_times(path: str | os.PathLike, seconds: np.ndarray) -> None:
    """Write per-frame times in seconds, one per line (got10k's ``times/<Seq>_time.txt``)."""
    with atomic_open(path, "w", encoding="utf-8", newline="\n") as handle:
        for value in np.asarray(seconds, dtype=np.float64).ravel():
            handle.write(f"{value:.6f}\n")

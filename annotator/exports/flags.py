"""The flags file: one CSV row per processed frame per track, for review and evaluation tools.

Columns (header always present, in this order)::

    frame,track,confidence,log_likelihood,accepted,flagged,reason

* ``frame``: source frame index, 0-based (the same index as the COCO image's
  ``frame_index`` and the overlay video's frame number).
* ``track``: ``TrackResult.track_id``.
* ``confidence``: in [0, 1], 6 decimals.
* ``log_likelihood``: the tracker's score, 6 significant digits; ``inf``,
  ``-inf`` and ``nan`` are written as such (Python and pandas read them).
* ``accepted``, ``flagged``: ``1`` or ``0``.
* ``reason``: why the frame is flagged, empty when it is not; absences
  (``outside``) are flagged frames with their reason, as FORMATS.md asks.
  Every reason is explained in :data:`annotator.flagging.REASONS`.

Then one column per signal the tracks carry (:attr:`TrackResult.signals`):
``p_fail``, the failure probability (``confidence`` is ``1 - p_fail``), first,
then the failure signals of :data:`annotator.failure.SIGNALS` in that order
(but for ``log_likelihood`` and ``accepted``, already columns), 6 significant
digits; empty where a track has no such value.

Rows are sorted by frame, then track. Fields are quoted only when needed
(RFC 4180, a reason holding a comma).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from annotator.atomic import atomic_open
from annotator.tracks import TrackResult, select_rows

__all__ = ["FLAGS_HEADER", "FlagTable", "FlagsFormatError", "read_flags_csv", "write_flags_csv"]

FLAGS_HEADER = ("frame", "track", "confidence", "log_likelihood", "accepted", "flagged", "reason")


class FlagsFormatError(ValueError):
    """A flags CSV that cannot be parsed; the message names the file and line."""


@dataclass(frozen=True)
class FlagTable:
    """The rows of a flags CSV as a struct of arrays, in file order (frame, then track).

    Attributes
    ----------
    frame, track : (n,) int64 ndarray
    confidence, log_likelihood : (n,) float64 ndarray
    accepted, flagged : (n,) bool ndarray
    reason : tuple of str, length n
    """

    frame: np.ndarray
    track: np.ndarray
    confidence: np.ndarray
    log_likelihood: np.ndarray
    accepted: np.ndarray
    flagged: np.ndarray
    reason: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def for_track(self, track_id: int) -> FlagTable:
        """The rows of one track."""
        return select_rows(self, np.flatnonzero(self.track == track_id))


def signal_columns(tracks: Sequence[TrackResult]) -> list[str]:
    """The signal columns of a flags file: ``p_fail``, then the failure signals in their order, then any other."""
    from annotator.failure.signals import SIGNALS

    # A signal named like a fixed column (the tracker's log-likelihood and acceptance) is that column already.
    names = {name for t in tracks for name in t.signals} - set(FLAGS_HEADER)
    known = [n for n in ("p_fail", *SIGNALS) if n in names]
    return known + sorted(names - set(known))


def _value(values, i: int) -> str:
    if values is None or not np.isfinite(values[i]):
        return ""
    return f"{values[i]:.6g}"


def _rows(tracks: Sequence[TrackResult], columns: Sequence[str]):
    order = sorted((int(f), t.track_id, n, i) for n, t in enumerate(tracks) for i, f in enumerate(t.frame_indices))
    for frame, track_id, n, i in order:
        t = tracks[n]
        yield (
            frame,
            track_id,
            f"{t.confidence[i]:.6f}",
            f"{t.log_likelihood[i]:.6g}",
            int(t.accepted[i]),
            int(t.flagged[i]),
            t.reasons[i],
            *(_value(t.signals.get(name), i) for name in columns),
        )


def write_flags_csv(path: str | os.PathLike, tracks: Sequence[TrackResult]) -> None:
    """Write the flags CSV of ``tracks`` atomically (format in the module docstring)."""
    tracks = list(tracks)
    ids = [t.track_id for t in tracks]
    if len(set(ids)) != len(ids):
        raise ValueError(f"track ids must be unique in a flags file, got {ids}")
    columns = signal_columns(tracks)
    with atomic_open(path, "w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow((*FLAGS_HEADER, *columns))
        for row in _rows(tracks, columns):
            writer.writerow(row)


_TRUE = {"1", "true", "True", "TRUE"}
_FALSE = {"0", "false", "False", "FALSE"}


def _parse_bool(text: str, where: str, column: str) -> bool:
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    raise FlagsFormatError(f"{where}: column {column!r} must be 1 or 0, got {text!r}")


def read_flags_csv(path: str | os.PathLike) -> FlagTable:
    """Read a flags CSV written by :func:`write_flags_csv`.

    Raises
    ------
    FlagsFormatError
        Wrong header, wrong number of fields or an unparsable value, naming file and line.
    FileNotFoundError
        No such file.
    """
    path = Path(path)
    frames, tracks, conf, loglik, accepted, flagged, reasons = [], [], [], [], [], [], []
    with open(path, encoding="utf-8-sig", newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header is None or tuple(h.strip() for h in header[: len(FLAGS_HEADER)]) != FLAGS_HEADER:
            raise FlagsFormatError(
                f"{path}:1: expected the header {','.join(FLAGS_HEADER)!r}, got {','.join(header or [])!r}; "
                f"is this a flags file written by sptpt-annotate?"
            )
        for row in reader:
            where = f"{path}:{reader.line_num}"
            if not row:
                continue
            if len(row) != len(header):
                raise FlagsFormatError(f"{where}: expected {len(header)} fields, got {len(row)} in {row!r}")
            try:
                frames.append(int(row[0]))
                tracks.append(int(row[1]))
                conf.append(float(row[2]))
                loglik.append(float(row[3]))
            except ValueError:
                raise FlagsFormatError(
                    f"{where}: expected integer frame and track and numeric confidence and log_likelihood, got {row!r}"
                ) from None
            accepted.append(_parse_bool(row[4], where, "accepted"))
            flagged.append(_parse_bool(row[5], where, "flagged"))
            reasons.append(row[6])
    return FlagTable(
        frame=np.asarray(frames, dtype=np.int64),
        track=np.asarray(tracks, dtype=np.int64),
        confidence=np.asarray(conf, dtype=np.float64),
        log_likelihood=np.asarray(loglik, dtype=np.float64),
        accepted=np.asarray(accepted, dtype=bool),
        flagged=np.asarray(flagged, dtype=bool),
        reason=tuple(reasons),
    )

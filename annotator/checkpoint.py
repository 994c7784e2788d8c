"""Checkpoints of a run in progress, so that an interrupted run goes on where it stopped (``--resume``).

Every :data:`CHECKPOINT_EVERY` frames the frame loop waits until no frame is
in flight (each tracker idle, every tracked frame measured and flagged) and
the whole state of the run is written to ``<out>/.sptpt-checkpoint.pkl``
(atomically: a run killed while writing keeps the previous checkpoint): the
trackers (their models and random streams) and the measuring and flagging
stage. A resumed run loads it, decodes and skips the frames up to it, and
tracks on, so its boxes, scores and flags are those of a run never
interrupted, to the bit (frames submitted ahead give the same results as
frames tracked one at a time, so the wait costs no accuracy).

The file is a pickle, as only the trackers themselves know their state; it is
read only from the run's own output folder, written by this tool, and it
names the run it belongs to (:func:`run_key`: the input's path, size and
modification time, the range, the targets, the settings and the tool
version), so a checkpoint of another run is refused rather than continued.
A run that finishes removes it.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from annotator.atomic import write_bytes_atomic
from annotator.errors import EXIT_OUTPUT, ToolError
from annotator.output_files import CHECKPOINT_NAME
from annotator.version import __version__

__all__ = ["CHECKPOINT_EVERY", "CHECKPOINT_NAME", "Checkpoint", "read_checkpoint", "remove_checkpoint",
           "run_key", "write_checkpoint"]

#: The checkpoint's file name inside the output folder (hidden: it is no result).
#: Frames between checkpoints: at most this many are tracked again after an interruption. Writing one takes
#: a few tens of milliseconds (a few MiB per tracker), against several seconds of tracking between them.
CHECKPOINT_EVERY = 100
_MAGIC = b"sptpt-annotate checkpoint 1\n"


@dataclass
class Checkpoint:
    """A run's state after its first ``frames_tracked`` frames, the last being source frame ``last_index``."""

    key: dict[str, Any]
    frames_tracked: int
    last_index: int
    seconds_tracking: float
    trackers: dict  # track id -> sptpt.Tracker
    records: Any  # annotator.pipeline.TrackRecords


def _input_identity(path: Path) -> list:
    """The input as the file system describes it (cheap, unlike a content hash of a long video)."""
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    identity = []
    for file in files:
        stat = file.stat()
        identity.append([str(file.relative_to(path)) if path.is_dir() else file.name, stat.st_size,
                         stat.st_mtime_ns])
    return identity


def run_key(input_path: str | os.PathLike, frames: range, targets: Sequence, settings: dict) -> dict[str, Any]:
    """What a checkpoint must match to be continued: the same input, range, targets, settings and tool version."""
    path = Path(input_path).resolve()
    return {
        "tool_version": __version__,
        "input": str(path),
        "input_files": _input_identity(path),
        "range": [frames.start, frames.stop, frames.step],
        "targets": [[t.track_id, t.label, [float(v) for v in t.box_xywh]] for t in targets],
        "settings": settings,
    }


def write_checkpoint(out_dir: str | os.PathLike, checkpoint: Checkpoint) -> None:
    """Write ``checkpoint`` into ``out_dir`` atomically (the previous one stays whole until it is replaced)."""
    write_bytes_atomic(Path(out_dir) / CHECKPOINT_NAME,
                       _MAGIC + pickle.dumps(checkpoint, protocol=pickle.HIGHEST_PROTOCOL))


def read_checkpoint(out_dir: str | os.PathLike) -> Checkpoint | None:
    """The checkpoint in ``out_dir``, or None when there is none.

    Raises
    ------
    ToolError
        The file cannot be read or is not a checkpoint of this tool's version (exit code 5, naming ``--force``).
    """
    path = Path(out_dir) / CHECKPOINT_NAME
    if not path.is_file():
        return None
    try:
        data = path.read_bytes()
        if not data.startswith(_MAGIC):
            raise ValueError("not a checkpoint of this tool")
        checkpoint = pickle.loads(data[len(_MAGIC):])
        if not isinstance(checkpoint, Checkpoint):
            raise ValueError("not a checkpoint of this tool")
    except Exception as exc:  # noqa: BLE001 - a damaged or foreign file: any unpickling error means the same
        raise ToolError(f"{path}: the checkpoint cannot be read ({exc}): pass --force to start the run again",
                        EXIT_OUTPUT) from None
    return checkpoint


def remove_checkpoint(out_dir: str | os.PathLike) -> None:
    """Remove the checkpoint of ``out_dir`` (its run finished), if any."""
    try:
        (Path(out_dir) / CHECKPOINT_NAME).unlink()
    except FileNotFoundError:
        pass

"""OTB result files for tracks: ``<name>.txt`` (1-based ``x,y,w,h``) and ``times/<name>_time.txt``.

The layout is the one the got10k and pysot toolkits read for a tracker's
results folder. One row per processed frame, the first frame included, and a
row even for frames where the object is absent or lost (the toolkits assert
``len(results) == len(groundtruth)``); absences live in the flags file.

Several tracks of one video follow OTB's multi-target naming: the ground
truth of ``Jogging`` is ``groundtruth_rect.1.txt`` and ``.2.txt`` and got10k
calls the sequences ``Jogging.1`` and ``Jogging.2``, so the results are
``Jogging.1.txt`` and ``Jogging.2.txt`` with ``times/Jogging.1_time.txt``. A
single track is written as ``<name>.txt`` whatever its id.
"""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import Sequence

from annotator.otb_format import write_otb_boxes, write_otb_times
from annotator.tracks import TrackResult

__all__ = ["otb_result_globs", "otb_sequence_names", "write_otb_results"]


def otb_sequence_names(name: str, tracks: Sequence[TrackResult]) -> list[str]:
    """Sequence names of the tracks: ``[name]`` for one track, ``name.<track_id>`` for several."""
    if len(tracks) == 1:
        return [name]
    ids = [t.track_id for t in tracks]
    if len(set(ids)) != len(ids):
        raise ValueError(f"track ids must be unique to name OTB files {name}.<id>.txt, got {ids}")
    return [f"{name}.{t.track_id}" for t in tracks]


def otb_result_globs(name: str) -> tuple[str, ...]:
    """Glob patterns, relative to the results folder, of every file :func:`write_otb_results` may write for ``name``."""
    name = glob.escape(name)
    return f"{name}.txt", f"{name}.*.txt", f"times/{name}_time.txt", f"times/{name}.*_time.txt"


def write_otb_results(
    out_dir: str | os.PathLike, name: str, tracks: Sequence[TrackResult], *, times: bool = True
) -> list[Path]:
    """Write each track as an OTB result file (1-based), plus its per-frame times.

    Parameters
    ----------
    out_dir : path-like
        Results folder (created if missing); times go to ``out_dir/times/``.
    name : str
        Sequence name, e.g. ``VideoInfo.name``.
    tracks : sequence of TrackResult
        One file per track; see the module docstring for names.
    times : bool
        Also write ``times/<seq>_time.txt`` from ``TrackResult.seconds``.

    Returns
    -------
    list of Path
        The files written, boxes and times of each track in turn.
    """
    tracks = list(tracks)
    if not tracks:
        raise ValueError(f"no tracks to write for {name!r}; expected at least one TrackResult")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for seq, track in zip(otb_sequence_names(name, tracks), tracks):
        boxes_path = out_dir / f"{seq}.txt"
        write_otb_boxes(boxes_path, track.boxes_xywh, origin=1)
        written.append(boxes_path)
        if times:
            (out_dir / "times").mkdir(exist_ok=True)
            times_path = out_dir / "times" / f"{seq}_time.txt"
            write_otb_times(times_path, track.seconds)
            written.append(times_path)
    return written

"""Writing a run's files: one way for a first run and for a re-track.

The track store is written first; every other file is a view of it (the
exports, the report) or says what the folder holds (run.json, written last:
its presence marks a finished run, and batch resumption relies on it). The
overlay is not written here: it is a sink of the tracking pipeline
(:class:`annotator.pipeline.OverlaySink`), streamed by a first run while it
tracks and rendered from the tracks by a re-track, before the files here.

Both write into a staging folder and :func:`move_into_place` moves the
complete set into the output folder, the track store next to last and
run.json last, so that an earlier run stays whole until then.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from annotator.atomic import atomic_path, write_text_atomic
from annotator.exports import ExportOptions, record_review_exports, write_exports
from annotator.output_files import OVERLAY_NAME, REPORT_NAME, RUN_JSON
from annotator.pass_cache import PASSES_NAME, pass_fingerprint, write_pass_cache
from annotator.provenance import json_default
from annotator.run_report import corrections_section, render_report, track_summary
from annotator.track_store import STORE_NAME, RunStore, write_store
from annotator.tracks import SpanThumbnail

__all__ = ["OVERLAY_NAME", "REPORT_NAME", "RUN_JSON", "MoveError", "move_into_place", "run_fingerprint",
           "write_run_files"]



def run_fingerprint(info: Mapping[str, Any]) -> str:
    """The pass cache's fingerprint of a run: its config as run.json holds it, input content hash and range."""
    config = json.loads(json.dumps(info.get("config", {}), default=json_default))  # as it reads back
    return pass_fingerprint(config, info["input"].get("content_hash"), info["range"])


def write_run_files(
    folder: Path,
    store: RunStore,
    info: Mapping[str, Any],
    *,
    settings: Mapping[str, Any],
    options: ExportOptions,
    passes: Mapping | None,
    thumbnails: Sequence[SpanThumbnail] = (),
    overlay: bool = False,
    passes_kept: bool = False,
) -> dict[str, list[Path]]:
    """Write ``store`` into ``folder``, then every view of it that ``info["formats"]`` asks for, run.json last.

    Parameters
    ----------
    folder : Path
        A staging folder (the caller moves the files into the output folder).
    store : RunStore
        The run's tracks: every export, the report and run.json's track summaries are written from it.
    info : mapping
        run.json's content without ``tracks`` and ``outputs`` (filled in here); ``formats``, ``config``,
        ``input`` and ``range`` as a run writes them, ``timings`` for the report, and for a re-track the
        ``review`` section the report lists.
    settings : mapping
        The configuration the report shows (``RunConfig.to_dict()``).
    options : ExportOptions
    passes : mapping or None
        The forward passes to keep for the next re-track (:mod:`annotator.pass_cache`); None writes none.
    thumbnails : sequence of SpanThumbnail
        The flagged spans' overlay frames, for the report.
    overlay : bool
        ``folder`` holds the overlay the pipeline rendered (:data:`OVERLAY_NAME`).
    passes_kept : bool
        With ``passes`` None: the output folder's pass cache stays as it is and run.json still lists it.

    Returns
    -------
    dict of str to list of Path
        The files written, by kind, run.json under ``provenance`` (last).
    """
    formats = list(info["formats"])
    outputs: dict[str, list[Path]] = {"store": [write_store(folder / STORE_NAME, store)]}
    if passes is not None:
        outputs["passes"] = [write_pass_cache(folder / PASSES_NAME, passes, run_fingerprint(info))]
    outputs.update(write_exports(folder, store, formats, options))
    if overlay:
        outputs["overlay"] = [folder / OVERLAY_NAME]
    info = {**info, "tracks": [track_summary(t) for t in store.tracks]}
    if record := record_review_exports(info.get("review_exports"), store, formats):
        info["review_exports"] = record
    if "report" in formats:
        render_report(folder / REPORT_NAME, video=store.video, tracks=store.tracks, thumbnails=thumbnails,
                      settings=dict(settings), run_info=_report_run_info(info, store),
                      overlay_name=OVERLAY_NAME if overlay else None,
                      review=corrections_section(info["review"], store.tracks, store.video.fps)
                      if "review" in info else None)
        outputs["report"] = [folder / REPORT_NAME]
    info["outputs"] = {kind: [str(p.relative_to(folder)) for p in paths] for kind, paths in outputs.items()}
    if passes is None and passes_kept:
        info["outputs"]["passes"] = [PASSES_NAME]
    write_text_atomic(folder / RUN_JSON, json.dumps(info, indent=2, default=json_default) + "\n")
    outputs["provenance"] = [folder / RUN_JSON]
    return outputs


def _report_run_info(info: Mapping[str, Any], store: RunStore) -> dict[str, Any]:
    """run.json's content with the figures the report's summary shows; a run.json written before they were
    recorded shows the frames its store holds and no time."""
    timings = info.get("timings") or {}
    return {**info, "frames_processed": info.get("frames_processed", len(store.frame_indices)),
            "seconds_total": timings.get("seconds_total") or 0.0,
            "seconds_tracking": timings.get("seconds_tracking") or 0.0,
            "seconds_outside": timings.get("seconds_outside_tracker") or 0.0}


class MoveError(Exception):
    """:func:`move_into_place` stopped: ``cause`` says why, ``moved`` what was already in place (relative names).

    ``blocked`` is the earlier file that could not be moved aside (then nothing changed), else None.
    """

    def __init__(self, cause: OSError, moved: Sequence[Path], blocked: Path | None = None) -> None:
        super().__init__(str(cause))
        self.cause, self.moved, self.blocked = cause, list(moved), blocked


def move_into_place(staging: Path, out_dir: Path, names: Iterable[str | os.PathLike], *,
                    retire: Iterable[str | os.PathLike] = (), unmark_first: bool = False) -> list[Path]:
    """Move the files ``names`` (relative to ``staging``) into ``out_dir``, the track store next to last and
    run.json last; return where they are.

    Parameters
    ----------
    staging, out_dir : Path
    names : iterable of path-like
        The files a run wrote into ``staging``.
    retire : iterable of path-like
        Files of ``out_dir`` that the new run does not write and that would disagree with it. Each is moved aside
        before anything else, so that one that cannot be (a video open in a player on Windows) stops the move
        with nothing changed; they are deleted once every file is in place, and put back if a move fails.
    unmark_first : bool
        Remove ``out_dir``'s run.json before anything moves, so that a crash part-way leaves a folder that holds no
        finished run (a first run: batch resumption redoes it). A re-track keeps it: the earlier run.json goes on
        describing the earlier track store until both are replaced, so the re-track can be run again.

    Raises
    ------
    MoveError
        A file could not be moved aside (nothing changed) or moved in (``moved`` lists what had been).
    """
    paths = [Path(name) for name in names]
    last = [name for name in (Path(STORE_NAME), Path(RUN_JSON)) if name in paths]
    order = [*(name for name in paths if name not in last), *last]
    try:
        out_dir.mkdir(exist_ok=True)
    except OSError as exc:
        raise MoveError(exc, []) from None
    aside: dict[Path, Path] = {}
    for name in map(Path, retire):
        target = out_dir / name
        if target.is_file():
            try:
                os.replace(target, target.with_name(f".{target.name}.stale"))
            except OSError as exc:
                _put_back(aside)
                raise MoveError(exc, [], blocked=target) from None
            aside[target] = target.with_name(f".{target.name}.stale")
    moved: list[Path] = []
    try:
        if unmark_first:
            (out_dir / RUN_JSON).unlink(missing_ok=True)
        for name in order:
            (out_dir / name).parent.mkdir(parents=True, exist_ok=True)
            _move(staging / name, out_dir / name)
            moved.append(name)
    except OSError as exc:
        _put_back(aside)
        raise MoveError(exc, moved) from None
    for stale in aside.values():
        with contextlib.suppress(OSError):
            stale.unlink()
    return [out_dir / name for name in order]


def _put_back(aside: Mapping[Path, Path]) -> None:
    for target, stale in aside.items():
        with contextlib.suppress(OSError):
            os.replace(stale, target)


def _move(source: Path, target: Path) -> None:
    """Rename ``source`` onto ``target``; across file systems (a symlinked subfolder), copy it atomically."""
    try:
        os.replace(source, target)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        with atomic_path(target) as tmp:
            shutil.copyfile(source, tmp)
        source.unlink()

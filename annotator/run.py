"""The main job: one video (or image folder) and first-frame boxes in, every output written.

Shared by the ``sptpt-annotate VIDEO`` command and each item of a batch run.
Validation happens before any tracking. A run is written to a staging folder
inside the output folder and moved into place once written, run.json last; a
decode error or an interruption part-way still writes everything computed up
to it, beside (not over) an earlier finished run in the same folder.
"""

from __future__ import annotations

import datetime as _dt
import json
import numbers
import os
import platform
import shutil
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import sptpt
from annotator.atomic import ctrl_c_ignored
from annotator.box_input import parse_box
from annotator.checkpoint import CHECKPOINT_NAME, Checkpoint, read_checkpoint, remove_checkpoint, run_key
from annotator.config import RunConfig, resolve_config
from annotator.corrections import Correction, resolve_corrections
from annotator.errors import (
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_OUTPUT,
    EXIT_PARTIAL,
    EXIT_VALUE,
    InputWarning,
    ToolError,
)
from annotator.exports import ExportOptions
from annotator.frame_sources import FrameRangeError, FrameSource, FrameSourceError, VideoSource, open_frames
from annotator.output_files import ALL_FORMATS, DEFAULT_FORMATS, RUN_FILES, RUN_JSON
from annotator.output_folder import folder_lock, remove_staging_folders, staging_folder
from annotator.pass_cache import first_pass
from annotator.pipeline import TrackingRun, track_source
from annotator.progress import CountNote, Progress
from annotator.provenance import content_hash
from annotator.publish import OVERLAY_NAME, MoveError, move_into_place, write_run_files
from annotator.track_store import RunStore
from annotator.tracks import Target
from annotator.version import __version__
from annotator.wording import plural
from sptpt.boxes import clip_xyxy, lies_outside, xywh_to_xyxy

__all__ = ["ALL_FORMATS", "DEFAULT_FORMATS", "AnnotateResult", "annotate", "default_output_dir", "previous_outputs"]

#: Said when the first frame takes long and numba's cache lacks the tracker's kernels: on the first run after
#: installing, numba compiles them (README: the figure measured) and caches them beside the package.
COMPILING_NOTE = "compiling the tracker's kernels (once per install; cached for later runs)..."
#: Where a run cut short (Ctrl-C, a decode error) goes when the output folder already holds a finished run.
INCOMPLETE_DIR = "incomplete"


@dataclass
class AnnotateResult:
    """What a run wrote, and how it ended.

    Attributes
    ----------
    out_dir : Path
        The output folder.
    run : TrackingRun
        The tracking as it ran: tracks, timings, a decode error or an interruption.
    outputs : dict of str to list of Path
        The files written, by kind (``store``, ``otb``, ``coco``, ``flags``, ``overlay``, ``report``, ...).
    exit_code, message : int, str
        0 and "" for a finished run; else the exit code the command line ends with and why.
    store : RunStore or None
        The run's track store, as written to ``tracks.npz``: every per-frame value, every export a view of it.
    """

    out_dir: Path
    run: TrackingRun
    outputs: dict[str, list[Path]] = field(default_factory=dict)
    exit_code: int = 0
    message: str = ""
    store: RunStore | None = None


def default_output_dir(input_path: Path) -> Path:
    """``<input>_sptpt/`` beside the input (``clip.mp4`` -> ``clip_sptpt/``)."""
    input_path = Path(input_path)
    stem = input_path.name if input_path.is_dir() else input_path.stem
    return input_path.resolve().parent / f"{stem}_sptpt"


def _check_output_dir(out_dir: Path, *, force: bool, resume: bool = False) -> None:
    """The output folder's refusals that need nothing from the input: a file, earlier results, a run in it."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ToolError(f"output folder {out_dir} is a file: give --out a folder path", EXIT_OUTPUT)
    if out_dir.is_dir() and not force:
        interrupted = _interrupted_at(out_dir)
        if resume:
            if interrupted is None and _holds_finished_run(out_dir):
                raise ToolError(f"output folder {out_dir} holds a finished run: there is nothing to resume; pass "
                                "--force to start again", EXIT_OUTPUT)
            return
        if interrupted is not None:
            raise ToolError(f"output folder {out_dir} holds a run {interrupted}: --resume to continue, --force to "
                            "start again", EXIT_OUTPUT)
        existing = [name for name in RUN_FILES if (out_dir / name).exists()]  # a folder holding a run's results
        if existing:
            raise ToolError(f"output folder {out_dir} already holds results ({', '.join(existing)}): "
                            "pass --force to overwrite them or choose another --out", EXIT_OUTPUT)
    if out_dir.is_dir():
        with folder_lock(out_dir):
            pass


def _interrupted_at(out_dir: Path) -> str | None:
    """How far the run in ``out_dir`` went when it was cut short (``"interrupted at frame 48 of 100"``), or None
    when it holds no cut-short run: one that run.json says was interrupted, or whose checkpoint alone is left (a
    run killed before it wrote anything else)."""
    info = _run_info(out_dir)
    if info.get("interrupted") is True:
        ranged = info.get("range") or {}
        frames = info.get("input", {}).get("frame_count")
        try:
            total = len(range(int(ranged["start"]), int(ranged["stop"] if ranged.get("stop") is not None else frames),
                              int(ranged["step"])))
            return f"interrupted at frame {int(info['frames_processed'])} of {total}"
        except (KeyError, TypeError, ValueError):
            return "interrupted"
    if not info and (out_dir / CHECKPOINT_NAME).is_file():
        return "stopped before it finished (a checkpoint is left)"
    return None


def _prepare_output_dir(out_dir: Path, *, force: bool, resume: bool = False) -> None:
    _check_output_dir(out_dir, force=force, resume=resume)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out_dir):
            pass
    except OSError as exc:
        raise ToolError(f"output folder {out_dir} cannot be written ({exc.strerror}): "
                        "choose a writable --out folder", EXIT_OUTPUT) from None


#: Boxes smaller than this (px, either side) hold too little texture for the tracker's superpixels and
#: histograms: accepted, with a warning.
SMALL_BOX_PX = 8
#: A first-frame box with less than this share of its area inside the frame gets a warning.
MIN_VISIBLE_SHARE = 0.5


def _check_boxes(targets: Sequence[Target], source: FrameSource) -> None:
    for target in targets:
        x, y, w, h = target.box_xywh
        text = f"--box {x:g},{y:g},{w:g},{h:g} (0-based)"
        if lies_outside(target.box_xywh, source.width, source.height):
            raise ToolError(
                f"{text} lies outside the {source.width}x{source.height} first frame "
                f"of {source.path}: give pixel coordinates of the object in frame {source.start}"
                " (use --box-origin 1 for OTB-style 1-based boxes)", EXIT_VALUE)
        if w < SMALL_BOX_PX or h < SMALL_BOX_PX:
            warnings.warn(f"{text} is only {w:g}x{h:g} px: the tracker needs about {SMALL_BOX_PX}x{SMALL_BOX_PX} px "
                          "of object to follow it; check the box (x,y is the top-left corner, then width, height)",
                          InputWarning, stacklevel=3)
        x0, y0, x1, y1 = clip_xyxy(xywh_to_xyxy(target.box_xywh), source.width, source.height)
        visible = (x1 - x0) * (y1 - y0) / (w * h)
        if visible < MIN_VISIBLE_SHARE:
            warnings.warn(f"{text} lies {100 * (1 - visible):.0f}% outside the {source.width}x{source.height} frame: "
                          "the tracker learns the object from the part inside; check the box", InputWarning,
                          stacklevel=3)


def annotate(
    input_path: str | os.PathLike,
    targets: Target | Sequence[Target] | Sequence[float] | str | Sequence[Sequence[float] | str],
    config: RunConfig | None = None,
    *,
    out_dir: str | os.PathLike | None = None,
    start: int = 0,
    stop: int | None = None,
    step: int = 1,
    formats: Sequence[str] = DEFAULT_FORMATS,
    force: bool = False,
    show_progress: bool = True,
    corrections: Sequence[Correction] | None = None,
    media_url: str | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> AnnotateResult:
    """Track ``targets`` through a video or image folder and write every requested output.

    What ``sptpt-annotate VIDEO --box ...`` runs, and each item of a batch.

    Parameters
    ----------
    input_path : path-like
        A video file or a folder of images.
    targets : box, Target, or a sequence of them
        The objects' first-frame boxes. A box is four numbers ``x, y, w, h`` (0-based pixels) or the text
        ``"x,y,w,h"``, read as ``--box`` reads it (:func:`annotator.box_input.parse_box`); boxes get the track
        ids 1, 2, ... in order and the label ``object``. A :class:`~annotator.tracks.Target` gives its own.
    config : RunConfig, optional
        From :func:`annotator.config.resolve_config`; by default ``resolve_config()``, what the command line uses
        without options (the default preset, seed 0).
    out_dir : path-like, optional
        By default ``<input>_sptpt/`` beside the input.
    start, stop, step : int
        The source frames to track (``--start``, ``--stop``, ``--step``); ``stop`` None: to the end.
    formats : sequence of str
        The outputs to write (``--formats``); the track store is always written.
    force : bool
        Replace the results an earlier run left in ``out_dir`` (``--force``).
    show_progress : bool
        Progress bars on stderr (not ``--quiet``).
    corrections : sequence of Correction, optional
        Only checked here against the frames and tracks the run will have, before any tracking (a correction of a
        frame outside ``start``/``stop`` fails at once); the caller applies them afterwards with
        :func:`apply_corrections`.
    media_url : str, optional
        The video's URL written into ``labelstudio.json`` (``--media-url``), kept in run.json.
    resume : bool
        Go on from the checkpoint of an interrupted run into ``out_dir`` (``--resume``): the boxes are those of an
        uninterrupted run.
    progress : callable, optional
        ``progress(done, in_all)``, called with 0 frames done before the first, then after each (with or without
        ``show_progress``).

    Returns
    -------
    AnnotateResult
        The output folder, the files written by kind, the run's track store, and how the run ended.

    Raises
    ------
    ToolError
        With the exit code of the problem (see :mod:`annotator.errors`); a
        decode error part-way is not raised but reported in the result's
        ``exit_code`` and ``message``, after the outputs are written.

    Examples
    --------
    >>> from annotator import annotate
    >>> result = annotate("samples/clip.mp4", (136, 129, 48, 40), out_dir="clip_out", stop=5,
    ...                   formats=("otb", "coco", "flags"), show_progress=False)
    >>> result.exit_code, sorted(result.outputs)
    (0, ['coco', 'flags', 'otb', 'passes', 'provenance', 'store'])
    >>> result.store.track(1).boxes_xywh.shape
    (5, 4)
    """
    input_path = Path(input_path)
    targets = _as_targets(targets)
    config = resolve_config() if config is None else config
    _check_request(targets, formats)
    out_dir = Path(out_dir) if out_dir is not None else default_output_dir(input_path)
    if input_path.exists():  # (a missing input is open_frames' error to give, first)
        # Before opening the input: opening a video counts its frames, minutes for a long one, and a refusal
        # after that wait would waste it.
        _check_output_dir(out_dir, force=force, resume=resume)
    counting = CountNote(input_path.name, enabled=show_progress)
    try:
        source = open_frames(input_path, start=start, stop=stop, step=step, counting=counting)
    except FrameRangeError as exc:
        raise ToolError(str(exc), EXIT_VALUE) from None
    except FrameSourceError as exc:
        raise ToolError(str(exc), EXIT_INPUT) from None
    finally:
        counting.close()
    _check_boxes(targets, source)
    if corrections is not None:
        resolve_corrections(corrections, frame_indices=source.indices, track_ids=[t.track_id for t in targets],
                            width=source.width, height=source.height)
    _prepare_output_dir(out_dir, force=force, resume=resume)
    with folder_lock(out_dir):
        return _run_into(out_dir, source, targets, config, formats, input_path, show_progress,
                         ExportOptions(media_url=media_url), resume, progress)


def _checkpoint_to_resume(out_dir: Path, key: dict) -> Checkpoint | None:
    """The checkpoint ``--resume`` goes on from, checked to be this run's; None when the folder holds none."""
    checkpoint = read_checkpoint(out_dir)
    if checkpoint is None:
        return None
    differs = [name for name in ("input", "input_files", "range", "targets", "settings", "tool_version")
               if checkpoint.key.get(name) != key.get(name)]
    if differs:
        what = {"input": "input", "input_files": "input file (changed since)", "range": "frame range",
                "targets": "boxes or labels", "settings": "settings", "tool_version": "tool version"}
        raise ToolError(f"the checkpoint in {out_dir} is of another run (its {', '.join(what[d] for d in differs)} "
                        "differs): resume with the run's own input, boxes and options, or pass --force to start "
                        "again", EXIT_OUTPUT)
    return checkpoint


def _check_request(targets: Sequence[Target], formats: Sequence[str]) -> None:
    """Refuse unknown formats, no target, or an empty label: before anything is opened."""
    unknown = sorted(set(formats) - set(ALL_FORMATS))
    if unknown:
        raise ToolError(f"--formats {','.join(unknown)} is not known: choose from {','.join(ALL_FORMATS)}", EXIT_VALUE)
    if not targets:
        raise ToolError("no --box given: give the object's first-frame box as --box x,y,w,h", EXIT_VALUE)
    for target in targets:
        if not isinstance(target.label, str) or not target.label.strip():
            raise ToolError(f"--label {target.label!r} of box {target.track_id} is empty: give a category name "
                            "such as 'car'", EXIT_VALUE)


def _as_targets(given) -> list[Target]:
    """``annotate``'s ``targets`` as a list of Targets: one box or Target, or a sequence of them."""
    if isinstance(given, (str, Target)) or (len(given) and all(isinstance(v, numbers.Real) for v in given)):
        given = [given]
    return [item if isinstance(item, Target) else Target(parse_box(item, name="box"), track_id=position)
            for position, item in enumerate(given, start=1)]


def _run_into(out_dir: Path, source: FrameSource, targets: Sequence[Target], config: RunConfig,
              formats: Sequence[str], input_path: Path, show_progress: bool, options: ExportOptions,
              resume: bool, on_update: Callable[[int, int], None] | None) -> AnnotateResult:
    remove_staging_folders(out_dir)  # under the folder's lock, any staging folder is a dead run's
    key = run_key(input_path, range(source.start, source.stop, source.step), targets, config.to_dict())
    checkpoint = _checkpoint_to_resume(out_dir, key) if resume else None
    if not resume:
        remove_checkpoint(out_dir)  # another run's: this one writes its own
    # The run is written to a staging folder inside out_dir and moved into place when it is written completely,
    # so that an earlier run there stays whole until then, and stays at all if this one is cut short (Ctrl-C).
    with staging_folder(out_dir) as staging:
        render = "overlay" in formats
        # Closed here too, so that an error inside the tracking leaves no bar drawn (or cursor hidden).
        # Only when numba will compile: a slow first frame on a busy machine with the kernels cached is no compile.
        compiling = COMPILING_NOTE if not sptpt.kernels_cached() else None
        with Progress(len(source), enabled=show_progress, slow_start=compiling, on_update=on_update) as progress:
            run = track_source(source, targets, config, overlay_path=staging.path / OVERLAY_NAME if render else None,
                               progress=progress, checkpoints=(out_dir, key), resume=checkpoint)
        result = AnnotateResult(out_dir=staging.path, run=run)
        if (run.decode_error is not None or run.interrupted) and _holds_finished_run(out_dir):
            destination = out_dir / INCOMPLETE_DIR
            kept = f"; the earlier finished run in {out_dir} is kept"
        else:
            destination, kept = out_dir, ""
        if run.decode_error is not None:
            err = run.decode_error
            result.exit_code = EXIT_PARTIAL
            result.message = (f"{source.path}: decoding stopped after frame {err.last_good_index} ({err.reason}); "
                              f"results for the {plural(run.frames_processed, 'frame')} before it were written to "
                              f"{destination}{kept}")
        elif run.interrupted:
            result.exit_code = EXIT_INTERRUPTED
            result.message = (f"interrupted after {plural(run.frames_processed, 'frame')} of {source.path}; "
                              f"their results were written to {destination}{kept}")
        _write_outputs(result, source, targets, config, formats, input_path, options)
        try:
            with ctrl_c_ignored():
                if destination == out_dir and _holds_run(out_dir / INCOMPLETE_DIR):
                    # A partial run kept beside an earlier finished one is out of date once that one is replaced.
                    shutil.rmtree(out_dir / INCOMPLETE_DIR, ignore_errors=True)
                _publish(result, destination)
                if result.exit_code == EXIT_OK:  # every frame tracked and published: nothing left to resume
                    remove_checkpoint(out_dir)
        except MoveError as failed:
            staging.keep()
            exc = failed.cause
            raise ToolError(f"{exc.filename or destination}: {exc.strerror or exc} while moving the results into "
                            f"{destination}; this run's complete results are in {staging.path}: move them by hand "
                            "or rerun with another --out", EXIT_OUTPUT) from None
    return result


def _run_info(out_dir: Path) -> dict:
    """``out_dir``'s run.json if this tool wrote one there, else ``{}``."""
    try:
        info = json.loads((out_dir / RUN_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) and info.get("tool") == "sptpt-annotate" else {}


def _holds_run(out_dir: Path) -> bool:
    return bool(_run_info(out_dir))


def _holds_finished_run(out_dir: Path) -> bool:
    """Whether ``out_dir``'s run.json says its run went through every frame."""
    return _run_info(out_dir).get("complete") is True


def _publish(result: AnnotateResult, out_dir: Path) -> None:
    """Move a run written to ``result.out_dir`` (the staging folder) into ``out_dir``, run.json last.

    The earlier run's run.json goes first, so that a crash part-way leaves a folder that says it holds no
    finished run; files of the earlier run that this run did not rewrite are removed, since they would
    disagree with the new run.json. ``result`` then names the files where they ended up.
    """
    staging = result.out_dir
    names = [str(p.relative_to(staging)) for paths in result.outputs.values() for p in paths]
    retire = sorted(previous_outputs(out_dir) - set(names)) if out_dir.is_dir() else []
    move_into_place(staging, out_dir, names, retire=retire, unmark_first=True)
    result.out_dir = out_dir
    result.outputs = {kind: [out_dir / p.relative_to(staging) for p in paths] for kind, paths in result.outputs.items()}
    if result.run.overlay_path is not None:
        result.run.overlay_path = out_dir / result.run.overlay_path.relative_to(staging)


def _write_outputs(result: AnnotateResult, source: FrameSource, targets: Sequence[Target], config: RunConfig,
                   formats: Sequence[str], input_path: Path, options: ExportOptions) -> None:
    run = result.run
    if run.frames_processed == 0:
        why = f" ({run.decode_error.reason})" if run.decode_error is not None else ""
        raise ToolError(f"{source.path}: no frame could be decoded in the selected range{why}; nothing was written",
                        EXIT_INPUT)
    # Every output is a view of the store, whatever --formats says.
    result.store = RunStore(video=run.video, start=source.start, stop=source.stop, step=source.step,
                            tracks=tuple(run.tracks))
    # Each track as the forward pass from its first frame, for the first re-track to reuse.
    first_passes = dict(first_pass(t, run.tracker_confidence[t.track_id]) for t in run.tracks)
    info = _first_run_info(result, source, targets, config, formats, input_path, options)
    result.outputs = write_run_files(result.out_dir, result.store, info, settings=config.to_dict(), options=options,
                                     passes=first_passes, thumbnails=run.thumbnails,
                                     overlay=run.overlay_path is not None)


def _first_run_info(result: AnnotateResult, source: FrameSource, targets: Sequence[Target], config: RunConfig,
                    formats: Sequence[str], input_path: Path, options: ExportOptions) -> dict:
    """run.json's record of a first run (:func:`annotator.publish.write_run_files` adds the tracks and files)."""
    run = result.run
    return {
        "tool": "sptpt-annotate",
        "tool_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "input": {
            "path": str(input_path.resolve()),
            "content_hash": content_hash(input_path),
            # Image folders: frames are turned as their EXIF orientation says (since 0.2.0's later builds; a run
            # without this key read them as stored, and retrack refuses it where an image has an orientation).
            **({"exif_orientation": "applied"} if source.kind == "images" else {}),
            "frame_count": source.frame_count,
            # Videos: ffmpeg's message where decoding stopped early (None: decoded to its end). With the count, it
            # lets `retrack` skip the counting decode once the content hash says the file is the same.
            **({"damage": source.damage} if isinstance(source, VideoSource) else {}),  # kind "video": damage is its
            "fps": source.fps,
            "width": source.width,
            "height": source.height,
        },
        "range": {"start": source.start, "stop": source.stop, "step": source.step},
        "frames_processed": run.frames_processed,
        "targets": [{"track_id": t.track_id, "label": t.label, "box_xywh": list(t.box_xywh), "box_origin": 0}
                    for t in targets],
        "config": config.to_dict(),
        "timings": {
            "seconds_total": run.seconds_total,
            "seconds_tracking": run.seconds_tracking,
            "seconds_outside_tracker": run.seconds_total - run.seconds_tracking,
            "frames_per_second": run.frames_processed / run.seconds_total if run.seconds_total > 0 else None,
        },
        "decode_error": result.message or None,
        "complete": run.decode_error is None and not run.interrupted,
        "interrupted": run.interrupted,
        "formats": list(formats),
        # Options of the views that a re-track must write again the same way.
        **({"export_options": {"media_url": options.media_url}} if options.media_url is not None else {}),
    }


def previous_outputs(out_dir: Path) -> set[str]:
    """Result files of an earlier run in ``out_dir``: the fixed names, and the files its run.json lists."""
    names = set(RUN_FILES) - {RUN_JSON}
    try:
        listed = json.loads((out_dir / RUN_JSON).read_text(encoding="utf-8"))["outputs"]
        names |= {str(name) for files in listed.values() for name in files}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass  # no earlier run, or a run.json this tool did not write
    # Only plain relative names inside the folder: never follow a hand-edited run.json, or a symlinked
    # subfolder, elsewhere.
    root = out_dir.resolve()
    return {n for n in names if not Path(n).is_absolute() and ".." not in Path(n).parts
            and (out_dir / n).resolve().is_relative_to(root)}

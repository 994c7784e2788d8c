"""``sptpt-annotate track``: the main job, also run as plain ``sptpt-annotate VIDEO --box ...``."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from annotator.commands.common import fail, one_line_warnings
from annotator.config import DEFAULT_PRESET
from annotator.errors import EXIT_OK, EXIT_USAGE, EXIT_VALUE, ToolError
from annotator.output_files import DEFAULT_FORMATS
from annotator.wording import plural
from sptpt import PRESETS


def track_command(
    video: Path = typer.Argument(..., help="Video file (mp4, avi, mov, mkv, ...) or folder of images (OTB Name/ or any)."),
    box: List[str] = typer.Option(..., "--box", metavar="X,Y,W,H",
                                  help="First-frame box x,y,w,h in pixels (0-based). Repeat for several objects."),
    label: List[str] = typer.Option([], "--label", metavar="NAME", help="Label of each --box (one per box, or one for all). Default 'object'."),
    box_origin: int = typer.Option(0, "--box-origin", help="1 to read --box as OTB-style 1-based coordinates."),
    start: int = typer.Option(0, "--start", help="First frame to process (0-based source index)."),
    stop: Optional[int] = typer.Option(None, "--stop", help="Stop before this source frame (default: the end)."),
    step: int = typer.Option(1, "--step", help="Process every n-th frame."),
    preset: Optional[str] = typer.Option(
        None, "--preset", help=f"Tracker preset: {', '.join(PRESETS)}. [default: {DEFAULT_PRESET}, or the --config "
                               "file's preset]"),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML file with preset, seed, tracker and flags keys."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (default 0): same seed, same boxes."),
    out: Optional[Path] = typer.Option(None, "--out", help="Output folder (default: <input>_sptpt beside the input)."),
    formats: str = typer.Option(",".join(DEFAULT_FORMATS), "--formats",
                                help="Comma-separated outputs: otb, coco, flags, overlay, report, and for review tools "
                                     "cvat (cvat.xml), mot (mot/gt/), labelstudio (labelstudio.json), yolo (yolo/). "
                                     "The track store tracks.npz is always written."),
    media_url: Optional[str] = typer.Option(
        None, "--media-url", metavar="URL",
        help="The video's URL written into labelstudio.json (data.video), where a Label Studio server plays it, "
             "e.g. /data/local-files/?d=videos/clip.mp4 with a local-files storage (docs/review-tools.md); a URL "
             "ending in / or = gets the video's file name. Default: the video's path, which a server cannot play."),
    no_render: bool = typer.Option(False, "--no-render", help="Skip the overlay video (faster)."),
    force: bool = typer.Option(False, "--force", help="Overwrite results already in the output folder."),
    resume: bool = typer.Option(False, "--resume", help="Go on with a run that was cut short (Ctrl-C, kill) from its last checkpoint, with the same boxes as a run never interrupted."),
    corrections: Optional[Path] = typer.Option(
        None, "--corrections",
        help="CSV frame,x,y,w,h[,track_id] or COCO file of human boxes, applied right after tracking "
             "(as 'sptpt-annotate retrack')."),
    review_budget: Optional[float] = typer.Option(
        None, "--review-budget", metavar="PCT",
        help="Flag the PCT% most doubtful frames of each track (highest failure probability) instead of every frame "
             "above the threshold, for a fixed amount of review time."),
    failure_model: Optional[Path] = typer.Option(
        None, "--failure-model", help="A failure-model JSON refitted with benchmarks/failure_model.py "
                                      "(default: the one shipped)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar and no summary (errors and warnings still show)."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks."),
) -> None:
    """Track objects from their first-frame boxes; write OTB, COCO, flags, overlay video and review report."""
    from annotator.run import annotate

    try:
        if resume and force:
            raise ToolError("--resume goes on with the run in the output folder and --force discards it: give one of "
                            "them", EXIT_USAGE)
        targets = _targets(box, label, box_origin)
        config = _config(config_file, preset, seed, review_budget, failure_model)
        chosen = [f.strip() for f in formats.split(",") if f.strip()]
        if no_render:
            chosen = [f for f in chosen if f != "overlay"]
        fixes = None
        if corrections is not None:
            from annotator.corrections import read_corrections

            fixes = read_corrections(corrections)  # a malformed file, or one that does not fit, fails before tracking
        with one_line_warnings():
            result = annotate(video, targets, config, out_dir=out, start=start, stop=stop, step=step,
                              formats=chosen, force=force, resume=resume, show_progress=not quiet, corrections=fixes,
                              media_url=media_url)
        review = _apply_given_corrections(result, corrections, quiet) if corrections is not None else None
    except ToolError as error:
        fail(error, debug)
    if result.exit_code != EXIT_OK:
        skipped = (f"; the corrections were not applied: apply them with 'sptpt-annotate retrack {result.out_dir} "
                   f"--corrections {corrections}'") if corrections is not None else ""
        typer.echo(f"sptpt-annotate: warning: {result.message}{skipped}", err=True)
        raise typer.Exit(result.exit_code)
    if not quiet:
        _summary(result, review)


def _targets(box: list[str], label: list[str], box_origin: int) -> list:
    """The ``--box`` and ``--label`` options as targets with the track ids 1, 2, ..."""
    from annotator.box_input import parse_box
    from annotator.tracks import Target

    if box_origin not in (0, 1):
        raise ToolError(f"--box-origin {box_origin} is invalid: expected 0 (default) or 1 (OTB)", EXIT_VALUE)
    boxes = [parse_box(b, name="--box", origin=box_origin) for b in box]
    if label and len(label) not in (1, len(boxes)):
        raise ToolError(f"--label given {len(label)} times for {len(boxes)} boxes: give one per box or one for all",
                        EXIT_VALUE)
    labels = (label * len(boxes) if len(label) == 1 else label) or ["object"] * len(boxes)
    return [Target(box, track_id=i + 1, label=name) for i, (box, name) in enumerate(zip(boxes, labels))]


def _config(config_file: Path | None, preset: str | None, seed: int | None, review_budget: float | None,
            failure_model: Path | None):
    """The run's configuration from the ``--config`` file and the options that override it."""
    from annotator.config import ConfigError, load_config_file, resolve_config

    try:
        file_values = load_config_file(config_file) if config_file is not None else {}
        flag_overrides = {"review_budget": review_budget} if review_budget is not None else None
        if review_budget is not None and not 0 < review_budget <= 100:
            raise ToolError(f"--review-budget {review_budget:g} is out of range: give a percentage of frames "
                            "to review, 0 < PCT <= 100 (e.g. --review-budget 5)", EXIT_VALUE)
        return resolve_config(file_values, source=str(config_file or "command line"), preset=preset, seed=seed,
                              flag_overrides=flag_overrides, failure_model=failure_model)
    except ConfigError as exc:
        raise ToolError(str(exc), exc.exit_code) from None


def _apply_given_corrections(result, corrections: Path, quiet: bool):
    """``--corrections`` applied right after a finished run, as ``retrack`` would; None after an unfinished one."""
    if result.exit_code != EXIT_OK:
        return None
    from annotator.review import correct_run

    try:
        with one_line_warnings():
            return correct_run(result.out_dir, corrections, show_progress=not quiet, verify_input=False,
                               input_checked=True)
    except ToolError as exc:
        raise ToolError(
            f"{exc}; the tracked results without corrections are in {result.out_dir}: fix the file and run "
            f"'sptpt-annotate retrack {result.out_dir} --corrections FILE'", exc.exit_code) from None


def _summary(result, review) -> None:
    flagged = sum(int(t.flagged.sum()) for t in result.run.tracks)
    total = sum(len(t.frame_indices) for t in result.run.tracks)
    typer.echo(f"{plural(result.run.frames_processed, 'frame')} tracked in {result.run.seconds_total:.1f} s; "
               f"{flagged} of {plural(total, 'frame box', 'frame boxes')} flagged for review; "
               f"results in {result.out_dir}", err=True)
    from annotator.run_report import keyframe_note

    # After corrections that changed the boxes, the review's summary speaks for the re-tracked tracks.
    note = "" if review is not None and review.changed else keyframe_note(result.run.tracks, result.out_dir)
    if note:
        typer.echo(note, err=True)
    if review is not None:
        typer.echo(review.summary(), err=True)

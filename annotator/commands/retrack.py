"""``sptpt-annotate retrack OUTPUT_DIR --corrections FILE``: apply a reviewer's boxes and re-track around them."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from annotator.commands.common import fail, one_line_warnings
from annotator.errors import EXIT_INTERRUPTED, EXIT_VALUE, ToolError


def retrack_command(
    output_dir: Path = typer.Argument(..., help="Output folder of an sptpt-annotate run (holds run.json and tracks.npz)."),
    corrections: Path = typer.Option(..., "--corrections", help="CSV frame,x,y,w,h[,track_id] (source frame index, "
                                     "0-based pixels; empty x,y,w,h = absent until the next correction), a COCO "
                                     "file whose corrected annotations have attributes.keyframe = true, or the run's "
                                     "cvat.xml / Label Studio export after review (boxes that differ from the run)."),
    merge: str = typer.Option("", "--merge", help="Where a forward and a backward pass meet: chosen (default: where "
                              "the passes disagree, the forward box, the backward box or the interpolation of the two "
                              "human boxes, as the failure model's pass_choice section finds most probably right; "
                              "elsewhere as anchored), anchored (the pass still near its human box, else the more "
                              "confident), confidence, blend or handover."),
    no_verify: bool = typer.Option(False, "--no-verify", help="Skip checking the input's content hash against run.json."),
    input_path: Optional[Path] = typer.Option(
        None, "--input", help="Where the video or image folder is now, if it moved since the run (checked against "
                              "the content hash in run.json, then recorded there)."),
    media_url: Optional[str] = typer.Option(
        None, "--media-url", metavar="URL", help="A new URL of the video for labelstudio.json (as on the main "
                                                 "command), kept in run.json for later rounds."),
    no_render: bool = typer.Option(False, "--no-render", help="This round only: do not re-render the overlay video "
                                   "(it is decoded and encoded in full, which on a long video takes much of a "
                                   "round). It is removed, as it would show the old boxes, and the report has no "
                                   "video or thumbnails; a later retrack without --no-render (with the same "
                                   "corrections file if nothing is new) renders them again."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar and no summary (errors and warnings still show)."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks."),
) -> None:
    """Apply corrections to a run: human boxes become anchors, the spans they affect are re-tracked forward and
    backward, and every output (OTB, COCO, flags, overlay unless --no-render, report, run.json) is rewritten; on
    any error the folder is left unchanged."""
    from annotator.review import DEFAULT_MERGE, MERGES, apply_corrections

    try:
        method = merge or DEFAULT_MERGE
        if method not in MERGES:
            raise ToolError(f"--merge {merge!r} is not known: choose from {', '.join(MERGES)}", EXIT_VALUE)
        with one_line_warnings():  # a reviewer's file read with a warning (FiftyOne's trailing outside keyframe)
            result = apply_corrections(output_dir, corrections, merge=method, show_progress=not quiet,
                                       verify_input=not no_verify, input_path=input_path, render=not no_render,
                                       media_url=media_url)
    except ToolError as error:
        fail(error, debug)
    except KeyboardInterrupt:
        # Outputs are only moved in once the whole re-track is written, so an interruption changes nothing.
        typer.echo(f"sptpt-annotate: warning: interrupted; nothing in {output_dir} was changed", err=True)
        raise typer.Exit(EXIT_INTERRUPTED) from None
    if not quiet:
        typer.echo(result.summary(), err=True)

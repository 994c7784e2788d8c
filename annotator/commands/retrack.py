"""``sptpt-annotate retrack OUTPUT_DIR --corrections FILE``: apply a reviewer's boxes and re-track around them."""

from __future__ import annotations

from pathlib import Path

import typer

from annotator.commands.common import fail
from annotator.errors import EXIT_VALUE, ToolError


def retrack_command(
    output_dir: Path = typer.Argument(..., help="Output folder of an sptpt-annotate run (holds run.json and flags.csv)."),
    corrections: Path = typer.Option(..., "--corrections", help="CSV frame,x,y,w,h[,track_id] (source frame index, "
                                     "0-based pixels; empty x,y,w,h = absent until the next correction) or a COCO "
                                     "file whose corrected annotations have attributes.keyframe = true."),
    merge: str = typer.Option("", "--merge", help="Where a forward and a backward pass meet: anchored (default: the "
                              "pass still near its human box, else the more confident), confidence, blend or "
                              "handover."),
    no_verify: bool = typer.Option(False, "--no-verify", help="Skip checking the input's content hash against run.json."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks."),
) -> None:
    """Apply corrections to a run: human boxes become anchors, the spans they affect are re-tracked forward and
    backward, and every output (OTB, COCO, flags, overlay, report, run.json) is rewritten; on any error the folder
    is left unchanged."""
    from annotator.review import DEFAULT_MERGE, MERGES
    from annotator.review import apply_corrections

    try:
        method = merge or DEFAULT_MERGE
        if method not in MERGES:
            raise ToolError(f"--merge {merge!r} is not known: choose from {', '.join(MERGES)}", EXIT_VALUE)
        result = apply_corrections(output_dir, corrections, merge=method, show_progress=not quiet,
                                   verify_input=not no_verify)
    except ToolError as error:
        fail(error, debug)
    if not quiet:
        typer.echo(result.summary(), err=True)

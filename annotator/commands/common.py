"""What every command shares: turning a ToolError into one line and an exit code."""

from __future__ import annotations

import typer

from annotator.errors import ToolError


def fail(error: ToolError, debug: bool) -> None:
    """Report ``error`` as one line on stderr and exit with its code (re-raise under ``--debug``)."""
    if debug:
        raise error
    typer.echo(f"sptpt-annotate: error: {error}", err=True)
    raise typer.Exit(error.exit_code)

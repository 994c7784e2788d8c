"""What every command shares: turning a ToolError into one line and an exit code, and warnings into one line."""

from __future__ import annotations

import contextlib
import warnings
from typing import Iterator

import typer

from annotator.errors import InputWarning, ToolError


def fail(error: ToolError, debug: bool) -> None:
    """Report ``error`` as one line on stderr and exit with its code (re-raise under ``--debug``)."""
    if debug:
        raise error
    typer.echo(f"sptpt-annotate: error: {error}", err=True)
    raise typer.Exit(error.exit_code)


@contextlib.contextmanager
def one_line_warnings() -> Iterator[None]:
    """Print each :class:`~annotator.errors.InputWarning` as ``sptpt-annotate: warning: ...``, as it happens."""

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, InputWarning):
            typer.echo(f"sptpt-annotate: warning: {message}", err=True)
        else:
            previous(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        previous = warnings.showwarning
        warnings.simplefilter("always", InputWarning)
        warnings.showwarning = show
        yield

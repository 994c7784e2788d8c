"""Command line: ``sptpt-annotate VIDEO --box x,y,w,h`` and its subcommands.

Commands parse and delegate; every domain error becomes one line on stderr
and an exit code documented in :mod:`annotator.errors` (no traceback unless
``--debug``).
"""

from __future__ import annotations

import errno
import sys
import traceback

import typer

from annotator.allocator import keep_freed_memory
from annotator.errors import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, ToolError
from annotator.version import __version__

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
    help=(
        "Label an object in a video with boxes, headless, using the SPTPT tracker.\n\n"
        "Main use:  sptpt-annotate VIDEO --box x,y,w,h   (the 'track' command is the default).\n\n"
        "Exit codes: 0 ok, 1 internal error, 2 usage, 3 unreadable input, 4 invalid value, "
        "5 output folder problem, 6 partial results (decode error), 7 some batch items failed, 130 interrupted."
    ),
)

from annotator.commands.batch import batch_command  # noqa: E402
from annotator.commands.eval import eval_command  # noqa: E402
from annotator.commands.retrack import retrack_command  # noqa: E402
from annotator.commands.track import track_command  # noqa: E402

app.command("track")(track_command)
app.command("eval")(eval_command)
app.command("batch")(batch_command)
app.command("retrack")(retrack_command)

SUBCOMMANDS = ("track", "eval", "batch", "retrack")

def _with_default_command(argv: list[str]) -> list[str]:
    """``sptpt-annotate VIDEO ...`` means ``sptpt-annotate track VIDEO ...``."""
    if not argv:
        return argv
    first = argv[0]
    if first in SUBCOMMANDS or first in ("--help", "-h", "--version"):
        return argv
    return ["track", *argv]


def _mistyped_command(argv: list[str]) -> str | None:
    """A first word that is not a path but close to a command name (``evall``): the command meant."""
    import difflib
    from pathlib import Path

    first = argv[0] if argv else ""
    if not first or first.startswith("-") or first in SUBCOMMANDS or Path(first).exists():
        return None
    close = difflib.get_close_matches(first, SUBCOMMANDS, n=1, cutoff=0.75)
    return close[0] if close else None


#: errno values that mean the disk (or the user's quota) is full.
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def _internal_error(exc: Exception) -> None:
    print(f"sptpt-annotate: internal error: {type(exc).__name__}: {exc} (rerun with --debug for the traceback)",
          file=sys.stderr)
    raise SystemExit(EXIT_INTERNAL)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    # The click that typer raises from: its own copy in recent typer, the click package before.
    click_errors = sys.modules[typer.BadParameter.__module__]
    no_args_is_help = getattr(click_errors, "NoArgsIsHelpError", ())

    argv = list(sys.argv[1:] if argv is None else argv)
    keep_freed_memory()
    if argv[:1] == ["--version"]:
        print(f"sptpt-annotate {__version__}")
        raise SystemExit(EXIT_OK)
    meant = _mistyped_command(argv)
    if meant is not None:
        print(f"sptpt-annotate: error: {argv[0]!r} is neither a command nor an existing video or folder: did you "
              f"mean 'sptpt-annotate {meant}'?", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)
    debug = "--debug" in argv
    try:
        # Not standalone: click's usage errors come back here to be printed as one line, like every other error.
        code = app(args=_with_default_command(argv), prog_name="sptpt-annotate", standalone_mode=False)
    except no_args_is_help as exc:
        exc.show()
        raise SystemExit(exc.exit_code) from None
    except click_errors.UsageError as exc:
        where = exc.ctx.command_path if exc.ctx is not None else "sptpt-annotate"
        print(f"sptpt-annotate: error: {exc.format_message().rstrip('.')} (see '{where} --help')", file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except click_errors.ClickException as exc:
        print(f"sptpt-annotate: error: {exc.format_message()}", file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except (KeyboardInterrupt, typer.Abort):
        print("sptpt-annotate: interrupted", file=sys.stderr)
        raise SystemExit(EXIT_INTERRUPTED) from None
    except SystemExit:
        raise
    except ToolError as exc:  # re-raised by the command under --debug: the traceback, and still its exit code
        traceback.print_exc()
        raise SystemExit(exc.exit_code) from None
    except OSError as exc:
        if debug:
            raise
        if exc.errno in DISK_FULL:  # not a bug: the machine ran out of room for the results
            where = f" while writing {exc.filename}" if exc.filename else ""
            print(f"sptpt-annotate: error: no space left on the disk{where} ({exc.strerror}): free space, or write "
                  "the results elsewhere with --out", file=sys.stderr)
            raise SystemExit(EXIT_OUTPUT) from None
        _internal_error(exc)
    except Exception as exc:  # a bug: one line unless --debug
        if debug:
            raise
        _internal_error(exc)
    # A command ends by returning None or raising typer.Exit (its code comes back here): nothing else is a code.
    raise SystemExit(code if isinstance(code, int) and not isinstance(code, bool) else EXIT_OK)


if __name__ == "__main__":  # pragma: no cover
    main()

"""Errors the tool reports to its user, each with a documented exit code.

| code | meaning |
|---:|---|
| 0 | success |
| 1 | internal error (a bug: rerun with ``--debug`` and report the traceback) |
| 2 | command-line usage error (unknown option, missing argument) |
| 3 | input cannot be read: missing or unreadable file, not a video, folder without images, corrupt video |
| 4 | invalid value: box, frame range, configuration file or parameter |
| 5 | output folder cannot be written, or already holds results (use ``--force``) |
| 6 | decoding stopped part-way: results up to the last good frame were written |
| 7 | batch: some items failed (see ``failures.jsonl``) |
| 130 | interrupted (Ctrl-C): results up to the interruption were written |
"""

from __future__ import annotations

__all__ = ["InputWarning", "ToolError", "require_extra", "EXIT_OK", "EXIT_INTERNAL", "EXIT_USAGE", "EXIT_INPUT",
           "EXIT_VALUE", "EXIT_OUTPUT", "EXIT_PARTIAL", "EXIT_BATCH_FAILURES", "EXIT_INTERRUPTED"]

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_INPUT = 3
EXIT_VALUE = 4
EXIT_OUTPUT = 5
EXIT_PARTIAL = 6
EXIT_BATCH_FAILURES = 7
EXIT_INTERRUPTED = 130


class ToolError(Exception):
    """A problem to report as one line and an exit code; never a traceback (unless ``--debug``).

    Parameters
    ----------
    message : str
        One line: the input, what was expected, how to fix it.
    exit_code : int
        The command line's exit code for it (:data:`EXIT_INPUT`, :data:`EXIT_VALUE`, :data:`EXIT_OUTPUT`, ...).
    """

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code


class InputWarning(UserWarning):
    """Input the tool accepts but that will likely give poor results; the CLI prints it as one line."""


#: Optional feature -> (module it imports, the extra that installs it).
EXTRAS = {"--scheduler": ("distributed", "cluster"), "eval --out": ("matplotlib", "plots")}


def require_extra(feature: str) -> None:
    """Raise a one-line :class:`ToolError` naming the pip command when ``feature``'s optional extra is missing."""
    import importlib.util

    module, extra = EXTRAS[feature]
    if importlib.util.find_spec(module) is None:
        raise ToolError(f"{feature} needs {module}, which is not installed: "
                        f"pip install 'sptpt-annotate[{extra}]'", EXIT_USAGE)

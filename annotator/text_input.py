"""Reading the text files people give the tool: box files, corrections, manifests, review-tool exports."""

from __future__ import annotations

import codecs
import os
from pathlib import Path
from typing import Callable

from annotator.errors import EXIT_INPUT, EXIT_VALUE, ToolError

__all__ = ["TEXT_ENCODINGS", "decode_text", "read_text", "read_given_file"]

#: What :func:`decode_text` reads, as error messages say it.
TEXT_ENCODINGS = "UTF-8, or UTF-16 with a byte-order mark"

_MARKS = ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"),
          (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))


def decode_text(data: bytes) -> str:
    """UTF-8 (with or without a byte-order mark), or UTF-16/32 with one.

    Windows PowerShell 5's ``>`` writes UTF-16 with a byte-order mark, as do Notepad's and Excel's "Unicode"
    saves, so a file made there is not UTF-8; the mark says which it is (UTF-32's mark starts with UTF-16's,
    so it is tried first). Raises :class:`UnicodeDecodeError` for anything else, UTF-16 without a mark included.
    """
    encoding = next((name for mark, name in _MARKS if data.startswith(mark)), "utf-8-sig")
    text = data.decode(encoding)
    nul = text.find("\x00")
    if nul >= 0:  # decodes, but no text file holds NUL: UTF-16 without its mark, or a binary file
        raise UnicodeDecodeError(encoding, data, nul, nul + 1, "NUL character in text")
    return text


def read_text(path: str | os.PathLike) -> str:
    """The text of ``path`` decoded by :func:`decode_text`, with ``\\r\\n`` and ``\\r`` read as ``\\n`` (as
    :meth:`pathlib.Path.read_text` reads them)."""
    return decode_text(Path(path).read_bytes()).replace("\r\n", "\n").replace("\r", "\n")


def read_given_file(path: str | os.PathLike, *, what: str, expected: str,
                    error: Callable[[str, int], Exception] = ToolError) -> str:
    """The text of a file the user gave (:func:`read_text`), or one line that says what is wrong and what to give.

    ``what`` names the file in the message ("corrections file"), ``expected`` says what to give instead ("a CSV
    frame,x,y,w,h"). ``error(message, exit_code)`` is raised: exit 3 (EXIT_INPUT) when the file is missing, a
    folder or unreadable, 4 (EXIT_VALUE) when it is not text.
    """
    try:
        return read_text(path)
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist: give {expected}", EXIT_INPUT) from None
    except IsADirectoryError:
        raise error(f"{what} {path} is a folder: give {expected}", EXIT_INPUT) from None
    except UnicodeDecodeError:
        raise error(f"{what} {path} is not text ({TEXT_ENCODINGS}): give {expected}", EXIT_VALUE) from None
    except OSError as exc:
        raise error(f"{what} {path} cannot be read ({exc.strerror or exc}): check its permissions, or give "
                    f"{expected}", EXIT_INPUT) from None

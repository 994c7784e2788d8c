"""Reading the text files people give the tool: box files, corrections, manifests, review-tool exports."""

from __future__ import annotations

import codecs
import os
from pathlib import Path

__all__ = ["TEXT_ENCODINGS", "decode_text", "read_text"]

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

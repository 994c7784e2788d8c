"""Text files people give the tool, in the encodings their tools write."""

from __future__ import annotations

import codecs

import pytest

from annotator.text_input import decode_text, read_text

TEXT = "frame,x,y,w,h\n12,10.5,20,30,40\n"


@pytest.mark.parametrize("data", [
    TEXT.encode("utf-8"),
    codecs.BOM_UTF8 + TEXT.encode("utf-8"),
    TEXT.encode("utf-16"),  # with its mark, in the machine's order (PowerShell 5's `>`, Notepad's "Unicode")
    codecs.BOM_UTF16_BE + TEXT.encode("utf-16-be"),
    TEXT.encode("utf-32"),  # its mark begins with UTF-16 LE's: must not be read as UTF-16
    codecs.BOM_UTF32_BE + TEXT.encode("utf-32-be"),
])
def test_decodes_utf8_and_marked_utf16_and_utf32(data):
    assert decode_text(data) == TEXT


@pytest.mark.parametrize("data", [
    b"\x89PNG\r\n\x1a\n\xff\xd8\xff",
    "1,2,3,4".encode("utf-16-le"),  # valid UTF-8 with a NUL after every character
    b"1,2,3,4\n\x00\x00",
])
def test_binary_and_unmarked_utf16_are_not_text(data):
    with pytest.raises(UnicodeDecodeError):
        decode_text(data)


def test_read_text_reads_windows_and_old_mac_line_ends_as_newlines(tmp_path):
    path = tmp_path / "fixes.csv"
    path.write_bytes("a\r\nb\rc\n".encode("utf-16"))
    assert read_text(path) == "a\nb\nc\n"

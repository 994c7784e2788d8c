"""The run report's page read back: its flagged-span rows and their seek links, and the frame a seek shows."""

from __future__ import annotations

import html
import html.parser
import re


class SpanRows(html.parser.HTMLParser):
    """The ``<tr class="span">`` rows: cell texts, the seek link's onclick and the thumbnail src of each."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict] = []
        self.videos: list[dict] = []
        self.flag_rects: list[dict] = []
        self._row: dict | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "tr" and "span" in (attrs.get("class") or "").split():
            self._row = {"cells": [], "seek": None, "img": None, "thumb_seek": None}
        elif tag == "video":
            self.videos.append(attrs)
        elif tag == "rect" and attrs.get("class") == "flag":
            self.flag_rects.append(attrs)
        elif self._row is not None:
            if tag == "td":
                self._cell = []
            elif tag == "a" and "thumb" in (attrs.get("class") or "").split():
                self._row["thumb_seek"] = attrs.get("onclick")
            elif tag == "a" and "seek" in (attrs.get("class") or ""):
                self._row["seek"] = attrs.get("onclick")
            elif tag == "img":
                self._row["img"] = attrs.get("src")

    def handle_endtag(self, tag):
        if self._row is None:
            return
        if tag == "td" and self._cell is not None:
            self._row["cells"].append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr":
            self.rows.append(self._row)
            self._row = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def parse(page: str) -> SpanRows:
    parser = SpanRows()
    parser.feed(page)
    parser.close()
    return parser


def seek_seconds(onclick: str) -> float:
    match = re.fullmatch(r"seekTo\(([0-9.]+)\)", onclick)
    assert match, onclick
    return float(match.group(1))


def shows_frame(seconds: float, position: int, fps: float) -> bool:
    """Whether a player seeking to ``seconds`` shows frame ``position`` of a constant-rate video."""
    return position / fps <= seconds < (position + 1) / fps

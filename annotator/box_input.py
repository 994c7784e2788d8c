"""Boxes people give the tool, read one way wherever they come from.

``--box`` on the command line, ``box`` and ``boxes`` in a batch manifest, the
``x,y,w,h`` columns of a corrections CSV, a COCO ``bbox``, and a box passed
to :func:`annotator.annotate` from Python all go through :func:`parse_box`:
the same rules, and the same one-line error naming the input, what was
expected and how to fix it. (The review tools' files give corners, not
boxes: :mod:`annotator.review.imports` reads those.)

The rules: a box is four finite numbers ``x, y, w, h``, the left and top edge
then the width and height in pixels, 0-based (``origin=1`` reads OTB's
1-based ``x, y``), with ``w`` and ``h`` > 0. As text, the numbers are separated
by commas, semicolons, or spaces and tabs (a row copied from a
whitespace-separated file), with any spaces around a comma or semicolon; as
data (a YAML or JSON list, a tuple), four numbers. Whether the box fits the
video is checked where the video is known.
"""

from __future__ import annotations

import math
import numbers
import re
from typing import Any

from annotator.errors import EXIT_VALUE, ToolError

__all__ = ["Box", "BoxError", "parse_box"]

#: 0-based ``x, y, w, h`` in pixels.
Box = tuple[float, float, float, float]

_SEPARATOR = re.compile(r"\s*[,;]\s*|\s+")


class BoxError(ToolError, ValueError):
    """A box that is not four finite numbers with a positive width and height (exit code 4, invalid value)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, EXIT_VALUE)


def parse_box(value: Any, *, name: str, origin: int = 0) -> Box:
    """Read one box given as text (``"x,y,w,h"``) or as four numbers, into 0-based ``x, y, w, h`` floats.

    Parameters
    ----------
    value : str or sequence of 4 numbers
        The box as given.
    name : str
        What the box is called where it was given (``--box``, ``box``, ``boxes[2]``, ``bbox``); the error
        message starts with it, and a caller puts the file and line in front where there is one.
    origin : {0, 1}
        1 for OTB-style 1-based coordinates: ``x`` and ``y`` are shifted by -1.

    Raises
    ------
    BoxError
        Naming ``name`` and ``value``: not four numbers (and which one is wrong), or a width or height <= 0.
    """
    text = isinstance(value, str)
    if hasattr(value, "tolist"):  # a NumPy array or scalar: its plain Python values, to show and check
        value = value.tolist()
    parts = _SEPARATOR.split(value.strip()) if text else _items(value)
    shown = repr(value)
    if parts is None or len(parts) != 4:
        many = f" (it has {len(parts)} values)" if parts and parts != [""] else ""
        raise BoxError(_not_four(name, shown, many, text))
    values = []
    for axis, part in zip("xywh", parts):
        number = _number(part, from_text=text)
        if number is None:
            raise BoxError(_not_four(name, shown, f" ({axis} is {part!r})", text))
        values.append(number)
    x, y, w, h = values
    if w <= 0 or h <= 0:
        raise BoxError(f"{name} {shown} has zero or negative size (w={w:g}, h={h:g}): width and height must be > 0")
    return (x - origin, y - origin, w, h)


def _not_four(name: str, shown: str, which: str, text: bool) -> str:
    example = "120,80,40,60" if text else "[120, 80, 40, 60]"  # in the form the box was given in
    return f"{name} {shown} is not four numbers x,y,w,h{which}: give e.g. {example}"


def _items(value: Any) -> list[Any] | None:
    """The items of a sequence given as a box; None for anything else (a number, a mapping, bytes)."""
    if isinstance(value, (bytes, dict)) or not hasattr(value, "__len__") or not hasattr(value, "__iter__"):
        return None
    return list(value)


def _number(part: Any, *, from_text: bool) -> float | None:
    """A finite float from one item, or None: text items are parsed, data items must be numbers (not booleans)."""
    if from_text:
        try:
            number = float(part)
        except ValueError:
            return None
    elif isinstance(part, numbers.Real) and not isinstance(part, bool):
        number = float(part)
    else:
        return None
    return number if math.isfinite(number) else None

"""Counts in words for one-line summaries and reports: ``1 frame``, ``2 frames``."""

from __future__ import annotations

__all__ = ["ordinal", "plural"]


def plural(count: int, singular: str, plural_form: str | None = None) -> str:
    """``count`` followed by the noun in the number it needs.

    Parameters
    ----------
    count : int
    singular : str
        The noun for one, e.g. ``"frame"``.
    plural_form : str, optional
        The noun for any other count; ``singular + "s"`` by default.

    Examples
    --------
    >>> plural(1, "frame"), plural(0, "frame"), plural(3, "box", "boxes")
    ('1 frame', '0 frames', '3 boxes')
    """
    return f"{count} {singular if count == 1 else (plural_form or singular + 's')}"


def ordinal(n: int) -> str:
    """The English ordinal of ``n``.

    Examples
    --------
    >>> ordinal(2), ordinal(3), ordinal(11), ordinal(21), ordinal(112)
    ('2nd', '3rd', '11th', '21st', '112th')
    """
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"

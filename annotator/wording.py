"""Counts in words for one-line summaries and reports: ``1 frame``, ``2 frames``."""

from __future__ import annotations

__all__ = ["plural"]


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

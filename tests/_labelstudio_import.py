"""What Label Studio shows of a video rectangle's keyframes: its interpolation rule, replayed (as ``_cvat_import``
replays CVAT's)."""

from __future__ import annotations


def interpolate_labelstudio(sequence: list[dict], frame: int) -> tuple[list[float] | None, bool]:
    """Label Studio's box at a 1-based frame (VideoRectangleRegion.getRectangle and isInLifespan)."""
    previous = [k for k in sequence if k["frame"] <= frame]
    if not previous:
        return None, False
    prev = previous[-1]
    shown = prev["enabled"] or prev["frame"] == frame
    following = [k for k in sequence if k["frame"] > frame]
    keys = ("x", "y", "width", "height")
    if prev["frame"] == frame or not following:
        return [prev[k] for k in keys], shown
    nxt = following[0]
    r = (frame - prev["frame"]) / (nxt["frame"] - prev["frame"])
    return [prev[k] + (nxt[k] - prev[k]) * r for k in keys], shown

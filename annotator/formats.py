"""The output formats a run can write (``--formats``), in one place the CLI can import cheaply."""

from __future__ import annotations

__all__ = ["ALL_FORMATS", "DEFAULT_FORMATS", "REVIEW_TOOL_FORMATS"]

#: Files for the review tools people already use; written only when asked for.
REVIEW_TOOL_FORMATS = ("cvat", "mot", "labelstudio", "yolo")
#: What a run writes when --formats is not given.
DEFAULT_FORMATS = ("otb", "coco", "flags", "overlay", "report")
#: What --formats accepts. The track store (tracks.npz) is always written and is not a format.
ALL_FORMATS = (*DEFAULT_FORMATS, *REVIEW_TOOL_FORMATS)

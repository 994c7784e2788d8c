"""SPTPT: the Superpixel Tensor Pooling Tracker (Wu, Zhang, Cao, Yan, IEEE Access 2019).

Pure numerics: RGB frames in, boxes and likelihoods out. No file, video or
configuration I/O lives here; see the ``annotator`` package for the tool.

What a Python user imports::

    from sptpt import Tracker, preset

    tracker = Tracker(preset("robust"), seed=0)
    result = tracker.init(first_frame, (136, 129, 48, 40))   # (H, W, 3) uint8 RGB; box x, y, w, h, 0-based
    result = tracker.update(next_frame)                     # a FrameResult: box_xywh, confidence, ...

``TrackerParams`` holds every parameter (build one with :func:`dataclasses.replace` on a preset). The ``fused``
preset also takes a learned tracker beside SPTPT, a :class:`Guide` (``Tracker(preset("fused"), guide=...)``; the
tool's is ``annotator.NanoTrackGuide``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = ["FrameResult", "Guide", "Tracker", "TrackerParams", "check_params", "compile_kernels", "kernels_cached",
           "preset"]

# Where each public name lives, as (module, name there). Imported on first use: ``import sptpt.boxes`` (the tool
# does, at start-up) should not load the tracker and numba.
_HOMES = {
    "FrameResult": ("sptpt.results", "FrameResult"),
    "Guide": ("sptpt.tracker", "Guide"),
    "Tracker": ("sptpt.tracker", "Tracker"),
    "TrackerParams": ("sptpt.params", "TrackerParams"),
    "check_params": ("sptpt.tracker", "check_params"),
    "compile_kernels": ("sptpt._kernels.warmup", "compile_kernels"),
    "kernels_cached": ("sptpt._kernels.warmup", "kernels_cached"),
    "preset": ("sptpt.params", "get_preset"),
}


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module 'sptpt' has no attribute {name!r}")
    module, attribute = _HOMES[name]
    return getattr(importlib.import_module(module), attribute)


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


if TYPE_CHECKING:  # the same names, for type checkers and editors
    from sptpt._kernels.warmup import compile_kernels, kernels_cached
    from sptpt.params import TrackerParams
    from sptpt.params import get_preset as preset
    from sptpt.results import FrameResult
    from sptpt.tracker import Guide, Tracker, check_params

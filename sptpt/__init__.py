"""SPTPT: the Superpixel Tensor Pooling Tracker (Wu, Zhang, Cao, Yan, IEEE Access 2019).

Pure numerics: RGB frames in, boxes and likelihoods out. No file, video or
configuration I/O lives here; see the ``annotator`` package for the tool.

What a Python user imports::

    from sptpt import Tracker, preset

    tracker = Tracker(preset("robust"), seed=0)
    result = tracker.init(first_frame, (136, 129, 48, 40))   # (H, W, 3) uint8 RGB; box x, y, w, h, 0-based
    result = tracker.update(next_frame)                     # a FrameResult: box_xywh, confidence, ...

``TrackerParams`` holds every parameter (build one with :func:`dataclasses.replace` on a preset, or
:func:`params_from_mapping` from a configuration's values; :data:`PRESETS` names them all). The ``fused``
preset also takes a learned tracker beside SPTPT, a :class:`Guide` (``Tracker(preset("fused"), guide=...)``; the
tool's is ``annotator.NanoTrackGuide``). :func:`colour_contrast` measures how a box's colours stand out from
its surroundings; :func:`kmeans_centroids` is the k-means a tracker learns its dictionary with (the default of
``Tracker(kmeans=...)``, which takes any :data:`KMeansFunction`); :func:`checked_box` and
:func:`checked_particles` check a result's arrays.

Box geometry (corners, clipping, overlap) is the public module :mod:`sptpt.boxes`. Every other module is the
library's inside and may change.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = ["PRESETS", "FrameResult", "Guide", "Tracker", "TrackerParams", "check_params", "checked_box",
           "checked_particles", "colour_contrast", "compile_kernels", "kernels_cached", "KMeansFunction",
           "kmeans_centroids", "params_from_mapping", "preset", "TrackerInspection"]

# Where each public name lives, as (module, name there). Imported on first use: ``import sptpt.boxes`` (the tool
# does, at start-up) should not load the tracker and numba.
_HOMES = {
    "PRESETS": ("sptpt.params", "PRESETS"),
    "FrameResult": ("sptpt.results", "FrameResult"),
    "Guide": ("sptpt.tracker", "Guide"),
    "Tracker": ("sptpt.tracker", "Tracker"),
    "TrackerInspection": ("sptpt.tracker", "TrackerInspection"),
    "TrackerParams": ("sptpt.params", "TrackerParams"),
    "check_params": ("sptpt.tracker", "check_params"),
    "checked_box": ("sptpt.results", "checked_box"),
    "checked_particles": ("sptpt.results", "checked_particles"),
    "colour_contrast": ("sptpt.contrast", "colour_contrast"),
    "compile_kernels": ("sptpt._kernels.warmup", "compile_kernels"),
    "kernels_cached": ("sptpt._kernels.warmup", "kernels_cached"),
    "KMeansFunction": ("sptpt._kmeans", "KMeansFunction"),
    "kmeans_centroids": ("sptpt._kmeans", "kmeans_centroids"),
    "params_from_mapping": ("sptpt.params", "params_from_mapping"),
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
    from sptpt._kmeans import KMeansFunction, kmeans_centroids
    from sptpt.contrast import colour_contrast
    from sptpt.params import PRESETS, TrackerParams, params_from_mapping
    from sptpt.params import get_preset as preset
    from sptpt.results import FrameResult, checked_box, checked_particles
    from sptpt.tracker import Guide, Tracker, TrackerInspection, check_params

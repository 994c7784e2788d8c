"""sptpt-annotate: the headless annotation tool built on the ``sptpt`` tracker.

What a Python user imports::

    from annotator import annotate

    result = annotate("clip.mp4", (136, 129, 48, 40))   # a video and the object's first-frame box x, y, w, h
    result.store.track(1).boxes_xywh                    # (F, 4): a box for every processed frame

``annotate`` is what ``sptpt-annotate VIDEO --box ...`` runs; ``apply_corrections`` what ``sptpt-annotate retrack``
runs; ``resolve_config`` (or ``load_config_file``) builds their settings; ``read_store`` reads a run's
``tracks.npz`` back; ``open_frames`` reads a video or image folder's frames; ``evaluate_result_file`` and
``evaluate_results_dir`` score results against ground truth; ``NanoTrackGuide`` is the learned tracker the ``fused``
preset's ``sptpt.Tracker`` takes as its ``guide``. The types they take and return are public too. docs/python-api.md
has the details. Everything else is the tool's inside and may change.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from annotator.version import __version__ as __version__

__all__ = ["AnchorChange", "AnnotateResult", "Correction", "DatasetScore", "DecodeError", "FlagParams", "FrameSource",
           "NanoTrackGuide", "PassResult", "RetrackResult", "ReviewResult", "RunConfig", "RunStore", "SegmentChange",
           "SequenceScore", "SpanThumbnail", "Target", "ToolError", "TrackResult", "TrackingRun", "VideoInfo",
           "annotate", "apply_corrections", "evaluate_result_file", "evaluate_results_dir", "load_config_file",
           "open_frames", "read_store", "resolve_config", "seed_for_track"]

# Where each public name lives. Imported on first use: ``import annotator.errors`` (every command, every batch
# worker) should not load the tracker, numba and the whole tool.
_HOMES = {
    "AnchorChange": "annotator.review.segments",
    "AnnotateResult": "annotator.run",
    "Correction": "annotator.corrections",
    "DatasetScore": "annotator.evaluation",
    "DecodeError": "annotator.frame_sources",
    "FlagParams": "annotator.flagging",
    "FrameSource": "annotator.frame_sources",
    "NanoTrackGuide": "annotator.nanotrack",
    "PassResult": "annotator.pass_cache",
    "RetrackResult": "annotator.review",
    "ReviewResult": "annotator.review",
    "RunConfig": "annotator.config",
    "RunStore": "annotator.track_store",
    "SegmentChange": "annotator.review.segments",
    "SequenceScore": "annotator.evaluation",
    "SpanThumbnail": "annotator.tracks",
    "Target": "annotator.tracks",
    "ToolError": "annotator.errors",
    "TrackResult": "annotator.tracks",
    "TrackingRun": "annotator.pipeline",
    "VideoInfo": "annotator.tracks",
    "annotate": "annotator.run",
    "apply_corrections": "annotator.review",
    "evaluate_result_file": "annotator.evaluation",
    "evaluate_results_dir": "annotator.evaluation",
    "load_config_file": "annotator.config",
    "open_frames": "annotator.frame_sources",
    "read_store": "annotator.track_store",
    "resolve_config": "annotator.config",
    "seed_for_track": "annotator.pipeline",
}


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module 'annotator' has no attribute {name!r}")
    return getattr(importlib.import_module(_HOMES[name]), name)


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


if TYPE_CHECKING:  # the same names, for type checkers and editors
    from annotator.config import RunConfig, load_config_file, resolve_config
    from annotator.corrections import Correction
    from annotator.errors import ToolError
    from annotator.evaluation import DatasetScore, SequenceScore, evaluate_result_file, evaluate_results_dir
    from annotator.flagging import FlagParams
    from annotator.frame_sources import DecodeError, FrameSource, open_frames
    from annotator.nanotrack import NanoTrackGuide
    from annotator.pass_cache import PassResult
    from annotator.pipeline import TrackingRun, seed_for_track
    from annotator.review import RetrackResult, ReviewResult, apply_corrections
    from annotator.review.segments import AnchorChange, SegmentChange
    from annotator.run import AnnotateResult, annotate
    from annotator.track_store import RunStore, read_store
    from annotator.tracks import SpanThumbnail, Target, TrackResult, VideoInfo

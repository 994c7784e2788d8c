"""The review loop: read a finished run back, apply a person's corrections, re-track what they affect.

Where things are:

* :mod:`~annotator.review.loaded_run`: reading a run back (``run.json`` and the track store).
* :mod:`~annotator.review.loop`: ``apply_corrections``, the whole loop on an output folder,
  and rewriting every output atomically.
* :mod:`~annotator.review.source_frames`: frames decoded again from the recorded input.
* :mod:`~annotator.review.segments`: anchors and the segments between them.
* :mod:`~annotator.review.passes`: the forward and backward tracker passes.
* :mod:`~annotator.review.merge`: how two passes combine, and the flags after a re-track (a pass's rows, and the
  passes a run folder keeps for its next re-track, are in :mod:`annotator.pass_cache`).
* :mod:`~annotator.review.retrack`: ``retrack_tracks``, re-tracking in memory (no files).
"""

from __future__ import annotations

from annotator.review.loaded_run import LoadedRun, load_run
from annotator.review.loop import ReviewResult, apply_corrections, correct_run
from annotator.review.merge import DEFAULT_MERGE, MERGES, NO_SCORING, PassResult, merge_passes, reflag
from annotator.review.passes import ArrayFrames, FrameProvider, pass_seed
from annotator.review.retrack import RetrackResult, retrack_tracks
from annotator.review.segments import AnchorChange, PreviousTrack, Segment, SegmentChange, plan_segments, same_box
from annotator.review.source_frames import BUFFER_BYTES, SourceFrames

__all__ = [
    "AnchorChange",
    "ArrayFrames",
    "BUFFER_BYTES",
    "DEFAULT_MERGE",
    "FrameProvider",
    "LoadedRun",
    "MERGES",
    "NO_SCORING",
    "PassResult",
    "PreviousTrack",
    "RetrackResult",
    "ReviewResult",
    "Segment",
    "SegmentChange",
    "SourceFrames",
    "apply_corrections",
    "correct_run",
    "load_run",
    "merge_passes",
    "pass_seed",
    "plan_segments",
    "reflag",
    "retrack_tracks",
    "same_box",
]

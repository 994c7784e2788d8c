"""sptpt-annotate: the headless annotation tool built on the ``sptpt`` tracker.

What a Python user imports::

    from annotator import annotate

    result = annotate("clip.mp4", (136, 129, 48, 40))   # a video and the object's first-frame box x, y, w, h
    result.store.track(1).boxes_xywh                    # (F, 4): a box for every processed frame

``annotate`` is what ``sptpt-annotate VIDEO --box ...`` runs; ``apply_corrections`` what ``sptpt-annotate retrack``
runs; ``resolve_config`` builds their settings; ``read_store`` reads a run's ``tracks.npz`` back; ``NanoTrackGuide``
is the learned tracker the ``fused`` preset's ``sptpt.Tracker`` takes as its ``guide``. docs/python-api.md
has the details. Everything else is the tool's inside and may change.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from annotator.version import __version__ as __version__

__all__ = ["AnnotateResult", "NanoTrackGuide", "Target", "ToolError", "annotate", "apply_corrections", "read_store",
           "resolve_config"]

# Where each public name lives. Imported on first use: ``import annotator.errors`` (every command, every batch
# worker) should not load the tracker, numba and the whole tool.
_HOMES = {
    "AnnotateResult": "annotator.job",
    "NanoTrackGuide": "annotator.nanotrack",
    "Target": "annotator.tracks",
    "ToolError": "annotator.errors",
    "annotate": "annotator.job",
    "apply_corrections": "annotator.review",
    "read_store": "annotator.store",
    "resolve_config": "annotator.config",
}


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module 'annotator' has no attribute {name!r}")
    return getattr(importlib.import_module(_HOMES[name]), name)


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


if TYPE_CHECKING:  # the same names, for type checkers and editors
    from annotator.config import resolve_config
    from annotator.errors import ToolError
    from annotator.job import AnnotateResult, annotate
    from annotator.nanotrack import NanoTrackGuide
    from annotator.review import apply_corrections
    from annotator.store import read_store
    from annotator.tracks import Target

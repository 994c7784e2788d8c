"""What a run writes: the output formats (``--formats``), and the name of every file a run, a re-track, a batch
or an eval writes into its output folder.

Writers and readers (a re-track, a resumed run, a batch reusing finished
items, ``eval`` finding a run's results) meet on these names, and
``docs/outputs.md`` lists them; naming each once keeps them in step.
"""

from __future__ import annotations

#: Files for the review tools people already use; written only when asked for.
REVIEW_TOOL_FORMATS = ("cvat", "mot", "labelstudio", "yolo")
#: What a run writes when --formats is not given.
DEFAULT_FORMATS = ("otb", "coco", "flags", "overlay", "report")
#: What --formats accepts. The track store (tracks.npz) is always written and is not a format.
ALL_FORMATS = (*DEFAULT_FORMATS, *REVIEW_TOOL_FORMATS)

# A run's folder (``sptpt-annotate VIDEO``; a re-track rewrites the same files).
RUN_JSON = "run.json"  #: what the folder holds; written last, so its presence marks a finished run
STORE_NAME = "tracks.npz"  #: the track store: every other file is a view of it
PASSES_NAME = "passes.npz"  #: the forward passes a re-track reuses
CHECKPOINT_NAME = ".sptpt-checkpoint.pkl"  #: the trackers' state while a run is going, for --resume
OVERLAY_NAME = "overlay.mp4"
REPORT_NAME = "report.html"
COCO_NAME = "annotations.json"
FLAGS_NAME = "flags.csv"
CVAT_NAME = "cvat.xml"
LABELSTUDIO_NAME = "labelstudio.json"
LABELSTUDIO_CONFIG = "labelstudio_config.xml"  #: the labeling config beside labelstudio.json
MOT_FOLDER = "mot"
YOLO_FOLDER = "yolo"
#: Prefix of the folder a run or a re-track is written into before its files move into place.
STAGING_PREFIX = ".sptpt-run."

#: The fixed names of a run's results (the OTB file, the MOT and YOLO folders are named by the video).
RUN_FILES = (RUN_JSON, STORE_NAME, COCO_NAME, FLAGS_NAME, OVERLAY_NAME, REPORT_NAME, CVAT_NAME, LABELSTUDIO_NAME)

# A batch's folder: one sub-folder per item, named by its id, and these beside them.
SUMMARY_NAME = "summary.json"
FAILURES_NAME = "failures.jsonl"
#: The batch-level files; no item may be called after one of them.
BATCH_FILES = (COCO_NAME, LABELSTUDIO_NAME, SUMMARY_NAME, REPORT_NAME, FAILURES_NAME)

# ``eval --out``: got10k's plot names.
SUCCESS_PLOT = "success_plots.png"
PRECISION_PLOT = "precision_plots.png"
RESULTS_MD = "results.md"
RESULTS_JSON = "results.json"
CALIBRATION_PLOT = "calibration.png"

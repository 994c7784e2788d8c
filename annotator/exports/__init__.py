"""Exporters: OTB result files, COCO with video fields, the flags CSV, and the review tools' formats
(CVAT for video 1.1, MOT 1.1, Label Studio video tracking, YOLO labels); all views of the track store
(:mod:`annotator.exports.views`).

Every writer goes through :mod:`annotator.atomic`, so an interrupted export
leaves the previous file or none, never half of one.
"""

from __future__ import annotations

from annotator.exports.coco import build_coco, dumps_coco, merge_coco, save_coco, write_coco
from annotator.exports.cvat import build_cvat_xml, write_cvat_xml
from annotator.exports.flags import FLAGS_HEADER, FlagsFormatError, FlagTable, read_flags_csv, write_flags_csv
from annotator.exports.labelstudio import build_labelstudio_tasks, write_labelstudio
from annotator.exports.mot import build_mot_gt, write_mot
from annotator.exports.otb import otb_sequence_names, write_otb_results
from annotator.exports.views import (
    DATASET_EXPORTS,
    FILE_EXPORTS,
    ExportOptions,
    record_review_exports,
    write_dataset_exports,
    write_exports,
)
from annotator.exports.yolo import build_yolo_labels, write_yolo

__all__ = [
    "DATASET_EXPORTS",
    "ExportOptions",
    "FILE_EXPORTS",
    "FLAGS_HEADER",
    "FlagTable",
    "FlagsFormatError",
    "build_coco",
    "build_cvat_xml",
    "build_labelstudio_tasks",
    "build_mot_gt",
    "build_yolo_labels",
    "dumps_coco",
    "merge_coco",
    "otb_sequence_names",
    "read_flags_csv",
    "record_review_exports",
    "save_coco",
    "write_coco",
    "write_cvat_xml",
    "write_dataset_exports",
    "write_flags_csv",
    "write_exports",
    "write_labelstudio",
    "write_mot",
    "write_otb_results",
    "write_yolo",
]

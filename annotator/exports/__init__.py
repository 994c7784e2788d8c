"""Exporters: OTB result files, COCO with video fields, the flags CSV; all views of the track store.

Every writer goes through :mod:`annotator.atomic`, so an interrupted export
leaves the previous file or none, never half of one.
"""

from __future__ import annotations

from annotator.exports.coco import build_coco, dumps_coco, merge_coco, save_coco, write_coco
from annotator.exports.flags import FLAGS_HEADER, FlagTable, FlagsFormatError, read_flags_csv, write_flags_csv
from annotator.exports.otb import otb_sequence_names, write_otb_results
from annotator.exports.views import FILE_EXPORTS, write_exports

__all__ = [
    "FILE_EXPORTS",
    "FLAGS_HEADER",
    "FlagTable",
    "FlagsFormatError",
    "build_coco",
    "dumps_coco",
    "merge_coco",
    "otb_sequence_names",
    "read_flags_csv",
    "save_coco",
    "write_coco",
    "write_flags_csv",
    "write_exports",
    "write_otb_results",
]

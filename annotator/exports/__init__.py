"""Exporters: OTB result files, COCO with video fields, the flags CSV.

Every writer goes through :mod:`annotator.atomic`, so an interrupted export
leaves the previous file or none, never half of one.
"""

from __future__ import annotations

from annotator.exports.coco import build_coco, dumps_coco, merge_coco, save_coco, write_coco
from annotator.exports.flags import FLAGS_HEADER, FlagTable, FlagsFormatError, read_flags_csv, write_flags_csv
from annotator.exports.otb import otb_sequence_names, write_otb_results

__all__ = [
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
    "write_otb_results",
]

"""Batch manifests: which videos to label, from which first-frame boxes, with which settings.

A manifest lists *items*. The minimal item is the same in every format: a
``video`` (a video file or a folder of images, relative paths resolving
against the manifest's folder) and a ``box`` ``"x,y,w,h"`` (0-based pixels of
the object in the first processed frame, read as ``--box`` reads it:
:func:`annotator.box_input.parse_box`). Optional fields:

``boxes``
    Several objects: a list of boxes, each ``"x,y,w,h"``, a list of four
    numbers, or a mapping ``{box: ..., label: ..., track_id: ...}``. Give
    either ``box`` or ``boxes``. Track ids default to the box's position
    (1, 2, ...).
``box_origin``
    ``0`` (the default) when the item's boxes are 0-based pixels, ``1`` when
    they are OTB-style 1-based (pasted from an OTB ``groundtruth_rect.txt``),
    as ``--box-origin`` for a single video. ``batch --box-origin`` sets it
    for the items that give none.
``label``
    Category of the boxes that do not name their own (default ``object``).
``start``, ``stop``, ``step``
    Frame range, 0-based source indices as in ``sptpt-annotate VIDEO``.
``id``
    The item's name: its output subfolder and its key in ``summary.json``.
    Letters, digits, ``.``, ``_``, ``-``; starting with a letter or digit; at
    most 100 characters; unique (ignoring case, so that the subfolders are
    distinct on every file system). Default: the video's stem (an OTB
    ``Name/img`` folder gives ``Name``) with other characters replaced by
    ``_``; repeated stems become ``stem-2``, ``stem-3`` ... in manifest order.
``params``
    Per-item settings over the batch's: tracker parameter names
    (``n_particles: 300``), flag parameter names (``drop: 0.4``), ``preset``,
    or nested ``tracker:`` / ``flags:`` mappings as in a ``--config`` file.
    A name that is both (``accept_threshold``) means the tracker's. The seed
    is not an item parameter: each item's seed derives from the batch seed
    and the item id (see :func:`annotator.batch.item_seed`).

Formats, chosen by extension:

* **CSV** (``.csv``): a header row naming the fields; empty cells are "not
  given". ``boxes`` holds boxes separated by ``|`` (``10,20,30,40|50,60,30,40``)
  and ``label`` then one label per box, also ``|``-separated, or one for all.
  ``params`` holds a YAML/JSON mapping (``"{n_particles: 300}"``); a column
  ``params.NAME`` sets one parameter (the cell read as a YAML scalar).
* **JSON Lines** (``.jsonl``): one JSON object per line; blank lines skipped.
* **YAML** (``.yaml``, ``.yml``): a list of items, or a mapping with the key
  ``items`` holding that list.

What is checked here, before any work starts (all problems of a manifest are
reported at once, each as ``file:line``, the field and the fix): the syntax,
field names (an unknown one names the closest valid one), box syntax and
sizes, ranges, labels, track ids, item ids, and parameter names and types.
What needs the video (that it exists and decodes, that the box lies inside
the frame, that the range fits) is checked when the item runs, and fails
that item only.

An OTB-layout root is a manifest too (:func:`items_from_otb_root`).
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import yaml

from annotator.box_input import Box, BoxError, parse_box
from annotator.config import ConfigError, resolve_config
from annotator.errors import EXIT_INPUT, EXIT_VALUE
from annotator.flagging import FlagParams
from annotator.output_files import BATCH_FILES
from annotator.text_input import TEXT_ENCODINGS, read_text
from annotator.tracks import Target
from sptpt import TrackerParams

__all__ = [
    "BatchItem",
    "InvalidManifestError",
    "ITEM_FIELDS",
    "MANIFEST_SUFFIXES",
    "ManifestError",
    "RESERVED_IDS",
    "items_from_otb_root",
    "output_stem",
    "read_manifest",
    "safe_item_id",
]

#: Fields an item may have; ``video`` and one of ``box`` / ``boxes`` are required.
ITEM_FIELDS: tuple[str, ...] = ("video", "box", "boxes", "box_origin", "label", "start", "stop", "step", "id",
                                 "params")
#: Keys of a mapping inside ``boxes``.
BOX_FIELDS: tuple[str, ...] = ("box", "label", "track_id")
#: Manifest file extensions and their format.
MANIFEST_SUFFIXES: dict[str, str] = {".csv": "csv", ".jsonl": "jsonl", ".yaml": "yaml", ".yml": "yaml"}
#: Names of the batch-level outputs: no item may be called that (its folder would take their place).
RESERVED_IDS: tuple[str, ...] = BATCH_FILES

_ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
_ID_MAX = 100
_TRACKER_KEYS = tuple(f.name for f in dataclasses.fields(TrackerParams))
_FLAG_KEYS = tuple(f.name for f in dataclasses.fields(FlagParams))
_PARAM_KEYS = ("preset", "tracker", "flags", *_TRACKER_KEYS, *(k for k in _FLAG_KEYS if k not in _TRACKER_KEYS))


class ManifestError(ValueError):
    """One problem of a manifest, naming the file, the line and the field.

    Attributes
    ----------
    path : str
        The manifest (or ground-truth) file.
    line : int
        1-based line of the problem; 0 when it concerns the whole file.
    field : str
        The field concerned (``box``, ``boxes[2]``, ``params``, ...) or ``""``.
    """

    def __init__(self, path: str | os.PathLike, line: int, field: str, problem: str) -> None:
        self.path = str(path)
        self.line = int(line)
        self.field = field
        self.problem = problem
        where = f"{self.path}:{self.line}" if self.line > 0 else self.path
        super().__init__(f"{where}: {problem}")


class InvalidManifestError(ValueError):
    """Every problem found in a manifest; ``errors`` holds one :class:`ManifestError` each, in line order."""

    def __init__(self, errors: Sequence[ManifestError], *, exit_code: int = EXIT_VALUE) -> None:
        self.errors = sorted(errors, key=lambda e: (e.path, e.line))
        #: EXIT_INPUT when the manifest or dataset root cannot be read at all, EXIT_VALUE for what it says.
        self.exit_code = exit_code
        super().__init__("\n".join(str(e) for e in self.errors))


@dataclass(frozen=True)
class BatchItem:
    """One video of a batch and what to do with it.

    Attributes
    ----------
    id : str
        Unique, file-name-safe name: the output subfolder.
    input_path : Path
        Absolute path of the video file or image folder.
    targets : tuple of Target
        First-frame boxes (0-based ``xywh``), track ids and labels.
    start, stop, step : int or None
        The frame range; None where the manifest does not give it (the
        batch's defaults then apply).
    params : dict
        Per-item settings, normalised to ``{"preset": str, "tracker": {...},
        "flags": {...}}`` (keys present only when given).
    source : str
        The manifest file the item came from.
    line : int
        Its line in ``source`` (1-based).
    """

    id: str
    input_path: Path
    targets: tuple[Target, ...]
    start: int | None = None
    stop: int | None = None
    step: int | None = None
    params: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    line: int = 0

    @property
    def where(self) -> str:
        """``file:line`` of the item, for messages."""
        return f"{self.source}:{self.line}" if self.line else self.source


# --------------------------------------------------------------------------- ids


def safe_item_id(name: str) -> str:
    """A file-name-safe item id made from ``name`` (a video stem or folder name).

    Characters other than letters, digits, ``.``, ``_`` and ``-`` become
    ``_``; leading characters other than a letter or digit are dropped; the
    result is at most 100 characters; an empty result is ``item``.
    """
    text = re.sub(r"[^A-Za-z0-9._-]+", "_", str(name))
    text = re.sub(r"^[^A-Za-z0-9]+", "", text)[:_ID_MAX]
    return text or "item"


def output_stem(path: Path) -> str:
    """The name an output gets: a file's stem, a folder's name, ``Name`` for an OTB ``Name/img`` folder."""
    if path.suffix and not path.is_dir():
        return path.stem
    if path.name == "img":
        return path.parent.name
    return path.name


def _assign_ids(items: list[dict[str, Any]], errors: list[ManifestError]) -> None:
    """Check explicit ids, then give the others a default, unique ignoring case; in place."""
    taken: dict[str, dict[str, Any]] = {r.casefold(): {"line": 0, "source": ""} for r in RESERVED_IDS}
    for item in items:
        given = item.get("id")
        if given is None:
            continue
        key = given.casefold()
        if key in taken:
            other = taken[key]
            if other["line"]:
                errors.append(ManifestError(item["source"], item["line"], "id", (
                    f"id {given!r} is already used by the item at line {other['line']}: give each item its own id")))
            else:
                errors.append(ManifestError(item["source"], item["line"], "id", (
                    f"id {given!r} is the name of a batch-level output: choose another id")))
            continue
        taken[key] = item
    for item in items:
        if item.get("id") is not None:
            continue
        base = safe_item_id(output_stem(item["input_path"]))
        candidate, n = base, 1
        while candidate.casefold() in taken:
            n += 1
            suffix = f"-{n}"
            candidate = base[: _ID_MAX - len(suffix)] + suffix
        item["id"] = candidate
        taken[candidate.casefold()] = item


# --------------------------------------------------------------------------- field parsing


class _RowErrors:
    """Collects the problems of one row."""

    def __init__(self, source: str, line: int, key_lines: Mapping[str, int] | None = None) -> None:
        self.source, self.line = source, line
        self.key_lines = dict(key_lines or {})
        self.errors: list[ManifestError] = []

    def add(self, field_name: str, problem: str) -> None:
        top = field_name.split("[", 1)[0].split(".", 1)[0]
        self.errors.append(ManifestError(self.source, self.key_lines.get(top, self.line), field_name, problem))


def _closest(key: str, valid: Sequence[str]) -> str:
    close = difflib.get_close_matches(str(key), list(valid), n=1)
    return f"did you mean {close[0]!r}?" if close else f"valid fields: {', '.join(valid)}"


def _parse_box(value: Any, name: str, errs: _RowErrors, origin: int = 0) -> Box | None:
    try:
        return parse_box(value, name=name, origin=origin)
    except BoxError as exc:
        errs.add(name, str(exc))
        return None


def _parse_int(value: Any, name: str, errs: _RowErrors, *, minimum: int) -> int | None:
    if isinstance(value, str):
        text = value.strip()
        value = int(text) if re.fullmatch(r"[+-]?\d+", text) else value
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        errs.add(name, f"{name} {value!r} is not an integer: give a 0-based frame index such as 0 or 120")
        return None
    if value < minimum:
        errs.add(name, f"{name} {value} is below {minimum}: give an integer >= {minimum}")
        return None
    return value


def _parse_label(value: Any, name: str, errs: _RowErrors) -> str | None:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = str(value)
    if not isinstance(value, str) or not value.strip():
        errs.add(name, f"{name} {value!r} is not a label: give a non-empty text such as \"person\"")
        return None
    return value.strip()


def _normalise_params(value: Any, errs: _RowErrors) -> dict[str, Any]:
    """Sort a params mapping into preset / tracker / flags, and check it resolves."""
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value) if value.strip() else {}
        except yaml.YAMLError as exc:
            errs.add("params", f"params {value!r} is not a YAML/JSON mapping ({getattr(exc, 'problem', exc)}): "
                               "give e.g. \"{n_particles: 300}\"")
            return {}
    if value is None:
        return {}
    if not isinstance(value, dict):
        errs.add("params", f"params {value!r} is not a mapping: give parameter names and values, "
                           "e.g. {n_particles: 300}")
        return {}
    out: dict[str, Any] = {}
    tracker: dict[str, Any] = {}
    flags: dict[str, Any] = {}
    for key, val in value.items():
        if key == "seed":
            errs.add("params", "params.seed cannot be set per item: each item's seed derives from the batch seed "
                               "and the item id; set the batch seed with --seed or in --config")
        elif key == "preset":
            out["preset"] = val
        elif key in ("tracker", "flags"):
            if not isinstance(val, dict):
                errs.add("params", f"params.{key} {val!r} is not a mapping: give parameter names and values")
                continue
            (tracker if key == "tracker" else flags).update(val)
        elif key in _TRACKER_KEYS:
            tracker[key] = val
        elif key in _FLAG_KEYS:
            flags[key] = val
        else:
            errs.add("params", f"params.{key} is not a parameter: {_closest(str(key), _PARAM_KEYS)}")
    if tracker:
        out["tracker"] = tracker
    if flags:
        out["flags"] = flags
    if out:
        try:
            resolve_config({}, source="params", preset=out.get("preset"), tracker_overrides=tracker,
                           flag_overrides=flags)
        except ConfigError as exc:
            errs.add("params", f"{exc}; fix the item's params")
    return out


def _parse_origin(record: Mapping[str, Any], default: int, errs: _RowErrors) -> int:
    value = record.get("box_origin")
    if value is None:
        return default
    if isinstance(value, str) and value.strip() in ("0", "1"):
        return int(value)
    if value in (0, 1) and not isinstance(value, bool):
        return int(value)
    errs.add("box_origin", f"box_origin {value!r} is not 0 or 1: give 0 for 0-based pixels, 1 for OTB-style "
                           "1-based boxes")
    return default


def _parse_boxes(record: Mapping[str, Any], errs: _RowErrors, origin: int = 0) -> list[Target]:
    label_value = record.get("label")
    if "box" in record and "boxes" in record:
        errs.add("boxes", "both box and boxes are given: give one box as box, or a list of them as boxes")
        return []
    if "box" in record:
        entries: list[Any] = [record["box"]]
        names = ["box"]
    elif "boxes" in record:
        raw = record["boxes"]
        if isinstance(raw, str):
            text = raw.strip()
            if text.startswith("["):
                try:
                    raw = yaml.safe_load(text)
                except yaml.YAMLError:
                    errs.add("boxes", f"boxes {raw!r} is not a list: give boxes as x,y,w,h|x,y,w,h")
                    return []
            else:
                raw = [part for part in text.split("|")]
        if not isinstance(raw, list) or not raw:
            errs.add("boxes", f"boxes {record['boxes']!r} is not a non-empty list of boxes: "
                              "give e.g. [\"10,20,30,40\", \"50,60,30,40\"]")
            return []
        entries = raw
        names = [f"boxes[{i}]" for i in range(len(raw))]
    else:
        errs.add("box", "no box given: give the object's first-frame box as box \"x,y,w,h\" (0-based pixels)")
        return []

    labels: list[str | None]
    default_label = "object"
    if isinstance(label_value, str) and "|" in label_value and len(entries) > 1:
        labels = [_parse_label(part, "label", errs) for part in label_value.split("|")]
        if len(labels) != len(entries):
            errs.add("label", f"label {label_value!r} gives {len(labels)} labels for {len(entries)} boxes: "
                              "give one per box or one for all")
            return []
    else:
        if label_value is not None:
            default_label = _parse_label(label_value, "label", errs) or default_label
        labels = [None] * len(entries)

    targets: list[Target] = []
    used_ids: dict[int, str] = {}
    for position, (entry, name, label) in enumerate(zip(entries, names, labels), start=1):
        track_id: int | None = position
        if isinstance(entry, dict):
            unknown = [k for k in entry if k not in BOX_FIELDS]
            for key in unknown:
                errs.add(name, f"{name}.{key} is not a box field: {_closest(str(key), BOX_FIELDS)}")
            if "box" not in entry:
                errs.add(name, f"{name} has no box: give {{box: \"x,y,w,h\"}}")
                continue
            if "label" in entry:
                label = _parse_label(entry["label"], f"{name}.label", errs)
            if "track_id" in entry:
                track_id = _parse_int(entry["track_id"], f"{name}.track_id", errs, minimum=1)
            entry = entry["box"]
        box = _parse_box(entry, name, errs, origin)
        if box is None or track_id is None:
            continue
        if track_id in used_ids:
            errs.add(name, f"{name} has track id {track_id}, already used by {used_ids[track_id]}: "
                           "give each box its own track_id")
            continue
        used_ids[track_id] = name
        targets.append(Target(box, track_id=track_id, label=label or default_label))
    return targets


def _parse_record(record: Mapping[str, Any], *, base: Path, errs: _RowErrors,
                  box_origin: int = 0) -> dict[str, Any] | None:
    """One raw item (a mapping of field values) -> the keyword arguments of a BatchItem, or None."""
    n_before = len(errs.errors)
    for key in record:
        if key not in ITEM_FIELDS:
            errs.add(str(key), f"{key!r} is not an item field: {_closest(str(key), ITEM_FIELDS)}")
    video = record.get("video")
    if isinstance(video, (int, float)) and not isinstance(video, bool):
        video = str(video)  # an unquoted YAML name such as 2024
    input_path = None
    if video is None:
        errs.add("video", "no video given: give the path of a video file or image folder as video")
    elif not isinstance(video, str) or not video.strip():
        errs.add("video", f"video {video!r} is not a path: give the path of a video file or image folder")
    else:
        input_path = Path(os.path.abspath(base / Path(video.strip()).expanduser()))
    targets = _parse_boxes(record, errs, _parse_origin(record, box_origin, errs))
    ranges: dict[str, int | None] = {}
    for key, minimum in (("start", 0), ("stop", 1), ("step", 1)):
        ranges[key] = _parse_int(record[key], key, errs, minimum=minimum) if record.get(key) is not None else None
    if ranges["start"] is not None and ranges["stop"] is not None and ranges["stop"] <= ranges["start"]:
        errs.add("stop", f"stop {ranges['stop']} is not after start {ranges['start']}: "
                         "stop is exclusive, give stop > start")
    item_id = record.get("id")
    if item_id is not None:
        if isinstance(item_id, (int, float)) and not isinstance(item_id, bool):
            item_id = str(item_id)
        if not isinstance(item_id, str) or not _ID_PATTERN.fullmatch(item_id):
            errs.add("id", f"id {item_id!r} is not a safe name: use 1-100 letters, digits, '.', '_' or '-', "
                           "starting with a letter or digit")
            item_id = None
    params = _normalise_params(record.get("params"), errs)
    if len(errs.errors) > n_before or input_path is None:
        return None
    return {"id": item_id, "input_path": input_path, "targets": tuple(targets), **ranges, "params": params}


# --------------------------------------------------------------------------- formats


def _records_csv(path: Path, text: str, errors: list[ManifestError]) -> Iterable[tuple[int, dict, dict]]:
    reader = csv.reader(text.splitlines(keepends=True))
    header: list[str] | None = None
    header_line = 0
    for row in reader:
        line = reader.line_num
        if header is None:
            if not any(cell.strip() for cell in row):
                continue
            header = [cell.strip() for cell in row]
            header_line = line
            seen: set[str] = set()
            for name in header:
                if name in seen:
                    errors.append(ManifestError(path, line, name, f"column {name!r} appears twice in the header: "
                                                                  "keep one"))
                seen.add(name)
                if name not in ITEM_FIELDS and not name.startswith("params."):
                    errors.append(ManifestError(path, line, name, f"column {name!r} is not an item field: "
                                                                  f"{_closest(name, ITEM_FIELDS)}"))
            if "video" not in header:
                errors.append(ManifestError(path, line, "video", "the header has no 'video' column: "
                                                                 "the first row must name the fields, e.g. video,box"))
            continue
        if not any(cell.strip() for cell in row):
            continue
        if len(row) > len(header):
            errors.append(ManifestError(path, line, "", f"row has {len(row)} cells but the header (line "
                                        f"{header_line}) names {len(header)}: quote cells that hold commas, "
                                        f"e.g. \"10,20,30,40\""))
            continue
        record: dict[str, Any] = {}
        params: dict[str, Any] = {}
        for name, cell in zip(header, row):
            cell = cell.strip()
            if not cell or name not in ITEM_FIELDS and not name.startswith("params."):
                continue
            if name.startswith("params."):
                try:
                    params[name[len("params."):]] = yaml.safe_load(cell)
                except yaml.YAMLError:
                    params[name[len("params."):]] = cell
            else:
                record[name] = cell
        if params:
            base = record.get("params")
            if base is not None:
                try:
                    loaded = yaml.safe_load(base)
                except yaml.YAMLError:
                    loaded = base
                record["params"] = {**loaded, **params} if isinstance(loaded, dict) else loaded
            else:
                record["params"] = params
        yield line, record, {}
    if header is None:
        errors.append(ManifestError(path, 0, "", "the CSV file is empty: give a header row (e.g. video,box) "
                                                 "and one row per item"))


def _records_jsonl(path: Path, text: str, errors: list[ManifestError]) -> Iterable[tuple[int, dict, dict]]:
    for line, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        try:
            record = json.loads(raw)
        except json.JSONDecodeError as exc:
            errors.append(ManifestError(path, line, "", f"not valid JSON ({exc.msg} at column {exc.colno}): "
                                                        "give one JSON object per line, e.g. "
                                                        "{\"video\": \"a.mp4\", \"box\": \"10,20,30,40\"}"))
            continue
        if not isinstance(record, dict):
            errors.append(ManifestError(path, line, "", f"a JSON {type(record).__name__} is not an item: "
                                                        "give one JSON object per line"))
            continue
        yield line, record, {}


def _records_yaml(path: Path, text: str, errors: list[ManifestError]) -> Iterable[tuple[int, dict, dict]]:
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        errors.append(ManifestError(path, mark.line + 1 if mark is not None else 0, "",
                                    f"not valid YAML ({getattr(exc, 'problem', None) or exc}): fix the syntax"))
        return
    if root is None:
        return
    if isinstance(root, yaml.MappingNode) and isinstance(data, dict):
        unknown = [k for k in data if k != "items"]
        for key in unknown:
            errors.append(ManifestError(path, 1, str(key), f"top-level key {key!r} is not known: a YAML manifest is "
                                                           "a list of items or a mapping with the key 'items'"))
        node = next((v for k, v in root.value if k.value == "items"), None)
        data = data.get("items")
        if node is None:
            errors.append(ManifestError(path, 1, "items", "no 'items' key: give the list of items under items:"))
            return
    else:
        node = root
    if not isinstance(node, yaml.SequenceNode) or not isinstance(data, list):
        errors.append(ManifestError(path, node.start_mark.line + 1, "", "expected a list of items, each a mapping "
                                                                        "with video and box"))
        return
    for item_node, record in zip(node.value, data):
        line = item_node.start_mark.line + 1
        if not isinstance(record, dict):
            errors.append(ManifestError(path, line, "", f"item {record!r} is not a mapping: give e.g. "
                                                        "{video: a.mp4, box: \"10,20,30,40\"}"))
            continue
        key_lines = {k.value: k.start_mark.line + 1 for k, _ in item_node.value if isinstance(k, yaml.ScalarNode)}
        yield line, record, key_lines


_READERS = {"csv": _records_csv, "jsonl": _records_jsonl, "yaml": _records_yaml}


def read_manifest(path: str | os.PathLike, *, box_origin: int = 0) -> list[BatchItem]:
    """Read and check a manifest; relative video paths resolve against its folder.

    Parameters
    ----------
    path : path-like
        A ``.csv``, ``.jsonl``, ``.yaml`` or ``.yml`` file (see the module notes).
    box_origin : {0, 1}
        The origin of the boxes of items without a ``box_origin`` field: 0 for
        0-based pixels, 1 for OTB-style 1-based boxes.

    Returns
    -------
    list of BatchItem
        In manifest order, with unique ids.

    Raises
    ------
    InvalidManifestError
        Every problem found, each a :class:`ManifestError` naming ``file:line``
        and the field; nothing is returned unless the whole manifest is valid.
    """
    path = Path(path)
    if box_origin not in (0, 1):
        raise ValueError(f"box_origin must be 0 or 1, got {box_origin!r}")
    if not path.exists():
        raise InvalidManifestError([ManifestError(path, 0, "", "manifest file does not exist: give the path of a "
                                                               "CSV, JSON Lines or YAML manifest")],
                                   exit_code=EXIT_INPUT)
    fmt = MANIFEST_SUFFIXES.get(path.suffix.lower())
    if fmt is None:
        raise InvalidManifestError([ManifestError(path, 0, "", (
            f"manifest extension {path.suffix or '(none)'!r} is not known: name it "
            f"{', '.join(MANIFEST_SUFFIXES)} (CSV, JSON Lines or YAML)"))])
    try:
        text = read_text(path)
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else f"not text ({TEXT_ENCODINGS})"
        raise InvalidManifestError([ManifestError(path, 0, "", f"manifest cannot be read ({reason}): "
                                                               "give a readable text file")],
                                   exit_code=EXIT_INPUT) from None
    errors: list[ManifestError] = []
    raw_items: list[dict[str, Any]] = []
    for line, record, key_lines in _READERS[fmt](path, text, errors):
        errs = _RowErrors(str(path), line, key_lines)
        parsed = _parse_record(record, base=path.parent, errs=errs, box_origin=box_origin)
        errors.extend(errs.errors)
        if parsed is not None:
            raw_items.append({**parsed, "source": str(path), "line": line})
    if not raw_items and not errors:
        errors.append(ManifestError(path, 0, "", "the manifest holds no item: give at least one video with its box"))
    _assign_ids(raw_items, errors)
    if errors:
        raise InvalidManifestError(errors)
    return [BatchItem(**item) for item in raw_items]


def items_from_otb_root(root: str | os.PathLike) -> list[BatchItem]:
    """One item per sequence of an OTB-layout root, initialised from the first line of its ground truth.

    Sequences are found as in :func:`annotator.evaluation.discover_otb_sequences`
    (``Name/groundtruth_rect.txt``; a folder with ``groundtruth_rect.1.txt``,
    ``.2.txt`` gives items ``Name.1``, ``Name.2`` on the same frames). The item
    id is the sequence name, so that ``sptpt-annotate eval OUT ROOT`` finds
    ``OUT/Name/Name.txt`` for the usual one-target folders.

    Raises
    ------
    InvalidManifestError
        ``root`` holds no sequence, or a ground truth whose first line is not
        a usable box (naming the file and line).
    """
    from annotator.evaluation.dataset import discover_otb_sequences
    from annotator.evaluation.metrics import EvaluationError, MissingInputError
    from annotator.otb_format import OTBFormatError, read_otb_boxes

    root = Path(root)
    try:
        sequences = discover_otb_sequences(root)
    except EvaluationError as exc:
        message = str(exc).removeprefix(f"{root}: ")  # the error names the root itself; say it once
        raise InvalidManifestError([ManifestError(root, 0, "", message)],
                                   exit_code=EXIT_INPUT if isinstance(exc, MissingInputError) else EXIT_VALUE) from None
    errors: list[ManifestError] = []
    items: list[dict[str, Any]] = []
    for name, gt_path in sequences.items():
        try:
            boxes = read_otb_boxes(gt_path, origin=1)
        except (OTBFormatError, OSError) as exc:
            errors.append(ManifestError(gt_path, 0, "box", f"{exc}; fix the ground-truth file"))
            continue
        errs = _RowErrors(str(gt_path), 1)
        if not len(boxes):
            errs.add("box", "the ground truth has no row: the first frame needs a box x,y,w,h")
            box = None
        else:
            box = _parse_box(boxes[0], "first ground-truth box", errs)
        if box is None:
            errors.extend(errs.errors)
            continue
        items.append({"id": safe_item_id(name), "input_path": Path(os.path.abspath(gt_path.parent)),
                      "targets": (Target(box, track_id=1, label="object"),), "start": None, "stop": None,
                      "step": None, "params": {}, "source": str(gt_path), "line": 1})
    _assign_ids(items, errors)
    if errors:
        raise InvalidManifestError(errors)
    return [BatchItem(**item) for item in items]

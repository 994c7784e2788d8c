"""Where batch runs are planned: each item's job, its seed, and the resume rule that decides what to redo.

Resuming
    An item is *finished* when ``OUT/<id>/run.json`` exists (annotate writes
    it last, atomically), says ``"complete": true``, and records exactly what
    this run would do: the same resolved input path and content hash
    (SHA-256 of the file, or of an image folder's names and bytes), frame
    range, boxes, labels and track ids, full tracker/flag configuration
    (seed included) and output formats. A finished item is skipped and its
    outputs are kept; anything else is redone from scratch: its ``run.json``
    is removed first, then its other outputs and leftover temporary files
    (see :func:`annotator.batch.workers.run_item`), so that a run killed
    part-way never leaves a folder that looks finished. The tool version is
    not compared: after upgrading, rerun with ``--force``, which redoes every
    item. Failed and partially decoded items are always retried.

Determinism
    Item ``id`` gets the seed :func:`item_seed` ``(base seed, id)`` (SHA-256,
    not Python's salted ``hash``), so results depend on neither the number
    of workers nor the order items run in. Items are dispatched longest
    first (by :attr:`PlannedItem.estimate`) to shorten the tail of a
    parallel run.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from annotator.config import ConfigError, RunConfig, resolve_config
from annotator.errors import EXIT_VALUE, ToolError
from annotator.manifest import BatchItem, InvalidManifestError, ManifestError
from annotator.output_files import ALL_FORMATS, DEFAULT_FORMATS, RUN_JSON
from annotator.provenance import content_hash
from annotator.tracks import Target


def item_seed(base_seed: int, item_id: str) -> int:
    """The seed of one item: a stable 48-bit hash of the batch seed and the item id.

    SHA-256 of ``"sptpt-batch:<base_seed>:<item_id>"``, first 6 bytes big-endian:
    the same on every machine and Python (unlike ``hash()``), below 2**53 so
    that JSON readers in any language keep it exact.
    """
    digest = hashlib.sha256(f"sptpt-batch:{int(base_seed)}:{item_id}".encode("utf-8")).digest()
    return int.from_bytes(digest[:6], "big")



@dataclass(frozen=True)
class ItemJob:
    """Everything a worker needs to run one item (picklable; paths as strings)."""

    item_id: str
    input_path: str
    targets: tuple[Target, ...]
    start: int
    stop: int | None
    step: int
    config: RunConfig
    folder: str
    formats: tuple[str, ...]
    #: ``--media-url`` (ends in / or =: each item's labelstudio.json gets its video's file name appended).
    media_url: str | None = None
    threads: int | None = None  # numba threads for this item; None leaves the worker's setting
    #: Go on from the checkpoint an interrupted run of the item left in its folder (none: from the first frame).
    resume: bool = False



@dataclass
class PlannedItem:
    """An item with its resolved settings and whether its finished outputs can be kept."""

    item: BatchItem
    job: ItemJob
    reuse: bool
    estimate: int  # frames, for dispatch order only



def _job_config(item: BatchItem, *, file_values: Mapping[str, Any], source: str, preset: str | None,
                seed: int | None) -> RunConfig:
    """Defaults < config file < command line < item params; the seed derived from the base seed and id."""
    params = item.params
    base = resolve_config(file_values, source=source, preset=preset, seed=seed)
    return resolve_config(
        file_values, source=f"{item.where} params", preset=params.get("preset") or preset,
        seed=item_seed(base.seed, item.id), tracker_overrides=params.get("tracker"),
        flag_overrides=params.get("flags"))


def normalised_json(value: Any) -> Any:
    """``value`` as it reads back from JSON (tuples as lists, paths as strings), to compare with a ``run.json``."""
    return json.loads(json.dumps(value, default=str))


def _expected_targets(targets: Sequence[Target]) -> list[dict[str, Any]]:
    return [{"track_id": t.track_id, "label": t.label, "box_xywh": [float(v) for v in t.box_xywh], "box_origin": 0}
            for t in targets]


def read_run_json(folder: str | os.PathLike) -> dict[str, Any] | None:
    """An item folder's ``run.json``, or None when it is absent or unreadable."""
    try:
        data = json.loads((Path(folder) / RUN_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_item_finished(job: ItemJob, run: Mapping[str, Any] | None) -> bool:
    """Whether a folder's ``run.json`` records a complete run of exactly this job (the resume rule).

    Compares the completion flag, input path and content hash, frame range,
    targets, full configuration (seed included) and formats; see "Resuming"
    in this module's notes. The content hash is computed only when everything else matches.
    """
    if not run or run.get("complete") is not True:
        return False
    try:
        recorded_input = run["input"]
        recorded_range = run["range"]
        frame_count = int(recorded_input["frame_count"])
        expected_stop = frame_count if job.stop is None else min(job.stop, frame_count)
        same = (
            recorded_input["path"] == str(Path(job.input_path).resolve())
            and recorded_range == {"start": job.start, "stop": expected_stop, "step": job.step}
            and normalised_json(run["targets"]) == normalised_json(_expected_targets(job.targets))
            and normalised_json(run["config"]) == normalised_json(job.config.to_dict())
            and list(run["formats"]) == list(job.formats)
            and (run.get("export_options") or {}).get("media_url") == job.media_url
            # An image folder tracked before EXIF orientations were applied may hold boxes in sideways frames.
            and (not Path(job.input_path).is_dir() or recorded_input.get("exif_orientation") == "applied")
        )
    except (KeyError, TypeError, ValueError):
        return False
    if not same:
        return False
    try:
        return recorded_input.get("content_hash") == content_hash(Path(job.input_path))
    except OSError:
        return False


def _estimate_frames(item: BatchItem, start: int, stop: int | None, step: int) -> int:
    """A cheap frame-count estimate for dispatch order: image files counted, video size / 4 kB."""
    path = item.input_path
    try:
        if path.is_dir():
            folder = path / "img" if (path / "img").is_dir() else path
            total = sum(1 for _ in folder.iterdir())
        else:
            total = max(1, path.stat().st_size // 4096)
    except OSError:
        return 0
    end = total if stop is None else min(stop, total)
    return max(0, (end - start + step - 1) // step) * max(1, len(item.targets))


@dataclass(frozen=True)
class BatchRequest:
    """What a batch asks of every item, as ``sptpt-annotate batch`` takes it from the command line.

    Attributes
    ----------
    config_values : mapping, optional
        A ``--config`` file's mapping (item params override it).
    config_source : str
        Where it came from, for error messages.
    preset : str, optional
        ``--preset``.
    seed : int, optional
        The base seed (``--seed``): item ``id`` gets :func:`item_seed` ``(seed, id)``.
    formats : sequence of str
        Outputs of each item (``otb, coco, flags, overlay, report``, ...).
    start, stop, step : int, optional
        Frame range of items whose manifest row gives none.
    media_url : str, optional
        The prefix of each video's URL in the review tools' task files.
    """

    config_values: Mapping[str, Any] | None = None
    config_source: str = "config"
    preset: str | None = None
    seed: int | None = None
    formats: Sequence[str] = DEFAULT_FORMATS
    start: int | None = None
    stop: int | None = None
    step: int | None = None
    media_url: str | None = None


def plan_batch(items: Sequence[BatchItem], request: BatchRequest = BatchRequest(), *, out_dir: str | os.PathLike,
               force: bool = False) -> list[PlannedItem]:
    """Resolve every item's settings and decide which finished outputs to keep.

    ``request``'s ``start``, ``stop``, ``step`` are defaults for items that give no range.

    Raises
    ------
    InvalidManifestError
        An item's params do not resolve against the batch configuration
        (naming the item's ``file:line``).
    ToolError
        The batch configuration itself is invalid (exit code 4).
    """
    out_dir = Path(out_dir)
    config_source, preset, seed, formats = request.config_source, request.preset, request.seed, request.formats
    file_values = dict(request.config_values or {})
    unknown = sorted(set(formats) - set(ALL_FORMATS))
    if unknown:
        raise ToolError(f"--formats {','.join(unknown)} is not known: choose from {','.join(ALL_FORMATS)}", EXIT_VALUE)
    try:
        resolve_config(file_values, source=config_source, preset=preset, seed=seed)
    except ConfigError as exc:
        raise ToolError(str(exc), EXIT_VALUE) from None
    planned: list[PlannedItem] = []
    errors: list[ManifestError] = []
    for item in items:
        try:
            config = _job_config(item, file_values=file_values, source=config_source, preset=preset, seed=seed)
        except ConfigError as exc:
            errors.append(ManifestError(item.source, item.line, "params", f"{exc}; fix the item's params"))
            continue
        item_start = item.start if item.start is not None else (request.start or 0)
        item_stop = item.stop if item.stop is not None else request.stop
        item_step = item.step if item.step is not None else (request.step or 1)
        job = ItemJob(item_id=item.id, input_path=str(item.input_path), targets=tuple(item.targets),
                      start=item_start, stop=item_stop, step=item_step, config=config,
                      folder=str(out_dir / item.id), formats=tuple(formats), media_url=request.media_url)
        reuse = not force and is_item_finished(job, read_run_json(job.folder))
        planned.append(PlannedItem(item, job, reuse, _estimate_frames(item, item_start, item_stop, item_step)))
    if errors:
        raise InvalidManifestError(errors)
    return planned

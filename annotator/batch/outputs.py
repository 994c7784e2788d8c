"""Batch-level outputs: status rows, ``failures.jsonl``, the merged COCO file, ``summary.json`` and the index.

Layout of the output folder ``OUT``::

    OUT/<id>/...            each item's outputs, exactly as ``sptpt-annotate VIDEO`` writes them
    OUT/annotations.json    COCO for the whole dataset (merge_coco: ids unique across videos)
    OUT/labelstudio.json    with --formats labelstudio: every item's Label Studio task in one import file
    OUT/summary.json        settings, counts and one row per item
    OUT/failures.jsonl      one JSON object per failed item: id, input, manifest line, exit code, error
    OUT/report.html         index: a sortable row per item, linking ``<id>/report.html``

The batch-level files are rebuilt at the end of every run from all items'
``run.json`` and track stores (never their exports), so a resumed run
indexes old and new items alike; each is
written atomically (write to a temporary file, rename). ``failures.jsonl``
is also rewritten whenever an item fails, so a killed run still lists the
failures so far.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from annotator.atomic import write_text_atomic
from annotator.batch.plan import BatchRequest, PlannedItem, normalised_json, read_run_json
from annotator.batch.workers import ItemOutcome
from annotator.errors import EXIT_BATCH_FAILURES, EXIT_OK
from annotator.exports import DATASET_EXPORTS, ExportOptions, write_dataset_exports
from annotator.html_pages import BATCH_TEMPLATE, template_environment
from annotator.output_files import FAILURES_NAME, REPORT_NAME, SUMMARY_NAME
from annotator.track_store import STORE_NAME, RunStore, read_store
from annotator.version import __version__


@dataclass
class BatchResult:
    """What a batch run did."""

    out_dir: Path
    rows: list[dict[str, Any]]
    exit_code: int
    counts: dict[str, int]
    frames_this_run: int
    seconds: float
    paths: dict[str, Path] = field(default_factory=dict)

    @property
    def failures(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] in ("failed", "partial")]



def _status_row(plan: PlannedItem, outcome: ItemOutcome | None, run: Mapping[str, Any] | None,
                out_dir: Path) -> dict[str, Any]:
    item, job = plan.item, plan.job
    if plan.reuse:
        status = "done"
    elif outcome is None:
        status = "pending"
    else:
        status = outcome.status
    row: dict[str, Any] = {
        "id": item.id,
        "status": status,
        "reused": plan.reuse,
        "input": str(item.input_path),
        "manifest": item.where,
        "seed": job.config.seed,
        "folder": item.id,
        "report": None,
        "frames": None,
        "tracks": len(item.targets),
        "flagged": None,
        "flagged_share": None,
        "longest_flagged_span": None,
        "keyframes_asked": None,
        "mean_confidence": None,
        "seconds": None,
        "frames_per_second": None,
        "exit_code": outcome.exit_code if outcome is not None else EXIT_OK,
        "error": outcome.error if outcome is not None else None,
        "worker_cpu_seconds": outcome.cpu_seconds if outcome is not None else None,
        "worker_pid": outcome.pid if outcome is not None else None,
        "worker_host": outcome.host if outcome is not None else None,
        "worker_peak_rss_mb": outcome.peak_rss_mb if outcome is not None else None,
    }
    if status == "pending":
        row["error"] = "not run: the batch was interrupted; rerun to finish it"
    if run is not None and status in ("done", "partial"):
        tracks = run.get("tracks") or []
        boxes = sum(int(t.get("frames", 0)) for t in tracks)
        flagged = sum(int(t.get("flagged", 0)) for t in tracks)
        timings = run.get("timings") or {}
        confidences = [t["mean_confidence"] for t in tracks
                       if isinstance(t.get("mean_confidence"), (int, float)) and math.isfinite(t["mean_confidence"])]
        row.update({
            "frames": run.get("frames_processed"),
            "flagged": flagged,
            "flagged_share": flagged / boxes if boxes else 0.0,
            "longest_flagged_span": max((int(t.get("longest_span", 0)) for t in tracks), default=0),
            # A lost track's flags are the keyframes it asks for: few and short, so its flagged share looks good.
            "keyframes_asked": sum(len(t.get("keyframes_asked") or []) for t in tracks),
            "mean_confidence": sum(confidences) / len(confidences) if confidences else None,
            "seconds": timings.get("seconds_total"),
            "frames_per_second": timings.get("frames_per_second"),
        })
        if (out_dir / item.id / REPORT_NAME).is_file():
            row["report"] = f"{item.id}/{REPORT_NAME}"
    return row


def write_failures(out_dir: Path, planned: Sequence[PlannedItem], outcomes: Mapping[str, ItemOutcome]) -> Path:
    """``OUT/failures.jsonl``: one object per item of this run that failed or was only partly decoded."""
    lines = []
    for plan in planned:
        outcome = outcomes.get(plan.item.id)
        if outcome is None or outcome.status == "done":
            continue
        record = {"id": plan.item.id, "status": outcome.status, "input": str(plan.item.input_path),
                  "manifest": plan.item.where, "exit_code": outcome.exit_code, "error": outcome.error}
        if outcome.traceback:
            record["traceback"] = outcome.traceback
        lines.append(json.dumps(record, ensure_ascii=False) + "\n")
    path = out_dir / FAILURES_NAME
    write_text_atomic(path, "".join(lines))
    return path


def _item_stores(out_dir: Path, rows: Sequence[Mapping[str, Any]]) -> list[RunStore]:
    """The track stores of the items that have results, in manifest order, each video named for its item id.

    The id is unique in the batch where video names need not be; a video
    item's frame-dump names (``<name>/<frame:06d>.jpg``) follow the new name,
    while an image-folder item keeps its real image paths.
    """
    stores = []
    for row in rows:
        path = out_dir / row["id"] / STORE_NAME
        if row["status"] not in ("done", "partial") or not path.is_file():
            continue
        store = read_store(path)
        stores.append(dataclasses.replace(store, video=dataclasses.replace(store.video, name=row["id"])))
    return stores


def _render_index(path: Path, summary: Mapping[str, Any]) -> None:
    page = template_environment().get_template(BATCH_TEMPLATE).render(summary=summary, rows=summary["items"])
    write_text_atomic(path, page)


def write_batch_outputs(planned: Sequence[PlannedItem], outcomes: Mapping[str, ItemOutcome], request: BatchRequest,
                        *, out_dir: Path, seconds: float, manifest: str | None, settings: Mapping[str, Any],
                        interrupted: bool) -> BatchResult:
    """Write every batch-level file from all planned items (reused ones included) and say what the run did."""
    formats, seed, config_values, media_url = request.formats, request.seed, request.config_values, request.media_url
    rows = [_status_row(plan, outcomes.get(plan.item.id), read_run_json(plan.job.folder), out_dir)
            for plan in planned]
    counts = {"items": len(rows)}
    for status in ("done", "partial", "failed", "pending"):
        counts[status] = sum(r["status"] == status for r in rows)
    counts["reused"] = sum(r["reused"] for r in rows)
    frames_this_run = sum(o.frames for o in outcomes.values())
    frames_total = sum(int(r["frames"] or 0) for r in rows)
    exit_code = EXIT_OK if counts["done"] == counts["items"] else EXIT_BATCH_FAILURES
    base_seed = seed if seed is not None else int((config_values or {}).get("seed", 0) or 0)
    summary = {
        "tool": "sptpt-annotate batch",
        "tool_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "manifest": manifest,
        "out": str(out_dir.resolve()),
        "settings": {"base_seed": base_seed, "preset": request.preset,
                     "config": normalised_json(dict(config_values or {})),
                     "formats": list(formats), **dict(settings)},
        "counts": counts,
        "exit_code": exit_code,
        "interrupted": interrupted,
        "frames": frames_total,
        "frames_this_run": frames_this_run,
        "wall_seconds": seconds,
        "frames_per_second_this_run": frames_this_run / seconds if seconds > 0 and frames_this_run else None,
        "items": rows,
    }
    paths = {"failures": write_failures(out_dir, planned, outcomes)}
    # Merged views of every item's track store, for the formats that hold several videos.
    stores = _item_stores(out_dir, rows) if set(DATASET_EXPORTS) & set(formats) else []
    for kind, written in write_dataset_exports(out_dir, stores, formats, ExportOptions(media_url=media_url)).items():
        paths[kind] = written[0]
    write_text_atomic(out_dir / SUMMARY_NAME, json.dumps(summary, indent=2, ensure_ascii=False) + "\n")
    paths["summary"] = out_dir / SUMMARY_NAME
    _render_index(out_dir / REPORT_NAME, summary)
    paths["report"] = out_dir / REPORT_NAME
    return BatchResult(out_dir=out_dir, rows=rows, exit_code=exit_code, counts=counts,
                       frames_this_run=frames_this_run, seconds=seconds, paths=paths)

"""Batch runs: every item of a manifest through :func:`annotator.run.annotate`, resumably, in parallel.

Where things are
    :mod:`~annotator.batch.plan`
        Where runs are planned: each item's job and seed, and the resume
        rule (:func:`is_item_finished`) that decides what a rerun redoes.
    :mod:`~annotator.batch.workers`
        Where items execute: :func:`run_item` in a worker process, isolating
        the item's failures, and the progress events it sends.
    :mod:`~annotator.batch.executors`
        Where items are sent: a local process pool or a Dask cluster, and the
        loop that collects outcomes and replaces dead workers.
    :mod:`~annotator.batch.outputs`
        The batch-level files in ``OUT``: ``annotations.json`` (merged COCO),
        ``summary.json``, ``failures.jsonl`` and the ``report.html`` index.
    :mod:`~annotator.batch.runner`
        The entry point :func:`run_batch`, which holds the output folder's
        lock and ties the above together.

    The progress display of a whole run, :class:`BatchProgress`, is in
    :mod:`annotator.progress`, with the single video's.

Killing a run
    Whatever ends the main process, ``kill -9`` included, leaves no work
    running: its local workers, their fork server and multiprocessing's
    resource tracker stop within moments (how: "When the main process dies"
    in :mod:`~annotator.batch.executors`). Finished items keep their
    outputs, and a rerun redoes only the rest (the resume rule).
"""

from __future__ import annotations

from annotator.batch.executors import default_workers
from annotator.batch.outputs import BatchResult
from annotator.batch.plan import (
    BatchRequest,
    ItemJob,
    PlannedItem,
    is_item_finished,
    item_seed,
    plan_batch,
    read_run_json,
)
from annotator.batch.runner import run_batch
from annotator.batch.workers import ItemOutcome, run_item
from annotator.output_files import BATCH_FILES
from annotator.progress import BatchProgress

__all__ = [
    "BATCH_FILES",
    "BatchProgress",
    "BatchRequest",
    "BatchResult",
    "ItemJob",
    "ItemOutcome",
    "PlannedItem",
    "default_workers",
    "item_seed",
    "is_item_finished",
    "plan_batch",
    "read_run_json",
    "run_batch",
    "run_item",
]

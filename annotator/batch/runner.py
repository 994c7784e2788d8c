"""The entry point :func:`run_batch`: plan, hold the output folder, execute, write the batch-level files.

One run at a time per folder
    The output folder's lock (:func:`annotator.output_folder.folder_lock`)
    stops two runs writing to one folder at once; the kernel releases it
    when the holder dies. Items are judged finished or not (the resume rule, in
    :mod:`annotator.batch.plan`) only under the lock, and temporary files of
    batch-level writes that a killed run left behind are removed first.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from pathlib import Path
from typing import Sequence, TextIO

from annotator.batch.executors import (
    check_scheduler_address,
    default_workers,
    execute_items,
    threads_per_worker,
    worker_context,
)
from annotator.batch.outputs import BatchResult, write_batch_outputs
from annotator.batch.plan import BatchRequest, PlannedItem, is_item_finished, plan_batch, read_run_json
from annotator.batch.workers import ItemOutcome
from annotator.errors import EXIT_OUTPUT, EXIT_VALUE, ToolError, require_extra
from annotator.manifest import BatchItem
from annotator.output_files import BATCH_FILES, RUN_JSON
from annotator.output_folder import folder_lock
from annotator.progress import BatchProgress

#: run_batch's request when none is given: the command line's defaults (frozen, so one instance serves every call).
_DEFAULT_REQUEST = BatchRequest()


def _prepare_out_dir(out_dir: Path, planned: list) -> None:
    """Refuse an output folder the planned items cannot safely share, else create it and check it is writable."""
    _refuse_unsafe_out_dir(out_dir, planned)
    if out_dir.exists() and not out_dir.is_dir():
        raise ToolError(f"output folder {out_dir} is a file: give --out a folder path", EXIT_OUTPUT)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe = out_dir / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ToolError(f"output folder {out_dir} cannot be written ({exc.strerror}): choose a writable --out folder",
                        EXIT_OUTPUT) from None


def _refuse_unsafe_out_dir(out_dir: Path, planned: Sequence[PlannedItem]) -> None:
    """Refuse an ``--out`` whose use would overwrite inputs or another run's results.

    An item's folder ``OUT/<id>`` that is an input image folder, or holds
    one, would get result files written among its frames and files
    (``--otb-root R --out R`` makes ``R/Deer`` both), whichever item the
    input belongs to. A video file inside an item folder is left alone (only
    the tool's own names are written and cleared). A single-video run
    folder (``run.json`` at its top) would have its ``annotations.json`` and
    ``report.html`` replaced by the batch's index.
    """
    folders = {Path(plan.job.folder).resolve(): plan.job.item_id for plan in planned}
    for plan in planned:
        source = Path(plan.job.input_path).resolve()
        if not source.is_dir():
            continue
        for place in (source, *source.parents):
            if place in folders:
                raise ToolError(f"--out {out_dir}: item {folders[place]!r} would write into the input folder {source}: "
                                "choose an --out folder outside the input folders", EXIT_OUTPUT)
    if (out_dir / RUN_JSON).is_file():
        raise ToolError(f"--out {out_dir} holds a single-video run (run.json): the batch's index would replace its "
                        "files; choose another --out folder", EXIT_OUTPUT)


def _remove_stale_temporaries(out_dir: Path) -> None:
    """Temporary files of batch-level writes that a killed run left behind (atomic_path names)."""
    for name in BATCH_FILES:
        for path in out_dir.glob(f".{name}.*.tmp*"):
            with contextlib.suppress(OSError):
                path.unlink()


def _check_batch_settings(request: BatchRequest, *, workers: int | None, scheduler: str | None) -> None:
    start, stop, step = request.start, request.stop, request.step
    if workers is not None and workers < 1:
        raise ToolError(f"--workers {workers} is invalid: give 1 or more worker processes", EXIT_VALUE)
    if start is not None and start < 0:
        raise ToolError(f"--start {start} is invalid: give a first frame of 0 or more (0-based)", EXIT_VALUE)
    if stop is not None and stop <= (start or 0):
        raise ToolError(f"--stop {stop} is invalid: give a frame after the first one ({start or 0}), or leave it "
                        "out to run to the end", EXIT_VALUE)
    if step is not None and step < 1:
        raise ToolError(f"--step {step} is invalid: give 1 or more", EXIT_VALUE)
    if scheduler is not None and workers is not None:
        raise ToolError("--workers and --scheduler were both given: --workers sizes local processes, --scheduler "
                        "sends items to a Dask cluster; give one", EXIT_VALUE)
    if scheduler is not None:
        require_extra("--scheduler")
        check_scheduler_address(scheduler)


def _schedule(planned: list, *, force: bool, n_workers: int, scheduler: str | None) -> tuple[list, int, dict]:
    """The items still to run, longest first, with the worker count and threads they get, and those settings as
    ``summary.json`` records them. Finished items are judged here, under the output folder's lock."""
    for plan in planned:
        plan.reuse = not force and is_item_finished(plan.job, read_run_json(plan.job.folder))
    todo = sorted((p for p in planned if not p.reuse), key=lambda p: -p.estimate)
    n_workers = min(n_workers, max(len(todo), 1))
    threads = None if scheduler else threads_per_worker(n_workers)
    for plan in todo:
        # An item cut short goes on from its checkpoint, unless --force asks for every item afresh.
        plan.job = dataclasses.replace(plan.job, threads=threads, resume=not force)
    settings = {"workers": None if scheduler else n_workers, "scheduler": scheduler,
                "start_method": None if scheduler else worker_context().get_start_method(),
                "numba_threads_per_worker": threads}
    return todo, n_workers, settings


def _run_items(planned: list, out_dir: Path, *, force: bool, scheduler: str | None, workers: int,
               show_progress: bool, stream: TextIO | None) -> tuple[dict[str, ItemOutcome], bool, dict]:
    """Run the items not finished yet (under the output folder's lock): the outcome of each that ended, whether
    Ctrl-C stopped the batch, and the worker settings for ``summary.json``."""
    _remove_stale_temporaries(out_dir)
    todo, workers, settings = _schedule(planned, force=force, n_workers=workers, scheduler=scheduler)
    progress = BatchProgress(len(todo), reused=len(planned) - len(todo), enabled=show_progress, stream=stream)
    outcomes: dict[str, ItemOutcome] = {}
    try:
        if todo:
            execute_items(todo, outcomes, progress, out_dir, planned, scheduler=scheduler, workers=workers)
    except KeyboardInterrupt:
        return outcomes, True, settings
    finally:
        progress.close()
    return outcomes, False, settings


def run_batch(
    items: Sequence[BatchItem],
    request: BatchRequest = _DEFAULT_REQUEST,
    *,
    out_dir: str | os.PathLike,
    force: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    show_progress: bool = True,
    manifest: str | None = None,
    stream: TextIO | None = None,
) -> BatchResult:
    """Run every item, skipping finished ones; write the batch-level files.

    Parameters
    ----------
    items : sequence of BatchItem
        From :func:`~annotator.manifest.read_manifest` or
        :func:`~annotator.manifest.items_from_otb_root`.
    request : BatchRequest
        What every item is asked for: configuration, seed, formats, default frame range, media URL.
    out_dir : path-like
        ``OUT``; each item writes to ``OUT/<id>/``.
    force : bool
        Redo finished items too.
    workers : int, optional
        Local worker processes (default: the number of cores).
    scheduler : str, optional
        Address of a Dask distributed scheduler to send the items to instead.
    show_progress : bool
    manifest : str, optional
        Where the items came from, recorded in ``summary.json``.

    Returns
    -------
    BatchResult
        ``exit_code`` 0 when every item is done, 7 (EXIT_BATCH_FAILURES)
        when some failed or were only partly decoded.

    Raises
    ------
    InvalidManifestError
        An item's params do not resolve (before any work).
    ToolError
        Invalid batch settings, or an output folder that cannot be used.
    KeyboardInterrupt
        After stopping the workers and writing the batch files for what finished.
    """
    out_dir = Path(out_dir)
    _check_batch_settings(request, workers=workers, scheduler=scheduler)
    # Settings are checked before the output folder is touched; finished outputs are judged under the lock.
    planned = plan_batch(items, request, out_dir=out_dir, force=True)
    _prepare_out_dir(out_dir, planned)
    started = time.perf_counter()
    with folder_lock(out_dir):
        outcomes, interrupted, settings = _run_items(planned, out_dir, force=force, scheduler=scheduler,
                                                     workers=workers or default_workers(),
                                                     show_progress=show_progress, stream=stream)
        result = write_batch_outputs(planned, outcomes, request, out_dir=out_dir,
                                     seconds=time.perf_counter() - started, manifest=manifest, settings=settings,
                                     interrupted=interrupted)
    if interrupted:
        raise KeyboardInterrupt
    return result

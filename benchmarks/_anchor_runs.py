"""Re-tracking from ground-truth anchors every M frames, as two benchmarks store it.

``anchored_failure.py`` and ``pass_choice.py`` both re-track each sequence of
``../shared/otb`` from its ground truth every M frames, one job per sequence,
seed and M, store what they measure in one ``.npz`` per job, and hold out one
video at a time. This module is what they share: the seeds and intervals from
the command line, the jobs on a process pool, the stored files' names and the
folds.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from annotator.failure.fit import video
from benchmarks._sequences import SequenceError, select_sequences

__all__ = ["add_arguments", "mean_std", "parse_seeds_and_intervals", "stored_data", "stored_rows", "track_jobs",
           "video"]


def add_arguments(parser: argparse.ArgumentParser, *, otb: Path, stop: int, every: str, every_help: str,
                  data: Path) -> None:
    """The options both scripts take: where the sequences are, which, how many frames, the seeds and intervals,
    where the rows are stored, whether to track them first, and on how many processes."""
    parser.add_argument("--otb", type=Path, default=otb)
    parser.add_argument("--sequences", default="all", help="comma-separated names, or 'all'")
    parser.add_argument("--stop", type=int, default=stop, help=f"first N frames of each sequence (default {stop})")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--every", default=every, help=every_help)
    parser.add_argument("--data", type=Path, default=data)
    parser.add_argument("--generate", action="store_true", help="track first (else use the stored data)")
    parser.add_argument("--workers", type=int, default=2)


def parse_seeds_and_intervals(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[list[int], list[int]]:
    """``--seeds`` and ``--every`` as lists of integers; a one-line usage error (exit 2) otherwise."""
    try:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        everies = [int(v) for v in args.every.split(",") if v.strip()]
    except ValueError:
        parser.error(f"--seeds {args.seeds!r} and --every {args.every!r} must be comma-separated integers")
    if not seeds or not everies or min(everies) < 2:
        parser.error("--seeds needs at least one seed and --every intervals of at least 2 frames")
    return seeds, everies


def stored_data(parser: argparse.ArgumentParser, args: argparse.Namespace, generate: Callable[[dict], str],
                load_data: Callable[..., dict[str, np.ndarray]]) -> tuple[list[int], list[int], dict[str, np.ndarray]]:
    """``(seeds, everies, data)`` of :func:`add_arguments`' options: the rows tracked first with ``--generate``,
    then read back by ``load_data(folder, sequences, seeds, everies, stop)``; one-line usage errors (exit 2) for
    bad options and for rows of fewer than two videos, which leave nothing to hold out."""
    seeds, everies = parse_seeds_and_intervals(parser, args)
    try:
        sequences = select_sequences(args.otb, args.sequences)
    except SequenceError as err:
        parser.error(str(err))
    if args.generate:
        track_jobs(generate, sequences, seeds, everies, args.stop, args.data, args.workers)
    data = load_data(args.data, {s.name for s in sequences}, seeds, everies, args.stop)
    if len({video(name) for name in data["sequence"]}) < 2:
        parser.error("held-out figures need the frames of at least two videos: give more --sequences")
    return seeds, everies, data


def track_jobs(generate: Callable[[dict], str], sequences: list[Path], seeds: list[int], everies: list[int],
               stop: int, folder: Path, workers: int) -> None:
    """Run ``generate`` once per sequence, seed and interval on ``workers`` processes, each writing its ``.npz``
    into ``folder`` (numba on one thread per process when there are several, so they do not fight for cores)."""
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [dict(seq_dir=str(s), seed=seed, every=every, stop=stop, threads=1 if workers > 1 else 0,
                 out=str(folder / f"{s.name}__s{seed}__m{every}.npz"))
            for seed in seeds for every in everies for s in sequences]
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
        list(pool.map(generate, jobs))


def _stored_runs(folder: Path, sequences: set[str] | None, seeds, everies) -> Iterator[tuple[Path, str, int, int]]:
    """``(path, sequence, seed, every)`` of the stored jobs of the given sequences (all when None), seeds and
    intervals, in name order."""
    for path in sorted(folder.glob("*.npz")):
        name, seed, every = path.stem.rsplit("__", 2)
        seed, every = int(seed[1:]), int(every[1:])
        if (sequences is None or name in sequences) and seed in seeds and every in everies:
            yield path, name, seed, every


def stored_rows(folder: Path, sequences: set[str] | None, seeds, everies, columns: tuple[str, ...],
                check: Callable[[Path, Any], None]) -> dict[str, np.ndarray]:
    """The ``columns`` of the stored jobs of the given sequences (all when None), seeds and intervals, one row a
    frame, with each row's ``sequence``, ``seed`` and ``every``. ``check(path, stored)`` raises ``SystemExit``
    for a file the script cannot use (another ``--stop``, version or model)."""
    parts = []
    for path, name, seed, every in _stored_runs(folder, sequences, seeds, everies):
        with np.load(path) as stored:
            check(path, stored)
            k = len(stored[columns[0]])
            parts.append(dict(sequence=np.full(k, name), seed=np.full(k, seed), every=np.full(k, every),
                              **{c: stored[c] for c in columns}))
    if not parts:
        raise SystemExit(f"no data in {folder} for these sequences, seeds and intervals: run with --generate first")
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}



def mean_std(values, digits: int = 3) -> str:
    """``mean ± sample std`` of the values, or the value alone when there is one."""
    v = np.asarray(list(values), dtype=np.float64)
    return f"{v[0]:.{digits}f}" if v.size == 1 else f"{v.mean():.{digits}f} ± {v.std(ddof=1):.{digits}f}"

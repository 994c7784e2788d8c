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
from typing import Callable, Iterator

import numpy as np

__all__ = ["mean_std", "parse_seeds_and_intervals", "stored_runs", "track_jobs", "video"]


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


def stored_runs(folder: Path, sequences: set[str] | None, seeds, everies) -> Iterator[tuple[Path, str, int, int]]:
    """``(path, sequence, seed, every)`` of the stored jobs of the given sequences (all when None), seeds and
    intervals, in name order."""
    for path in sorted(folder.glob("*.npz")):
        name, seed, every = path.stem.rsplit("__", 2)
        seed, every = int(seed[1:]), int(every[1:])
        if (sequences is None or name in sequences) and seed in seeds and every in everies:
            yield path, name, seed, every


def video(sequence: str) -> str:
    """The fold of a sequence: OTB's Jogging.1 and Jogging.2 are two people in one video."""
    return sequence.split(".")[0]


def mean_std(values, digits: int = 3) -> str:
    """``mean ± sample std`` of the values, or the value alone when there is one."""
    v = np.asarray(list(values), dtype=np.float64)
    return f"{v[0]:.{digits}f}" if v.size == 1 else f"{v.mean():.{digits}f} ± {v.std(ddof=1):.{digits}f}"

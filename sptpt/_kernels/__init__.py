"""Private numba kernels: tight loops only, no validation and no defaults (see the public wrappers).

The batch kernels are serial ``nogil`` loops over an item range ``start:stop``
writing into a preallocated output; :func:`run_in_chunks` runs contiguous
ranges of a batch on threads. numba's ``parallel=True`` (``prange``) would do
the same, but its parallel lowering added about 2 s of compilation per kernel
on a fresh install (``cue_features``: 3.9 s parallel, 1.6 s serial), most of
the quick start's first run, for no speed gain on these embarrassingly
parallel batches.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor, wait

import numba

_POOL: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    # A forked child inherits the pool object but not its threads; it would wait forever on them.
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forget_pool)


def run_in_chunks(kernel, n_items: int, n_chunks: int, *args) -> None:
    """Call ``kernel(*args, start, stop)`` on ``n_chunks`` contiguous ranges of ``range(n_items)`` in parallel.

    The calling thread runs the first range and pool threads the others. The
    kernel must release the GIL for most of its work (a ``nogil=True`` numba
    kernel, or NumPy and BLAS calls on large arrays) and write only to item
    ``start:stop`` of its outputs, so the result does not depend on
    ``n_chunks``. ``n_chunks`` is clipped to ``[1, n_items]``. The first
    exception of a range is raised once every range has finished.
    """
    global _POOL
    n_chunks = max(1, min(n_chunks, n_items))
    bounds = [chunk * n_items // n_chunks for chunk in range(n_chunks + 1)]
    if n_chunks == 1:
        kernel(*args, 0, n_items)
        return
    if _POOL is None:
        # As many workers as numba would start threads; a smaller thread
        # count (numba.set_num_threads) simply uses fewer of them.
        _POOL = ThreadPoolExecutor(max_workers=max(1, numba.config.NUMBA_NUM_THREADS - 1),
                                   thread_name_prefix="sptpt-kernel")
    futures = [_POOL.submit(kernel, *args, bounds[c], bounds[c + 1]) for c in range(1, n_chunks)]
    try:
        kernel(*args, bounds[0], bounds[1])
    finally:
        # Also when the first range raised: no range may still be writing once the caller goes on.
        wait(futures)
    for future in futures:
        future.result()

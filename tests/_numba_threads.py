"""numba's thread count for the length of a block."""

from __future__ import annotations

import contextlib


@contextlib.contextmanager
def numba_threads(n: int):
    """numba's thread count set to ``n`` inside the block, and back to what it was after it."""
    import numba

    previous = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield
    finally:
        numba.set_num_threads(previous)

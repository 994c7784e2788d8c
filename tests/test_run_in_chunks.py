"""The thread pool under the batch kernels and the tracker's parallel stages."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from sptpt._kernels import run_in_chunks


def test_every_item_is_done_once_whatever_the_chunk_count() -> None:
    for n_chunks in (1, 2, 3, 7, 50):
        done = np.zeros(10, dtype=int)

        def work(start: int, stop: int) -> None:
            done[start:stop] += 1

        run_in_chunks(work, 10, n_chunks)
        np.testing.assert_array_equal(done, np.ones(10, dtype=int))


def test_an_error_in_the_first_range_is_raised_after_the_other_ranges_finished() -> None:
    finished = threading.Event()

    def work(start: int, stop: int) -> None:
        if start == 0:
            raise ValueError("first range failed")
        time.sleep(0.2)
        finished.set()

    with pytest.raises(ValueError, match="first range failed"):
        run_in_chunks(work, 2, 2)
    assert finished.is_set()  # nothing still writes once the caller sees the error


def test_an_error_in_a_pool_range_reaches_the_caller() -> None:
    def work(start: int, stop: int) -> None:
        if start > 0:
            raise RuntimeError("pool range failed")

    with pytest.raises(RuntimeError, match="pool range failed"):
        run_in_chunks(work, 2, 2)

"""Keep freed memory in the process for reuse: the tracker allocates the same large arrays every frame.

Each frame the tracker allocates and frees arrays of 2-10 MiB (templates,
superpixel labels, features, codes, scoring temporaries). glibc's malloc
serves blocks that large with fresh ``mmap`` pages, or returns the top of
its heap to the system when they are freed, so every frame paid about 600
page faults of first touch (Deer, ``paper``, 60 frames: 105,000 page faults
in all, 70,000 with this setting; 2-3 ms a frame, 3-4% of the frame). With
higher thresholds the freed blocks stay in the heap and the next frame
reuses them. The cost is that memory freed after the peak is not returned
to the system until the process ends; the tool's peak does not change.

Kept memory is kept per arena, and glibc gives each new thread an arena of
its own, up to 8 per core: the decoding loop, the follow-up thread, numba's
and OpenCV's threads each kept their own freed blocks, about 100 MiB in all
at 1920x1080. The process uses two arenas instead (issue #69: the tool's
own peak at 1080p with the overlay 530 -> 482 MiB over 150 frames, CPU time
unchanged; one arena saved 6 MiB more for more lock contention).

What the first frame frees (the dictionary's k-means, the learned tracker's
start, the kernels' first calls) is no frame's working set, and neither is
what a checkpoint frees (its pickle): :func:`release_freed_memory` hands
such memory back to the system at those points, once, not every frame.
"""

from __future__ import annotations

import ctypes
import sys

# mallopt parameters (glibc malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
# Blocks up to this size come from the heap, not from mmap: the largest value glibc accepts on 64-bit
# (4 * 1024 * 1024 * sizeof(long)), above the tracker's largest per-frame array (10 MiB).
_MMAP_THRESHOLD = 32 << 20
# Free memory at the top of the heap returned to the system only beyond this.
_TRIM_THRESHOLD = 512 << 20
# Arenas the threads share: each arena keeps its own freed blocks (module docstring). Must be set before the
# threads start, which is why this runs first thing in the tool's processes.
_ARENA_MAX = 2

_done = False


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds and cap its arenas, once per process; False where malloc is not
    glibc's.

    Called where the process is the tool's own (the command line, batch pool
    workers, the benchmark runner), not in Dask tasks, whose worker processes
    are shared and long-lived and have memory limits of their own. Only the
    first call acts.
    """
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # glibc only: musl and others have no mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _done = all(mallopt(option, value) for option, value in (
        (_M_MMAP_THRESHOLD, _MMAP_THRESHOLD), (_M_TRIM_THRESHOLD, _TRIM_THRESHOLD), (_M_ARENA_MAX, _ARENA_MAX)))
    return _done


def release_freed_memory() -> bool:
    """Return the heap's free memory to the system (glibc's ``malloc_trim``) where :func:`keep_freed_memory` holds
    it back; False, doing nothing, elsewhere.

    For points where what was freed will not be needed again soon: after the first frame and after a
    checkpoint (1080p, fused: the tool's peak 504 -> 499 MiB over 400 frames, median of 3 runs; what it holds at
    frame 150, 503 -> 490 MiB). The next frame's arrays fault their pages in again, a few milliseconds once.
    """
    if not _done:
        return False
    trim = ctypes.CDLL(None).malloc_trim
    trim.argtypes = (ctypes.c_size_t,)
    trim.restype = ctypes.c_int
    trim(0)
    return True

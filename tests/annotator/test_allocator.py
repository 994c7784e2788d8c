"""The malloc setting the tool's processes start with."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_keep_freed_memory_acts_once_and_big_blocks_then_reuse_the_heap() -> None:
    """In a fresh process: the first call sets the thresholds, later calls are no-ops, and a freed 10 MiB
    block is reused by the next one (same address) instead of being unmapped and mapped again."""
    code = """
import ctypes, numpy as np
from annotator.allocator import keep_freed_memory
ok = keep_freed_memory()
again = keep_freed_memory()
addresses = []
for _ in range(3):
    a = np.empty(10 << 20, dtype=np.uint8)
    addresses.append(a.ctypes.data)
    del a
print(ok, again, len(set(addresses)))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    if out[0] == "False":
        pytest.skip("malloc is not glibc's")
    assert out == ["True", "True", "1"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_threads_share_two_arenas() -> None:
    """Each glibc arena keeps its own freed blocks, so the threads of a tool process share two (issue #69): eight
    threads allocating at once would otherwise get an arena each. Counted from malloc_info in a fresh process."""
    code = """
import ctypes, sys, threading
import numpy as np
from annotator.allocator import keep_freed_memory
set_up = keep_freed_memory() if sys.argv[1] == "capped" else True
barrier = threading.Barrier(8)
held = []
def work():
    barrier.wait()
    held.append(np.ones(1 << 20))  # 8 MiB, from the thread's arena (below the mmap threshold when capped)
threads = [threading.Thread(target=work) for _ in range(8)]
for t in threads: t.start()
for t in threads: t.join()
libc = ctypes.CDLL(None)
libc.open_memstream.restype = ctypes.c_void_p
buffer, size = ctypes.c_char_p(), ctypes.c_size_t()
stream = libc.open_memstream(ctypes.byref(buffer), ctypes.byref(size))
libc.malloc_info(0, ctypes.c_void_p(stream))
libc.fclose(ctypes.c_void_p(stream))
print(set_up, ctypes.string_at(buffer, size.value).count(b"<heap nr="))
"""
    capped = subprocess.run([sys.executable, "-c", code, "capped"], capture_output=True, text=True,
                            check=True).stdout.split()
    if capped[0] == "False":
        pytest.skip("malloc is not glibc's")
    assert int(capped[1]) <= 2
    free = subprocess.run([sys.executable, "-c", code, "free"], capture_output=True, text=True, check=True).stdout
    assert int(free.split()[1]) > 2  # the test can tell: without the cap the threads get arenas of their own


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_release_freed_memory_returns_the_freed_heap_to_the_system() -> None:
    """With the thresholds raised, 100 MiB of freed 1 MiB blocks stay resident until release_freed_memory; without
    keep_freed_memory it does nothing and says so."""
    code = """
import numpy as np
from annotator.allocator import keep_freed_memory, release_freed_memory
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
before_setup = release_freed_memory()
ok = keep_freed_memory()
blocks = [np.ones(1 << 17) for _ in range(100)]  # 1 MiB each, touched
keep = np.ones(1 << 10)  # above them on the heap, so they are not its top
del blocks
kept = rss()
released = release_freed_memory()
print(before_setup, ok, released, round(kept - rss()))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    if out[1] == "False":
        pytest.skip("malloc is not glibc's")
    assert out[:3] == ["False", "True", "True"]
    assert int(out[3]) > 80  # MiB given back

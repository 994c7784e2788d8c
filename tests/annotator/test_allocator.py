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

"""Compiling the kernels ahead of the tracker (``sptpt.compile_kernels``): the child process fills numba's cache
with exactly what the tracker's first frames ask for, and only one child compiles into a cache at a time.

Each test points numba at an empty cache folder of its own (``NUMBA_CACHE_DIR``) in fresh processes, so it sees
a first run on a new machine whatever the suite's own cache holds.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import pytest

from sptpt._kernels import warmup

ROOT = Path(__file__).resolve().parents[1]


def python(code: str, cache: Path, timeout: float = 600) -> str:
    """Run ``code`` in a fresh interpreter whose numba cache is ``cache``; return what it printed."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr
    return done.stdout


# Tracks a textured square for a few frames with the default preset and prints every function numba compiled
# meanwhile, a throwaway function of its own included (so that an empty list cannot mean a deaf listener).
TRACK_AND_LIST_COMPILES = """
    import json
    import numba
    import numpy as np
    from numba.core import event

    compiled = []

    class Listener(event.Listener):
        def on_start(self, ev):
            function = ev.data["dispatcher"].py_func
            compiled.append(f"{function.__module__}.{function.__name__}")

        def on_end(self, ev):
            pass

    event.register("numba:compile", Listener())
    from sptpt import Tracker, preset

    rng = np.random.default_rng(0)
    background = rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)
    patch = rng.integers(0, 256, (24, 24, 3), dtype=np.uint8)
    tracker = Tracker(preset("robust"), seed=0)
    for k in range(4):
        frame = background.copy()
        frame[30:54, 40 + 2 * k:64 + 2 * k] = patch
        if k == 0:
            tracker.init(frame, (40, 30, 24, 24))
        else:
            tracker.update(frame)

    @numba.njit
    def throwaway(x):
        return x + 1

    throwaway(1)
    print(json.dumps(compiled))
"""


def test_a_background_warm_up_compiles_exactly_what_the_trackers_first_frames_compile(tmp_path):
    cache = tmp_path / "numba-cache"
    out = python("""
        from sptpt import compile_kernels
        from sptpt._kernels.warmup import kernels_cached

        print(kernels_cached())
        child = compile_kernels(wait=False)
        print(child is not None and child.wait())
        print(kernels_cached(), compile_kernels(wait=False))
    """, cache)
    assert out.split() == ["False", "0", "True", "None"]

    compiled = json.loads(python(TRACK_AND_LIST_COMPILES, cache).splitlines()[-1])
    assert "__main__.throwaway" in compiled
    assert [name for name in compiled if name.startswith("sptpt.")] == []


def test_a_warm_up_leaves_a_cache_to_the_warm_up_already_compiling_into_it(tmp_path, monkeypatch):
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(cache))  # the lock of the child's cache, not the suite's
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    with warmup._sole_warmup() as sole:
        assert sole
        with warmup._sole_warmup() as second:
            assert not second
        subprocess.run([sys.executable, "-m", "sptpt._kernels.warmup"], cwd=ROOT, env=env, check=True, timeout=300)
    assert not list(cache.rglob("*.nbi")), "the second warm-up compiled"
    with warmup._sole_warmup() as sole:
        assert sole  # released


def test_a_numba_without_the_cache_internals_reads_as_not_cached():
    assert warmup._cached(object()) is False
    assert warmup._cached(numba.njit(lambda x: x)) is False  # no cache=True: nothing on disk


@pytest.mark.parametrize("cached", [True, False])
def test_compile_kernels_does_nothing_once_the_cache_holds_every_kernel(monkeypatch, cached):
    calls = []
    monkeypatch.setattr(warmup, "kernels_cached", lambda: cached)
    monkeypatch.setattr(warmup, "_compile_all", lambda: calls.append("compiled"))
    monkeypatch.setattr(warmup, "_CHILD", None)
    assert warmup.compile_kernels(wait=True) is None
    assert calls == ([] if cached else ["compiled"])


def test_a_child_that_cannot_start_leaves_the_compiling_to_the_tracker(monkeypatch):
    def refuse(*args, **kwargs):
        raise FileNotFoundError("no interpreter")

    monkeypatch.setattr(warmup, "kernels_cached", lambda: False)
    monkeypatch.setattr(warmup, "_CHILD", None)
    monkeypatch.setattr(warmup.subprocess, "Popen", refuse)
    assert warmup.compile_kernels(wait=False) is None

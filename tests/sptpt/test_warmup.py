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
from _paths import ROOT

from sptpt._kernels import warmup


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


@pytest.fixture
def own_lock(tmp_path, monkeypatch):
    """The cache folder of a test's child processes, and its warm-up lock seen from here (removed afterwards)."""
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(cache))  # the lock of the child's cache, not the suite's
    yield cache
    warmup._lock_path().unlink(missing_ok=True)


@pytest.mark.skipif(warmup._cores() < 2, reason="the background warm-up starts only with two cores or more")
def test_a_background_warm_up_compiles_exactly_what_the_trackers_first_frames_compile(own_lock):
    cache = own_lock
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


def test_a_warm_up_leaves_a_cache_to_the_warm_up_already_compiling_into_it(own_lock):
    cache = own_lock
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
def test_compile_kernels_compiles_here_only_what_the_cache_lacks(monkeypatch, cached):
    calls = []
    monkeypatch.setattr(warmup, "kernels_cached", lambda: cached)
    monkeypatch.setattr(warmup, "_compile_all", lambda: calls.append("compiled"))
    monkeypatch.setattr(warmup, "_CHILD", None)
    assert warmup.compile_kernels(wait=True) is None
    assert calls == ([] if cached else ["compiled"])


class RunningChild:
    """A child process that still runs until waited for."""

    def __init__(self):
        self.waited = False

    def poll(self):
        return 0 if self.waited else None

    def wait(self):
        self.waited = True
        return 0


def test_waiting_compile_kernels_waits_for_a_running_child_first(monkeypatch):
    child, calls = RunningChild(), []
    monkeypatch.setattr(warmup, "_CHILD", child)
    monkeypatch.setattr(warmup, "kernels_cached", lambda: child.waited)  # the child fills the cache
    monkeypatch.setattr(warmup, "_compile_all", lambda: calls.append("compiled"))
    assert warmup.compile_kernels(wait=False) is child  # no second child
    assert warmup.compile_kernels(wait=True) is None
    assert child.waited and calls == []


@pytest.mark.parametrize("setting", ["no interpreter", "frozen", "one core", "no jit"])
def test_no_child_where_it_would_not_help(monkeypatch, setting):
    monkeypatch.setattr(warmup, "kernels_cached", lambda: False)
    monkeypatch.setattr(warmup, "_CHILD", None)
    monkeypatch.setattr(warmup, "_cores", lambda: 1 if setting == "one core" else 2)
    monkeypatch.setattr(numba.config, "DISABLE_JIT", setting == "no jit")
    if setting == "no interpreter":
        monkeypatch.setattr(sys, "executable", None)
    if setting == "frozen":
        monkeypatch.setattr(sys, "frozen", True, raising=False)
    started = []
    monkeypatch.setattr(warmup.subprocess, "Popen", lambda *a, **k: started.append(a))
    assert warmup.compile_kernels(wait=False) is None
    assert started == []


def test_the_child_imports_this_processs_copy_of_the_package_wherever_it_starts(tmp_path):
    decoy = tmp_path / "sptpt"
    decoy.mkdir()
    (decoy / "__init__.py").write_text("")  # a folder of that name where the child starts (python -c puts it first)
    command = warmup._child_command()
    assert command[:2] == [sys.executable, "-c"]
    run_main = "from sptpt._kernels.warmup import main; sys.exit(main())"
    code = command[2].replace(run_main, "import sptpt; print(sptpt.__file__)")
    assert code != command[2]
    done = subprocess.run([command[0], "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    import sptpt

    assert Path(done.stdout.strip()) == Path(sptpt.__file__)


def test_the_warm_up_compiles_the_kernels_in_the_reverse_of_the_trackers_order(monkeypatch):
    import sptpt.affine
    import sptpt.coding
    import sptpt.features
    import sptpt.gradients
    import sptpt.superpixels

    calls = []
    for module, name, kernel in [(sptpt.gradients, "orientation_channels", "translation features"),
                                 (sptpt.gradients, "cell_histograms", "scale features"),
                                 (sptpt.coding, "encode_tensors", "lasso"),
                                 (sptpt.features, "superpixel_features", "cue features"),
                                 (sptpt.superpixels, "snic", "snic"),
                                 (sptpt.affine, "warp_candidates", "warp")]:
        monkeypatch.setattr(module, name, lambda *a, _kernel=kernel, **k: calls.append(_kernel))
    warmup._compile_all()
    assert calls == ["translation features", "scale features", "lasso", "cue features", "snic", "warp"]
    order = [d.py_func.__name__ for d in warmup._dispatchers()]
    assert order == ["_warp_range", "new_lab_memo", "_grow_range_rgb", "_cue_features_range", "_lasso_range",
                     "cell_histograms", "orientation_channels"]


def test_a_child_that_cannot_start_leaves_the_compiling_to_the_tracker(monkeypatch):
    def refuse(*args, **kwargs):
        raise FileNotFoundError("no interpreter")

    monkeypatch.setattr(warmup, "kernels_cached", lambda: False)
    monkeypatch.setattr(warmup, "_cores", lambda: 2)
    monkeypatch.setattr(warmup, "_CHILD", None)
    monkeypatch.setattr(warmup.subprocess, "Popen", refuse)
    assert warmup.compile_kernels(wait=False) is None

"""The kernels compiled into numba's on-disk cache before the tracker needs them, on a core of their own.

numba compiles a kernel on its first call and keeps the machine code in its cache, so only the first run on a
machine pays for it: about 18 s on a 2-core VM, measured when it was half of the README's first run. The
tracker's first frame compiles its kernels one after another (warp, SNIC, cue features, the LASSO, then the
filters' orientation kernels), on one core: numba's compiler
lock keeps a second thread of the same process from compiling beside it. A child process has a lock of its own.
:func:`compile_kernels` with ``wait=False`` starts one that compiles them in the opposite order, the LASSO first,
while the tracker compiles from the other end; when the tracker reaches a kernel the child has finished, numba
loads it from the cache. numba writes each cache file under a temporary name and renames it, and a tracker that
finds an index entry whose machine code is not written yet compiles the kernel itself. Where the two meet, both
may compile the same kernel: the result is the same, only that kernel's seconds are not saved.

The kernels are called through the public wrappers on tiny inputs of the dtypes and layouts the tracker passes,
so they compile exactly the signatures its first frame asks for (``tests/sptpt/test_warmup.py`` runs the tracker after
a warm-up and checks that it compiles nothing).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numba
import numpy as np

__all__ = ["compile_kernels", "kernels_cached"]

#: numba's settings (``numba.config``), read when used: numba sets them at import time, from the environment,
#: so they are invisible to the type checker.
_NUMBA_CONFIG: Any = numba.config


def _dispatchers() -> list:
    """The tracker's cached kernels, in the order of its first frame."""
    from sptpt._kernels import color, histograms, lasso, orientations, snic, warp

    return [warp._warp_range, color.new_lab_memo, snic._grow_range_rgb, histograms._cue_features_range,
            lasso._lasso_range, orientations.cell_histograms, orientations.orientation_channels]


def _cached(dispatcher) -> bool:
    """Whether numba's cache holds ``dispatcher`` compiled for this numba, this source file and this CPU.

    numba has no public query for it; this reads the cache index as numba's own loader does (an index written
    by another numba version or for another state of the source file reads as empty) and looks for an entry
    built for this CPU. It does not match the argument types, so an entry of other types alone reads as cached:
    the tracker then compiles on its own, as without a warm-up. Should a later numba rename these internals, the
    answer is False: a warm-up then starts when it need not, which costs a child's start-up, not a wrong result.
    """
    try:
        index = dispatcher._cache._cache_file._load_index()
        machine = dispatcher.targetctx.codegen().magic_tuple()
        return any(key[1] == machine for key in index)
    except Exception:  # noqa: BLE001 - any change of numba's internals reads as "not cached"
        return False


def kernels_cached() -> bool:
    """Whether every kernel the tracker's first frame calls is already in numba's on-disk cache.

    Returns
    -------
    bool
        True when a tracker's first frame will load every kernel instead of compiling one.
    """
    return all(_cached(dispatcher) for dispatcher in _dispatchers())


def _compile_all() -> None:
    """Call each kernel once, the tracker's last one first (see the module docstring)."""
    from sptpt.affine import warp_candidates
    from sptpt.coding import encode_tensors
    from sptpt.features import superpixel_features
    from sptpt.gradients import cell_histograms, orientation_channels
    from sptpt.params import get_preset
    from sptpt.scale import BINS, CELL
    from sptpt.superpixels import snic
    from sptpt.translation import BINS as TRANSLATION_BINS

    params = get_preset("robust")
    size, n_bins = params.template_size, params.n_bins
    rng = np.random.default_rng(0)
    templates = rng.integers(0, 256, (2, size, size, 3), dtype=np.uint8)
    grey = rng.random((2, size, size))
    orientation_channels(grey[0], TRANSLATION_BINS)  # the translation filter's features, after the scale filter's
    cell_histograms(grey, BINS, CELL)
    n_features = 8 * n_bins
    dictionary = np.abs(rng.standard_normal((n_features, params.n_atoms)))
    encode_tensors(np.abs(rng.standard_normal((2, 4, n_features))), dictionary, lam=params.lasso_lambda)
    labels = np.repeat(np.arange(4, dtype=np.int32), size * size // 4).reshape(1, size, size).repeat(2, axis=0)
    superpixel_features(templates, labels, 4, n_bins=n_bins)
    snic(templates, n_segments=params.n_superpixels, compactness=params.compactness, seeding=params.seeding)
    frame = rng.integers(0, 256, (2 * size, 2 * size, 3), dtype=np.uint8)
    states = np.array([[size, size, 1.0, 0.0, 1.0, 0.0]] * 2)
    warp_candidates(frame, states, size)


# The child this process started; a daemon thread waits for it, so that it is reaped when it ends.
_CHILD: subprocess.Popen | None = None


def _lock_path() -> Path:
    """One lock file per cache: this copy of the package, numba's version and its cache folder setting."""
    key = f"{Path(__file__).resolve()}|{numba.__version__}|{sys.version}|{_NUMBA_CONFIG.CACHE_DIR}"
    digest = hashlib.sha1(key.encode()).hexdigest()[:16]
    return Path(tempfile.gettempdir()) / f"sptpt-warmup-{os.getuid() if hasattr(os, 'getuid') else 0}-{digest}.lock"


@contextlib.contextmanager
def _sole_warmup():
    """Yield True if no other warm-up of this cache is running (and hold that until the block ends), else False.

    Batch workers each start one on their first video; the second would compile the same kernels on a core
    the workers need. Where there is no ``fcntl`` (Windows), every warm-up runs.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield True
        return
    # O_NOFOLLOW: in a shared temporary folder, never open a file another user's symlink points to.
    descriptor = os.open(_lock_path(), os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o600)
    with open(descriptor, "r+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def _child_command() -> list[str] | None:
    """The command of a child that imports what this process imports: this ``sys.path``, as multiprocessing's
    spawn passes it, not the current folder or ``PYTHONPATH`` first. None where no interpreter can be started:
    ``sys.executable`` unknown, or a frozen program, whose executable is the program itself."""
    if not sys.executable or getattr(sys, "frozen", False):
        return None
    code = f"import sys; sys.path[:] = {sys.path!r}; from sptpt._kernels.warmup import main; sys.exit(main())"
    return [sys.executable, "-c", code]


def compile_kernels(*, wait: bool = True) -> subprocess.Popen | None:
    """Compile the tracker's kernels into numba's on-disk cache, unless they are there already.

    Parameters
    ----------
    wait : bool
        True: compile them here (after a child this process started has ended). False: start a child process
        that compiles them, the ones the tracker needs last first, and return at once: a tracker started next
        compiles from the other end and loads what the child has finished.

    Returns
    -------
    subprocess.Popen or None
        The child, with ``wait=False``; it ends by itself and may go on compiling after a short run has ended.
        None with ``wait=True``, and where a child would not help: every kernel cached, one core, numba's JIT
        disabled, or no interpreter to start. While a child this process started still runs, that child.
    """
    global _CHILD
    running = _CHILD is not None and _CHILD.poll() is None
    if wait:
        if running:
            assert _CHILD is not None  # running: it was started and has not ended
            _CHILD.wait()
        if not kernels_cached():
            _compile_all()
        return None
    if running:
        return _CHILD
    if _NUMBA_CONFIG.DISABLE_JIT or _cores() < 2 or kernels_cached():
        return None
    command = _child_command()
    if command is None:
        return None
    env = dict(os.environ)
    if _NUMBA_CONFIG.CACHE_DIR:  # also when set in code, not in the environment
        env["NUMBA_CACHE_DIR"] = _NUMBA_CONFIG.CACHE_DIR
    try:
        _CHILD = subprocess.Popen(command, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
    except OSError:  # the interpreter cannot be started: the tracker compiles everything, as without
        return None
    threading.Thread(target=_CHILD.wait, name="sptpt-warmup-reaper", daemon=True).start()
    return _CHILD


def main() -> int:
    """The child of ``compile_kernels(wait=False)``."""
    # A batch worker ignores SIGINT (its parent handles it); its child should stop on Ctrl-C like a run.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    with _sole_warmup() as sole:
        if sole and not kernels_cached():
            _compile_all()
    return 0


if __name__ == "__main__":
    sys.exit(main())

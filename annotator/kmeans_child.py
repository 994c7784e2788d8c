"""The trackers' dictionary k-means, run in a child process.

Each SPTPT run learns its dictionary once, on its first frame, with scikit-learn's KMeans. Importing
scikit-learn (and the parts of scipy it loads) costs the importing process about 90 MiB resident for the rest of
its life, a quarter of the tool's memory at 320x240 and still a sixth of it at 1080p, for a few milliseconds of
work. So the tool runs that k-means here instead: a child process started at the first dictionary, which imports
numpy and scikit-learn and nothing of the tool, and which stops after a few idle seconds. It calls
:func:`sptpt.kmeans_centroids`, the very function a tracker calls in its own process, under the same
one-thread BLAS limit, so the centroids, and so every box, are the same to the bit (tested).

If the child cannot be started or dies, the k-means runs in this process: the same result, only the memory is
not saved.
"""

from __future__ import annotations

import atexit
import os
import pickle
import subprocess
import sys
import threading
from typing import IO

import numpy as np

from sptpt import kmeans_centroids

# A child that has had no work for this long stops. A run closes it as soon as its trackers have started, before
# the frames' memory grows; a re-track starts a tracker at each human box, a few frames apart, and keeps it that
# long after the last one.
IDLE_SECONDS = 5.0


class KMeansChild:
    """``sptpt``'s ``KMeansFunction`` (``Tracker(kmeans=...)``), computed in a child process.

    Thread-safe: requests are served one at a time. The child starts at the first call and stops after
    ``idle_seconds`` without one, at :meth:`close`, or when this process exits (it reads end-of-file). Once a child
    has failed (it could not start, died, or answered with an error), every later call computes here.
    """

    def __init__(self, idle_seconds: float = IDLE_SECONDS) -> None:
        self.idle_seconds = idle_seconds
        self._lock = threading.Lock()
        self._child: subprocess.Popen | None = None
        self._idle_timer: threading.Timer | None = None
        self._failed = False
        self.children_started = 0  # child processes started so far

    def __call__(self, features: np.ndarray, n_clusters: int, n_init: int, seed: int) -> np.ndarray:
        with self._lock:
            centroids = None if self._failed else self._ask_child(features, n_clusters, n_init, seed)
        if centroids is None:  # the same function here: the same centroids, or the error it raises
            return kmeans_centroids(features, n_clusters, n_init, seed)
        return centroids

    @property
    def running(self) -> bool:
        """Whether a child process is up now."""
        return self._child is not None

    def close(self) -> None:
        """Stop the child now (the next call starts another)."""
        with self._lock:
            self._stop()

    def forget(self) -> None:
        """In a forked child: the parent's child process and timer are the parent's; this process starts its own."""
        self._lock = threading.Lock()
        self._child, self._idle_timer = None, None

    def __reduce__(self) -> str | tuple:
        # A copied or checkpointed tracker keeps the shared one (no process or lock is copied); another starts
        # afresh, with nothing running.
        return "DICTIONARY_KMEANS" if self is DICTIONARY_KMEANS else (KMeansChild, (self.idle_seconds,))

    def _ask_child(self, features: np.ndarray, n_clusters: int, n_init: int, seed: int) -> np.ndarray | None:
        """The child's centroids, or None (and no child) where it failed; under the lock."""
        if self._idle_timer is not None:
            self._idle_timer.cancel()
            self._idle_timer = None
        try:
            if self._child is None:
                command = _child_command()
                if command is None:
                    raise OSError("no interpreter to start")
                self._child = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                self.children_started += 1
            stdin, stdout = self._child.stdin, self._child.stdout
            assert stdin is not None and stdout is not None
            pickle.dump((np.ascontiguousarray(features), n_clusters, n_init, seed), stdin,
                        protocol=pickle.HIGHEST_PROTOCOL)
            stdin.flush()
            kind, value = pickle.load(stdout)
            if kind != "centroids":
                raise ValueError(value)
        except Exception:
            self._failed = True
            self._stop()
            return None
        except BaseException:  # interrupted mid-exchange: a reply may be left unread, so this child is done
            self._stop()
            raise
        timer = threading.Timer(self.idle_seconds, lambda: self._close_if_idle(timer))
        timer.daemon = True
        self._idle_timer = timer
        timer.start()
        return value

    def _close_if_idle(self, timer: threading.Timer) -> None:
        with self._lock:
            if self._idle_timer is timer:  # not a timer a later call has replaced
                self._stop()

    def _stop(self) -> None:
        if self._idle_timer is not None:
            self._idle_timer.cancel()
            self._idle_timer = None
        child, self._child = self._child, None
        if child is not None:
            for stream in (child.stdin, child.stdout):
                if stream is not None:
                    stream.close()  # the child reads end-of-file and exits
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()


def _child_command() -> list[str] | None:
    """The child's command: this ``sys.path`` (so it imports the scikit-learn and numpy this process would), its
    replies on a descriptor of their own and anything a library prints sent to stderr, Ctrl-C ignored (the
    parent decides when to stop; the child ends when the parent closes the pipe). None where no interpreter can be
    started: ``sys.executable`` unknown, or a frozen program, whose executable is the program itself."""
    if not sys.executable or getattr(sys, "frozen", False):
        return None
    code = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_IGN); "
            "replies = os.fdopen(os.dup(1), 'wb'); os.dup2(2, 1); "
            f"sys.path[:] = {sys.path!r}; "
            "from annotator.kmeans_child import serve; serve(sys.stdin.buffer, replies)")
    return [sys.executable, "-c", code]


#: The one the tool's trackers share.
DICTIONARY_KMEANS = KMeansChild()
os.register_at_fork(after_in_child=DICTIONARY_KMEANS.forget)
atexit.register(DICTIONARY_KMEANS.close)


def serve(requests: IO[bytes], replies: IO[bytes]) -> None:
    """The child's loop: a request is ``(features, n_clusters, n_init, seed)``, a reply ``("centroids", array)``
    or ``("error", text)``; end-of-file (or a parent gone) ends it."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # as the tracker holds it around its runs' first frame
        while True:
            try:
                features, n_clusters, n_init, seed = pickle.load(requests)
            except EOFError:
                return
            try:
                reply: tuple = ("centroids", kmeans_centroids(features, n_clusters, n_init, seed))
            except Exception as error:  # the parent computes it itself, and so raises it there
                reply = ("error", f"{type(error).__name__}: {error}")
            try:
                pickle.dump(reply, replies, protocol=pickle.HIGHEST_PROTOCOL)
                replies.flush()
            except BrokenPipeError:
                return

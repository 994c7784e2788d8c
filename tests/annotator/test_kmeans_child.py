"""The dictionary's k-means in a child process (annotator.kmeans_child): the same centroids and boxes to the bit as
in the tracking process, scikit-learn never imported there, and the child gone when idle."""

from __future__ import annotations

import copy
import json
import pickle
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from _tracker_clips import growing_clip

from annotator.kmeans_child import DICTIONARY_KMEANS, KMeansChild
from sptpt import kmeans_centroids


def histogram_rows(n: int, width: int, seed: int) -> np.ndarray:
    """Rows like the superpixel features: non-negative, L2-normalised, many near-duplicates."""
    rng = np.random.default_rng(seed)
    rows = rng.gamma(0.3, size=(n, width)) * (rng.random((n, width)) < 0.4)
    rows[n // 2:] = rows[: n - n // 2] + rng.normal(0, 1e-3, (n - n // 2, width)).clip(0)
    return rows / np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-12)


@pytest.fixture(scope="module")
def child():
    kmeans = KMeansChild(idle_seconds=600)
    yield kmeans
    kmeans.close()


CASES = [(450, 40, 50, 1, 3), (900, 72, 50, 1, 11), (300, 24, 20, 3, 2**31 - 2), (60, 8, 60, 1, 5)]


def fresh_process(script: str, given: bytes = b"") -> subprocess.CompletedProcess:
    """``script`` run by a new interpreter with this process's environment.

    The references are computed there, not here: scikit-learn's OpenMP threads are fixed when a process first
    loads it, from the environment of that moment, and a test here may since have changed the environment (Dask's
    nanny sets OMP_NUM_THREADS=1 in the process that starts its workers). A child started now reads the
    environment of now, as a process started now does; the k-means of 450 rows or more depends on that thread
    count.
    """
    done = subprocess.run([sys.executable, "-c", script], input=given, capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    return done


def request(case: int) -> tuple[np.ndarray, int, int, int]:
    n, width, n_clusters, n_init, seed = CASES[case]
    features = histogram_rows(n, width, seed % 1000)
    return features, min(n_clusters, np.unique(features, axis=0).shape[0]), n_init, seed


@pytest.fixture(scope="module")
def references() -> list[np.ndarray]:
    """Each case's centroids from :func:`kmeans_centroids` called in a new process, BLAS on one thread as the
    tracker calls it."""
    script = """
import pickle, sys
from threadpoolctl import threadpool_limits
from sptpt import kmeans_centroids
with threadpool_limits(limits=1, user_api="blas"):
    out = [kmeans_centroids(*request) for request in pickle.load(sys.stdin.buffer)]
sys.stdout.buffer.write(pickle.dumps(out))
"""
    return pickle.loads(fresh_process(script, pickle.dumps([request(case) for case in range(len(CASES))])).stdout)


@pytest.mark.parametrize("case", range(len(CASES)))
def test_the_childs_centroids_equal_the_function_to_the_bit(child, references, case):
    there = child(*request(case))
    assert child.running and child.children_started == 1  # from the child, not from the fallback here
    assert there.dtype == np.float64 and there.shape == references[case].shape
    assert np.array_equal(there, references[case])


def test_one_child_serves_every_request_until_idle():
    kmeans = KMeansChild(idle_seconds=0.5)
    features = histogram_rows(200, 16, 0)
    for seed in range(3):
        kmeans(features, 10, 1, seed)
    assert kmeans.children_started == 1
    process = kmeans._child
    assert process is not None and process.poll() is None
    deadline = time.monotonic() + 20
    while kmeans.running and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not kmeans.running
    assert process.wait(timeout=10) == 0  # it read end-of-file and ended by itself
    kmeans(features, 10, 1, 0)
    assert kmeans.children_started == 2
    kmeans.close()


def test_a_child_that_cannot_start_leaves_the_work_to_this_process(monkeypatch):
    kmeans = KMeansChild()
    monkeypatch.setattr(sys, "executable", "/nonexistent/python")
    features = histogram_rows(200, 16, 1)
    assert np.array_equal(kmeans(features, 10, 1, 7), kmeans_centroids(features, 10, 1, 7))
    assert not kmeans.running


def test_after_a_child_dies_the_work_is_done_here():
    kmeans = KMeansChild()
    features = histogram_rows(200, 16, 2)
    kmeans(features, 10, 1, 1)
    assert kmeans._child is not None
    kmeans._child.kill()
    kmeans._child.wait()
    for seed in (9, 10):
        assert np.array_equal(kmeans(features, 10, 1, seed), kmeans_centroids(features, 10, 1, seed))
    assert kmeans.children_started == 1 and not kmeans.running  # no child started again and again


def test_the_childs_error_is_raised_here_and_no_child_is_left():
    kmeans = KMeansChild()
    features = histogram_rows(20, 8, 4)
    with pytest.raises(ValueError, match="n_samples=20 should be >= n_clusters=30"):
        kmeans(features, 30, 1, 0)  # scikit-learn's own error, raised by the same call here
    assert kmeans.children_started == 1 and not kmeans.running


def test_an_exchange_interrupted_leaves_no_reply_for_the_next_call(monkeypatch):
    kmeans = KMeansChild()
    features = histogram_rows(200, 16, 5)
    kmeans(features, 10, 1, 1)
    real_load = pickle.load

    def interrupted(stream):
        raise KeyboardInterrupt  # after the request went out, before its reply was read

    monkeypatch.setattr(pickle, "load", interrupted)
    with pytest.raises(KeyboardInterrupt):
        kmeans(features, 10, 1, 2)
    monkeypatch.setattr(pickle, "load", real_load)
    assert not kmeans.running
    assert np.array_equal(kmeans(features, 10, 1, 3), kmeans_centroids(features, 10, 1, 3))
    assert kmeans.children_started == 2
    kmeans.close()


def test_an_old_idle_timer_does_not_stop_the_child_of_a_later_call():
    kmeans = KMeansChild(idle_seconds=600)
    features = histogram_rows(200, 16, 6)
    kmeans(features, 10, 1, 1)
    old = kmeans._idle_timer
    kmeans(features, 10, 1, 2)
    kmeans._close_if_idle(old)  # as a timer that fired while the second call held the lock
    assert kmeans.running
    kmeans.close()


def test_copies_and_checkpoints_keep_the_shared_child_and_copy_no_process(child):
    assert copy.deepcopy(DICTIONARY_KMEANS) is DICTIONARY_KMEANS
    assert pickle.loads(pickle.dumps(DICTIONARY_KMEANS)) is DICTIONARY_KMEANS
    child(histogram_rows(100, 8, 3), 5, 1, 0)  # running
    other = pickle.loads(pickle.dumps(child))
    assert other is not child and not other.running


def test_a_run_of_the_tool_never_imports_scikit_learn_and_gives_the_boxes_of_one_that_does(tmp_path: Path):
    frames, boxes = growing_clip(n_frames=8)
    folder = tmp_path / "clip"
    folder.mkdir()
    for k, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"{k + 1:04d}.png"), cv2.cvtColor(frame.astype(np.uint8), cv2.COLOR_RGB2BGR))
    x, y, w, h = (float(v) for v in boxes[0])
    script = f"""
import json, sys
import numpy as np
from annotator import NanoTrackGuide, annotate, open_frames, resolve_config, seed_for_track
from annotator.kmeans_child import DICTIONARY_KMEANS
from sptpt import Tracker, preset
DICTIONARY_KMEANS.idle_seconds = 600  # not running after the run: closed by the run, not by the idle timer
config = resolve_config(preset="fused")
result = annotate({str(folder)!r}, [{x}, {y}, {w}, {h}], config, out_dir={str(tmp_path / "out")!r},
                  show_progress=False)
seen = {{"exit": result.exit_code, "sklearn": "sklearn" in sys.modules, "children": DICTIONARY_KMEANS.children_started,
        "running": DICTIONARY_KMEANS.running}}
tool = result.store.track(1).boxes_xywh
frames = [frame for _, frame in open_frames({str(folder)!r})]

def track(params, seed, **options):
    tracker = Tracker(params, seed=seed, **options)
    out = [tracker.init(frames[0], [{x}, {y}, {w}, {h}]).box_xywh]
    return np.array(out + [tracker.update(frame).box_xywh for frame in frames[1:]])

here = track(config.tracker, seed_for_track(config.seed, 1), guide=NanoTrackGuide())  # k-means in this process
seen["fused_equal"] = bool(np.array_equal(tool, here))
seen["robust_equal"] = bool(np.array_equal(track(preset("robust"), 5, kmeans=DICTIONARY_KMEANS),
                                           track(preset("robust"), 5)))
print(json.dumps(seen))
"""
    seen = json.loads(fresh_process(script).stdout.decode().strip().splitlines()[-1])
    assert seen == {"exit": 0, "sklearn": False, "children": 1, "running": False, "fused_equal": True,
                    "robust_equal": True}

"""passes.npz: the tracker passes a run keeps for its next re-track."""

from __future__ import annotations

import numpy as np
import pytest

from annotator.failure import SIGNALS
from annotator.pass_cache import (
    CachedPass,
    PassResult,
    keep_anchored,
    pass_fingerprint,
    pass_key,
    read_pass_cache,
    write_pass_cache,
)
from annotator.tracks import TrackResult

FINGERPRINT_ARGS = ({"preset": "robust", "seed": 0}, "sha256:abc", {"start": 0, "stop": 9, "step": 1})
FINGERPRINT = pass_fingerprint(*FINGERPRINT_ARGS)


def _pass(n: int, seed: int) -> CachedPass:
    rng = np.random.default_rng(seed)
    signals = rng.normal(size=(n, len(SIGNALS)))
    signals[:1, 1] = np.nan  # a signal not measured
    rows = PassResult(rng.normal(size=(n, 4)) * 50, rng.random(n), rng.normal(size=n), rng.random(n) > 0.5,
                      np.array(["bootstrap", "subspace", "init"] * n, dtype=object)[:n], rng.random(n), signals)
    return CachedPass(rows, float(rng.normal()), float(rng.random()))


def _same(a: CachedPass, b: CachedPass) -> None:
    for field in ("boxes_xywh", "confidence", "log_likelihood", "accepted", "seconds", "signals"):
        np.testing.assert_array_equal(getattr(a.rows, field), getattr(b.rows, field), err_msg=field)
    assert list(a.rows.scoring) == list(b.rows.scoring) and b.rows.scoring.dtype == object
    assert (a.init_log_likelihood, a.init_seconds) == (b.init_log_likelihood, b.init_seconds)


def test_round_trip_is_exact(tmp_path):
    cache = {pass_key(1, 0, 0, (10.5, 20.25, 30, 40)): _pass(7, 0), pass_key(2, 5, 1, (1 / 3, 2, 3, 4)): _pass(3, 1),
             pass_key(1, 4, 1, (0, 0, 1, 1)): _pass(0, 2)}
    path = write_pass_cache(tmp_path / "passes.npz", cache, FINGERPRINT)
    back = read_pass_cache(path, FINGERPRINT)
    assert list(back) == list(cache)
    for key in cache:
        _same(cache[key], back[key])


def test_a_foreign_damaged_or_missing_file_is_an_empty_cache(tmp_path):
    path = write_pass_cache(tmp_path / "passes.npz", {pass_key(1, 0, 0, (1, 2, 3, 4)): _pass(4, 0)}, FINGERPRINT)
    other = pass_fingerprint({"preset": "robust", "seed": 1}, "sha256:abc", {"start": 0, "stop": 9, "step": 1})
    assert other != FINGERPRINT and read_pass_cache(path, other) == {}
    assert len(read_pass_cache(path, FINGERPRINT)) == 1
    path.write_bytes(path.read_bytes()[:100])
    assert read_pass_cache(path, FINGERPRINT) == {}
    assert read_pass_cache(tmp_path / "none.npz", FINGERPRINT) == {}


def test_the_fingerprint_follows_config_input_and_range():
    base = ({"preset": "robust", "seed": 0}, "sha256:abc", {"start": 0, "stop": 9, "step": 1})
    changed = [({"preset": "paper", "seed": 0}, *base[1:]), (base[0], "sha256:abd", base[2]),
               (*base[:2], {"start": 0, "stop": 9, "step": 2})]
    assert len({pass_fingerprint(*base), *(pass_fingerprint(*c) for c in changed)}) == 4
    assert pass_fingerprint(*base) == FINGERPRINT


def test_only_passes_from_current_anchors_are_kept():
    n = 6
    keyframe = np.zeros(n, bool)
    keyframe[[0, 3]] = True
    boxes = np.tile([10.0, 10, 5, 5], (n, 1))
    boxes[3] = [12.5, 11, 5, 5]
    track = TrackResult(track_id=1, label="object", frame_indices=np.arange(n), boxes_xywh=boxes,
                        confidence=np.ones(n), log_likelihood=np.zeros(n), accepted=np.ones(n, bool),
                        flagged=np.zeros(n, bool), reasons=("",) * n, keyframe=keyframe, outside=np.zeros(n, bool),
                        seconds=np.zeros(n))
    cache = {pass_key(1, 0, 0, boxes[0]): _pass(2, 0),  # from the first frame: kept
             pass_key(1, 3, 1, boxes[3]): _pass(2, 1),  # from the correction: kept
             pass_key(1, 3, 0, (12, 11, 5, 5)): _pass(2, 2),  # from the box the correction had before: gone
             pass_key(1, 2, 0, boxes[2]): _pass(2, 3),  # from a frame that is no anchor: gone
             pass_key(2, 0, 0, boxes[0]): _pass(2, 4)}  # another track: gone
    assert list(keep_anchored(cache, [track])) == [pass_key(1, 0, 0, boxes[0]), pass_key(1, 3, 1, boxes[3])]


def test_kept_passes_are_cut_to_their_segments():
    """Anchors at 0, 4 (a box) and 7 (an absence) of 10 rows: a pass needs no row past the next anchor."""
    n = 10
    keyframe = np.isin(np.arange(n), [0, 4, 7])
    outside = np.arange(n) == 7
    boxes = np.tile([10.0, 10, 5, 5], (n, 1))
    track = TrackResult(track_id=1, label="object", frame_indices=np.arange(n), boxes_xywh=boxes,
                        confidence=np.ones(n), log_likelihood=np.zeros(n), accepted=np.ones(n, bool),
                        flagged=outside.copy(), reasons=tuple("outside" if o else "" for o in outside),
                        keyframe=keyframe, outside=outside, seconds=np.zeros(n))
    long = _pass(9, 0)
    cache = {pass_key(1, 0, 0, boxes[0]): long, pass_key(1, 4, 1, boxes[4]): _pass(2, 1),
             pass_key(1, 4, 0, boxes[4]): _pass(5, 2)}
    kept = keep_anchored(cache, [track])
    assert {k[:3]: len(v.rows.confidence) for k, v in kept.items()} == {(1, 0, 0): 3, (1, 4, 1): 2, (1, 4, 0): 2}
    np.testing.assert_array_equal(kept[pass_key(1, 0, 0, boxes[0])].rows.boxes_xywh, long.rows.boxes_xywh[:3])
    assert list(kept[pass_key(1, 0, 0, boxes[0])].rows.scoring) == list(long.rows.scoring[:3])


def test_the_fingerprint_follows_the_code(monkeypatch):
    """A change of the tracker's sources, or of a library under it, gives other rows: the kept passes go."""
    from pathlib import Path

    import annotator.pass_cache as pass_cache

    base = pass_fingerprint(*FINGERPRINT_ARGS)
    real = Path.read_bytes

    def edited(path):
        data = real(path)
        return data + b"# edited" if path.name == "tracker.py" and path.parent.name == "sptpt" else data

    pass_cache.code_identity.cache_clear()
    try:
        monkeypatch.setattr(Path, "read_bytes", edited)
        assert pass_fingerprint(*FINGERPRINT_ARGS) != base
        monkeypatch.undo()
        pass_cache.code_identity.cache_clear()
        assert pass_fingerprint(*FINGERPRINT_ARGS) == base
        monkeypatch.setattr(np, "__version__", "0.0.1")
        pass_cache.code_identity.cache_clear()
        assert pass_fingerprint(*FINGERPRINT_ARGS) != base
    finally:
        monkeypatch.undo()
        pass_cache.code_identity.cache_clear()


@pytest.mark.parametrize("n", [1, 2])
def test_first_pass_of_a_short_track(n):
    from annotator.pass_cache import first_pass

    track = TrackResult(track_id=3, label="object", frame_indices=np.arange(n),
                        boxes_xywh=np.tile([1.0, 2, 3, 4], (n, 1)), confidence=np.full(n, 0.4),
                        log_likelihood=np.arange(n, dtype=float), accepted=np.ones(n, bool),
                        flagged=np.zeros(n, bool), reasons=("",) * n, keyframe=np.arange(n) == 0,
                        outside=np.zeros(n, bool), seconds=np.full(n, 0.5),
                        signals={name: np.full(n, 0.25) for name in SIGNALS})
    key, cached = first_pass(track, np.full(n, 0.9))
    assert key == (3, 0, 0, (1.0, 2.0, 3.0, 4.0))
    assert len(cached.rows.confidence) == n - 1 and cached.rows.signals.shape == (n - 1, len(SIGNALS))
    assert np.all(cached.rows.confidence == 0.9) and cached.init_log_likelihood == 0.0

"""benchmarks/review_rounds.py: its helpers (the rounds themselves take minutes and run as a benchmark)."""

from __future__ import annotations

import numpy as np
from _benchmark_scripts import load_script

from annotator.corrections import read_corrections

review_rounds = load_script("review_rounds")


def test_the_corrections_it_writes_read_back_as_one_box(tmp_path):
    path = review_rounds.fix(tmp_path, 300)
    (correction,) = read_corrections(path)
    assert (correction.frame, correction.box_xywh) == (300, tuple(float(v) for v in review_rounds.BOX))


def test_track_stores_compare_all_but_timings(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    arrays = {"header": np.asarray("{}"), "t1.box_xywh": np.array([[1.0, 2, 3, np.nan]]), "t1.seconds": np.array([0.1])}
    np.savez(a / "tracks.npz", **arrays)
    np.savez(b / "tracks.npz", **{**arrays, "t1.seconds": np.array([0.2])})
    assert review_rounds.same_store(a, b)
    np.savez(b / "tracks.npz", **{**arrays, "t1.box_xywh": np.array([[1.0, 2, 3, 4]])})
    assert not review_rounds.same_store(a, b)

"""benchmarks/forward_backward.py: where the backward pass starts, and which frames it may replace."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from _benchmark_scripts import load_script, run_benchmark


def _module():
    return load_script("forward_backward")


def test_the_end_anchor_closes_the_last_run_of_accepted_frames():
    fb = _module()
    accepted = np.array([True, True, True, False, True, True, True, False, True])
    assert fb.end_anchor(accepted, stable=3) == 6
    assert fb.end_anchor(accepted, stable=2) == 6
    assert fb.end_anchor(accepted, stable=1) == 8
    # Frame 0 is the human box, not the tracker's claim: it never counts.
    assert fb.end_anchor(np.array([True, True, False]), stable=2) is None


def test_only_frames_strictly_between_the_first_frame_and_the_anchor_are_merged():
    fb = _module()
    n, anchor = 8, 5
    run = {f"fwd_{k}": v for k, v in _pass(n, box=10.0, confidence=0.2).items()}
    run.update({f"bwd_{k}": v for k, v in _pass(anchor + 1, box=20.0, confidence=0.9).items()})
    run["anchor"] = np.array(anchor)
    boxes = fb.merged_boxes(run, "confidence")
    assert boxes[:, 0].tolist() == [10, 20, 20, 20, 20, 10, 10, 10]
    run["anchor"] = np.array(-1)
    assert (fb.merged_boxes(run, "confidence") == 10).all()


def _pass(n: int, *, box: float, confidence: float) -> dict:
    return dict(boxes_xywh=np.full((n, 4), box), confidence=np.full(n, confidence), log_likelihood=np.zeros(n),
                accepted=np.ones(n, bool), scoring=np.array(["subspace"] * n, dtype=object), seconds=np.zeros(n))


def _otb_root(tmp_path: Path) -> Path:
    """Two sequences in OTB layout; the script only lists them before it refuses."""
    for name in ("Alpha", "Beta"):
        (tmp_path / "otb" / name).mkdir(parents=True)
        (tmp_path / "otb" / name / "groundtruth_rect.txt").write_text("1,1,4,4\n")
    return tmp_path / "otb"


def _refusal(*args: str) -> tuple[int, str]:
    done = run_benchmark("forward_backward", *args)
    return done.returncode, done.stderr.strip().splitlines()[-1]


def test_unknown_sequences_are_refused_in_one_line(tmp_path):
    code, line = _refusal("--otb", str(_otb_root(tmp_path)), "--sequences", "Alpha,Gamma", "--out", str(tmp_path / "o"))
    assert code == 2
    assert line == (f"forward_backward.py: error: --sequences: Gamma is not in {tmp_path / 'otb'}; "
                    "choose from Alpha, Beta")
    assert not (tmp_path / "o").exists()


def test_rescore_without_stored_passes_is_refused_in_one_line(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "Alpha.s0.npz").write_bytes(b"kept")
    code, line = _refusal("--otb", str(_otb_root(tmp_path)), "--seeds", "0", "--out", str(out), "--rescore")
    assert code == 2
    assert line == (f"forward_backward.py: error: --rescore: {out} lacks the stored passes ['Beta.s0.npz']; "
                    "track them first (the same command without --rescore)")
    assert (out / "Alpha.s0.npz").read_bytes() == b"kept"  # nothing already written is touched

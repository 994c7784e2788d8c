"""benchmarks/motion_signals.py: a stored track's motion signals measured again from its frames and boxes are the
ones tracking stored, bit for bit, and a replay that disagrees with what tracking stored stops."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from annotator.cli import main
from annotator.track_store import STORE_NAME, read_store, write_store
from sptpt_dev.synthetic import make_clip

NEW = ("flow_drift", "flow_scale_drift", "ring_with_box", "box_with_background")


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """A batch run of the tool over a one-sequence OTB root: its item folder and the root."""
    tmp = tmp_path_factory.mktemp("motion")
    root = tmp / "otb"
    clip = make_clip(14, size=(128, 96), object_size=(28, 24), seed=41)
    (root / "Alpha" / "img").mkdir(parents=True)
    for i, frame in enumerate(clip.frames):
        cv2.imwrite(str(root / "Alpha" / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    rows = [f"{x + 1:.2f},{y + 1:.2f},{w:.2f},{h:.2f}" for x, y, w, h in clip.boxes_xywh]
    (root / "Alpha" / "groundtruth_rect.txt").write_text("\n".join(rows) + "\n")
    config = tmp / "fast.yaml"
    config.write_text("tracker:\n  n_particles: 60\n  n_negatives: 20\n")
    out = tmp / "out"
    try:
        main(["batch", "--otb-root", str(root), "--out", str(out), "--workers", "1", "--config", str(config),
              "--no-render", "--quiet", "--formats", "flags"])
    except SystemExit as exc:
        assert exc.code in (None, 0)
    return out / "Alpha", root


def _without_new_signals(item, tamper: str | None = None) -> dict[str, np.ndarray]:
    store = read_store(item / STORE_NAME)
    track = store.tracks[0]
    signals = {k: v.copy() for k, v in track.signals.items() if k not in NEW}
    if tamper:
        signals[tamper][3] += 1e-9
    write_store(item / STORE_NAME, dataclasses.replace(store, tracks=(dataclasses.replace(track, signals=signals),)))
    return track.signals


def test_replayed_motion_signals_are_the_tracked_ones_bit_for_bit(tracked):
    from _benchmark_scripts import load_script

    item, root = tracked
    stored = _without_new_signals(item)
    load_script("motion_signals").replay(item, [root])
    replayed = read_store(item / STORE_NAME).tracks[0].signals
    assert np.isfinite(stored["flow_drift"]).all() and stored["flow_drift"][1:].max() > 0
    for name in stored:
        np.testing.assert_array_equal(replayed[name], stored[name], err_msg=name)


def test_a_replay_that_disagrees_with_the_stored_flow_stops(tracked):
    from _benchmark_scripts import load_script

    item, root = tracked
    _without_new_signals(item, tamper="flow_iou")
    with pytest.raises(SystemExit, match="replayed flow_iou differs from the stored one at rows \\[3\\]"):
        load_script("motion_signals").replay(item, [root])

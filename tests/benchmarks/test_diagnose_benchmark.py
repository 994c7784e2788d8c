"""benchmarks/diagnose_sptpt.py: it logs every frame through the tracker's public inspection API and leaves the boxes
as a plain run's."""

from __future__ import annotations

import ast
import zlib
from pathlib import Path

import cv2
import numpy as np
from _benchmark_scripts import BENCHMARKS, load_script

from annotator.evaluation.metrics import iou_xywh
from annotator.otb_format import read_otb_boxes
from sptpt.params import get_preset, params_from_mapping
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip


def _sequence(tmp_path: Path) -> Path:
    clip = make_clip(6, size=(96, 72), object_size=(24, 20), seed=3)
    folder = tmp_path / "Alpha"
    (folder / "img").mkdir(parents=True)
    for i, frame in enumerate(clip.frames):
        cv2.imwrite(str(folder / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    rows = [f"{x + 1:.2f},{y + 1:.2f},{w:.2f},{h:.2f}" for x, y, w, h in clip.boxes_xywh]  # OTB: 1-based
    (folder / "groundtruth_rect.txt").write_text("\n".join(rows) + "\n")
    return folder


def test_the_diagnosis_runs_and_logs_every_frame_after_the_first(tmp_path):
    diagnose = load_script("diagnose_sptpt").diagnose
    params = params_from_mapping({"n_particles": 30, "n_negatives": 20, "update_every": 3}, base=get_preset("paper"))
    folder = _sequence(tmp_path)
    rows = diagnose(folder, params, seed=0, stop=None)
    assert rows["iou"].shape == rows["pos_rank3"].shape == (5,)
    assert np.all((rows["iou"] >= 0) & (rows["iou"] <= 1))
    # The positive model exists once update_every frames were accepted; the log then shows its rank.
    assert rows["positive_batches"][-1] >= 1 and rows["pos_rank3"][-1] > 0
    # Inspecting reads only: the boxes are those of the same tracker run without the diagnosis (same seeding).
    frames = make_clip(6, size=(96, 72), object_size=(24, 20), seed=3).frames  # what the PNGs hold, losslessly
    gt = read_otb_boxes(folder / "groundtruth_rect.txt")
    tracker = Tracker(params, seed=np.random.default_rng(np.random.SeedSequence([0, zlib.crc32(b"Alpha")])))
    tracker.init(frames[0], gt[0])
    plain = np.array([tracker.update(frame).box_xywh for frame in frames[1:]])
    np.testing.assert_array_equal(rows["iou"], iou_xywh(plain, gt[1:]))


def test_the_diagnosis_reads_no_private_state():
    tree = ast.parse((BENCHMARKS / "diagnose_sptpt.py").read_text(encoding="utf-8"))
    private = [f"line {node.lineno}: .{node.attr}" for node in ast.walk(tree)
               if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.endswith("__")]
    assert not private

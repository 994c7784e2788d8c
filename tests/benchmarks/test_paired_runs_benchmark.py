"""benchmarks/paired_runs.py: each run of a multi-run tracker scored alone, from the stored per-run boxes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _benchmark_scripts import load_script

from annotator.otb_format import write_otb_boxes


def _module():
    return load_script("paired_runs")


def _write_run(tmp_path: Path, *, per_run: bool = True):
    """An OTB root with two sequences and a two-seed run: run 1 follows the truth, run 2 is lost after frame 5."""
    otb, out = tmp_path / "otb", tmp_path / "out"
    truth = np.column_stack([np.arange(20) * 2.0, np.full(20, 10.0), np.full(20, 20.0), np.full(20, 20.0)])
    lost = truth.copy()
    lost[5:, 0] += 200
    for name in ("A", "B"):
        (otb / name).mkdir(parents=True)
        write_otb_boxes(otb / name / "groundtruth_rect.txt", truth, origin=1)
        for seed in (0, 1):
            folder = out / f"seed{seed}" / "robust"
            folder.mkdir(parents=True, exist_ok=True)
            # A's choice is the good run; B's is the lost one: the choice gains on A and loses on B.
            choice = truth if name == "A" else lost
            write_otb_boxes(folder / f"{name}.txt", choice, origin=1)
            extra = {"run_boxes": np.stack([truth, lost], axis=1)} if per_run else {}
            np.savez(folder / f"{name}.frames.npz", log_likelihood=np.zeros(20), **extra)
    return otb, out


def test_each_run_is_scored_alone_and_the_choice_against_their_mean(tmp_path, capsys):
    paired = _module()
    otb, out = _write_run(tmp_path)
    gt = {n: np.loadtxt(otb / n / "groundtruth_rect.txt", delimiter=",") - [1, 1, 0, 0] for n in ("A", "B")}
    aucs = paired.sequence_aucs(out / "seed0", "robust", gt)
    good, bad = aucs["A"][1], aucs["A"][2]
    assert good > 0.9 and bad < 0.3
    np.testing.assert_allclose(aucs["A"], [good, good, bad])
    np.testing.assert_allclose(aucs["B"], [bad, good, bad])
    assert paired.main([str(out), "--otb", str(otb)]) == 0
    printed = capsys.readouterr().out
    # Mean choice = mean of the runs on these two sequences: a gain of exactly zero, in both seeds.
    assert "| seed0 |" in printed and "| seed1 |" in printed and "+0.000 (0 of 2 positive)" in printed
    assert f"| A | {good:.3f} | {(good + bad) / 2:.3f} | {good - (good + bad) / 2:+.3f} |" in printed


def test_a_run_without_per_run_boxes_is_refused_in_one_line(tmp_path, capsys):
    paired = _module()
    otb, out = _write_run(tmp_path, per_run=False)
    assert paired.main([str(out), "--otb", str(otb)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no per-run boxes" in err and "A.frames.npz" in err
    assert paired.main([str(tmp_path / "nowhere"), "--otb", str(otb)]) == 2
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.parametrize("names", ["A,Nope", ","])
def test_unknown_sequences_are_refused(tmp_path, names):
    otb, out = _write_run(tmp_path)
    assert _module().main([str(out), "--otb", str(otb), "--sequences", names]) == 2


def test_rechoose_contrast_reports_the_run_whose_box_stands_out(tmp_path, capsys):
    """With frames to read, --rechoose contrast picks per frame the run on the object (a red square on grey
    texture), whatever the stored choice was: B's stored choice is the lost run, its re-made choice the good one."""
    import cv2

    paired = _module()
    otb, out = _write_run(tmp_path)
    truth = np.loadtxt(otb / "A" / "groundtruth_rect.txt", delimiter=",") - [1, 1, 0, 0]
    rng = np.random.default_rng(0)
    for name in ("A", "B"):
        (otb / name / "img").mkdir()
        for k, (x, y, w, h) in enumerate(truth):
            frame = np.repeat(rng.integers(90, 130, (80, 320, 1), dtype=np.uint8), 3, axis=2)
            frame[int(y):int(y + h), int(x):int(x + w)] = (30, 30, 200)  # BGR: red
            cv2.imwrite(str(otb / name / "img" / f"{k + 1:04d}.jpg"), frame)
    gt = {n: truth for n in ("A", "B")}
    stored = paired.sequence_aucs(out / "seed0", "robust", gt)
    again = paired.sequence_aucs(out / "seed0", "robust", gt, rechoose="contrast", otb=otb)
    good, bad = stored["A"][1], stored["A"][2]
    assert stored["B"][0] == pytest.approx(bad) and again["B"][0] == pytest.approx(good)
    assert again["A"][0] == pytest.approx(good)
    np.testing.assert_array_equal(again["B"][1:], stored["B"][1:])  # the runs alone do not change
    assert paired.main([str(out), "--otb", str(otb), "--rechoose", "contrast"]) == 0
    assert "choice by contrast" in capsys.readouterr().out

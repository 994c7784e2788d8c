"""benchmarks/otb_benchmark.py: per-attribute success plots and table, from fake result files (no tracking)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from _benchmark_scripts import BENCHMARKS as BENCH
from _benchmark_scripts import load_script

CODES = {"IV", "SV", "OCC", "DEF", "MB", "FM", "IPR", "OPR", "OV", "BC", "LR"}
SEQUENCES = {"Bolt2", "Car4", "CarDark", "Coke", "Couple", "Crossing", "David", "Deer", "Diving", "Dog1", "Girl",
             "Human9", "Jogging.1", "Jogging.2", "Singer2", "Skiing", "Tiger1"}

# Ground truth is one fixed box; a result row is one of three boxes of known IoU with it.
GT = "11,11,10,10"
ROWS = {"same": GT, "third": "16,11,10,10", "miss": "200,200,10,10"}  # IoU 1, 1/3, 0
# Of the 21 thresholds 0:0.05:1 (strict IoU > t), IoU 1 passes 20, IoU 1/3 passes 7 (0 .. 0.30), IoU 0 none.
PASSED = {"same": 20, "third": 7, "miss": 0}

# The real table gives Car4 = IV SV, CarDark = IV BC, Bolt2 = DEF BC: IV and BC have two sequences each,
# SV and DEF only one. The first row is replaced by the ground truth (OTB's rule), whatever it holds.
RUNS = {
    ("paper", 0): {"Car4": ["same", "same", "third", "miss"], "CarDark": ["same", "miss", "miss"],
                   "Bolt2": ["same", "third", "third", "same", "miss"]},
    ("paper", 1): {"Car4": ["same", "miss", "miss", "miss"], "CarDark": ["same", "same", "same"],
                   "Bolt2": ["same", "third", "third", "same", "miss"]},
    ("csrt", 0): {"Car4": ["same", "same", "third", "miss"], "CarDark": ["same", "miss", "miss"],
                  "Bolt2": ["same", "miss", "miss", "miss", "miss"]},
}


def _module():
    return load_script("otb_benchmark")


def _auc(rows: list[str]) -> float:
    """By hand: the mean over frames of (thresholds passed) / 21, i.e. the mean of the 21 success rates."""
    return sum(PASSED[r] for r in rows) / (21 * len(rows))


def _fake_otb(root: Path) -> Path:
    otb = root / "otb"
    for name, rows in RUNS[("paper", 0)].items():
        (otb / name / "img").mkdir(parents=True)
        (otb / name / "groundtruth_rect.txt").write_text("\n".join([GT] * len(rows)) + "\n")
    return otb


def _write_run(out: Path, tracker: str, seed: int) -> None:
    for name, rows in RUNS[(tracker, seed)].items():
        path = out / f"seed{seed}" / tracker / f"{name}.txt"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(ROWS[r] for r in rows) + "\n")


def test_the_table_has_the_eleven_codes_and_the_seventeen_sequences():
    doc = json.loads((BENCH / "otb_attributes.json").read_text())
    assert doc["source"] and "votchallenge/toolkit" in doc["source"]
    assert set(doc["attributes"]) == CODES
    assert set(doc["sequences"]) == SEQUENCES
    for name, codes in doc["sequences"].items():
        assert codes and set(codes) <= CODES, name
        assert len(set(codes)) == len(codes), name
    assert doc["sequences"]["Jogging.1"] == doc["sequences"]["Jogging.2"]
    names, labels = _module().load_attributes()
    assert list(names) == list(doc["attributes"]) and labels == doc["sequences"]


def test_only_attributes_held_by_two_sequences_form_a_group():
    bench = _module()
    labels = {"a": ["IV", "SV"], "b": ["IV"], "c": ["SV", "LR"], "d": ["LR"]}
    assert bench.attribute_groups(labels, ["a", "b", "c"], ["IV", "SV", "LR", "OV"]) == {"IV": ["a", "b"],
                                                                                           "SV": ["a", "c"]}
    assert bench.attribute_groups(labels, ["a", "b", "c", "d"], ["LR"]) == {"LR": ["c", "d"]}


def test_attribute_auc_is_the_unweighted_mean_over_its_sequences_then_over_seeds(tmp_path):
    bench = _module()
    otb = _fake_otb(tmp_path)
    out = tmp_path / "runs"
    for tracker, seed in RUNS:
        _write_run(out, tracker, seed)
    sequences = sorted(otb.iterdir())
    gts = {s.name: bench.read_otb_boxes(s / "groundtruth_rect.txt") for s in sequences}
    per_seed = bench.scores_per_seed(out, [0, 1], ["paper", "csrt"], sequences, gts)
    assert [len(per_seed["paper"]), len(per_seed["csrt"])] == [2, 1]  # the peer runs once

    def by_hand(tracker: str, names: list[str]) -> float:
        seeds = [seed for (t, seed) in RUNS if t == tracker]
        return sum(sum(_auc(RUNS[(tracker, seed)][n]) for n in names) / len(names) for seed in seeds) / len(seeds)

    for code, names in {"IV": ["Car4", "CarDark"], "BC": ["Bolt2", "CarDark"]}.items():
        for tracker in ("paper", "csrt"):
            score = bench.attribute_score(per_seed[tracker], names)
            assert score.auc == pytest.approx(by_hand(tracker, names), abs=1e-12), (code, tracker)
    # The hand figures themselves, so that a wrong helper cannot agree with a wrong test:
    # paper IV = mean over seeds of mean(Car4, CarDark) = ((47/84 + 20/63) / 2 + (20/84 + 60/63) / 2) / 2.
    paper_iv = bench.attribute_score(per_seed["paper"], ["Car4", "CarDark"]).auc
    assert paper_iv == pytest.approx(((47 / 84 + 20 / 63) / 2 + (20 / 84 + 60 / 63) / 2) / 2, abs=1e-12)
    # A mean weighted by frames, or the first seed alone, would give something else.
    assert paper_iv != pytest.approx((47 + 20 + 20 + 60) / (21 * 14), abs=1e-6)
    assert paper_iv != pytest.approx((47 / 84 + 20 / 63) / 2, abs=1e-6)


def test_replot_draws_attributes_with_two_sequences_and_tables_their_auc(tmp_path, monkeypatch, capsys):
    bench = _module()
    otb = _fake_otb(tmp_path)
    out = tmp_path / "runs"
    for tracker, seed in RUNS:
        _write_run(out, tracker, seed)
    monkeypatch.setattr(sys, "argv", ["otb_benchmark.py", "--otb", str(otb), "--replot", str(out),
                                      "--trackers", "paper,csrt,kcf", "--no-record"])
    bench.main()
    printed = capsys.readouterr().out
    plots = out / "plots" / "attributes"
    assert sorted(p.name for p in plots.iterdir()) == ["BC.png", "IV.png"]  # SV, DEF: one sequence each
    assert all(p.stat().st_size > 1000 for p in plots.iterdir())
    assert "| Tracker | IV (2) | BC (2) |" in printed
    paper_iv = ((47 / 84 + 20 / 63) / 2 + (20 / 84 + 60 / 63) / 2) / 2
    csrt_bc = (20 / 63 + 20 / 105) / 2
    row = {line.split(" | ")[0]: line for line in printed.splitlines() if line.startswith("| SPTPT") or
           line.startswith("| CSRT")}
    assert row["| SPTPT-paper"].split(" | ")[1] == f"{paper_iv:.3f}"
    assert row["| CSRT"].split(" | ")[2].rstrip(" |") == f"{csrt_bc:.3f}"
    assert "KCF" not in printed  # no results: left out, not a crash
    assert "SV (Car4)" in printed and "DEF (Bolt2)" in printed and "OV (none)" in printed


def test_a_benchmark_run_appends_the_attribute_table_and_plots(tmp_path, monkeypatch, capsys):
    bench = _module()
    otb = _fake_otb(tmp_path)
    out = tmp_path / "runs"

    def fake_run(name, sequences, out_root, *, seed, **_):
        _write_run(out_root.parent, name, seed)
        return [dict(frames=len(RUNS[(name, seed)][s.name]), seconds_after_first=1.0,
                     stages={st: 0.001 for st in bench.STAGES}, peak_rss_mib=1.0) for s in sequences]

    monkeypatch.setattr(bench, "run_tracker", fake_run)
    monkeypatch.setattr(bench, "ensure_peer_env", lambda: Path(sys.executable))
    monkeypatch.setattr(bench, "update_section", lambda *a: pytest.fail("--no-record must not write RESULTS.md"))
    monkeypatch.setattr(sys, "argv", ["otb_benchmark.py", "--otb", str(otb), "--out", str(out), "--seeds", "0,1",
                                      "--trackers", "paper,csrt", "--no-record"])
    bench.main()
    printed = capsys.readouterr().out
    assert "### Success AUC per OTB attribute (mean over the sequences with the attribute, SPTPT also over " \
           "seeds 0, 1)" in printed
    assert sorted(p.name for p in (out / "seed0" / "plots" / "attributes").iterdir()) == ["BC.png", "IV.png"]
    assert (out / "seed0" / "plots" / "success_plots.png").is_file()
    # The overall table still uses the first seed, as before.
    assert f"| SPTPT-paper | {(47 / 84 + 20 / 63 + 54 / 105) / 3:.3f} |" in printed


def test_a_variant_keeps_commas_inside_a_list_value():
    name, params = _module().parse_variant("sc=robust:motion_sigma=[0.15,0.15,0.02,0,0.01,0],n_particles=200")
    assert name == "sc"
    assert params["motion_sigma"] == [0.15, 0.15, 0.02, 0.0, 0.01, 0.0] and params["n_particles"] == 200
    with pytest.raises(ValueError, match="motion_sigma"):
        _module().parse_variant("sc=robust:motion_sigma=[0.15,0.15]")

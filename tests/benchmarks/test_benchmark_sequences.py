"""benchmarks/_sequences.py: every benchmark selects OTB sequences by one rule, and refuses a name it lacks."""

from __future__ import annotations

from pathlib import Path

import pytest
from _benchmark_scripts import run_benchmark

from benchmarks._sequences import SequenceError, select_sequences


def _otb_root(tmp_path: Path) -> Path:
    for name in ("Beta", "Alpha"):
        (tmp_path / "otb" / name).mkdir(parents=True)
        (tmp_path / "otb" / name / "groundtruth_rect.txt").write_text("1,1,4,4\n")
    (tmp_path / "otb" / "notes").mkdir()  # a folder without ground truth is not a sequence
    return tmp_path / "otb"


def test_every_sequence_in_name_order_or_the_named_ones_in_their_order(tmp_path):
    root = _otb_root(tmp_path)
    for everything in (None, "", "all"):
        assert [p.name for p in select_sequences(root, everything)] == ["Alpha", "Beta"]
    assert [p.name for p in select_sequences(root, "Beta,Alpha,Beta")] == ["Beta", "Alpha"]
    assert [p.name for p in select_sequences(root, "Alpha, Beta")] == ["Alpha", "Beta"]  # spaces after commas
    assert select_sequences(root, "Alpha")[0] == root / "Alpha"


@pytest.mark.parametrize("names, unknown", [("Alpha,Gamma", "Gamma is"), ("notes,Delta", "notes, Delta are")])
def test_a_name_that_is_not_a_sequence_is_refused(tmp_path, names, unknown):
    root = _otb_root(tmp_path)
    with pytest.raises(SequenceError) as refused:
        select_sequences(root, names)
    assert str(refused.value) == f"--sequences: {unknown} not in {root}; choose from Alpha, Beta"


def test_an_empty_list_is_refused(tmp_path):
    with pytest.raises(SequenceError, match=r"^--sequences ', ' names no sequence: give comma-separated names such as "
                                            r"Alpha,Beta, or 'all'$"):
        select_sequences(_otb_root(tmp_path), ", ")


def test_a_root_without_sequences_is_refused(tmp_path):
    with pytest.raises(SequenceError, match="no sequence folders"):
        select_sequences(tmp_path / "missing", None)


@pytest.mark.parametrize("script", ["otb_benchmark", "simulated_reviewer", "forward_backward"])
def test_each_benchmark_refuses_an_unknown_sequence_in_one_line(tmp_path, script):
    root = _otb_root(tmp_path)
    done = run_benchmark(script, "--otb", str(root), "--sequences", "Alpha,Gamma", "--out", str(tmp_path / "o"),
                         timeout=300)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines()[-1] == \
        f"{script}.py: error: --sequences: Gamma is not in {root}; choose from Alpha, Beta"
    assert not (tmp_path / "o").exists()

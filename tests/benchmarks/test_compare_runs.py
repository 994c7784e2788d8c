"""benchmarks/compare_runs.py: two sets of stored runs, paired by seed and sequence."""

from __future__ import annotations

import pytest

from benchmarks.compare_runs import compare


def test_pairs_by_seed_and_sequence_and_marks_the_sequences_that_lost():
    before = {("A", 0): 0.6, ("B", 0): 0.4, ("A", 1): 0.5, ("B", 1): 0.3, ("C", 0): 0.9}
    after = {("A", 0): 0.62, ("B", 0): 0.34, ("A", 1): 0.54, ("B", 1): 0.3, ("D", 1): 0.1}
    text = "\n".join(compare(before, after, worst=0.02))
    assert "2 sequences, seeds 0, 1" in text  # C and D are in one set only
    assert "| 0 | 0.500 | 0.480 | -0.020 |" in text
    assert "| 1 | 0.400 | 0.420 | +0.020 |" in text
    assert "| A | 0.550 | 0.580 | +0.030 |" in text
    assert "| B | 0.350 | 0.320 | -0.030 **lower by more than 0.02** |" in text
    assert "| mean ± std | 0.450 ± 0.071 | 0.450 ± 0.042 | +0.000 |" in text


def test_runs_with_nothing_in_common_are_an_error():
    with pytest.raises(SystemExit, match="share no"):
        compare({("A", 0): 0.5}, {("A", 1): 0.5}, worst=0.03)

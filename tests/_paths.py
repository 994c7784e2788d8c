"""Where things are, for tests at any depth under ``tests/``: the project's folder and the tests' data."""

from __future__ import annotations

from pathlib import Path

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent  # the project's folder: README.md, docs/, samples/, benchmarks/
DATA = TESTS / "data"  # input files the tests read
GOLDEN = TESTS / "golden"  # expected outputs; UPDATE_GOLDEN=1 writes them again

"""The benchmark scripts (``benchmarks/*.py`` are scripts, not a package), loaded as modules for their tests."""

from __future__ import annotations

import importlib.util
import types
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_script(name: str) -> types.ModuleType:
    """``benchmarks/<name>.py`` as a fresh module (its own ``sys.path`` setup runs, as when it is run)."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

"""The benchmarks (``python -m benchmarks.<name>`` from the project root), loaded as modules or run for their tests."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"


def load_script(name: str) -> types.ModuleType:
    """``benchmarks.<name>`` as a fresh module (not the one ``import`` caches), as when it is run."""
    spec = importlib.util.spec_from_file_location(f"benchmarks.{name}", BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_benchmark(name: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``python -m benchmarks.<name> ARGS`` from the project root, as the docs run it; output captured as text."""
    return subprocess.run([sys.executable, "-m", f"benchmarks.{name}", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)

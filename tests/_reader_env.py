"""A virtual environment of its own for the third-party readers the review-tool exports are checked with.

datumaro 1.13 pins ``opencv-python-headless<5`` (the project runs on OpenCV 5)
and pulls pandas and pyarrow, so installing it beside the project would change
the project's own OpenCV. Like ``benchmarks/_env`` for the OpenCV peers, the
readers live in ``tests/_reader_env``; the checks run there as
``python tests/_reader_checks.py``.

The tests never install anything: ``.ci/run`` builds the environment before
pytest with ``python tests/_reader_env.py``. Where it is missing, the tests
that need it fail in CI (``CI`` set: a missing reader must not pass as a
skip) and are skipped elsewhere with the command that builds it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import venv
from pathlib import Path

HERE = Path(__file__).parent
READER_ENV = HERE / "_reader_env"
# datumaro: its "cvat" and "mot_seq" importers are what users load our files with;
# motmetrics: the MOTChallenge evaluation reads gt.txt with its loadtxt.
READER_REQUIREMENTS = ["datumaro>=1.13,<1.14", "motmetrics>=1.4"]
_DONE = READER_ENV / ".complete"  # written last: a half-built environment is rebuilt, never used
BUILD_COMMAND = "python tests/_reader_env.py"


def reader_python() -> Path | None:
    """The reader environment's python, or None when it has not been built (completely)."""
    python = READER_ENV / "bin" / "python"
    return python if _DONE.exists() and _DONE.read_text(encoding="utf-8").strip() == json.dumps(
        READER_REQUIREMENTS) else None


def build() -> Path:
    """Build the reader environment (once: a complete one with the same requirements is kept)."""
    python = reader_python()
    if python is not None:
        return python
    print(f"creating {READER_ENV} with {' '.join(READER_REQUIREMENTS)} ...", file=sys.stderr, flush=True)
    venv.EnvBuilder(with_pip=True, clear=True).create(READER_ENV)
    python = READER_ENV / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                    *READER_REQUIREMENTS], check=True, timeout=1800)
    _DONE.write_text(json.dumps(READER_REQUIREMENTS) + "\n", encoding="utf-8")
    return python


def run_check(check: str, **kwargs) -> dict:
    """Run ``check`` of ``_reader_checks.py`` in the reader environment; its JSON answer."""
    python = reader_python()
    if python is None:
        import pytest

        message = f"the reader environment {READER_ENV} is missing: build it with `{BUILD_COMMAND}`"
        if os.environ.get("CI"):
            pytest.fail(message + " (.ci/run does, before pytest)")
        pytest.skip(message)
    out = subprocess.run([str(python), str(HERE / "_reader_checks.py"), check, json.dumps(kwargs)],
                         capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise AssertionError(f"reader check {check} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    print(build())

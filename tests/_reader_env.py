"""A virtual environment of its own for the third-party readers the review-tool exports are checked with.

datumaro 1.13 pins ``opencv-python-headless<5`` (the project runs on OpenCV 5)
and pulls pandas and pyarrow, so installing it beside the project would change
the project's own OpenCV. Like ``benchmarks/_env`` for the OpenCV peers, the
readers live in ``tests/_reader_env``, created by the first test that needs it
and reused after; the checks run there as ``python tests/_reader_checks.py``.

If the environment cannot be built (no registry, no wheel for this Python),
:func:`reader_python` says why and the tests that need it are skipped with
that reason; the exporters' own golden tests still run.
"""

from __future__ import annotations

import fcntl
import json
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
_FAILED = READER_ENV.parent / "_reader_env.failed"


def reader_python() -> tuple[Path | None, str]:
    """``(python, "")`` of the reader environment, built once; ``(None, reason)`` when it cannot be built."""
    python = READER_ENV / "bin" / "python"
    if _DONE.exists():
        return python, ""
    if _FAILED.exists():
        return None, _FAILED.read_text(encoding="utf-8").strip()
    lock_path = HERE / "_reader_env.lock"
    with open(lock_path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # two pytest processes must not build it at once
        if _DONE.exists():
            return python, ""
        print(f"creating {READER_ENV} with {' '.join(READER_REQUIREMENTS)} (once) ...", file=sys.stderr)
        try:
            venv.EnvBuilder(with_pip=True, clear=True).create(READER_ENV)
            subprocess.run([str(python), "-m", "pip", "install", "--quiet", *READER_REQUIREMENTS], check=True,
                           capture_output=True, text=True, timeout=1800)
        except (OSError, subprocess.SubprocessError) as exc:
            detail = getattr(exc, "stderr", "") or str(exc)
            reason = (f"cannot build the reader environment {READER_ENV} with {' '.join(READER_REQUIREMENTS)}: "
                      f"{detail.strip().splitlines()[-1] if detail.strip() else exc}; delete {_FAILED.name} to retry")
            _FAILED.write_text(reason + "\n", encoding="utf-8")
            return None, reason
        _DONE.write_text(json.dumps(READER_REQUIREMENTS) + "\n", encoding="utf-8")
    return python, ""


def run_check(check: str, **kwargs) -> dict:
    """Run ``check`` of ``_reader_checks.py`` in the reader environment; its JSON answer."""
    python, reason = reader_python()
    if python is None:
        import pytest

        pytest.skip(reason)
    out = subprocess.run([str(python), str(HERE / "_reader_checks.py"), check, json.dumps(kwargs)],
                         capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise AssertionError(f"reader check {check} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    print(reader_python())

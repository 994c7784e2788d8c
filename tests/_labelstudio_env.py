"""A virtual environment of its own for the Label Studio server the review round trip is tested against.

Label Studio is a Django application with its own pinned dependencies
(Django, psycopg, boto, ...); installed beside the project it would change
them. Like ``tests/_reader_env`` for the file readers, the server lives in
``tests/_labelstudio_env`` and the test starts it there as a subprocess on
127.0.0.1.

The tests never install anything: ``.ci/run`` builds the environment before
pytest with ``python3 tests/_labelstudio_env.py``. Where it is missing, the
test that needs it fails in CI (``CI`` set: a missing server must not pass
as a skip) and is skipped elsewhere with the command that builds it.
"""

from __future__ import annotations

import json
import subprocess
import sys
import venv
from pathlib import Path

HERE = Path(__file__).parent
LABELSTUDIO_ENV = HERE / "_labelstudio_env"
# The version the round trip was verified with (issue #47); its REST API and export layout are what the test uses.
LABELSTUDIO_REQUIREMENTS = ["label-studio==1.23.2"]
_DONE = LABELSTUDIO_ENV / ".complete"  # written last: a half-built environment is rebuilt, never used
BUILD_COMMAND = "python3 tests/_labelstudio_env.py"


def labelstudio_executable() -> Path | None:
    """The environment's ``label-studio`` program, or None when it has not been built (completely)."""
    program = LABELSTUDIO_ENV / "bin" / "label-studio"
    return program if _DONE.exists() and _DONE.read_text(encoding="utf-8").strip() == json.dumps(
        LABELSTUDIO_REQUIREMENTS) else None


def build() -> Path:
    """Build the environment (once: a complete one with the same requirements is kept)."""
    program = labelstudio_executable()
    if program is not None:
        return program
    print(f"creating {LABELSTUDIO_ENV} with {' '.join(LABELSTUDIO_REQUIREMENTS)} ...", file=sys.stderr, flush=True)
    venv.EnvBuilder(with_pip=True, clear=True).create(LABELSTUDIO_ENV)
    python = LABELSTUDIO_ENV / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                    *LABELSTUDIO_REQUIREMENTS], check=True, timeout=3600)
    _DONE.write_text(json.dumps(LABELSTUDIO_REQUIREMENTS) + "\n", encoding="utf-8")
    return LABELSTUDIO_ENV / "bin" / "label-studio"


if __name__ == "__main__":
    print(build())

"""A virtual environment beside the project's, for third-party programs whose pinned dependencies would change
the project's own (the file readers, the Label Studio server).

The tests never install anything: ``.ci/run`` builds each environment before pytest by running its module as a
script. Where one is missing, a test that needs it fails in CI (``CI`` set: a missing program must not pass as a
skip) and is skipped elsewhere with the command that builds it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import venv
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class SideEnvironment:
    """``folder``, a venv with ``requirements``, built by ``build_command``."""

    what: str  # for messages: "the reader environment"
    folder: Path
    requirements: tuple[str, ...]
    build_command: str
    install_seconds: float

    @property
    def _done(self) -> Path:
        return self.folder / ".complete"  # written last: a half-built environment is rebuilt, never used

    def program(self, name: str) -> Path | None:
        """The environment's program ``name`` (``python``, a console script), or None when the environment has not
        been built completely with these requirements."""
        complete = self._done.exists() and self._done.read_text(encoding="utf-8").strip() == json.dumps(
            list(self.requirements))
        return self.folder / "bin" / name if complete else None

    def build(self) -> None:
        """Build the environment (once: a complete one with the same requirements is kept)."""
        if self.program("python") is not None:
            return
        print(f"creating {self.folder} with {' '.join(self.requirements)} ...", file=sys.stderr, flush=True)
        venv.EnvBuilder(with_pip=True, clear=True).create(self.folder)
        subprocess.run([str(self.folder / "bin" / "python"), "-m", "pip", "install", "--quiet",
                        "--disable-pip-version-check", *self.requirements], check=True, timeout=self.install_seconds)
        self._done.write_text(json.dumps(list(self.requirements)) + "\n", encoding="utf-8")

    def require(self, name: str) -> Path:
        """The program ``name``; where the environment is missing, the test fails in CI and is skipped elsewhere."""
        program = self.program(name)
        if program is None:
            import pytest

            message = f"{self.what} {self.folder} is missing: build it with `{self.build_command}`"
            if os.environ.get("CI"):
                pytest.fail(message + " (.ci/run does, before pytest)")
            pytest.skip(message)
        return program

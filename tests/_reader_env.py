"""A virtual environment of its own for the third-party readers the review-tool exports are checked with.

datumaro 1.13 pins ``opencv-python-headless<5`` (the project runs on OpenCV 5)
and pulls pandas and pyarrow, so installing it beside the project would change
the project's own OpenCV. Like ``benchmarks/_env`` for the OpenCV peers, the
readers live in ``tests/_reader_env``; the checks run there as
``python tests/_reader_checks.py``. ``.ci/run`` builds it with
``python tests/_reader_env.py`` (see ``_side_env``).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from _side_env import SideEnvironment

HERE = Path(__file__).parent
READERS = SideEnvironment(
    what="the reader environment",
    folder=HERE / "_reader_env",
    # datumaro: its "cvat" and "mot_seq" importers are what users load our files with;
    # motmetrics: the MOTChallenge evaluation reads gt.txt with its loadtxt.
    requirements=("datumaro>=1.13,<1.14", "motmetrics>=1.4"),
    build_command="python tests/_reader_env.py",
    install_seconds=1800,
)


def run_check(check: str, **kwargs) -> dict:
    """Run ``check`` of ``_reader_checks.py`` in the reader environment; its JSON answer."""
    python = READERS.require("python")
    out = subprocess.run([str(python), str(HERE / "_reader_checks.py"), check, json.dumps(kwargs)],
                         capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise AssertionError(f"reader check {check} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    READERS.build()

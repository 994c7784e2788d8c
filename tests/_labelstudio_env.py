"""A virtual environment of its own for the Label Studio server the review round trip is tested against.

Label Studio is a Django application with its own pinned dependencies
(Django, psycopg, boto, ...); installed beside the project it would change
them. Like ``tests/_reader_env`` for the file readers, the server lives in
``tests/_labelstudio_env`` and the test starts it there as a subprocess on
127.0.0.1. ``.ci/run`` builds it with ``python3 tests/_labelstudio_env.py``
(see ``_side_env``).
"""

from __future__ import annotations

from pathlib import Path

from _side_env import SideEnvironment

LABELSTUDIO = SideEnvironment(
    what="the Label Studio environment",
    folder=Path(__file__).parent / "_labelstudio_env",
    # The version the round trip was verified with (issue #47); its REST API and export layout are what the test
    # uses.
    requirements=("label-studio==1.23.2",),
    build_command="python3 tests/_labelstudio_env.py",
    install_seconds=3600,
)

if __name__ == "__main__":
    LABELSTUDIO.build()

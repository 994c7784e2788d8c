"""An output folder has one writer at a time: its lock, and where a run is written before it moves in.

A run, a re-track and a batch all hold :func:`folder_lock` on the folder they
write, and write their files into a :func:`staging_folder` inside it first,
so that the folder holds the earlier results, whole, until the new ones are
complete (:func:`annotator.publish.move_into_place` moves them in).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from annotator.errors import EXIT_OUTPUT, ToolError
from annotator.output_files import STAGING_PREFIX

__all__ = ["Staging", "folder_lock", "remove_staging_folders", "staging_folder"]


@contextlib.contextmanager
def folder_lock(out_dir: Path) -> Iterator[None]:
    """Hold a lock on ``out_dir`` while the block runs; a second writer stops with a :class:`ToolError` (exit 5).

    The lock is on the folder itself (``flock`` of its descriptor), so no lock file is left among the results,
    and the kernel releases it when the process ends, however it ends. Where there is none to take (not POSIX, a
    folder that can be written but not opened, a file system without locks), the block runs without it.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    try:
        fd = os.open(out_dir, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ToolError(f"output folder {out_dir} is in use by another sptpt-annotate run: wait for it to "
                            "finish or choose another --out", EXIT_OUTPUT) from None
        except OSError:
            pass  # some network mounts have no locks
        yield
    finally:
        os.close(fd)


@dataclass
class Staging:
    """A folder to write into before the files move into place: removed at the end unless :meth:`keep` was called
    (it holds complete results that could not be moved in, and the error says where they are)."""

    path: Path
    kept: bool = False

    def keep(self) -> None:
        self.kept = True


@contextlib.contextmanager
def staging_folder(out_dir: Path) -> Iterator[Staging]:
    """A new empty folder inside ``out_dir`` (``.sptpt-run.XXXX.tmp``: on the same file system, so moving the
    files in is a rename); a process killed before it ends leaves it to :func:`remove_staging_folders`."""
    try:
        staging = Staging(Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, suffix=".tmp", dir=out_dir)))
    except OSError as exc:
        raise ToolError(f"output folder {out_dir} cannot be written ({exc.strerror}); nothing was changed",
                        EXIT_OUTPUT) from None
    try:
        yield staging
    finally:
        if not staging.kept:
            shutil.rmtree(staging.path, ignore_errors=True)


def remove_staging_folders(out_dir: Path) -> None:
    """Remove the staging folders that runs killed before they finished (``kill -9``, power) left in ``out_dir``.

    Only under the folder's lock (or the batch's, for an item folder): a live run's staging folder is in use.
    """
    for folder in out_dir.glob(f"{STAGING_PREFIX}*.tmp"):
        if folder.is_dir() and not folder.is_symlink():
            shutil.rmtree(folder, ignore_errors=True)

"""Atomic file writes: a reader sees the old file or the complete new one, never a half.

Every output of the tool goes through here, so that a crash, a full disk or a
``kill -9`` in the middle of a write leaves no truncated file behind.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
from pathlib import Path
from typing import IO, Iterator

__all__ = ["atomic_path", "atomic_open", "ctrl_c_ignored", "write_text_atomic", "write_bytes_atomic"]

# mkstemp creates files readable by the owner only; outputs get the usual umask permissions.
_UMASK = os.umask(0)
os.umask(_UMASK)
_FILE_MODE = 0o666 & ~_UMASK


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    The temporary file lives in the target's folder so that the final
    ``os.replace`` is a rename within one file system (atomic on POSIX). On
    an exception the temporary file is removed and ``target`` is untouched.
    ``suffix`` defaults to the target's own suffix, which lets writers that
    choose a format by extension (ffmpeg, imageio) work on the temporary path.
    """
    target = Path(target)
    suffix = target.suffix if suffix is None else suffix
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{suffix}", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, _FILE_MODE)
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


@contextlib.contextmanager
def atomic_open(target: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary file for writing; it replaces ``target`` when the block ends cleanly."""
    if not any(flag in mode for flag in "wx"):
        raise ValueError(f"atomic_open mode must write ('w' or 'wb'), got {mode!r}")
    with atomic_path(target) as tmp:
        with open(tmp, mode.replace("x", "w"), **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())


def write_text_atomic(target: str | os.PathLike, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``target`` atomically."""
    with atomic_open(target, "w", encoding=encoding, newline="") as handle:
        handle.write(text)


def write_bytes_atomic(target: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``target`` atomically."""
    with atomic_open(target, "wb") as handle:
        handle.write(data)


@contextlib.contextmanager
def ctrl_c_ignored() -> Iterator[None]:
    """Ignore Ctrl-C while a run is moved into place (well under a second), so the folder is never half old.

    Only in the main thread, where Python handles signals; elsewhere a no-op.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)

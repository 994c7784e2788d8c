"""What ``run.json`` records of where a run came from: the input's content hash, and its values as JSON.

Below both the first run (:mod:`annotator.run`) and the re-track (:mod:`annotator.review`), which write
run.json, and the batch, which compares an item's input with the recorded hash to resume.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

__all__ = ["content_hash", "json_default"]


def content_hash(path: Path) -> str:
    """SHA-256 of a file, or of an image folder's names and bytes in order, as ``"sha256:<hex>"``."""
    digest = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for file in files:
        if path.is_dir():
            digest.update(str(file.relative_to(path)).encode())
        with open(file, "rb") as handle:
            for chunk in iter(lambda: handle.read(1 << 20), b""):
                digest.update(chunk)
    return "sha256:" + digest.hexdigest()


def json_default(value):
    """``json.dumps`` fallback for NumPy scalars and arrays and paths (run.json)."""
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")

"""Small real runs for the tests: synthetic clips written as files, the fast tracker settings, the command line, and
an output folder's bytes."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
from typer.testing import CliRunner

from annotator.cli import _with_default_command, app
from annotator.config import resolve_config
from sptpt_dev.synthetic import make_clip

SIZE, OBJECT = (96, 72), (24, 20)  # every clip here: 96x72 frames, a 24x20 object
FAST = "tracker:\n  n_particles: 60\n  n_negatives: 20\n"  # a config file: few particles, a fast run
CONFIG = resolve_config({"seed": 1, "tracker": {"n_particles": 60, "n_negatives": 20}})  # the same, resolved


def write_clip(path: Path, n: int, seed: int, *, faststart: bool = False) -> np.ndarray:
    """Write a synthetic H.264 clip; return its first ground-truth box."""
    clip = make_clip(n, size=SIZE, object_size=OBJECT, seed=seed)
    extra = ["-g", "4", "-movflags", "+faststart"] if faststart else []
    writer = imageio_ffmpeg.write_frames(str(path), SIZE, fps=25, codec="libx264", macro_block_size=1,
                                         ffmpeg_log_level="error", output_params=extra)
    writer.send(None)
    for frame in clip.frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    return clip.boxes_xywh[0]


def write_frames(path: Path, n: int) -> Path:
    """Write a synthetic clip as the folder ``path`` of PNG frames; return the folder."""
    clip = make_clip(n, size=SIZE, object_size=OBJECT)
    path.mkdir()
    for k, frame in enumerate(clip.frames):
        cv2.imwrite(str(path / f"{k:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    return path


GT = make_clip(28, size=SIZE, object_size=OBJECT).boxes_xywh  # the true boxes of write_frames(path, 28)


def box_text(box) -> str:
    return ",".join(f"{v:.3f}" for v in box)


def csv_row(frame: int, box=None, track="") -> str:
    values = ",,,," if box is None else ",".join(f"{v:.3f}" for v in box)
    return f"{frame},{values}{',' + str(track) if track != '' else ''}\n"


def write_jsonl(path: Path, rows: list[dict]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    return path


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder``, by relative path: the bytes a command must not change."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def run_cli(*args) -> tuple[int, str]:
    """The tool's command line in this process: its exit code and what it printed."""
    result = CliRunner().invoke(app, _with_default_command([str(a) for a in args]))
    return result.exit_code, result.stdout + result.stderr

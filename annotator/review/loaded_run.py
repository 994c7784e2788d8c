"""Reading a finished run back from its output folder: ``run.json`` and the track store, never an export."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from annotator.config import ConfigError, RunConfig, check_failure_model
from annotator.errors import EXIT_INPUT, EXIT_VALUE, ToolError
from annotator.flagging import FlagParams
from annotator.output_files import RUN_JSON
from annotator.review.segments import PreviousTrack
from annotator.track_store import STORE_NAME, RunStore, StoreError, read_store
from annotator.tracks import TrackResult, VideoInfo
from sptpt import params_from_mapping

__all__ = ["RUN_JSON", "LoadedRun", "load_run"]



@dataclass
class LoadedRun:
    """A run read back from its output folder: its run.json and its track store."""

    out_dir: Path
    info: dict[str, Any]  # run.json
    config: RunConfig
    store: RunStore
    targets: dict[int, dict[str, Any]]  # track_id -> run.json target
    formats: list[str]

    @property
    def video(self) -> VideoInfo:
        return self.store.video

    @property
    def tracks(self) -> list[TrackResult]:
        return list(self.store.tracks)

    @property
    def frame_indices(self) -> np.ndarray:
        return self.store.frame_indices

    def previous(self) -> dict[int, PreviousTrack]:
        return {t.track_id: PreviousTrack(t, np.asarray(t.scoring, dtype=object)) for t in self.store.tracks}


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ToolError(f"{path} does not exist: give the output folder of an sptpt-annotate run ({what})",
                        EXIT_INPUT) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ToolError(f"{path} cannot be read ({exc}): restore it or re-run the annotation", EXIT_INPUT) from None
    except json.JSONDecodeError as exc:
        raise ToolError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg}); restore it or re-run the annotation",
                        EXIT_INPUT) from None


def load_run(out_dir: str | os.PathLike) -> LoadedRun:
    """Read the run in ``out_dir`` back: ``run.json`` and the track store, never an export.

    Raises
    ------
    ToolError
        Exit code 3 when run.json or the store is missing, damaged or of
        another version (a folder written before track stores existed is
        rejected with how to redo it, or the failure-model file run.json
        names is gone), 4 when the configuration in run.json is not valid
        for this version or that failure-model file is damaged.
    """
    out_dir = Path(out_dir)
    if out_dir.is_file():
        raise ToolError(f"{out_dir} is a file: give the output folder an sptpt-annotate run wrote (the --out of "
                        "the run), not its video", EXIT_INPUT)
    if not out_dir.is_dir():
        raise ToolError(f"output folder {out_dir} does not exist: give the folder an sptpt-annotate run wrote",
                        EXIT_INPUT)
    run_path = out_dir / RUN_JSON
    info = _read_json(run_path, "run.json records the run")
    try:
        cfg = info["config"]
        config = RunConfig(preset=str(cfg["preset"]), tracker=params_from_mapping(cfg["tracker"]),
                           flags=FlagParams(**cfg["flags"]), seed=int(cfg["seed"]),
                           failure_model=cfg.get("failure_model"))
        # A run.json from before a flag setting existed gets its default, and says so when it is written again.
        cfg["flags"] = dataclasses.asdict(config.flags)
        targets = {int(t["track_id"]): t for t in info["targets"]}
        formats = list(info.get("formats") or [])
        # What re-tracking reads the frames back with (review.frames.open_run_source).
        if not isinstance(info["input"]["path"], str):
            raise TypeError("input.path must be a string")
        if not all(type(info["range"][key]) is int for key in ("start", "stop", "step")):
            raise TypeError("range start, stop and step must be integers")
    except (KeyError, TypeError, ValueError) as exc:
        raise ToolError(f"{run_path}: cannot use its configuration ({exc}); it was written by another version "
                        "or edited - re-run the annotation", EXIT_VALUE) from None
    if config.failure_model is not None:
        try:
            check_failure_model(config.failure_model)  # damaged or moved since the run
        except ConfigError as exc:
            raise ToolError(f"{exc} (the failure model {run_path} names)", exc.exit_code) from None
    store_path = out_dir / STORE_NAME
    if not store_path.exists():
        raise ToolError(f"{out_dir} holds no {STORE_NAME}: it was written by sptpt-annotate "
                        f"{info.get('tool_version', 'before 0.2')}, before runs kept a lossless track store; "
                        "re-run the annotation into it with --force", EXIT_INPUT)
    try:
        store = read_store(store_path)
    except StoreError as exc:
        raise ToolError(str(exc), EXIT_INPUT) from None
    ids = sorted(targets)
    found = sorted(t.track_id for t in store.tracks)
    if found != ids or not found:
        raise ToolError(f"{store_path} holds tracks {found} but {run_path} names tracks {ids}: the files are from "
                        "different runs - re-run the annotation", EXIT_INPUT)
    if any(not np.array_equal(t.frame_indices, store.frame_indices) for t in store.tracks):
        raise ToolError(f"{store_path}: its tracks cover different frames; restore the file or re-run the "
                        "annotation", EXIT_INPUT)
    return LoadedRun(out_dir=out_dir, info=info, config=config, store=store, targets=targets, formats=formats)

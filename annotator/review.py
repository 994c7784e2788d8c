"""The review loop on an output folder: read a run back, apply corrections, re-track, rewrite every output.

``sptpt-annotate retrack OUTPUT_DIR --corrections FILE`` and ``--corrections``
on the main command both come down to :func:`apply_corrections`.

Reading a run back
------------------
``run.json`` gives the source (path, range, content hash) and the
configuration; the track store (``tracks.npz``, :mod:`annotator.store`) every
per-frame value at full precision: boxes, scores, scoring stages, flags, and
the anchors (keyframe rows, with who gave them). No export is read. So a
re-track rewrites rows outside the affected spans bit for bit, and a
re-track with no new correction writes nothing at all (the outputs are
already those of the anchors: the command is idempotent). A folder written
before track stores existed is rejected with a message that says how to redo
it.

Additions to run.json
---------------------
A ``review`` section, written by the first re-track::

    "review": {
      "anchors": [{"track_id": 1, "frame": 120, "box_xywh": [x, y, w, h] | null, "source": "fix.csv:2"}, ...],
      "retracks": [{"created": ..., "corrections_file": ..., "anchors": [...], "segments": [...], ...}, ...]
    }

``anchors`` lists every human correction in force, for people reading the
file (re-tracking takes them from the store); ``retracks`` one entry per
re-track that changed something: its corrections, the segments re-tracked
and what changed in them.

Atomicity
---------
Every output is first written into a temporary folder beside the output
folder; only when all of them are complete are they moved in with
``os.replace`` (``run.json`` last). Any error before that leaves the output
folder exactly as it was, and the temporary folder is removed.

Overlay
-------
The overlay is re-rendered for the whole processed range from the tracks:
boxes, labels, corrected (keyframe) boxes and review marks. Particle clouds
and superpixels are not redrawn, on any frame: the tracker state that drew
them is gone for the kept frames, and a video that showed them on re-tracked
frames only would suggest a difference that is not there.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from annotator import __version__
from annotator.annotate import json_default
from annotator.atomic import write_text_atomic
from annotator.config import RunConfig
from annotator.corrections import read_corrections, resolve_corrections
from annotator.errors import EXIT_INPUT, EXIT_OUTPUT, EXIT_VALUE, ToolError
from annotator.exports import write_exports
from annotator.flagging import FlagParams
from annotator.frames import DecodeError, FrameSource, FrameSourceError, open_frames
from annotator.progress import Progress
from annotator.retrack import DEFAULT_MERGE, PreviousTrack, RetrackResult, retrack_tracks
from annotator.store import STORE_NAME, RunStore, StoreError, read_store, write_store
from annotator.tracks import KEYFRAME_GIVEN, TrackResult, VideoInfo
from sptpt.params import params_from_mapping

__all__ = ["LoadedRun", "ReviewResult", "SourceFrames", "apply_corrections", "load_run"]

RUN_JSON = "run.json"
OVERLAY_NAME = "overlay.mp4"
#: Memory a backward pass may spend on buffered frames; longer spans are re-read in chunks of this size
#: (see :mod:`annotator.retrack`). 512 MiB is ~580 frames of 640x480, ~85 of 1080p.
BUFFER_BYTES = 512 * 2**20


# --------------------------------------------------------------------------- reading a run


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
        rejected with how to redo it), 4 when the configuration in run.json
        is not valid for this version.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise ToolError(f"output folder {out_dir} does not exist: give the folder an sptpt-annotate run wrote",
                        EXIT_INPUT)
    run_path = out_dir / RUN_JSON
    info = _read_json(run_path, "run.json records the run")
    try:
        cfg = info["config"]
        config = RunConfig(preset=str(cfg["preset"]), tracker=params_from_mapping(cfg["tracker"]),
                           flags=FlagParams(**cfg["flags"]), seed=int(cfg["seed"]))
        targets = {int(t["track_id"]): t for t in info["targets"]}
        formats = list(info.get("formats") or [])
    except (KeyError, TypeError, ValueError) as exc:
        raise ToolError(f"{run_path}: cannot use its configuration ({exc}); it was written by another version "
                        "or edited - re-run the annotation", EXIT_VALUE) from None
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


# --------------------------------------------------------------------------- frames


class SourceFrames:
    """A :class:`~annotator.retrack.FrameProvider` over a run's frame source, decoding sequentially.

    Reading forward continues the live decoder (a video is decoded once for
    all the segments of a re-track); reading backwards, or far ahead in an
    image folder, re-opens the source at the first frame wanted (for a video,
    ffmpeg decodes again from the start of the file).
    """

    def __init__(self, source: FrameSource, frame_indices: np.ndarray) -> None:
        self.source = source
        self.frame_indices = np.asarray(frame_indices, dtype=np.int64)
        self._live: Iterator | None = None
        self._next = 0

    def _open(self, lo: int) -> None:
        self.close()
        if getattr(self.source, "kind", "") == "images":
            sub = open_frames(self.source.path, start=int(self.frame_indices[lo]), stop=self.source.stop,
                              step=self.source.step, fps=self.source.fps)
            self._live, self._next = iter(sub), lo
        else:
            self._live, self._next = iter(self.source), 0

    def close(self) -> None:
        if self._live is not None and hasattr(self._live, "close"):
            self._live.close()
        self._live = None

    def frames(self, lo: int, hi: int) -> Iterator[tuple[int, np.ndarray]]:
        if lo >= hi:
            return
        images = getattr(self.source, "kind", "") == "images"
        if self._live is None or self._next > lo or (images and lo - self._next > 8):
            self._open(lo)
        while self._next < hi:
            try:
                index, frame = next(self._live)
            except StopIteration:
                raise ToolError(f"{self.source.path}: ended before frame {int(self.frame_indices[self._next])} "
                                "that the run processed; the input changed - re-run the annotation", EXIT_INPUT) from None
            position = self._next
            if index != self.frame_indices[position]:
                raise ToolError(f"{self.source.path}: decoded frame {index} where the run had frame "
                                f"{int(self.frame_indices[position])}; the input changed - re-run the annotation",
                                EXIT_INPUT)
            self._next = position + 1
            if position >= lo:
                yield position, frame


def _open_source(run: LoadedRun, *, verify_input: bool) -> FrameSource:
    source_info, rng = run.info["input"], run.info["range"]
    path = Path(source_info["path"])
    try:
        source = open_frames(path, start=int(rng["start"]), stop=int(rng["stop"]), step=int(rng["step"]))
    except FrameSourceError as exc:
        raise ToolError(f"{exc} (the input recorded in {run.out_dir / RUN_JSON})", EXIT_INPUT) from None
    if (source.width, source.height, source.frame_count) != (run.video.width, run.video.height, run.video.frame_count):
        raise ToolError(f"{path} is now {source.width}x{source.height} with {source.frame_count} frames, the run had "
                        f"{run.video.width}x{run.video.height} with {run.video.frame_count}: the input changed - "
                        "re-run the annotation", EXIT_INPUT)
    if not np.array_equal(source.indices[: len(run.frame_indices)], run.frame_indices):
        raise ToolError(f"{path}: the frames of the recorded range do not match flags.csv: re-run the annotation",
                        EXIT_INPUT)
    if verify_input and source_info.get("content_hash"):
        from annotator.annotate import content_hash

        if content_hash(path) != source_info["content_hash"]:
            raise ToolError(f"{path} changed since the run (its content hash differs from run.json): corrections "
                            "refer to the frames the run saw - re-run the annotation on the new input", EXIT_INPUT)
    return source


# --------------------------------------------------------------------------- writing


@dataclass
class ReviewResult:
    """What :func:`apply_corrections` did."""

    out_dir: Path
    retrack: RetrackResult | None
    written: list[Path] = field(default_factory=list)
    flagged_before: int = 0
    flagged_after: int = 0

    @property
    def changed(self) -> bool:
        return self.retrack is not None and self.retrack.changed

    def summary(self) -> str:
        if not self.changed:
            return f"every correction is already applied; nothing re-tracked, {self.out_dir} unchanged"
        r = self.retrack
        frames = sum(s.frames for s in r.segments)
        return (f"{len(r.anchors)} new or changed correction{'s' if len(r.anchors) != 1 else ''}; re-tracked "
                f"{frames} frames in {len(r.segments)} span{'s' if len(r.segments) != 1 else ''} in {r.seconds:.1f} s; "
                f"{self.flagged_after} frame boxes flagged for review (was {self.flagged_before}); "
                f"outputs rewritten in {self.out_dir}")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return "sha256:" + digest.hexdigest()


def _box_list(box) -> list[float] | None:
    return None if box is None else [float(v) for v in box]


def apply_corrections(
    out_dir: str | os.PathLike,
    corrections_path: str | os.PathLike,
    *,
    merge: str = DEFAULT_MERGE,
    show_progress: bool = True,
    verify_input: bool = True,
    rewrite_unchanged: bool = False,
) -> ReviewResult:
    """Apply a corrections file to the run in ``out_dir``, re-track what they affect, rewrite every output.

    Parameters
    ----------
    out_dir : path-like
        Output folder of an ``sptpt-annotate`` run (holding run.json and flags.csv).
    corrections_path : path-like
        CSV ``frame,x,y,w,h[,track_id]`` or COCO with ``attributes.keyframe``
        (:mod:`annotator.corrections`).
    merge : str
        How the forward and backward passes combine (:data:`annotator.retrack.MERGES`).
    show_progress : bool
        Progress bars on stderr.
    verify_input : bool
        Check the input's content hash against run.json (reads the whole input once).
    rewrite_unchanged : bool
        Rewrite the outputs even when no correction is new (they come out
        the same; for tests and to regenerate a deleted output).

    Returns
    -------
    ReviewResult

    Raises
    ------
    ToolError
        Malformed corrections or ones that do not fit the run (exit 4, naming
        FILE:LINE), missing or inconsistent run files or input (3), an output
        folder that cannot be written (5). The output folder is then unchanged.
    """
    out_dir = Path(out_dir)
    corrections_path = Path(corrections_path)
    corrections = read_corrections(corrections_path)
    run = load_run(out_dir)
    resolved = resolve_corrections(corrections, frame_indices=run.frame_indices, track_ids=[t.track_id for t in run.tracks],
                                   width=run.video.width, height=run.video.height)
    source = _open_source(run, verify_input=verify_input)
    provider = SourceFrames(source, run.frame_indices)
    bar: list[Progress] = []

    def progress(done: int, total: int) -> None:
        if not bar:
            bar.append(Progress(total, label="re-tracked frames", enabled=show_progress))
        bar[0].advance(done - bar[0].done)

    result = ReviewResult(out_dir=out_dir, retrack=None, flagged_before=sum(int(t.flagged.sum()) for t in run.tracks))
    try:
        try:
            max_buffer = max(8, BUFFER_BYTES // (run.video.width * run.video.height * 3))
            retrack = retrack_tracks(provider, run.frame_indices, resolved, run.config, previous=run.previous(),
                                     width=run.video.width, height=run.video.height, merge=merge, progress=progress,
                                     max_buffer_frames=max_buffer)
        except DecodeError as exc:
            raise ToolError(f"{exc}; nothing in {out_dir} was changed", EXIT_INPUT) from None
        finally:
            if bar:
                bar[0].close()
        result.retrack = retrack
        result.flagged_after = sum(int(t.flagged.sum()) for t in retrack.tracks)
        if not retrack.changed and not rewrite_unchanged:
            return result
        result.written = _write_all(run, retrack, provider, corrections_path, merge=merge, show_progress=show_progress)
    finally:
        provider.close()
    return result


def _review_section(run: LoadedRun, retrack: RetrackResult, corrections_path: Path, merge: str) -> dict[str, Any]:
    """run.json's record of the corrections in force and of the re-tracks; written for people, never read back
    (the anchors that re-tracking uses are the store's keyframe rows)."""
    review = dict(run.info.get("review") or {})
    anchors = {(int(a["track_id"]), int(a["frame"])): a for a in review.get("anchors", [])}
    for change in retrack.anchors:
        anchors[(change.track_id, change.frame)] = {
            "track_id": change.track_id, "frame": change.frame, "box_xywh": _box_list(change.box_after),
            "source": change.where}
    history = list(review.get("retracks", []))
    if retrack.changed:
        history.append({
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "tool_version": __version__,
            "corrections_file": str(corrections_path.resolve()),
            "corrections_hash": _sha256(corrections_path),
            "merge": merge,
            "anchors": [c.to_dict() for c in retrack.anchors],
            "segments": [s.to_dict() for s in retrack.segments],
            "frames_tracked": retrack.frames_tracked,
            "seconds": round(retrack.seconds, 3),
        })
    return {"anchors": [anchors[k] for k in sorted(anchors)], "retracks": history}


def _report_review(review: dict[str, Any], tracks: Sequence[TrackResult], fps: float) -> dict[str, Any]:
    """What the report's Corrections section shows."""
    from annotator.report import _seek_seconds

    def fmt(box) -> str:
        return "absent" if box is None else ", ".join(f"{v:.1f}" for v in box)

    # Every human correction in force: the keyframes a person gave other than the first-frame boxes.
    anchors = sorted(
        ({"track_id": t.track_id, "frame": int(t.frame_indices[p]),
          "box": fmt(None if t.outside[p] else t.boxes_xywh[p]), "source": t.keyframe_source[p],
          "seconds": _seek_seconds(int(p), fps)}
         for t in tracks for p in np.flatnonzero(t.keyframe) if t.keyframe_source[p] != KEYFRAME_GIVEN),
        key=lambda a: (a["frame"], a["track_id"]))
    last = review["retracks"][-1] if review.get("retracks") else None
    if last is not None:
        last = {**last,
                "anchors": [{**a, "before": fmt(a["box_before"]), "after": fmt(a["box_after"]),
                             "iou_text": "" if a["iou"] is None else f"{a['iou']:.2f}"} for a in last["anchors"]],
                "segments": [{**s, "iou_text": "" if s["mean_iou"] is None else f"{s['mean_iou']:.2f}"}
                             for s in last["segments"]]}
    return {"anchors": anchors, "last": last, "count": len(review.get("retracks", []))}


def _write_all(run: LoadedRun, retrack: RetrackResult, provider: SourceFrames, corrections_path: Path, *,
               merge: str, show_progress: bool) -> list[Path]:
    out_dir = run.out_dir
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.retrack-", dir=out_dir.parent))
    except OSError:
        try:
            tmp = Path(tempfile.mkdtemp(prefix=".retrack-", dir=out_dir))
        except OSError as exc:
            raise ToolError(f"output folder {out_dir} cannot be written ({exc.strerror}); nothing was changed",
                            EXIT_OUTPUT) from None
    try:
        try:
            written = _write_outputs(tmp, run, retrack, provider, corrections_path, merge=merge,
                                     show_progress=show_progress)
        except DecodeError as exc:
            raise ToolError(f"{exc}; nothing in {out_dir} was changed", EXIT_INPUT) from None
        except OSError as exc:
            raise ToolError(f"cannot write the new outputs beside {out_dir} ({exc}); nothing was changed",
                            EXIT_OUTPUT) from None
        # Everything is complete: move it in, run.json last (its presence marks a finished run).
        done: list[Path] = []
        try:
            for rel in written:
                target = out_dir / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(tmp / rel, target)
                done.append(rel)
        except OSError as exc:
            raise ToolError(f"output folder {out_dir} could not take the new outputs ({exc}) after "
                            f"{', '.join(map(str, done)) or 'no file'} had been replaced; run.json still describes "
                            "the previous state - fix the folder and run the re-track again", EXIT_OUTPUT) from None
        return [out_dir / rel for rel in written]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _write_outputs(tmp: Path, run: LoadedRun, retrack: RetrackResult, provider: SourceFrames, corrections_path: Path,
                   *, merge: str, show_progress: bool) -> list[Path]:
    """Write every output of the run's formats into ``tmp``; return their paths relative to it."""
    from annotator.pipeline import SpanThumbnail, _thumbnail
    from annotator.render import OverlayRenderer, OverlayWriter, items_from_tracks
    from annotator.report import render_report, track_summary

    formats, tracks, video = run.formats, retrack.tracks, run.video
    store = RunStore(video=video, start=run.store.start, stop=run.store.stop, step=run.store.step, tracks=tracks)
    written: dict[str, list[Path]] = {"store": [write_store(tmp / STORE_NAME, store).relative_to(tmp)]}
    written.update({name: [p.relative_to(tmp) for p in paths]
                    for name, paths in write_exports(tmp, store, formats).items()})
    thumbnails: list[SpanThumbnail] = []
    if "overlay" in formats:
        renderer = OverlayRenderer()
        in_span = {t.track_id: False for t in tracks}
        n = len(run.frame_indices)
        bar = Progress(n, label="overlay frames", enabled=show_progress)
        with OverlayWriter(tmp / OVERLAY_NAME, fps=video.fps, width=video.width, height=video.height) as writer:
            for position, frame in provider.frames(0, n):
                index = int(run.frame_indices[position])
                drawn = renderer.annotate(frame, items_from_tracks(tracks, index))
                writer.write(drawn)
                for t in tracks:
                    flagged = bool(t.flagged[position])
                    if flagged and not in_span[t.track_id]:
                        thumbnails.append(SpanThumbnail(t.track_id, position, index, _thumbnail(drawn)))
                    in_span[t.track_id] = flagged
                bar.advance()
        bar.close()
        written["overlay"] = [Path(OVERLAY_NAME)]
    info = dict(run.info)
    info["tracks"] = [track_summary(t) for t in tracks]
    info["review"] = _review_section(run, retrack, corrections_path, merge)
    if "report" in formats:
        timings = info.get("timings") or {}
        render_report(
            tmp / "report.html", video=video, tracks=tracks, thumbnails=thumbnails, settings=run.config.to_dict(),
            run_info={**info, "frames_processed": info.get("frames_processed", len(run.frame_indices)),
                      "seconds_total": timings.get("seconds_total") or 0.0,
                      "seconds_tracking": timings.get("seconds_tracking") or 0.0,
                      "seconds_outside": timings.get("seconds_outside_tracker") or 0.0},
            overlay_name=OVERLAY_NAME if "overlay" in formats else None,
            review=_report_review(info["review"], tracks, video.fps),
        )
        written["report"] = [Path("report.html")]
    info["outputs"] = {k: [str(p) for p in v] for k, v in written.items()}
    write_text_atomic(tmp / RUN_JSON, json.dumps(info, indent=2, default=json_default) + "\n")
    files = [p for paths in written.values() for p in paths]
    return files + [Path(RUN_JSON)]


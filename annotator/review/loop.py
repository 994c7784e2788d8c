"""The review loop on an output folder: read a run back, apply corrections, re-track, rewrite every output.

``sptpt-annotate retrack OUTPUT_DIR --corrections FILE`` and ``--corrections``
on the main command both come down to :func:`apply_corrections`.

Reading a run back
------------------
``run.json`` gives the source (path, range, content hash) and the
configuration; the track store (``tracks.npz``, :mod:`annotator.track_store`) every
per-frame value at full precision: boxes, scores, scoring stages, flags, and
the anchors (keyframe rows, with who gave them). No export is read. So a
re-track rewrites rows outside the affected spans bit for bit, and a
re-track with no new correction writes nothing at all (the outputs are
already those of the anchors: the command is idempotent), unless a
``--no-render`` round removed the overlay, which it then renders again. A folder written
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
folder; only when all of them are complete are they moved in by
:func:`annotator.publish.move_into_place` (the track store next to last,
``run.json`` last). Any error before that leaves the output folder exactly
as it was, and the temporary folder is removed.

Overlay
-------
The overlay is re-rendered for the whole processed range from the tracks:
boxes, labels, the given first-frame box and corrected boxes, and review marks. Particle clouds
and superpixels are not redrawn, on any frame: the tracker state that drew
them is gone for the kept frames, and a video that showed them on re-tracked
frames only would suggest a difference that is not there.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from annotator.atomic import ctrl_c_ignored
from annotator.corrections import resolve_corrections
from annotator.errors import EXIT_INPUT, EXIT_OUTPUT, ToolError
from annotator.exports import ExportOptions
from annotator.frame_sources import DecodeError
from annotator.output_folder import folder_lock, remove_staging_folders, staging_folder
from annotator.pass_cache import PASSES_NAME, keep_anchored, read_pass_cache
from annotator.pipeline import OverlaySink, render_tracks
from annotator.progress import Progress
from annotator.provenance import content_hash
from annotator.publish import OVERLAY_NAME, MoveError, move_into_place, run_fingerprint, write_run_files
from annotator.render import OverlayWriter
from annotator.review.imports import read_run_corrections
from annotator.review.loaded_run import LoadedRun, load_run
from annotator.review.merge import DEFAULT_MERGE
from annotator.review.retrack import RetrackResult, retrack_tracks
from annotator.review.source_frames import BUFFER_BYTES, SourceFrames, checks_content_hash, open_run_source
from annotator.track_store import RunStore
from annotator.tracks import SpanThumbnail, TrackResult
from annotator.version import __version__
from annotator.wording import plural

__all__ = ["ReviewResult", "apply_corrections", "correct_run"]


@dataclass
class ReviewResult:
    """What :func:`apply_corrections` did.

    Attributes
    ----------
    out_dir : Path
        The run's output folder.
    retrack : RetrackResult or None
        The re-track; None when the corrections could not be applied.
    written : list of Path
        The files rewritten (none when no correction was new).
    flagged_before, flagged_after : int
        Flagged frames of all tracks before and after.
    overlay_removed : bool
        The overlay was removed, not re-rendered (``--no-render``): it would show the old boxes.
    overlay_restored : bool
        The overlay was rendered again after a ``--no-render`` round had removed it.
    """

    out_dir: Path
    retrack: RetrackResult | None
    written: list[Path] = field(default_factory=list)
    flagged_before: int = 0
    flagged_after: int = 0
    overlay_removed: bool = False
    overlay_restored: bool = False

    @property
    def changed(self) -> bool:
        return self.retrack is not None and self.retrack.changed

    def summary(self) -> str:
        if not self.changed:
            if self.written:
                why = ("; overlay.mp4 rendered again (a --no-render round had removed it)" if self.overlay_restored
                       else "")
                return (f"every correction is already applied; nothing re-tracked; outputs rewritten in "
                        f"{self.out_dir}{why}")
            return f"every correction is already applied; nothing re-tracked, {self.out_dir} unchanged"
        r = self.retrack
        assert r is not None  # changed: a re-track ran
        frames = sum(s.frames for s in r.segments)
        from annotator.run_report import keyframe_note

        note = keyframe_note(r.tracks, self.out_dir)
        return (f"{plural(len(r.anchors), 'new or changed correction')}; re-tracked "
                f"{plural(frames, 'frame')} in {plural(len(r.segments), 'span')} in {r.seconds:.1f} s; "
                f"{plural(self.flagged_after, 'frame box', 'frame boxes')} flagged for review "
                f"(was {self.flagged_before}); "
                f"outputs rewritten in {self.out_dir}"
                + ("; overlay.mp4 removed (--no-render): a retrack without --no-render (with this corrections file "
                   "again if nothing is new) renders it again" if self.overlay_removed else "")
                + (f"\n{note}" if note else ""))


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
    input_path: str | os.PathLike | None = None,
    render: bool = True,
    media_url: str | None = None,
) -> ReviewResult:
    """Apply a corrections file to the run in ``out_dir``, re-track what they affect, rewrite every output.

    Parameters
    ----------
    out_dir : path-like
        Output folder of an ``sptpt-annotate`` run (holding run.json and flags.csv).
    corrections_path : path-like
        CSV ``frame,x,y,w,h[,track_id]`` or COCO with ``attributes.keyframe``
        (:mod:`annotator.corrections`), or the run's ``cvat.xml`` or
        ``labelstudio.json`` after review (:mod:`annotator.review.imports`).
    merge : str
        How the forward and backward passes combine (:data:`annotator.review.MERGES`).
    show_progress : bool
        Progress bars on stderr.
    verify_input : bool
        Check the input's content hash against run.json (reads the whole input once).
    rewrite_unchanged : bool
        Rewrite the outputs even when no correction is new (they come out
        the same; for tests and to regenerate a deleted output).
    input_path : path-like, optional
        Where the input is now, when it moved since the run; checked against
        the content hash in run.json, and recorded there once the re-track
        is written.
    render : bool
        Re-render the overlay (if the run has one). Without, it is removed,
        since it would show the old boxes; the report then has no overlay
        or thumbnails, and the next re-track that renders writes it again.
        The overlay is decoded and encoded in full every time: on a long
        video, most of a round's time.
    media_url : str, optional
        A new URL of the video for ``labelstudio.json`` (``--media-url``),
        recorded in run.json; None keeps the run's.

    Returns
    -------
    ReviewResult
        Whether the corrections changed anything, the re-track (its tracks, anchors and changed segments), the
        files rewritten, and the flagged frames before and after.

    Raises
    ------
    ToolError
        Malformed corrections or ones that do not fit the run (exit 4, naming
        FILE:LINE), missing or inconsistent run files or input (3), an output
        folder that cannot be written (5). The output folder is then unchanged.

    Examples
    --------
    >>> from pathlib import Path
    >>> from annotator import annotate, apply_corrections
    >>> _ = annotate("samples/clip.mp4", (136, 129, 48, 40), out_dir="clip_out", stop=8, formats=("otb", "flags"),
    ...              show_progress=False)
    >>> _ = Path("fixes.csv").write_text("frame,x,y,w,h\\n5,140.0,130.0,48.0,40.0\\n")
    >>> review = apply_corrections("clip_out", "fixes.csv", show_progress=False)
    >>> review.changed, review.retrack.tracks[0].boxes_xywh[5].tolist()
    (True, [140.0, 130.0, 48.0, 40.0])
    """
    return correct_run(out_dir, corrections_path, merge=merge, show_progress=show_progress, verify_input=verify_input,
                       rewrite_unchanged=rewrite_unchanged, input_path=input_path, render=render, media_url=media_url)


def correct_run(out_dir: str | os.PathLike, corrections_path: str | os.PathLike, *, merge: str = DEFAULT_MERGE,
                show_progress: bool = True, verify_input: bool = True, rewrite_unchanged: bool = False,
                input_path: str | os.PathLike | None = None, input_checked: bool = False, render: bool = True,
                media_url: str | None = None) -> ReviewResult:
    """:func:`apply_corrections`, for the tool's own callers: ``input_checked`` says the caller has just read the
    input and recorded its content hash in run.json (``track --corrections`` right after the run), so it counts
    as verified without ``verify_input`` reading it again."""
    out_dir, corrections_path = Path(out_dir), Path(corrections_path)
    with folder_lock(out_dir):
        remove_staging_folders(out_dir)  # under the folder's lock, any staging folder is a dead run's
        run, resolved = _run_and_corrections(out_dir, corrections_path, media_url)
        provider, checked = _open_input(run, verify_input=verify_input, input_path=input_path,
                                        input_checked=input_checked)
        result = ReviewResult(out_dir=out_dir, retrack=None,
                              flagged_before=sum(int(t.flagged.sum()) for t in run.tracks))
        # The passes this run already ran and that its anchors still start: the re-track runs only the others.
        passes = read_pass_cache(out_dir / PASSES_NAME, run_fingerprint(run.info)) if checked else None
        try:
            result.retrack = retrack = _retrack(run, resolved, provider, merge=merge, passes=passes,
                                                show_progress=show_progress)
            result.flagged_after = sum(int(t.flagged.sum()) for t in retrack.tracks)
            _rewrite_if_needed(result, retrack, run, provider, corrections_path, merge=merge,
                               show_progress=show_progress, passes=passes, render=render,
                               always=rewrite_unchanged or media_url is not None)
        finally:
            provider.close()
        return result


def _run_and_corrections(out_dir: Path, corrections_path: Path, media_url: str | None) -> tuple[LoadedRun, dict]:
    """The run in ``out_dir`` (with a new ``media_url`` recorded) and its corrections, checked against it."""
    run = load_run(out_dir)
    corrections = read_run_corrections(corrections_path, video=run.video, tracks=run.tracks,
                                       frames=range(run.store.start, run.store.stop, run.store.step),
                                       exported=run.info.get("review_exports"))
    if media_url is not None:
        run.info["export_options"] = {**(run.info.get("export_options") or {}), "media_url": media_url}
    resolved = resolve_corrections(corrections, frame_indices=run.frame_indices,
                                   track_ids=[t.track_id for t in run.tracks],
                                   width=run.video.width, height=run.video.height)
    return run, resolved


def _open_input(run: LoadedRun, *, verify_input: bool, input_path: str | os.PathLike | None,
                input_checked: bool) -> tuple[SourceFrames, bool]:
    """The run's frames, decoded again (from ``input_path`` when it moved, recorded in the run), and whether its
    content hash was checked."""
    source = open_run_source(run, verify_input=verify_input, input_path=input_path, input_checked=input_checked)
    # Kept passes only for the bytes they were computed on: an input that was not checked (--no-verify, or a run
    # without a content hash) may have changed, and its passes would be stored under the recorded hash.
    checked = checks_content_hash(run, verify_input=verify_input or input_checked, input_path=input_path)
    if input_path is not None:
        moved = str(Path(input_path).resolve())
        run.info["input"] = {**run.info["input"], "path": moved}
        run.store = dataclasses.replace(run.store, video=dataclasses.replace(run.store.video, path=moved))
    return SourceFrames(source, run.frame_indices), checked


def _retrack(run: LoadedRun, resolved: dict, provider: SourceFrames, *, merge: str, passes: dict | None,
             show_progress: bool) -> RetrackResult:
    """Re-track what the corrections affect, with a progress bar once the work is known."""
    bar: list[Progress] = []

    def progress(done: int, total: int) -> None:
        if not bar:
            bar.append(Progress(total, label="re-tracked frames", enabled=show_progress))
        bar[0].advance(done - bar[0].done)

    try:
        max_buffer = max(8, BUFFER_BYTES // (run.video.width * run.video.height * 3))
        return retrack_tracks(provider, run.frame_indices, resolved, run.config, previous=run.previous(),
                              width=run.video.width, height=run.video.height, merge=merge, progress=progress,
                              max_buffer_frames=max_buffer, pass_cache=passes)
    except DecodeError as exc:
        raise ToolError(f"{exc}; nothing in {run.out_dir} was changed", EXIT_INPUT) from None
    finally:
        if bar:
            bar[0].close()


def _rewrite_if_needed(result: ReviewResult, retrack: RetrackResult, run: LoadedRun, provider: SourceFrames,
                       corrections_path: Path, *, merge: str, show_progress: bool, passes: dict | None, render: bool,
                       always: bool) -> None:
    """Rewrite the outputs when the re-track changed something, when ``always``, or when this round renders the
    overlay a ``--no-render`` round removed (it gets it back)."""
    overlay_missing = render and "overlay" in run.formats and (
        not (run.out_dir / OVERLAY_NAME).exists() or "overlay" not in (run.info.get("outputs") or {}))
    if not retrack.changed and not always and not overlay_missing:
        return
    result.written, result.overlay_removed = _write_all(
        run, retrack, provider, corrections_path, merge=merge, show_progress=show_progress, passes=passes,
        render=render)
    result.overlay_restored = overlay_missing


def _review_section(run: LoadedRun, retrack: RetrackResult, corrections_path: Path, merge: str,
                    rendered: bool) -> dict[str, Any]:
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
            "corrections_hash": content_hash(corrections_path),
            "merge": merge,
            "anchors": [c.to_dict() for c in retrack.anchors],
            "segments": [s.to_dict() for s in retrack.segments],
            "frames_tracked": retrack.frames_tracked,
            **({"overlay": "rendered" if rendered else "removed (--no-render)"} if "overlay" in run.formats else {}),
            "seconds": round(retrack.seconds, 3),
        })
    return {"anchors": [anchors[k] for k in sorted(anchors)], "retracks": history}


def _write_all(run: LoadedRun, retrack: RetrackResult, provider: SourceFrames, corrections_path: Path, *,
               merge: str, show_progress: bool, passes: dict | None, render: bool) -> tuple[list[Path], bool]:
    """Write every output into a staging folder inside the run's, then move them in: their paths, and whether a
    stale overlay went."""
    out_dir = run.out_dir
    with staging_folder(out_dir) as staging:
        tmp = staging.path
        try:
            written = _write_outputs(tmp, run, retrack, provider, corrections_path, merge=merge,
                                     show_progress=show_progress, passes=passes, render=render)
        except DecodeError as exc:
            raise ToolError(f"{exc}; nothing in {out_dir} was changed", EXIT_INPUT) from None
        except OSError as exc:
            raise ToolError(f"cannot write the new outputs into {out_dir} ({exc}); nothing was changed",
                            EXIT_OUTPUT) from None
        # Everything is complete: move it in. A stale overlay (a --no-render round: it shows the boxes before this
        # re-track) goes with it; run.json is kept until the last move, so that a failure leaves a run to re-track.
        stale = [OVERLAY_NAME] if not render and "overlay" in run.formats and (out_dir / OVERLAY_NAME).is_file() else []
        with ctrl_c_ignored():
            try:
                paths = move_into_place(tmp, out_dir, written, retire=stale)
            except MoveError as exc:
                if exc.blocked is not None:
                    raise ToolError(f"{exc.blocked} cannot be removed ({exc.cause.strerror}; is it open in a "
                                    "player?): close it and run the re-track again; nothing was changed",
                                    EXIT_OUTPUT) from None
                raise ToolError(f"output folder {out_dir} could not take the new outputs ({exc.cause}) after "
                                f"{', '.join(map(str, exc.moved)) or 'no file'} had been replaced; run.json still "
                                "describes the previous state - fix the folder and run the re-track again",
                                EXIT_OUTPUT) from None
        return paths, bool(stale)


def _write_outputs(tmp: Path, run: LoadedRun, retrack: RetrackResult, provider: SourceFrames, corrections_path: Path,
                   *, merge: str, show_progress: bool, passes: dict | None, render: bool) -> list[Path]:
    """Write every output of the run's formats, and the passes kept, into ``tmp``; return their paths relative to it."""
    tracks = retrack.tracks
    store = RunStore(video=run.video, start=run.store.start, stop=run.store.stop, step=run.store.step,
                     tracks=tuple(tracks))
    rendered = "overlay" in run.formats and render
    thumbnails = _render_overlay(tmp / OVERLAY_NAME, run, tracks, provider, show_progress) if rendered else []
    info = {**run.info, "review": _review_section(run, retrack, corrections_path, merge, rendered)}
    written = write_run_files(
        tmp, store, info, settings=run.config.to_dict(),
        options=ExportOptions(media_url=(run.info.get("export_options") or {}).get("media_url")),
        # Without passes (input not checked) the folder's file is left as it was: still right for the recorded input.
        passes=keep_anchored(passes, tracks) if passes is not None else None,
        passes_kept=(run.out_dir / PASSES_NAME).is_file(), thumbnails=thumbnails, overlay=rendered)
    return [path.relative_to(tmp) for paths in written.values() for path in paths]


def _render_overlay(path: Path, run: LoadedRun, tracks: list[TrackResult], provider: SourceFrames,
                    show_progress: bool) -> list[SpanThumbnail]:
    """The overlay of the re-tracked run, drawn from its tracks by the pipeline's overlay sink; its thumbnails."""
    n, video = len(run.frame_indices), run.video
    with (Progress(n, label="overlay frames", enabled=show_progress) as bar,
          OverlayWriter(path, fps=video.fps, width=video.width, height=video.height) as writer):
        return render_tracks(OverlaySink(writer), provider.frames(0, n), run.frame_indices, tracks, progress=bar)

"""``sptpt-annotate batch``: label every video of a manifest (or an OTB root), resumably, in parallel."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, cast

import typer

from annotator.commands.common import fail
from annotator.errors import EXIT_OK, EXIT_USAGE, EXIT_VALUE, ToolError, require_extra
from annotator.output_files import DEFAULT_FORMATS
from annotator.wording import plural


def batch_command(
    manifest: Optional[Path] = typer.Argument(None, help="Manifest: .csv, .jsonl or .yaml; each item a video and its first-frame box."),
    out: Path = typer.Option(..., "--out", help="Output folder: one subfolder per item, plus annotations.json, summary.json, failures.jsonl, report.html."),
    otb_root: Optional[Path] = typer.Option(None, "--otb-root", help="Use an OTB-layout root as the manifest (boxes from each ground truth's first line)."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Parallel worker processes on this machine (default: the number of cores)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Address of a Dask distributed scheduler to run the items on instead."),
    box_origin: int = typer.Option(0, "--box-origin", help="1 to read the boxes of items without a box_origin field as OTB-style 1-based coordinates."),
    start: Optional[int] = typer.Option(None, "--start", help="First frame of items whose manifest row gives none (default 0)."),
    stop: Optional[int] = typer.Option(None, "--stop", help="Stop before this frame in items whose row gives none (default: the end)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="Tracker preset for all items (item params override)."),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML file with preset, seed, tracker and flags keys."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Base seed (default 0); each item's seed derives from it and the item id."),
    formats: str = typer.Option(",".join(DEFAULT_FORMATS), "--formats", help="Comma-separated outputs per item, as for a single video (otb, coco, flags, overlay, report, cvat, mot, labelstudio, yolo)."),
    media_url: Optional[str] = typer.Option(
        None, "--media-url", metavar="URL", help="Where a Label Studio server finds the videos, ending in / or = "
                                                 "(e.g. /data/local-files/?d=videos/): each task's data.video is it "
                                                 "followed by the video's file name (docs/review-tools.md)."),
    no_render: bool = typer.Option(False, "--no-render", help="Skip the overlay videos (faster)."),
    force: bool = typer.Option(False, "--force", help="Redo every item, finished ones included."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress line and no summary (errors and warnings still show)."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks."),
) -> None:
    """Label a dataset: every manifest item in parallel; finished items are skipped on a rerun; failures stay isolated."""
    from annotator.batch import BatchRequest, run_batch
    from annotator.config import ConfigError, load_config_file
    from annotator.manifest import InvalidManifestError, items_from_otb_root, read_manifest

    try:
        if (manifest is None) == (otb_root is None):
            raise ToolError("give either a MANIFEST file or --otb-root DIR (one of them)", EXIT_USAGE)
        if scheduler is not None:
            require_extra("--scheduler")  # before the manifest is read: a missing install is the first thing to fix
        _check_box_origin(box_origin, otb_root)
        try:
            items = (items_from_otb_root(otb_root) if otb_root is not None
                     else read_manifest(cast(Path, manifest), box_origin=box_origin))  # exactly one of the two (above)
            file_values = load_config_file(config_file) if config_file is not None else {}
            chosen = [f.strip() for f in formats.split(",") if f.strip()]
            if media_url is not None and not media_url.endswith(("/", "=")):
                raise ToolError(f"--media-url {media_url!r} would give every video of the batch the same URL: end it "
                                "with / or = (e.g. /data/local-files/?d=videos/), and each video's file name is "
                                "appended", EXIT_VALUE)
            if no_render:
                chosen = [f for f in chosen if f != "overlay"]
            request = BatchRequest(config_values=file_values, config_source=str(config_file or "command line"),
                                   preset=preset, seed=seed, formats=chosen, start=start, stop=stop,
                                   media_url=media_url)
            result = run_batch(items, request, out_dir=out, force=force, workers=workers, scheduler=scheduler,
                               show_progress=not quiet, manifest=str(otb_root or manifest))
        except InvalidManifestError as exc:
            if debug:
                raise
            for error in exc.errors[:50]:
                typer.echo(f"sptpt-annotate: error: {error}", err=True)
            if len(exc.errors) > 50:
                typer.echo(f"sptpt-annotate: ... and {len(exc.errors) - 50} more problems", err=True)
            raise typer.Exit(exc.exit_code) from None
        except ConfigError as exc:
            raise ToolError(str(exc), exc.exit_code) from None
    except ToolError as error:
        fail(error, debug)
    counts = result.counts
    message = (f"{plural(counts['items'], 'item')}: {counts['done']} done ({counts['reused']} kept from an earlier "
               f"run), {counts['partial']} partly decoded, {counts['failed']} failed; "
               f"{plural(result.frames_this_run, 'frame')} tracked in {result.seconds:.1f} s; "
               f"index {result.paths['report']}")
    lost = [r["id"] for r in result.rows if r.get("keyframes_asked")]
    lost_note = (f"{plural(len(lost), 'item')} with a track that looks lost and asks for keyframes (box them, then "
                 f"retrack the item's folder; see its report.html): {', '.join(lost[:10])}"
                 + (f" and {len(lost) - 10} more" if len(lost) > 10 else "")) if lost else ""
    if result.exit_code != EXIT_OK:
        typer.echo(f"sptpt-annotate: warning: {message}; reasons in {result.paths['failures']}", err=True)
        if lost_note:
            typer.echo(lost_note, err=True)
        raise typer.Exit(result.exit_code)
    if not quiet:
        typer.echo(message, err=True)
        if lost_note:
            typer.echo(lost_note, err=True)


def _check_box_origin(box_origin: int, otb_root: Path | None) -> None:
    if box_origin not in (0, 1):
        raise ToolError(f"--box-origin {box_origin} is invalid: expected 0 (default) or 1 (OTB)", EXIT_VALUE)
    if otb_root is not None and box_origin:
        raise ToolError("--box-origin applies to a manifest's boxes: --otb-root reads OTB's 1-based ground "
                        "truth as such already; drop --box-origin", EXIT_USAGE)

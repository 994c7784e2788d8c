"""The review report: one self-contained HTML page per run (Jinja2 template in ``templates/``)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import jinja2
import numpy as np
from markupsafe import Markup

from annotator.atomic import write_text_atomic
from annotator.flagging import spans_from_mask
from annotator.pipeline import SpanThumbnail
from annotator.tracks import TrackResult

__all__ = ["FlaggedSpan", "flagged_spans", "track_summary", "render_report", "templates_dir"]

REPORT_TEMPLATE = "report.html.j2"


def templates_dir() -> Path:
    """The folder holding the Jinja2 templates: the source tree's ``templates/``, or the installed copy."""
    candidates = [
        Path(__file__).resolve().parent.parent / "templates",
        Path(sys.prefix) / "share" / "sptpt-annotate" / "templates",
    ]
    for candidate in candidates:
        if (candidate / REPORT_TEMPLATE).is_file():
            return candidate
    raise FileNotFoundError(f"report template {REPORT_TEMPLATE} not found in {', '.join(map(str, candidates))}; reinstall the package")


@dataclass(frozen=True)
class FlaggedSpan:
    """A run of consecutive flagged frames of one track."""

    track_id: int
    start: int  # position in the processed frame list
    stop: int  # exclusive
    first_frame: int  # source frame index
    last_frame: int
    min_confidence: float
    reasons: tuple[str, ...]

    @property
    def length(self) -> int:
        return self.stop - self.start


def flagged_spans(track: TrackResult) -> list[FlaggedSpan]:
    """Every flagged span of a track, with its weakest confidence and the reasons seen in it."""
    spans = []
    for start, stop in spans_from_mask(track.flagged):
        reasons = sorted({part for r in track.reasons[start:stop] for part in r.split("+") if part})
        spans.append(FlaggedSpan(
            track_id=track.track_id, start=int(start), stop=int(stop),
            first_frame=int(track.frame_indices[start]), last_frame=int(track.frame_indices[stop - 1]),
            min_confidence=float(track.confidence[start:stop].min()), reasons=tuple(reasons)))
    return spans


def track_summary(track: TrackResult) -> dict[str, Any]:
    """Headline numbers of one track: frames, flagged share, longest flagged span, speed."""
    spans = flagged_spans(track)
    seconds = float(track.seconds.sum())
    n = len(track.frame_indices)
    return {
        "track_id": track.track_id,
        "label": track.label,
        "frames": n,
        "flagged": int(track.flagged.sum()),
        "flagged_share": float(track.flagged.mean()) if n else 0.0,
        "spans": len(spans),
        "longest_span": max((s.length for s in spans), default=0),
        "mean_confidence": float(track.confidence.mean()) if n else float("nan"),
        "seconds": seconds,
        "fps": n / seconds if seconds > 0 else float("nan"),
    }


def _seek_seconds(position: int, fps: float) -> float:
    """Overlay time that shows processed frame ``position``: the middle of its display interval.

    Seeking to ``position / fps`` itself, printed to the millisecond, can fall
    just before the frame's timestamp (30 fps: frame 1 is at 0.0333 s, the
    link said 0.033) and the browser then shows the previous frame.
    """
    return (position + 0.5) / fps


def _timeline_svg(track: TrackResult, fps: float, *, width: int = 900, height: int = 120) -> str:
    """Confidence over the processed frames as an inline SVG; flagged spans shaded and clickable."""
    n = len(track.confidence)
    if n == 0:
        return ""
    pad = 4
    x = lambda i: pad + (width - 2 * pad) * (i / max(n - 1, 1))  # noqa: E731
    y = lambda c: pad + (height - 2 * pad) * (1.0 - float(np.clip(c, 0, 1)))  # noqa: E731
    parts = [f'<svg class="timeline" viewBox="0 0 {width} {height}" preserveAspectRatio="none" role="img" '
             f'aria-label="confidence of track {track.track_id} per frame">']
    for span in flagged_spans(track):
        x0, x1 = x(span.start) - 1, x(span.stop - 1) + 1
        parts.append(f'<rect class="flag" x="{x0:.1f}" y="0" width="{max(x1 - x0, 2):.1f}" height="{height}" '
                     f'onclick="seekTo({_seek_seconds(span.start, fps):.3f})"><title>frames {span.first_frame}-'
                     f'{span.last_frame} flagged</title></rect>')
    parts.append(f'<line class="threshold" x1="0" x2="{width}" y1="{y(0.5):.1f}" y2="{y(0.5):.1f}"/>')
    # Human corrections (keyframes after the first frame, which every run has) as green ticks.
    for i in np.flatnonzero(track.keyframe[1:]) + 1:
        parts.append(f'<line class="corrected" x1="{x(i):.1f}" x2="{x(i):.1f}" y1="0" y2="{height}" '
                     'stroke="#00b400" stroke-width="2" vector-effect="non-scaling-stroke" style="cursor: pointer" '
                     f'onclick="seekTo({_seek_seconds(int(i), fps):.3f})"><title>frame {int(track.frame_indices[i])} '
                     f'corrected</title></line>')
    step = max(1, n // 2000)
    points = " ".join(f"{x(i):.1f},{y(track.confidence[i]):.1f}" for i in range(0, n, step))
    parts.append(f'<polyline class="confidence" points="{points}"/>')
    parts.append("</svg>")
    return "".join(parts)


def render_report(
    path: Path,
    *,
    video: Any,
    tracks: Sequence[TrackResult],
    thumbnails: Sequence[SpanThumbnail],
    settings: dict[str, Any],
    run_info: dict[str, Any],
    overlay_name: str | None,
    review: dict[str, Any] | None = None,
) -> None:
    """Write ``report.html``: summary, confidence timelines, flagged spans with thumbnails, settings.

    The page is self-contained (inline CSS, SVG and JPEG thumbnails) apart
    from the overlay video beside it, which the span links seek. ``review``
    adds the Corrections section after a re-track (built by
    :mod:`annotator.review`: the corrections in force and what the last
    re-track changed).
    """
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(templates_dir())),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
        undefined=jinja2.StrictUndefined,
    )
    thumbs = {(t.track_id, t.position): t.jpeg_base64 for t in thumbnails}
    spans = [s for track in tracks for s in flagged_spans(track)]
    spans.sort(key=lambda s: (s.start, s.track_id))
    fps = float(video.fps)
    page = env.get_template(REPORT_TEMPLATE).render(
        video=video,
        summaries=[track_summary(t) for t in tracks],
        timelines=[(t.track_id, Markup(_timeline_svg(t, fps))) for t in tracks],
        spans=[{"span": s, "seconds": _seek_seconds(s.start, fps), "thumbnail": thumbs.get((s.track_id, s.start))}
               for s in spans],
        settings=settings,
        run=run_info,
        overlay=overlay_name,
        review=review,
    )
    write_text_atomic(path, page)

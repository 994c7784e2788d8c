"""The review report: one self-contained HTML page per run (Jinja2 template in ``templates/``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from markupsafe import Markup

from annotator.atomic import write_text_atomic
from annotator.flagging import REASONS, keyframe_rows, spans_from_mask
from annotator.html_pages import REPORT_TEMPLATE, template_environment
from annotator.tracks import KEYFRAME_GIVEN, SpanThumbnail, TrackResult
from annotator.wording import plural

__all__ = ["FlaggedSpan", "by_expected_errors", "flagged_spans", "keyframe_note", "keyframes_asked", "reason_legend",
           "track_summary", "corrections_section", "render_report"]


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
    expected_errors: float = 0.0
    """Sum of p_fail over the span's frames (absent frames count 0): how many wrong boxes a review should find."""
    worst_p_fail: float = float("nan")
    """Highest p_fail in the span; NaN when the object is absent from every frame of it."""
    worst: int = -1
    """Position of the frame with the highest p_fail (the first such frame; ``start`` when there is none)."""
    worst_frame: int = -1
    """Source frame index of ``worst``."""

    @property
    def length(self) -> int:
        return self.stop - self.start


def flagged_spans(track: TrackResult) -> list[FlaggedSpan]:
    """Every flagged span of a track, in frame order, with its expected errors, worst frame and reasons."""
    spans = []
    p_fail = track.p_fail
    for start, stop in spans_from_mask(track.flagged):
        start, stop = int(start), int(stop)
        reasons = sorted({part for r in track.reasons[start:stop] for part in r.split("+") if part})
        values = p_fail[start:stop]
        finite = np.isfinite(values)
        # argmax of the finite values picks the first of equal maxima, as the overlay's thumbnail capture does.
        worst = start + int(np.argmax(np.where(finite, values, -np.inf))) if finite.any() else start
        spans.append(FlaggedSpan(
            track_id=track.track_id, start=start, stop=stop,
            first_frame=int(track.frame_indices[start]), last_frame=int(track.frame_indices[stop - 1]),
            min_confidence=float(track.confidence[start:stop].min()), reasons=tuple(reasons),
            expected_errors=float(values[finite].sum()),
            worst_p_fail=float(values[finite].max()) if finite.any() else float("nan"),
            worst=worst, worst_frame=int(track.frame_indices[worst])))
    return spans


def by_expected_errors(spans: Sequence[FlaggedSpan]) -> list[FlaggedSpan]:
    """The spans most likely to hold wrong boxes first; ties in frame order, then by track."""
    return sorted(spans, key=lambda s: (-s.expected_errors, s.start, s.track_id))


def reason_legend(tracks: Sequence[TrackResult]) -> list[tuple[str, str]]:
    """``(reason, explanation)`` for every reason the tracks' flags use, in :data:`REASONS` order.

    Only the reasons present: the full list is in docs/flags.md, and the page
    should explain what it shows. A reason this version does not know (a
    store written by another version) is listed without an explanation
    rather than hidden.
    """
    present = {part for track in tracks for r in track.reasons for part in r.split("+") if part}
    known = [(name, text) for name, text in REASONS.items() if name in present]
    unknown = [(name, "") for name in sorted(present - set(REASONS))]
    return known + unknown


def keyframes_asked(track: TrackResult) -> list[int]:
    """Source frame indices flagged with reason ``keyframe``: the track is probably lost, and a person should box
    these (:func:`annotator.flagging.with_keyframe_request`)."""
    return [int(track.frame_indices[p]) for p in keyframe_rows(track.reasons)]


def _frame_list(frames: Sequence[int], most: int = 6) -> str:
    if len(frames) <= most:
        return ", ".join(map(str, frames))
    return ", ".join(map(str, frames[: most - 2])) + f", ..., {frames[-1]}"


def keyframe_note(tracks: Sequence[TrackResult], out_dir: Path | str) -> str:
    """What the command line says about tracks that ask for keyframes; '' when none does."""
    asking = [(t, keyframes_asked(t)) for t in tracks]
    asking = [(t, frames) for t, frames in asking if frames]
    if not asking:
        return ""
    parts = [f"track {t.track_id} ({t.label}) looks lost on most of its frames: box frames {_frame_list(frames)} "
             f"({plural(len(frames), 'frame')}, reason 'keyframe' in flags.csv)" for t, frames in asking]
    return ("; ".join(parts) + f"; then 'sptpt-annotate retrack {out_dir} --corrections FILE' tracks between them "
            "(for a lost track this costs less time than correcting one doubtful frame at a time)")


def track_summary(track: TrackResult) -> dict[str, Any]:
    """Headline numbers of one track: frames, flagged share, longest flagged span, speed, keyframes asked for."""
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
        # Over the frames that have a box: an absent frame's confidence (0) says nothing about the boxes.
        "mean_confidence": float(track.confidence[~track.outside].mean()) if (~track.outside).any() else float("nan"),
        "seconds": seconds,
        # The first frame is left out of the speed: it holds the tracker's set-up and, on a first run, the kernels'
        # compile, neither of which a longer video pays again.
        "fps": (n - 1) / float(track.seconds[1:].sum()) if n > 1 and track.seconds[1:].sum() > 0 else float("nan"),
        "keyframes_asked": keyframes_asked(track),
    }


def _seek_seconds(position: int, fps: float) -> float:
    """Overlay time that shows processed frame ``position``: the middle of its display interval.

    Seeking to ``position / fps`` itself, printed to the millisecond, can fall
    just before the frame's timestamp (30 fps: frame 1 is at 0.0333 s, the
    link said 0.033) and the browser then shows the previous frame.
    """
    return (position + 0.5) / fps


def _tick_step(span: float, target: int = 8) -> int:
    """A 1, 2 or 5 times power-of-ten frame step giving at most about ``target`` ticks over ``span`` frames."""
    raw = max(span / target, 1.0)
    magnitude = 10 ** int(np.floor(np.log10(raw)))
    return next(m * magnitude for m in (1, 2, 5, 10) if m * magnitude >= raw)


def _timeline_svg(track: TrackResult, fps: float, *, width: int = 900, height: int = 150) -> str:
    """The failure probability over the processed frames as an inline SVG; flagged spans shaded and clickable.

    ``p_fail`` (higher = worse) is drawn where it is finite: a frame where the
    object is absent breaks the line and is marked by a grey bar under the
    plot, so an absence never reads as a sure box. The x axis is ticked with
    source frame numbers (at 1, 2, 5 x 10^k steps, placed by interpolation so
    a ``--step`` run is ticked right), the y axis at p_fail 0, 0.5 and 1. The
    SVG scales uniformly, so its text is never stretched.
    """
    n = len(track.frame_indices)
    if n == 0:
        return ""
    left, right, top, bottom = 52, 10, 8, 36  # plot margins: room for tick labels and axis titles
    plot_w, plot_h = width - left - right, height - top - bottom
    x = lambda i: left + plot_w * (i / max(n - 1, 1))  # noqa: E731
    y = lambda c: top + plot_h * (1.0 - float(np.clip(c, 0, 1)))  # noqa: E731
    parts = [f'<svg class="timeline" viewBox="0 0 {width} {height}" role="img" '
             f'aria-label="p_fail of track {track.track_id} per frame">',
             f'<rect class="plot" x="{left}" y="{top}" width="{plot_w}" height="{plot_h}"/>']
    for span in flagged_spans(track):
        x0, x1 = x(span.start) - 1, x(span.stop - 1) + 1
        parts.append(f'<rect class="flag" x="{x0:.1f}" y="{top}" width="{max(x1 - x0, 2):.1f}" height="{plot_h}" '
                     f'onclick="seekTo({_seek_seconds(span.start, fps):.3f})"><title>frames {span.first_frame}-'
                     f'{span.last_frame} flagged</title></rect>')
    parts.append(f'<line class="threshold" x1="{left}" x2="{left + plot_w}" y1="{y(0.5):.1f}" y2="{y(0.5):.1f}"/>')
    # Human corrections (keyframes after the first frame, which every run has) as green ticks.
    for i in np.flatnonzero(track.keyframe[1:]) + 1:
        parts.append(f'<line class="corrected" x1="{x(i):.1f}" x2="{x(i):.1f}" y1="{top}" y2="{top + plot_h}" '
                     'stroke="#00b400" stroke-width="2" style="cursor: pointer" '
                     f'onclick="seekTo({_seek_seconds(int(i), fps):.3f})"><title>frame {int(track.frame_indices[i])} '
                     f'corrected</title></line>')
    p_fail = track.p_fail
    step = max(1, n // 2000)  # at most about 2000 points per line: the plot is 838 px wide
    bottom_y = top + plot_h
    for start, stop in spans_from_mask(np.isfinite(p_fail)):
        if stop - start == 1:  # a lone frame between absences: a dot, since a one-point line draws nothing
            parts.append(f'<circle class="p-fail" cx="{x(start):.1f}" cy="{y(p_fail[start]):.1f}" r="1.5"/>')
            continue
        # Every step-th frame and the run's last, so the line ends where the run does.
        positions = [*range(int(start), int(stop), step)]
        if positions[-1] != stop - 1:
            positions.append(int(stop) - 1)
        points = " ".join(f"{x(i):.1f},{y(p_fail[i]):.1f}" for i in positions)
        parts.append(f'<polyline class="p-fail" points="{points}"/>')
    for start, stop in spans_from_mask(~np.isfinite(p_fail)):
        x0, x1 = x(start) - 1, x(stop - 1) + 1
        parts.append(f'<rect class="absent" x="{x0:.1f}" y="{bottom_y - 4}" width="{max(x1 - x0, 2):.1f}" height="4">'
                     f'<title>frames {int(track.frame_indices[start])}-{int(track.frame_indices[stop - 1])}: '
                     'object absent</title></rect>')
    # Axes: frame-number ticks below the plot, p_fail ticks on its left.
    frames = track.frame_indices.astype(np.float64)
    first, last = int(frames[0]), int(frames[-1])
    tick = _tick_step(last - first)
    for frame in range(-(-first // tick) * tick, last + 1, tick):
        tx = x(float(np.interp(frame, frames, np.arange(n))))
        parts.append(f'<g class="tick x"><line x1="{tx:.1f}" x2="{tx:.1f}" y1="{bottom_y}" y2="{bottom_y + 4}"/>'
                     f'<text x="{tx:.1f}" y="{bottom_y + 16}" text-anchor="middle">{frame}</text></g>')
    for value in (0.0, 0.5, 1.0):
        ty = y(value)
        parts.append(f'<g class="tick y"><line x1="{left - 4}" x2="{left}" y1="{ty:.1f}" y2="{ty:.1f}"/>'
                     f'<text x="{left - 6}" y="{ty + 4:.1f}" text-anchor="end">{value:g}</text></g>')
    parts.append(f'<text class="axis-label" x="{left + plot_w / 2:.1f}" y="{height - 4}" text-anchor="middle">'
                 'source frame</text>')
    parts.append(f'<text class="axis-label" x="12" y="{top + plot_h / 2:.1f}" text-anchor="middle" '
                 f'transform="rotate(-90 12 {top + plot_h / 2:.1f})">p_fail</text>')
    parts.append("</svg>")
    return "".join(parts)


def corrections_section(review: dict[str, Any], tracks: Sequence[TrackResult], fps: float) -> dict[str, Any]:
    """What the report's Corrections section shows, from run.json's ``review`` section after a re-track.

    Every human correction in force (the keyframes a person gave, not the first-frame boxes), each with the
    overlay time that shows it, and the anchors and segments of the last re-track, as text.
    """

    def fmt(box) -> str:
        return "absent" if box is None else ", ".join(f"{v:.1f}" for v in box)

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
    """Write ``report.html``: summary, p_fail timelines, flagged spans with thumbnails, settings.

    The page is self-contained (inline CSS, SVG and JPEG thumbnails) apart
    from the overlay video beside it, which the span links seek. Spans are
    listed by expected errors, highest first; each shows the thumbnail in
    ``thumbnails`` at its worst frame (or, failing that, any one inside it),
    and clicking the thumbnail seeks to that frame. ``review``
    adds the Corrections section after a re-track
    (:func:`corrections_section`: the corrections in force and what the
    last re-track changed).

    The input path shown is the absolute one recorded in run.json
    (``run_info["input"]["path"]``), the same before and after a re-track;
    ``video.path`` (as given on the command line) only when there is none.
    """
    env = template_environment()
    thumbs = {(t.track_id, t.position): t for t in thumbnails}
    spans = by_expected_errors([s for track in tracks for s in flagged_spans(track)])

    def span_item(span: FlaggedSpan) -> dict[str, Any]:
        inside = [thumbs[(span.track_id, p)] for p in range(span.start, span.stop) if (span.track_id, p) in thumbs]
        thumb = thumbs.get((span.track_id, span.worst)) or (inside[0] if inside else None)
        return {"span": span, "seconds": _seek_seconds(span.start, fps),
                "thumbnail": thumb.jpeg_base64 if thumb else None,
                "thumbnail_frame": thumb.frame_index if thumb else None,
                "thumbnail_seconds": _seek_seconds(thumb.position, fps) if thumb else None}

    fps = float(video.fps)
    input_path = (run_info.get("input") or {}).get("path") or video.path
    page = env.get_template(REPORT_TEMPLATE).render(
        video=video,
        input_path=input_path,
        summaries=[track_summary(t) for t in tracks],
        timelines=[(t.track_id, Markup(_timeline_svg(t, fps))) for t in tracks],
        spans=[span_item(s) for s in spans],
        keyframes=[{"track_id": t.track_id, "label": t.label,
                    "frames": [(int(t.frame_indices[p]), _seek_seconds(p, fps)) for p in keyframe_rows(t.reasons)]}
                   for t in tracks],
        legend=reason_legend(tracks),
        settings=settings,
        run=run_info,
        overlay=overlay_name,
        review=review,
    )
    write_text_atomic(path, page)

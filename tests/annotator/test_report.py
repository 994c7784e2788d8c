"""The review report: every flagged span is listed once, most expected errors first, with a link that seeks the
overlay to its first frame and a thumbnail of its worst frame; the timeline plots p_fail; a legend explains the
reasons shown.

The golden file ``tests/golden/annotate/report.html`` pins the page for fixed
inputs. After an intended template change, regenerate it with::

    UPDATE_GOLDEN=1 pytest tests/annotator/test_report.py

and review the diff before committing.
"""

from __future__ import annotations

import html
import html.parser
import os
import re

import numpy as np
import pytest
from _paths import GOLDEN as GOLDEN_ROOT
from _report_page import parse, seek_seconds, shows_frame

from annotator.flagging import REASONS
from annotator.pipeline import WorstFrameThumbnails
from annotator.run_report import (
    _tick_step,
    by_expected_errors,
    flagged_spans,
    keyframe_note,
    keyframes_asked,
    reason_legend,
    render_report,
    track_summary,
)
from annotator.tracks import SpanThumbnail, TrackResult, VideoInfo
from annotator.wording import plural

GOLDEN = GOLDEN_ROOT / "annotate"
UPDATE = os.environ.get("UPDATE_GOLDEN") == "1"

FPS = 20.0
VIDEO = VideoInfo(path="clips/walk.mp4", name="walk", width=96, height=72, fps=FPS, frame_count=40)


def make_track(track_id: int, frame_indices, flags: str, *, label: str = "object", reasons: dict | None = None,
               p_fail=None):
    """A track whose flags are drawn as a string: ``X`` flagged, ``O`` flagged and absent, ``.`` neither (one
    character per processed frame). ``p_fail`` (NaN where absent) defaults to 0.1 rising to 0.7."""
    n = len(flags)
    flagged = np.array([c in "XO" for c in flags])
    outside = np.array([c == "O" for c in flags])
    reasons = {**{i: "outside" for i in np.flatnonzero(outside)}, **(reasons or {})}
    p_fail = np.linspace(0.1, 0.7, n) if p_fail is None else np.asarray(p_fail, dtype=np.float64)
    p_fail = np.where(outside, np.nan, p_fail)
    confidence = np.where(np.isfinite(p_fail), 1.0 - p_fail, 0.0)
    return TrackResult(
        track_id=track_id,
        label=label,
        frame_indices=np.asarray(frame_indices, dtype=np.int64),
        boxes_xywh=np.tile([10.0, 12.0, 20.0, 16.0], (n, 1)),
        confidence=confidence,
        log_likelihood=np.linspace(5.0, -1.0, n),
        accepted=~flagged,
        flagged=flagged,
        reasons=tuple(reasons.get(i, "doubt:score") if f else "" for i, f in enumerate(flagged)),
        keyframe=np.arange(n) == 0,
        outside=outside,
        seconds=np.full(n, 0.125),
        signals={"p_fail": p_fail},
    )


def make_tracks() -> list[TrackResult]:
    """Two tracks over source frames 1, 3, 5, ... (step 2): positions and source indices differ."""
    indices = np.arange(1, 25, 2)  # 12 processed frames
    one = make_track(1, indices, ".XXX....XX.X", reasons={1: "doubt:motion", 2: "doubt:flow", 3: "span"})
    two = make_track(2, indices, "......XXXXXX", label="car", reasons={6: "budget+doubt:appearance"})
    return [one, two]


RUN_INFO = {
    "tool_version": "0.0.test",
    "created": "2026-01-01T00:00:00+00:00",
    "frames_processed": 12,
    "seconds_total": 3.0,
    "seconds_tracking": 2.5,
    "seconds_outside": 0.5,
    "decode_error": None,
}
SETTINGS = {"preset": "paper", "seed": 0, "tracker": {"n_particles": 60}, "flags": {"merge_gap": 5, "min_span": 3}}


def render(tmp_path, tracks, *, overlay: str | None = "overlay.mp4", thumbnails=(), run_info=None, video=VIDEO) -> str:
    path = tmp_path / "report.html"
    render_report(path, video=video, tracks=tracks, thumbnails=list(thumbnails), settings=SETTINGS,
                  run_info=run_info or RUN_INFO, overlay_name=overlay)
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    return path.read_text(encoding="utf-8")


# --------------------------------------------------------------------------- spans


def test_flagged_spans_of_a_track():
    one, two = make_tracks()
    spans = flagged_spans(one)
    assert [(s.start, s.stop, s.first_frame, s.last_frame, s.length) for s in spans] == [
        (1, 4, 3, 7, 3), (8, 10, 17, 19, 2), (11, 12, 23, 23, 1),
    ]  # fmt: skip
    assert spans[0].reasons == ("doubt:flow", "doubt:motion", "span")
    assert spans[0].min_confidence == pytest.approx(one.confidence[3])
    p = np.linspace(0.1, 0.7, 12)
    assert [s.expected_errors for s in spans] == pytest.approx([p[1:4].sum(), p[8:10].sum(), p[11]])
    assert [(s.worst, s.worst_frame) for s in spans] == [(3, 7), (9, 19), (11, 23)]
    assert [s.worst_p_fail for s in spans] == pytest.approx([p[3], p[9], p[11]])
    assert [(s.start, s.stop, s.reasons) for s in flagged_spans(two)] == [
        (6, 12, ("budget", "doubt:appearance", "doubt:score"))]


def test_spans_are_sorted_by_expected_errors():
    # Expected errors: 0.9 (one sure failure), 1.2 (four doubtful frames), 0.6, and 0 for an absence.
    p_fail = [0.0, 0.9, 0.0, 0.3, 0.3, 0.3, 0.3, 0.0, 0.2, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0]
    track = make_track(1, np.arange(15), ".X.XXXX.XXX.OO.", p_fail=p_fail)
    two = make_track(2, np.arange(15), "........XXX....", p_fail=p_fail)  # ties track 1's third span: frame order
    spans = by_expected_errors(flagged_spans(track) + flagged_spans(two))
    assert [(s.track_id, s.first_frame) for s in spans] == [(1, 3), (1, 1), (1, 8), (2, 8), (1, 12)]
    assert [s.expected_errors for s in spans] == pytest.approx([1.2, 0.9, 0.6, 0.6, 0.0])
    absent = spans[-1]
    assert np.isnan(absent.worst_p_fail) and (absent.worst, absent.worst_frame) == (12, 12)


def test_worst_frame_thumbnail_is_the_highest_p_fail_of_each_span():
    """Frames streamed as the overlay is drawn: each span's thumbnail is of its highest-p_fail frame."""
    p_fail = [0.0, 0.4, 0.8, 0.8, 0.5, 0.0, 0.6, 0.3, 0.9, 0.1, 0.0, np.nan, np.nan]
    flags = ".XXXX.XXXX.OO"
    track = make_track(1, np.arange(100, 113), flags, p_fail=p_fail)
    capture = WorstFrameThumbnails()
    frames = {}
    for position, (flag, p) in enumerate(zip(flags, p_fail)):
        # Each frame a different flat grey, so a thumbnail tells which frame it was taken from.
        frames[position] = np.full((30, 40, 3), 20 * position, np.uint8)
        capture.add(1, position, 100 + position, flagged=flag in "XO", p_fail=p, drawn=frames[position])
    thumbs = capture.finish()
    # Ties keep the first frame; a span with no finite p_fail (object absent) keeps its first frame.
    assert [(t.position, t.frame_index) for t in thumbs] == [(2, 102), (8, 108), (11, 111)]
    assert [(s.worst, s.worst_frame) for s in flagged_spans(track)] == [(t.position, t.frame_index) for t in thumbs]
    import base64

    import cv2
    for t in thumbs:
        image = cv2.imdecode(np.frombuffer(base64.b64decode(t.jpeg_base64), np.uint8), cv2.IMREAD_COLOR)
        assert image.shape[1] == 200 and abs(int(image.mean()) - 20 * t.position) <= 2


def test_track_summary():
    summary = track_summary(make_tracks()[0])
    assert summary["frames"] == 12 and summary["flagged"] == 6 and summary["spans"] == 3
    assert summary["longest_span"] == 3 and summary["flagged_share"] == pytest.approx(0.5)
    assert summary["seconds"] == pytest.approx(1.5) and summary["fps"] == pytest.approx(8.0)
    # A first frame that compiled the kernels (10 s) does not count against the speed of the others.
    track = make_tracks()[0]
    seconds = track.seconds.copy()
    seconds[0] = 10.0
    slow_start = track_summary(TrackResult(**{**track.__dict__, "seconds": seconds}))
    assert slow_start["seconds"] == pytest.approx(11.375) and slow_start["fps"] == pytest.approx(8.0)


@pytest.mark.parametrize("fps", [FPS, 25.0, 30.0, 30000 / 1001, 60.0])
def test_report_lists_every_flagged_span_with_a_seek_link(tmp_path, fps):
    tracks = make_tracks()
    thumbnails = [SpanThumbnail(1, 3, 7, "AAAA"), SpanThumbnail(2, 11, 23, "BBBB")]  # the spans' worst frames
    video = VideoInfo(path="clips/walk.mp4", name="walk", width=96, height=72, fps=fps, frame_count=40)
    page = render(tmp_path, tracks, thumbnails=thumbnails, video=video)
    parsed = parse(page)
    expected = sorted((s for t in tracks for s in flagged_spans(t)), key=lambda s: -s.expected_errors)
    assert len(parsed.rows) == len(expected) == 4
    assert [(s.track_id, s.start) for s in expected] == [(2, 6), (1, 8), (1, 11), (1, 1)]
    for row, span in zip(parsed.rows, expected):
        track, frames, length, errors, worst, reasons, _ = row["cells"]
        assert int(track) == span.track_id
        assert frames == f"{span.first_frame}\u2013{span.last_frame}"
        assert int(length) == span.length
        assert float(errors) == pytest.approx(span.expected_errors, abs=0.005)
        assert float(worst) == pytest.approx(span.worst_p_fail, abs=0.005)
        assert reasons == ", ".join(span.reasons)
        # The overlay holds the processed frames only, at the source rate: the link shows the span's first one.
        assert shows_frame(seek_seconds(row["seek"]), span.start, fps), (row["seek"], span.start, fps)
        if row["img"]:  # and the thumbnail the span's worst frame
            assert shows_frame(seek_seconds(row["thumb_seek"]), span.worst, fps)
    thumbs = {(int(row["cells"][0]), row["cells"][1]): row["img"] for row in parsed.rows if row["img"]}
    assert thumbs == {(1, "3\u20137"): "data:image/jpeg;base64,AAAA", (2, "13\u201323"): "data:image/jpeg;base64,BBBB"}
    assert [v.get("src") for v in parsed.videos] == ["overlay.mp4"]
    # The timelines shade the same spans, and clicking them seeks to the same frames.
    assert [r["onclick"] for r in parsed.flag_rects] == [
        row["seek"] for row in sorted(parsed.rows, key=lambda row: (int(row["cells"][0]), seek_seconds(row["seek"])))
    ]
    assert f"Flagged spans ({len(expected)})" in page


def test_report_without_overlay_has_no_links_and_says_why(tmp_path):
    page = render(tmp_path, make_tracks(), overlay=None)
    parsed = parse(page)
    assert len(parsed.rows) == 4 and all(row["seek"] is None for row in parsed.rows)
    assert parsed.videos == [] and "No overlay video in this folder" in page


def test_report_without_flags(tmp_path):
    track = make_track(1, np.arange(8), "........")
    parsed = parse(page := render(tmp_path, [track]))
    assert parsed.rows == [] and parsed.flag_rects == []
    assert "No frame was flagged for review." in page and "Flagged spans (0)" in page


def test_report_shows_a_decode_error(tmp_path):
    page = render(tmp_path, make_tracks(), run_info={**RUN_INFO, "decode_error": "clip.mp4: decoding stopped <here>"})
    assert "Decoding stopped early" in page and "decoding stopped &lt;here&gt;" in page  # escaped


def test_labels_and_paths_are_escaped(tmp_path):
    track = make_track(1, np.arange(4), ".XXX", label="<script>alert(1)</script>")
    page = render(tmp_path, [track])
    assert "<script>alert(1)" not in page and "&lt;script&gt;alert(1)" in page


def svg_texts(page: str, track_id: int) -> list[tuple[dict, str]]:
    """The ``<text>`` elements of one track's timeline: attributes and text."""
    svg = re.search(rf'<svg class="timeline"[^>]*aria-label="p_fail of track {track_id} per frame">(.*?)</svg>',
                    page, re.S).group(1)
    return [(dict(re.findall(r'(\S+)="([^"]*)"', attrs)), text)
            for attrs, text in re.findall(r"<text([^>]*)>([^<]*)</text>", svg)]


def test_timeline_has_frame_ticks_and_axis_labels(tmp_path):
    page = render(tmp_path, make_tracks())
    texts = svg_texts(page, 1)
    labels = [text for attrs, text in texts if attrs.get("class") == "axis-label"]
    assert labels == ["source frame", "p_fail"]
    x_ticks = [(float(a["x"]), t) for a, t in texts if "class" not in a and a.get("text-anchor") == "middle"]
    y_ticks = [t for a, t in texts if a.get("text-anchor") == "end"]
    # Source frames 1, 3, ..., 23 (step 2): ticks every 5 frames, at the frame's place on the processed axis.
    assert [t for _, t in x_ticks] == ["5", "10", "15", "20"]
    left, plot_w = 52, 900 - 52 - 10
    assert x_ticks[0][0] == pytest.approx(left + plot_w * 2 / 11, abs=0.05)  # frame 5 is position 2
    assert x_ticks[1][0] == pytest.approx(left + plot_w * 4.5 / 11, abs=0.05)  # frame 10 lies between 9 and 11
    assert y_ticks == ["0", "0.5", "1"]


@pytest.mark.parametrize(("span", "step"), [(0, 1), (7, 1), (22, 5), (100, 20), (1000, 200), (12345, 2000)])
def test_tick_step_is_one_two_or_five_times_a_power_of_ten(span, step):
    assert _tick_step(span) == step


def test_single_frame_timeline_and_singular_wording(tmp_path):
    track = make_track(1, [7], ".")
    page = render(tmp_path, [track], run_info={**RUN_INFO, "frames_processed": 1})
    assert [t for a, t in svg_texts(page, 1) if "class" not in a and a.get("text-anchor") == "middle"] == ["7"]
    assert "Processed 1 frame in" in page and "1 frames" not in page


def test_thumbnail_seeks_the_overlay_to_its_own_frame(tmp_path):
    # Track 2's thumbnail is of its span's first frame (a thumbnail set made before worst frames): still shown.
    page = render(tmp_path, make_tracks(), thumbnails=[SpanThumbnail(1, 3, 7, "AAAA"), SpanThumbnail(2, 6, 13, "BBBB")])
    rows = {int(row["cells"][0]): row for row in parse(page).rows if row["img"]}
    assert (shows_frame(seek_seconds(rows[1]["thumb_seek"]), 3, FPS)
            and not shows_frame(seek_seconds(rows[1]["seek"]), 3, FPS))
    assert rows[2]["thumb_seek"] == rows[2]["seek"] is not None
    assert 'alt="frame 7"' in page and 'alt="frame 13"' in page
    no_overlay = render(tmp_path, make_tracks(), overlay=None, thumbnails=[SpanThumbnail(1, 3, 7, "AAAA")])
    assert all(row["thumb_seek"] is None for row in parse(no_overlay).rows)


def timeline_lines(page: str, track_id: int) -> tuple[list[list[tuple[float, float]]], list[tuple[float, float]], int]:
    """The p_fail polylines (points), dots, and absent-frame marks of one track's timeline."""
    svg = re.search(rf'aria-label="p_fail of track {track_id} per frame">(.*?)</svg>', page, re.S).group(1)
    lines = [[tuple(map(float, p.split(","))) for p in points.split()]
             for points in re.findall(r'<polyline class="p-fail" points="([^"]*)"', svg)]
    dots = [(float(cx), float(cy)) for cx, cy in re.findall(r'<circle class="p-fail" cx="([^"]*)" cy="([^"]*)"', svg)]
    return lines, dots, len(re.findall(r'<rect class="absent"', svg))


def test_timeline_plots_p_fail_with_gaps_where_the_object_is_absent(tmp_path):
    p_fail = [0.0, 0.25, 0.5, 1.0, 0.0, 0.75, 0.0, 0.5]
    track = make_track(1, np.arange(8), "....O.OX", p_fail=p_fail)
    page = render(tmp_path, [track])
    lines, dots, absent = timeline_lines(page, 1)
    # The span of absent frames has no worst p_fail and no expected errors; it comes last.
    assert [r["cells"][1:5] for r in parse(page).rows] == [["6\u20137", "2", "0.50", "0.50"],
                                                           ["4\u20134", "1", "0.00", "\u2013"]]
    top, plot_h, left, plot_w = 8, 150 - 8 - 36, 52, 900 - 52 - 10
    to_p = lambda py: 1.0 - (py - top) / plot_h  # noqa: E731 - higher p_fail is higher on the plot
    to_i = lambda px: (px - left) / plot_w * 7  # noqa: E731
    assert [[(round(to_i(px)), round(to_p(py), 2)) for px, py in line] for line in lines] == [
        [(0, 0.0), (1, 0.25), (2, 0.5), (3, 1.0)]]
    # Frame 5 lies alone between two absences: a dot; so does frame 7 at the end.
    assert [(round(to_i(px)), round(to_p(py), 2)) for px, py in dots] == [(5, 0.75), (7, 0.5)]
    assert absent == 2


def test_legend_explains_the_reasons_present(tmp_path):
    tracks = make_tracks()
    legend = reason_legend(tracks)
    assert [name for name, _ in legend] == ["doubt:score", "doubt:motion", "doubt:flow", "doubt:appearance", "span",
                                            "budget"]  # REASONS order
    assert all(text == REASONS[name] for name, text in legend)
    page = render(tmp_path, tracks)
    dl = re.search(r'<dl class="reasons">(.*?)</dl>', page, re.S).group(1)
    assert [(name, html.unescape(text)) for name, text in re.findall(r"<dt>([^<]*)</dt><dd>([^<]*)</dd>", dl)] == legend
    assert "outside" not in dict(legend)
    old = make_track(1, np.arange(4), ".XX.", reasons={1: "held"})
    assert reason_legend([old]) == [("doubt:score", REASONS["doubt:score"]), ("held", "")]
    assert "not described by this version" in render(tmp_path, [old])


def test_overlay_video_has_a_plain_fallback_link(tmp_path):
    page = render(tmp_path, make_tracks())
    video = re.search(r"<video[^>]*>(.*?)</video>", page, re.S).group(1)
    assert '<a href="overlay.mp4">' in video  # for browsers without <video>
    assert '<a class="video-file" href="overlay.mp4">' in page  # for browsers that cannot decode the file


def test_report_shows_the_absolute_input_path_from_run_json(tmp_path):
    absolute = str((tmp_path / "clips" / "walk.mp4").resolve())
    page = render(tmp_path, make_tracks(), run_info={**RUN_INFO, "input": {"path": absolute}})
    assert (f'<div class="muted">{absolute} &middot;' in page
            and "clips/walk.mp4 &middot;" not in page.replace(absolute, ""))


def test_report_golden(tmp_path):
    page = render(tmp_path, make_tracks(), thumbnails=[SpanThumbnail(1, 3, 7, "AAAA")])
    golden = GOLDEN / "report.html"
    if UPDATE:
        golden.parent.mkdir(parents=True, exist_ok=True)
        golden.write_text(page, encoding="utf-8")
    assert golden.exists(), f"missing golden file {golden}; create it with UPDATE_GOLDEN=1"
    assert page == golden.read_text(encoding="utf-8"), f"report differs from {golden}; if intended, UPDATE_GOLDEN=1"


@pytest.mark.parametrize(("count", "text"), [(0, "0 frames"), (1, "1 frame"), (2, "2 frames")])
def test_counts_are_worded_in_the_right_number(count, text):
    assert plural(count, "frame") == text
    assert plural(count, "frame box", "frame boxes") == text.replace("frame", "frame box").replace("boxs", "boxes")


def test_keyframes_asked_for_are_listed_shortly_on_the_command_line():
    n = 30
    flags = "".join("X" if (p % 10 == 0 and p > 0) or p == n - 1 else "." for p in range(n))
    lost = make_track(3, np.arange(100, 100 + 2 * n, 2), flags, label="car",
                      reasons={p: "keyframe" for p in (10, 20, 29)})
    other = make_track(4, np.arange(n), "....XXXX" + "." * (n - 8))
    assert keyframes_asked(lost) == [120, 140, 158] and keyframes_asked(other) == []
    assert track_summary(lost)["keyframes_asked"] == [120, 140, 158]
    note = keyframe_note([lost, other], "out/clip_sptpt")
    assert note == ("track 3 (car) looks lost on most of its frames: box frames 120, 140, 158 (3 frames, reason "
                    "'keyframe' in flags.csv); then 'sptpt-annotate retrack out/clip_sptpt --corrections FILE' tracks "
                    "between them (for a lost track this costs less time than correcting one doubtful frame at a "
                    "time)")
    many = make_track(5, np.arange(200), "X" * 200, reasons={p: "keyframe" for p in range(200)})
    assert "box frames 0, 1, 2, 3, ..., 199 (200 frames," in keyframe_note([many], "o")
    assert keyframe_note([other], "o") == ""


def test_mean_confidence_is_over_the_frames_with_a_box():
    """An absent frame has confidence 0 in flags.csv; the summary's mean leaves it out (0.8, not 0.53)."""
    track = make_track(1, range(6), "..OO..", p_fail=np.full(6, 0.2))
    assert track_summary(track)["mean_confidence"] == pytest.approx(0.8)
    assert np.isnan(track_summary(make_track(2, range(2), "OO"))["mean_confidence"])


def test_the_report_and_the_batch_index_share_one_template_environment():
    from annotator.html_pages import BATCH_TEMPLATE, REPORT_TEMPLATE, template_environment

    env = template_environment()
    assert template_environment() is env  # built once per process
    for name in (REPORT_TEMPLATE, BATCH_TEMPLATE):
        assert env.get_template(name).environment is env
    assert env.filters["plural"] is plural and env.autoescape(REPORT_TEMPLATE)

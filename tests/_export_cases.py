"""What the export tests write and compare: a small video's tracks with every special case, their golden files, and
the edits a reviewer makes to an exported file."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from _paths import GOLDEN as GOLDEN_ROOT

from annotator.tracks import TrackResult, VideoInfo

GOLDEN = GOLDEN_ROOT / "exports"
UPDATE = os.environ.get("UPDATE_GOLDEN") == "1"

VIDEO = VideoInfo(path="clips/walk.mp4", name="walk", width=64, height=48, fps=25.0, frame_count=12)


def check_golden(path: Path, golden_name: str, *, root: Path = GOLDEN) -> None:
    golden = root / golden_name
    text = path.read_text(encoding="utf-8")
    if UPDATE:
        golden.parent.mkdir(parents=True, exist_ok=True)
        golden.write_text(text, encoding="utf-8")
    assert golden.exists(), f"missing golden file {golden}; create it with UPDATE_GOLDEN=1"
    expected = golden.read_text(encoding="utf-8")
    assert text == expected, f"{path.name} differs from {golden}; if the change is intended, UPDATE_GOLDEN=1"


def make_tracks() -> list[TrackResult]:
    """Two tracks over a 12-frame video sub-sampled by 2, with every special case once."""
    walker = TrackResult(
        track_id=1,
        label="person",
        frame_indices=np.array([0, 2, 4, 6, 8, 10]),
        boxes_xywh=np.array(
            [
                [10.0, 12.0, 20.0, 30.0],  # keyframe (given by a human)
                [11.25, 12.5, 20.0, 30.0],
                [-4.0, 30.0, 20.0, 30.0],  # leaves the image at left and bottom: clipped in COCO
                [12.0, 13.0, 20.0, 30.0],  # outside: no COCO annotation, still an OTB row
                [13.0, 13.0, 20.0, 30.0],  # human correction
                [13.5, 13.0, 20.0, 30.0],
            ]
        ),
        confidence=np.array([1.0, 0.9, 0.42, 0.1, 1.0, 0.87654]),
        log_likelihood=np.array([np.inf, 3.5, -0.25, -7.0, 2.0, 1.234567891]),
        accepted=np.array([True, True, False, False, True, True]),
        flagged=np.array([False, False, True, True, False, False]),
        reasons=("", "", "rejected", "outside, lost", "", ""),
        keyframe=np.array([True, False, False, False, True, False]),
        outside=np.array([False, False, False, True, False, False]),
        seconds=np.array([0.5, 0.125, 0.25, 0.0625, 0.5, 0.125]),
    )
    car = TrackResult(
        track_id=2,
        label="car",
        frame_indices=np.array([4, 6, 8]),
        boxes_xywh=np.array([[40.0, 5.0, 10.0, 8.0], [np.nan] * 4, [70.0, 5.0, 10.0, 8.0]]),  # lost; off-image
        confidence=np.array([1.0, 0.3, 0.55]),
        log_likelihood=np.array([np.nan, -1.0, 0.5]),
        accepted=np.array([True, False, True]),
        flagged=np.array([False, True, False]),
        reasons=("", "lost", ""),
        keyframe=np.array([True, False, False]),
        outside=np.array([False, False, False]),
        seconds=np.array([0.25, 0.25, 0.25]),
        occluded=np.array([False, True, False]),
    )
    return [walker, car]


def shifted_track() -> TrackResult:
    """One track on source frames 3, 5, 7, 9 (start 3, step 2), absent at 7, corrected at 9."""
    return TrackResult(
        track_id=4, label="person", frame_indices=np.array([3, 5, 7, 9]),
        boxes_xywh=np.array([[10.0, 10.0, 20.0, 20.0], [12.0, 10.0, 20.0, 20.0], [14.0, 10.0, 20.0, 20.0],
                             [16.0, 10.0, 20.0, 20.0]]),
        confidence=np.array([1.0, 0.8, 0.2, 1.0]), log_likelihood=np.zeros(4),
        accepted=np.array([True, True, False, True]), flagged=np.array([False, False, True, False]),
        reasons=("", "", "object absent", ""), keyframe=np.array([True, False, False, True]),
        outside=np.array([False, False, True, False]), seconds=np.zeros(4),
    )


SHIFTED = range(3, 10, 2)  # shifted_track()'s source frames


def jittery_track(n: int, *, seed: int, step: int = 1, start: int = 0) -> TrackResult:
    """A tracker-like track: smooth motion with per-frame jitter, two flagged spans, an absence, a NaN row, a
    correction, and a last box seen before the range ends (so the track is ended by an extra outside box)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.float64)
    boxes = np.stack([150 + 60 * np.sin(t / 25), 90 + 0.7 * t, 48 + 6 * np.cos(t / 17), 40 + 0.05 * t], axis=1)
    boxes += rng.normal(0, 0.4, boxes.shape)
    flagged = np.zeros(n, bool)
    flagged[20:26] = flagged[50:58] = True
    outside = np.zeros(n, bool)
    outside[50:58] = True
    boxes[70] = np.nan
    keyframe = np.zeros(n, bool)
    keyframe[[0, 40]] = True
    return TrackResult(
        track_id=5, label="object", frame_indices=start + step * np.arange(n), boxes_xywh=boxes,
        confidence=np.full(n, 0.8), log_likelihood=np.zeros(n), accepted=~flagged, flagged=flagged,
        reasons=tuple("check" if f else "" for f in flagged), keyframe=keyframe, outside=outside,
        seconds=np.zeros(n))


def edit_box(text: str, frame: int, **attrs: str) -> str:
    """Change attributes of the <box> at ``frame`` in a CVAT XML (as a reviewer in CVAT would)."""
    def replace(match: re.Match) -> str:
        element = match.group(0)
        for key, value in attrs.items():
            element = re.sub(rf'{key}="[^"]*"', f'{key}="{value}"', element)
        return element

    edited, count = re.subn(rf'<box frame="{frame}"[^>]*>', replace, text)
    assert count == 1
    return edited

"""Regenerate ``samples/clip.mp4`` and its first-frame box, the project's own quick-start clip.

A textured object moves across a textured background and grows; at frame 48 a
look-alike (the same colours in another pattern) crosses in front of it and
takes the tracker with it, so the quick start's report has a flagged span to
review and a correction to make (``docs/sample-walkthrough.md``). Sensor noise
and H.264 compression make it look like real video. Ground truth for every
frame goes to ``clip_groundtruth.txt`` (OTB format, 1-based) so that the quick
start can also be scored with ``sptpt-annotate eval``.

    python samples/make_sample.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # sptpt_dev lives in the source tree, not in the installed package

from annotator.otb_format import write_otb_boxes  # noqa: E402
from sptpt_dev.synthetic import make_clip  # noqa: E402

FPS = 25
#: The look-alike meets the object 40% into a 120-frame path (frame 48), where the ``robust`` tracker follows it
#: (later meetings, 0.5 to 0.7, it shakes off within a few frames). The sample keeps the first 100 frames: the track
#: is wrong from the crossing on, and on the full 120 it is wrong on so many frames that the mean p_fail nears the
#: 0.6 at which the tool asks for keyframes instead of flagging the span.
PATH_FRAMES, LOOKALIKE, N_FRAMES = 120, 0.4, 100


def main() -> None:
    clip = make_clip(PATH_FRAMES, size=(320, 240), object_size=(48, 40), seed=2026, occlusion=None, lookalike=LOOKALIKE)
    frames, boxes = clip.frames[:N_FRAMES], clip.boxes_xywh[:N_FRAMES]
    writer = imageio_ffmpeg.write_frames(
        str(HERE / "clip.mp4"), (320, 240), fps=FPS, codec="libx264", pix_fmt_out="yuv420p", quality=None,
        output_params=["-crf", "20", "-preset", "slow", "-movflags", "+faststart"], macro_block_size=1,
        ffmpeg_log_level="error")
    writer.send(None)
    for frame in frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    write_otb_boxes(HERE / "clip_groundtruth.txt", boxes, origin=1)
    x, y, w, h = boxes[0]
    (HERE / "clip_box.txt").write_text(f"{x:.0f},{y:.0f},{w:.0f},{h:.0f}\n")
    print(f"wrote {HERE / 'clip.mp4'}: {len(frames)} frames, first-frame box (0-based) {x:.0f},{y:.0f},{w:.0f},{h:.0f}")


if __name__ == "__main__":
    main()

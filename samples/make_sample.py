"""Regenerate ``samples/clip.mp4`` and its first-frame box, the project's own quick-start clip.

A textured object moves across a textured background, grows and shrinks, and
passes behind an occluding bar for a stretch of frames; sensor noise and
H.264 compression make it look like real video. Ground truth for every frame
goes to ``clip_groundtruth.txt`` (OTB format, 1-based) so that the quick start
can also be scored with ``sptpt-annotate eval``.

    python samples/make_sample.py
"""

from __future__ import annotations

from pathlib import Path

import imageio_ffmpeg
import numpy as np

from annotator.otb import write_otb_boxes
from annotator.synthetic import make_clip

HERE = Path(__file__).resolve().parent
FPS = 25


def main() -> None:
    clip = make_clip(100, size=(320, 240), object_size=(48, 40), seed=2026, occlusion=(0.45, 0.58))
    writer = imageio_ffmpeg.write_frames(
        str(HERE / "clip.mp4"), (320, 240), fps=FPS, codec="libx264", pix_fmt_out="yuv420p", quality=None,
        output_params=["-crf", "20", "-preset", "slow", "-movflags", "+faststart"], macro_block_size=1,
        ffmpeg_log_level="error")
    writer.send(None)
    for frame in clip.frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    write_otb_boxes(HERE / "clip_groundtruth.txt", clip.boxes_xywh, origin=1)
    x, y, w, h = clip.boxes_xywh[0]
    (HERE / "clip_box.txt").write_text(f"{x:.0f},{y:.0f},{w:.0f},{h:.0f}\n")
    print(f"wrote {HERE / 'clip.mp4'}: {len(clip.frames)} frames, first-frame box (0-based) {x:.0f},{y:.0f},{w:.0f},{h:.0f}")


if __name__ == "__main__":
    main()

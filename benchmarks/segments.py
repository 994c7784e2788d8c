"""Restarted segments: each OTB sequence tracked anew from its true box every 80 frames, for 40 frames.

Writes the batch manifest of one OTB root, then runs the tool's own batch on it (``benchmarks/_right_tracks.py``
says what the segments measure)::

    for SET in otb otb_extra; do for S in 0 1 2; do
      python -m benchmarks.segments --otb ../shared/$SET --out benchmarks/_runs/segments/$SET/robust-s$S --seed $S
    done; done

The batch is ``sptpt-annotate batch MANIFEST --seed S --no-render --formats flags --workers 2 --preset robust``,
as the runs of ``benchmarks/failure_model.py`` are; a rerun skips the finished segments.
"""

from __future__ import annotations

import argparse
import csv
import io
import subprocess
import sys
from pathlib import Path

from annotator.atomic import write_text_atomic
from benchmarks._right_tracks import EVERY, LENGTH, segment_rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--otb", type=Path, required=True, help="an OTB root (../shared/otb or ../shared/otb_extra)")
    parser.add_argument("--out", type=Path, required=True, help="the batch output folder")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="robust")
    parser.add_argument("--config", type=Path, default=None,
                        help="a YAML config for the batch (preset, tracker values), e.g. a variant of robust")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--length", type=int, default=LENGTH, help=f"frames per segment (default {LENGTH})")
    parser.add_argument("--every", type=int, default=EVERY, help=f"frames between segment starts (default {EVERY})")
    args = parser.parse_args()
    if not args.otb.is_dir():
        parser.error(f"--otb {args.otb}: not a folder; give an OTB root such as ../shared/otb")
    if args.length < 20 or args.every < 1:
        parser.error("--length must be >= 20 frames and --every >= 1")
    rows = segment_rows(args.otb, args.length, args.every)
    if not rows:
        parser.error(f"--otb {args.otb}: no sequence with a groundtruth_rect.txt and 20 frames or more")
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    manifest = args.out.parent / f"{args.out.name}.csv"
    write_text_atomic(manifest, text.getvalue())
    command = ["sptpt-annotate", "batch", str(manifest), "--out", str(args.out), "--seed", str(args.seed),
               "--no-render", "--formats", "flags", "--workers", str(args.workers), "--preset", args.preset, "--quiet"]
    if args.config is not None:
        command += ["--config", str(args.config)]
    print(f"{len(rows)} segments of {args.otb}: {' '.join(command)}", flush=True)
    return subprocess.call(command, stdout=sys.stdout, stderr=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())

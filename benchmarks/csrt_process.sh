#!/bin/sh
# OpenCV CSRT (one thread), one process per sequence, on the speed manifest's Dog1, Coke and Car4, first STOP frames
# (default 200): the peer of issue #44's whole-process ratio ("The default's speed" in RESULTS.md). Needs
# benchmarks/_env (created by `python -m benchmarks.otb_benchmark --trackers csrt`). Run from anywhere.
set -e
cd "$(dirname "$0")/.."
STOP=${STOP:-200}
for s in Dog1 Coke Car4; do
  benchmarks/_env/bin/python benchmarks/_peer_runner.py \
    "{\"tracker\": \"csrt\", \"seq_dir\": \"../shared/otb/$s\", \"out_dir\": \"/tmp/spd/csrt\", \"name\": \"$s\", \"stop\": $STOP}" >/dev/null
done

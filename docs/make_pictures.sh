#!/usr/bin/env bash
# Regenerate docs/overlay.png and docs/report.png from the quick start's run on the sample clip.
# Needs the tool installed and Chromium (Debian: apt-get install chromium) for the report's screenshot.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -f samples/clip_sptpt/report.html ] || sptpt-annotate samples/clip.mp4 --box "$(cat samples/clip_box.txt)" --force --quiet
# A flagged frame of the overlay: the box on the look-alike, the red REVIEW border.
python3 - <<'PY'
import cv2
capture = cv2.VideoCapture("samples/clip_sptpt/overlay.mp4")
capture.set(cv2.CAP_PROP_POS_FRAMES, 55)
ok, frame = capture.read()
assert ok, "cannot read frame 55 of samples/clip_sptpt/overlay.mp4"
cv2.imwrite("docs/overlay.png", cv2.resize(frame, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
PY
chromium --headless --no-sandbox --disable-gpu --hide-scrollbars --window-size=1100,1400 \
    --screenshot="$PWD/docs/report.png" "file://$PWD/samples/clip_sptpt/report.html" 2>/dev/null
echo "wrote docs/overlay.png and docs/report.png"

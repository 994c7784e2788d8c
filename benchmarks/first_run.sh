#!/bin/sh
# The README's sample run as on a fresh install: numba's cache empty (a new temporary folder), every output
# written to another. The command timed for issue #44's quick-start target ("The default's speed" in RESULTS.md);
# time it whole, e.g. `/usr/bin/time -f %e benchmarks/first_run.sh`. WARM=1 keeps the user's cache instead (a
# later run). A tree other than the installed one: PYTHONPATH=<worktree>. Run from anywhere.
set -e
cd "$(dirname "$0")/.."
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
if [ -z "$WARM" ]; then
  export NUMBA_CACHE_DIR="$out/numba-cache"
fi
sptpt-annotate samples/clip.mp4 --box 136,129,48,40 --force --out "$out/clip_sptpt" --quiet

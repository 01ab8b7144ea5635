#!/bin/bash
# The set-up figures of docs/tutorials/first-dataset.md: a fresh clone of this repository under a scratch directory, its
# own .venv from the package index (no pip cache), then `make dataset FRAMES=2`. Prints the
# seconds from the clone to the end of `make venv`, the .venv's size, any test-only package that
# slipped in (none expected), and the seconds from the clone to the build's last line; the
# build's output, each line stamped with its seconds since the clone, is in DIR/build.log.
#
#   bash tools/measure_first_build.sh [DIR] [BRANCH]     (DIR default /tmp/carlaocc-first-build)
set -u
DIR=${1:-/tmp/carlaocc-first-build}
BRANCH=${2:-$(git rev-parse --abbrev-ref HEAD)}
SRC=$(git rev-parse --show-toplevel)
rm -rf "$DIR" && mkdir -p "$DIR" && cd "$DIR" || exit 1
t0=$(date +%s.%N)
since() { echo "$(date +%s.%N) - $t0" | bc; }
git clone -q --branch "$BRANCH" "$SRC" clone && cd clone || exit 1
PIP_NO_CACHE_DIR=1 make venv > ../venv.log 2>&1 || { echo "make venv failed: see $DIR/venv.log"; exit 1; }
echo "clone to .venv ready: $(since) s"
du -sm .venv | awk '{print ".venv: " $1 " MB"}'
.venv/bin/pip list 2>/dev/null | grep -iE "^(pytest|hypothesis|torch|moto|flask-cors|nuscenes) " \
  | sed 's/^/test-only package installed: /'
make dataset FRAMES=2 ROOT="$DIR/root" 2>&1 | while IFS= read -r line; do
  printf '%s %s\n' "$(since)" "$line"; done > ../build.log
echo "clone to the build's last line: $(since) s"
tail -1 ../build.log

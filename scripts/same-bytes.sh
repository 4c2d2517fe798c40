#!/usr/bin/env bash
# Usage: scripts/same-bytes.sh OLD_RAILVIEW NEW_RAILVIEW [WORK_DIR]
#
# Whether two builds of railview make the same bytes: with each binary, builds the castle
# at faces of 48 px and the street scene file at 32 px, renders two views of the castle, and
# runs the demo at faces of 16 px; then compares the SHA-256 of every database file
# (manifests, tables, objects) and both renders. Exits 0 when all are identical, 1 with the
# differing files listed otherwise. About a minute per binary on two cores.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 OLD_RAILVIEW NEW_RAILVIEW [WORK_DIR]" >&2
  exit 2
fi
old=$(realpath "$1")
new=$(realpath "$2")
root=$(cd "$(dirname "$0")/.." && pwd)
work=${3:-$(mktemp -d)}
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$work/xdg}
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"

outputs() {
  local bin=$1 out=$2
  rm -rf "$out" && mkdir -p "$out" && cd "$out"
  "$bin" build --scene castle --track main --face-size 48 --out castle48/db >castle48.log 2>&1
  "$bin" build --scene "$root/scenes/street.toml" --track main --face-size 32 \
    --out street32/db >street32.log 2>&1
  "$bin" render castle48/db --at 3.3 --yaw 20 --pitch 5 --fov 90 --size 160x90 -o r1.png >r1.log 2>&1
  "$bin" render castle48/db --at 0 --fov 70 --size 128x96 -o r2.png >r2.log 2>&1
  "$bin" demo --no-window --face-size 16 --walk-speed 36 --out demo16 >demo16.log 2>&1
  find castle48/db street32/db demo16/db -type f | sort | xargs sha256sum >hashes.txt
  sha256sum r1.png r2.png >>hashes.txt
}

outputs "$old" "$work/old"
outputs "$new" "$work/new"
if diff "$work/old/hashes.txt" "$work/new/hashes.txt" >"$work/differences.txt"; then
  echo "same bytes: $(wc -l <"$work/new/hashes.txt") files (databases and renders) in $work"
else
  echo "different bytes (see $work/differences.txt):" >&2
  grep '^>' "$work/differences.txt" | awk '{print "  " $3}' >&2
  exit 1
fi

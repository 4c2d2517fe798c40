#!/usr/bin/env bash
# What a client and the server cost on towns of growing size (issue 45), for BENCHMARKS:
#
#   scripts/bench-town.sh OUT K...
#
# For each K: builds `--scene town-K --track all --face-size 16` into OUT/tK (reused when its
# manifest is there; the build's wall time, CPU time and peak RSS from /usr/bin/time -v in
# OUT/tK.build.log), prints the index's cost (examples/index_cost), serves the database with
# `railview serve` on loopback, walks 500 m of the route ROUTE (default
# ew-0,ns-2,ew-2,ns-0: round a block in town-1; LENGTH metres, default 500) at 2 Mbit/s and
# 50 ms (visibility+prefetch, 4 m/s) under /usr/bin/time -v, and reads the server's peak RSS
# (VmHWM) after the walk. One line of JSON per town on stdout, also in OUT/table.jsonl.
set -euo pipefail
out=$1
shift
here=$(cd "$(dirname "$0")/.." && pwd)
railview=${RAILVIEW:-$here/target/release/railview}
cost=${INDEX_COST:-$here/target/release/examples/index_cost}
route=${ROUTE:-ew-0,ns-2,ew-2,ns-0}
length=${LENGTH:-500}
mkdir -p "$out"
out=$(cd "$out" && pwd)
: > "$out/table.jsonl"
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
field() { grep -F "$1" "$2" | head -1 | awk -F': ' '{print $2}'; }
for k in "$@"; do
  db="$out/t$k"
  if [ ! -f "$db/manifest.json" ]; then
    /usr/bin/time -v "$railview" build --scene "town-$k" --track all --face-size 16 --out "$db" \
      > "$out/t$k.build.log" 2>&1
  fi
  index=$("$cost" "$db")
  port=$(free_port)
  "$railview" serve "$db" --addr "127.0.0.1:$port" > "$out/t$k.serve.log" 2>&1 &
  spid=$!
  for _ in $(seq 100); do
    curl -sf "http://127.0.0.1:$port/manifest.json" > /dev/null && break
    sleep 0.1
  done
  rm -rf "$out/t$k.walk"
  /usr/bin/time -v "$railview" walk "http://127.0.0.1:$port" --out "$out/t$k.walk" \
    --speed 4 --bandwidth 2mbit --strategy visibility+prefetch --route "$route" --length "$length" \
    > "$out/t$k.walk.log" 2>&1
  serve_kb=$(awk '/VmHWM/ {print $2}' "/proc/$spid/status")
  kill "$spid"
  wait "$spid" 2> /dev/null || true
  python3 - "$out" "$k" "$serve_kb" "$index" << 'EOF' | tee -a "$out/table.jsonl"
import json, re, sys
out, k, serve_kb, index = sys.argv[1], sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
def time_v(path):
    text = open(path).read()
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", text).group(1)
    secs = sum(float(x) * 60 ** i for i, x in enumerate(reversed(wall.split(":"))))
    user = float(re.search(r"User time \(seconds\): (\S+)", text).group(1))
    sys_ = float(re.search(r"System time \(seconds\): (\S+)", text).group(1))
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", text).group(1))
    return {"wall_s": round(secs, 1), "cpu_s": round(user + sys_, 1), "peak_rss_kb": rss}
walk = json.load(open(f"{out}/t{k}.walk/walk.json"))
run = walk["runs"][0]
row = {
    "town_km": int(k),
    "viewpoints": index["viewpoints"],
    "junctions": index["junctions"],
    "build": time_v(f"{out}/t{k}.build.log") if __import__("os").path.exists(f"{out}/t{k}.build.log") else None,
    "root_bytes": index["root_bytes"],
    "index_pieces": index["pieces"],
    "index_bytes": index["piece_bytes"],
    "first_view_index_bytes_if_near_only": index["first_view_index_bytes"],
    "walk_m": walk["length_m"],
    "walk_route": walk["track"],
    "walk_manifest_bytes": run["manifest_bytes"],
    "walk_manifest_s": round(run["manifest_s"], 3),
    "walk_first_frame_bytes": run.get("first_frame_bytes"),
    "walk_time_to_first_frame_s": run.get("time_to_first_frame_s"),
    "walk": time_v(f"{out}/t{k}.walk.log"),
    "serve_peak_rss_kb": serve_kb,
}
print(json.dumps(row))
EOF
done

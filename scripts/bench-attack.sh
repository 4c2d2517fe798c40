#!/usr/bin/env bash
# The attack benchmark of BENCHMARKS.md: wrk with 100 connections against `railview serve`,
# alone and while 400 slow header senders and 256 stalled readers of an 8 MiB /bundle
# attack from 16 loopback addresses; requests/s, p50 and p99 of the legitimate traffic and
# the server's peak RSS.
#
#   scripts/bench-attack.sh [DB] [SECONDS]
#
# DB defaults to bench-castle-192 (built here once: castle, face 192, as the demo builds it).
# Needs wrk (apt-get install wrk).
set -euo pipefail
cd "$(dirname "$0")/.."
db=${1:-bench-castle-192}
secs=${2:-15}
port=18480
command -v wrk >/dev/null || { echo "wrk is not installed (apt-get install wrk)" >&2; exit 1; }
cargo build --release --locked -q
cargo build --release --locked -q -p streamer --example attack
rv=target/release/railview
attack=target/release/examples/attack
if [ ! -f "$db/manifest.json" ]; then
  "$rv" build --scene castle --track main --face-size 192 --out "$db"
fi
work=$(mktemp -d)
"$attack" --paths "$db" 2000 > "$work/paths.txt"
"$rv" serve "$db" --addr 127.0.0.1:$port 2> "$work/serve.log" &
server=$!
trap 'kill $server 2>/dev/null || true' EXIT
sleep 1
url=http://127.0.0.1:$port
run_wrk() {
  wrk -t2 -c100 -d"${secs}s" --latency -s scripts/wrk-paths.lua "$url" -- "$work/paths.txt"
}
summary() {
  awk -v name="$1" '/Requests\/sec/ {rps=$2} /^ +50%/ {p50=$2} /^ +99%/ {p99=$2}
    END {printf "%s: %s req/s, p50 %s, p99 %s\n", name, rps, p50, p99}' "$2"
}
# Alone and under attack, twice in turn: other load on the machine changes between phases,
# so compare each attack phase with the alone phase before it.
for round in 1 2; do
  echo "== round $round: wrk alone"
  run_wrk | tee "$work/alone$round.txt"
  echo "== round $round: wrk under attack"
  "$attack" --target 127.0.0.1:$port --db "$db" --slow 400 --stalled 256 --sources 16 \
    --seconds $((secs + 8)) &
  attacker=$!
  sleep 5
  run_wrk | tee "$work/attack$round.txt"
  wait $attacker
  sleep 2
done
peak=$(awk '/VmHWM/ {print $2}' /proc/$server/status)
kill -TERM $server; wait $server || true
tail -1 "$work/serve.log"
echo "== $(nproc) cores, $(date -u '+%Y-%m-%d %H:%M UTC'), load $(cut -d' ' -f1-3 /proc/loadavg)"
for round in 1 2; do
  summary "round $round alone" "$work/alone$round.txt"
  summary "round $round under attack" "$work/attack$round.txt"
done
echo "server peak RSS: $((peak / 1024)) MiB"
rm -rf "$work"

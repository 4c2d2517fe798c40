#!/usr/bin/env bash
# The same walk over nginx (the README's configuration), `railview serve` and
# `railview serve --no-bundles`, for the BENCHMARKS table:
#
#   scripts/bench-static-hosts.sh DB [OUT] [WALK ARGS...]
#
# DB is a database directory; OUT (default bench-static-hosts/) receives one walk directory
# per server (walk.json, summary.md) and table.md. nginx is started unprivileged on a free
# loopback port with the README's own server block (its listen and root lines replaced);
# both railview servers run on loopback too. Extra arguments go to every `railview walk`
# (default: --speed 4 --bandwidth 2mbit,unlimited --strategy visibility+prefetch).
set -euo pipefail
db=$(cd "$1" && pwd)
out=${2:-bench-static-hosts}
shift $(( $# >= 2 ? 2 : 1 ))
args=("$@")
[ ${#args[@]} -eq 0 ] && args=(--speed 4 --bandwidth 2mbit,unlimited --strategy visibility+prefetch)
here=$(cd "$(dirname "$0")/.." && pwd)
railview=${RAILVIEW:-$here/target/release/railview}
nginx=$(command -v nginx || echo /usr/sbin/nginx)
mkdir -p "$out"
out=$(cd "$out" && pwd)
work=$(mktemp -d)
# nginx's workers (nobody, when started as root) read the database through it.
chmod 755 "$work"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

# nginx with the README's server block.
port=$(free_port)
mkdir -p "$work/www" "$work/temp"/{body,proxy,fastcgi,uwsgi,scgi}
chmod -R 777 "$work/temp"
ln -s "$db" "$work/www/db"
server=$(sed -n '/^```nginx$/,/^```$/p' "$here/README.md" | sed '1d;$d' \
  | sed -E "s|^( *)listen .*|\1listen 127.0.0.1:$port;|; s|^( *)root .*|\1root $work/www;|")
cat > "$work/nginx.conf" <<EOF
daemon off;
worker_processes 1;
pid $work/nginx.pid;
error_log $work/error.log warn;
events { worker_connections 256; }
http {
  access_log off;
  client_body_temp_path $work/temp/body;
  proxy_temp_path $work/temp/proxy;
  fastcgi_temp_path $work/temp/fastcgi;
  uwsgi_temp_path $work/temp/uwsgi;
  scgi_temp_path $work/temp/scgi;
$server
}
EOF
"$nginx" -p "$work" -c "$work/nginx.conf" > /dev/null 2>&1 &
pids+=($!)

# Both railview servers, each printing its URL on its first line.
"$railview" serve "$db" --addr 127.0.0.1:0 > /dev/null 2> "$work/serve.log" &
pids+=($!)
"$railview" serve "$db" --addr 127.0.0.1:0 --no-bundles > /dev/null 2> "$work/plain.log" &
pids+=($!)
url_of() {
  for _ in $(seq 100); do
    grep -q 'http://' "$1" 2>/dev/null && break
    sleep 0.1
  done
  grep -o 'http://[0-9.:]*' "$1" | head -1
}
bundles=$(url_of "$work/serve.log")
plain=$(url_of "$work/plain.log")
for _ in $(seq 50); do
  (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null && break
  sleep 0.1
done

for pair in "nginx=http://127.0.0.1:$port/db" "serve=$bundles" "serve-no-bundles=$plain"; do
  name=${pair%%=*}
  url=${pair#*=}
  echo "walking over $name ($url)" >&2
  "$railview" walk "$url" --out "$out/$name" "${args[@]}" > /dev/null
done

{
  echo "| server | bandwidth | strategy | first frame (s) | needed fraction | requests | requests/m | bytes | bytes/m |"
  echo "|---|---|---|---|---|---|---|---|---|"
  for name in nginx serve serve-no-bundles; do
    python3 - "$out/$name/walk.json" "$name" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
for run in r["runs"]:
    bw = run["bandwidth_bps"]
    bw = "unlimited" if bw is None else f"{bw / 1e6:g} Mbit/s"
    ff = run["time_to_first_frame_s"]
    ff = "never" if ff is None else f"{ff:.2f}"
    print(f"| {sys.argv[2]} | {bw} | {run['strategy']} | {ff} | {run['mean_needed_fraction']:.3f} "
          f"| {run['requests']} | {run['requests_per_m']:.1f} | {run['bytes']} | {run['bytes_per_m']:.0f} |")
PY
  done
} | tee "$out/table.md"

#!/usr/bin/env bash
# Sharded jobs (docs/sharding.md) through a local nimbusd: the wall time of
# one big coloured chaos-game job unsharded and split into 2 and 4 shards,
# with 1 and 2 workers (threads per job = cores / workers), the time of the
# merge (the parent's run: reading and adding the partials, then writing
# the VDB), and whether every result's sha256 equals the unsharded one.
#
# Usage: bench/sharding_bench.sh [ITERATIONS] [RESOLUTION]
#   (default 200000000 iterations of the volume fern at 256^3, map colour)
# merge_s is the parent's whole run: adding the partials (add_ms, from the
# nimbusd log) and then the finishing and VDB write every job pays.
# Environment: BIN (folder of nimbusd and nimbus, default build/bin).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
bin="${BIN:-$here/../build/bin}"
iterations="${1:-200000000}"
resolution="${2:-256}"
cores="$(nproc)"
for b in nimbusd nimbus; do
  if [ ! -x "$bin/$b" ]; then
    echo "sharding_bench: no $b in $bin (build the nimbusd and nimbus targets)" >&2
    exit 2
  fi
done

work="$(mktemp -d)"
server_pid=""
cleanup() {
  if [ -n "$server_pid" ]; then
    kill "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT

# The fern of examples/fern_volume.json, coloured by map, at this size.
python3 - "$here/../examples/fern_volume.json" "$work/spec.json" "$iterations" "$resolution" <<'PY'
import json, sys
spec = json.load(open(sys.argv[1]))
spec["name"] = "sharding_bench"
spec["grid"]["resolution"] = [int(sys.argv[4])]
cg = spec["chaos_game"]
cg["iterations"] = sys.argv[3]
for i, m in enumerate(cg["ifs"]["maps"]):
    m["color"] = i / max(1, len(cg["ifs"]["maps"]) - 1)
cg["color"] = {"mode": "COLOR_MODE_MAP", "blend": 0.3}
json.dump(spec, open(sys.argv[2], "w"))
PY

start_server() {  # workers
  rm -rf "$work/data" "$work/port"
  "$bin/nimbusd" --listen 127.0.0.1:0 --port-file "$work/port" --data-dir "$work/data" \
    --workers "$1" --threads-per-job "$(( cores / $1 > 0 ? cores / $1 : 1 ))" \
    --log-level info --min-free-disk-mib 0 > "$work/log" 2>&1 &
  server_pid=$!
  for _ in $(seq 1 100); do [ -s "$work/port" ] && break; sleep 0.1; done
  server="127.0.0.1:$(cat "$work/port")"
}
stop_server() {
  kill "$server_pid"; wait "$server_pid" 2>/dev/null || true; server_pid=""
}

# Prints: wall seconds, merge seconds (the parent's run), the part of it
# spent reading and adding partials (ms), sha256.
run_job() {  # shards
  local t0 t1 id
  t0=$(date +%s.%N)
  id=$("$bin/nimbus" --server "$server" submit "$work/spec.json" --no-cache --shards "$1" \
       | grep -o 'j-[0-9a-f]*' | head -1)
  "$bin/nimbus" --server "$server" watch "$id" >/dev/null 2>&1 || true
  t1=$(date +%s.%N)
  "$bin/nimbus" --server "$server" get "$id" > "$work/job.json"
  local add
  add=$(grep "job=$id event=merged" "$work/log" | grep -o 'add_partials_ms=[0-9]*' \
        | cut -d= -f2 || true)
  python3 - "$work/job.json" "$t0" "$t1" "$1" "${add:--}" <<'PY'
import json, sys
from datetime import datetime
job = json.load(open(sys.argv[1]))
assert job.get("state") == "JOB_STATE_SUCCEEDED", job.get("error")
def t(s): return datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()
wall = float(sys.argv[3]) - float(sys.argv[2])
merge = t(job["end_time"]) - t(job["start_time"]) if int(sys.argv[4]) > 1 else float("nan")
print(f"{wall:.2f} {merge:.2f} {sys.argv[5]} {job['result']['sha256']}")
PY
}

echo "sharding_bench: $iterations iterations, ${resolution}^3, map colour, $cores cores"
printf "%-8s %-7s %10s %10s %10s %s\n" workers shards wall_s merge_s add_ms same_bytes
for workers in 1 2; do
  start_server "$workers"
  base=""
  for shards in 1 2 4; do
    read -r wall merge add sha < <(run_job "$shards")
    [ -z "$base" ] && base="$sha"
    same=$([ "$sha" = "$base" ] && echo yes || echo NO)
    label=$([ "$shards" = 1 ] && echo none || echo "$shards")
    printf "%-8s %-7s %10s %10s %10s %s\n" "$workers" "$label" "$wall" "$merge" "$add" "$same"
  done
  stop_server
done

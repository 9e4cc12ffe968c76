#!/usr/bin/env bash
# A big sharded job on replicas sharing one PostgreSQL queue (docs/sharding.md,
# docs/operator_guide.md "Several replicas"): the wall time, from submit to
# the merged result, of one Sierpinski tetrahedron 256^3 job split into
# SHARDS shards, on 1 and on 3 local nimbusd replicas, and whether the
# result's sha256 equals the unsharded job's on one replica.
#
# Starts a throwaway PostgreSQL (initdb + pg_ctl as the `postgres` user when
# run as root) on a unix socket in a temp folder, and removes it at the end.
#
# Usage: bench/replica_shard_bench.sh [ITERATIONS] [SHARDS]
#   (default 10000000000 iterations, 16 shards)
# Environment: BIN (folder of nimbusd and nimbus, default build/bin).
# On one machine the replicas share its cores, so 3 replicas cannot beat
# 1: the figures show what sharding and the shared queue cost; the gain
# needs replicas on separate machines.
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
bin="${BIN:-$here/../build/bin}"
iterations="${1:-10000000000}"
shards="${2:-16}"
cores="$(nproc)"
pgbin="$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1)"
if [ -z "$pgbin" ] || [ ! -x "$pgbin/pg_ctl" ]; then
  echo "replica_shard_bench: PostgreSQL is not installed (scripts/install_deps.sh installs it)" >&2
  exit 2
fi

work="$(mktemp -d)"
chmod 755 "$work"
as_pg() { if [ "$(id -u)" -eq 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi; }
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  as_pg "$pgbin/pg_ctl" -D "$work/pg" -m immediate stop >/dev/null 2>&1 || true
  rm -rf "$work"
}
trap cleanup EXIT

mkdir -p "$work/pg" "$work/sock"
[ "$(id -u)" -eq 0 ] && chown postgres "$work/pg" "$work/sock"
as_pg "$pgbin/initdb" -D "$work/pg" -A trust -U nimbus >/dev/null
as_pg "$pgbin/pg_ctl" -D "$work/pg" -l "$work/pg/server.log" -w \
  -o "-k $work/sock -c listen_addresses='' -c fsync=off" start >/dev/null

python3 - "$here/../examples/sierpinski_tetrahedron.json" "$work/spec.json" "$iterations" <<'PY'
import json, sys
spec = json.load(open(sys.argv[1]))
spec["name"] = "replica_shard_bench"
spec["chaos_game"]["iterations"] = sys.argv[3]
json.dump(spec, open(sys.argv[2], "w"))
PY

db=0
start_replicas() {  # count
  db=$((db + 1))
  as_pg "$pgbin/createdb" -h "$work/sock" -U nimbus "bench$db"
  local url="postgresql://nimbus@/bench$db?host=$work/sock"
  rm -rf "$work/results"
  servers=()
  for i in $(seq 1 "$1"); do
    rm -f "$work/port$i"
    "$bin/nimbusd" --listen 127.0.0.1:0 --port-file "$work/port$i" --data-dir "$work/data$db-$i" \
      --store "$url" --results-dir "$work/results" --replica-id "r$i" --workers 1 \
      --threads-per-job "$(( cores / $1 > 0 ? cores / $1 : 1 ))" --min-free-disk-mib 0 \
      > "$work/log$db-$i" 2>&1 &
    pids+=($!)
    for _ in $(seq 1 100); do [ -s "$work/port$i" ] && break; sleep 0.1; done
    servers+=("127.0.0.1:$(cat "$work/port$i")")
  done
}
stop_replicas() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  pids=()
}

run() {  # shards -> "seconds sha256"
  local t0 t1 id
  t0=$(date +%s.%N)
  id=$("$bin/nimbus" --server "${servers[0]}" submit "$work/spec.json" --no-cache \
       --shards "$1" | grep -o 'j-[0-9a-f]*' | head -1)
  "$bin/nimbus" --server "${servers[0]}" watch "$id" >/dev/null 2>&1 || true
  t1=$(date +%s.%N)
  local sha
  sha=$("$bin/nimbus" --server "${servers[${#servers[@]}-1]}" get "$id" \
        | python3 -c 'import json,sys; j=json.load(sys.stdin); print(j["result"]["sha256"])')
  echo "$(echo "$t1 - $t0" | bc -l) $sha"
}

echo "replica_shard_bench: tetrahedron 256^3, $iterations iterations, $cores cores"
start_replicas 1
read -r base_s base_sha < <(run 1)
printf "%-28s %8.1f s  %6.0f M/s\n" "1 replica, unsharded" "$base_s" \
  "$(echo "$iterations / $base_s / 1000000" | bc -l)"
read -r s1 sha1 < <(run "$shards")
stop_replicas
printf "%-28s %8.1f s  %6.0f M/s  same bytes: %s\n" "1 replica, $shards shards" "$s1" \
  "$(echo "$iterations / $s1 / 1000000" | bc -l)" "$([ "$sha1" = "$base_sha" ] && echo yes || echo NO)"
start_replicas 3
read -r s3 sha3 < <(run "$shards")
stop_replicas
printf "%-28s %8.1f s  %6.0f M/s  same bytes: %s\n" "3 replicas, $shards shards" "$s3" \
  "$(echo "$iterations / $s3 / 1000000" | bc -l)" "$([ "$sha3" = "$base_sha" ] && echo yes || echo NO)"

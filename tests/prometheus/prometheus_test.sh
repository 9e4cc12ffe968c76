#!/usr/bin/env bash
# A real Prometheus scrapes nimbusd: Debian's prometheus on loopback with a
# temporary config, nimbusd's /metrics checked by promtool, then a query
# through Prometheus' HTTP API must return the jobs-by-state series of the
# jobs this script ran (2 succeeded, 1 cancelled).
# Usage: prometheus_test.sh NIMBUSD SOURCE_DIR
set -euo pipefail
NIMBUSD=$1
SRC=$2
DIR=$(mktemp -d)
NPID=""
PPID_PROM=""
cleanup() {
  [ -n "$PPID_PROM" ] && kill "$PPID_PROM" 2>/dev/null && wait "$PPID_PROM" 2>/dev/null
  [ -n "$NPID" ] && kill "$NPID" 2>/dev/null && wait "$NPID" 2>/dev/null
  rm -rf "$DIR"
}
trap cleanup EXIT

"$NIMBUSD" --listen 127.0.0.1:0 --port-file "$DIR/port" --http 127.0.0.1:0 \
  --http-port-file "$DIR/http_port" --data-dir "$DIR/data" --workers 2 --threads-per-job 1 \
  --min-free-disk-mib 0 --log-level warn &
NPID=$!
for _ in $(seq 200); do [ -s "$DIR/port" ] && break; sleep 0.1; done
HTTP="127.0.0.1:$(cat "$DIR/http_port")"

submit() {  # submit SPEC_JSON -> job id
  curl -sf -X POST -H 'Content-Type: application/json' --data "{\"spec\": $1}" "http://$HTTP/api/v1/jobs" |
    python3 -c 'import json,sys; print(json.load(sys.stdin)["job"]["id"])'
}
state() { curl -sf "http://$HTTP/api/v1/jobs/$1" | python3 -c 'import json,sys; print(json.load(sys.stdin)["job"]["state"])'; }
await_state() {
  for _ in $(seq 600); do [ "$(state "$1")" = "$2" ] && return 0; sleep 0.1; done
  echo "FAILED: job $1 never reached $2"; exit 1
}

SMALL=$(python3 -c 'import json,sys; s=json.load(open(sys.argv[1])); s["grid"]["resolution"]=[16]; s["chaos_game"]["iterations"]="100000"; print(json.dumps(s))' "$SRC/examples/sierpinski_tetrahedron.json")
ENDLESS=$(python3 -c 'import json,sys; s=json.loads(sys.argv[1]); s["chaos_game"]["iterations"]=str(2**38); print(json.dumps(s))' "$SMALL")
A=$(submit "$SMALL"); B=$(submit "$SMALL"); C=$(submit "$ENDLESS")
await_state "$A" JOB_STATE_SUCCEEDED
await_state "$B" JOB_STATE_SUCCEEDED
await_state "$C" JOB_STATE_RUNNING
curl -sf -X POST -H 'Content-Type: application/json' -d '{}' "http://$HTTP/api/v1/jobs/$C/cancel" >/dev/null
await_state "$C" JOB_STATE_CANCELLED

curl -sf "http://$HTTP/metrics" > "$DIR/metrics.txt"
promtool check metrics < "$DIR/metrics.txt"
echo "ok: promtool check metrics"

PROM_PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
cat > "$DIR/prometheus.yml" <<YML
global:
  scrape_interval: 1s
scrape_configs:
  - job_name: nimbusd
    static_configs:
      - targets: ["$HTTP"]
YML
promtool check config "$DIR/prometheus.yml" >/dev/null
# The operator guide's example config and alert rules (deploy/prometheus).
(cd "$SRC/deploy/prometheus" && promtool check config prometheus.yml >/dev/null)
echo "ok: deploy/prometheus config and rules" 
prometheus --config.file="$DIR/prometheus.yml" --storage.tsdb.path="$DIR/tsdb" \
  --web.listen-address="127.0.0.1:$PROM_PORT" --log.level=warn &
PPID_PROM=$!

query() {  # query PROMQL -> value of the single series, or empty
  curl -sf --get --data-urlencode "query=$1" "http://127.0.0.1:$PROM_PORT/api/v1/query" |
    python3 -c 'import json,sys; r=json.load(sys.stdin)["data"]["result"]; print(r[0]["value"][1] if len(r)==1 else "")' 2>/dev/null || true
}
for _ in $(seq 300); do
  [ "$(query 'nimbus_jobs{job="nimbusd",state="succeeded",kind="chaos_game"}')" = 2 ] && break
  sleep 0.2
done
SUCCEEDED=$(query 'nimbus_jobs{job="nimbusd",state="succeeded",kind="chaos_game"}')
CANCELLED=$(query 'nimbus_jobs{job="nimbusd",state="cancelled",kind="chaos_game"}')
RUNNING=$(query 'nimbus_jobs{job="nimbusd",state="running",kind="chaos_game"}')
UP=$(query 'up{job="nimbusd"}')
echo "prometheus: up=$UP succeeded=$SUCCEEDED cancelled=$CANCELLED running=$RUNNING"
[ "$UP" = 1 ] && [ "$SUCCEEDED" = 2 ] && [ "$CANCELLED" = 1 ] && [ "$RUNNING" = 0 ] ||
  { echo "FAILED: Prometheus' series do not match the jobs run"; exit 1; }
echo "prometheus_test: all checks passed"

#!/usr/bin/env bash
# Runs the deployment of deploy/compose.sh (PostgreSQL and two nimbusd
# replicas in containers, a 64 MB tmpfs results volume) through failure
# scenarios and prints each one's result and timings:
#   jobs       50 jobs over both replicas end SUCCEEDED after one attempt,
#              each started and ended once, all with the same sha256
#   failover   the replica running a long job is killed (SIGKILL): the other
#              finishes it, attempts 2, the sha256 of an undisturbed run
#   rolling    each replica in turn stopped with SIGTERM and started again
#              from the image while jobs run: none fails, none ends twice,
#              a watcher on the restarted replica follows its job to the end
#   postgres   the PostgreSQL container stopped and started: both replicas
#              NOT_SERVING while it is down, SERVING again by themselves,
#              every job submitted before the outage SUCCEEDED once
#   disk-full  the results volume filled up: a job ends with
#              RESOURCE_EXHAUSTED, the replicas stay SERVING, and once space
#              is freed the next job succeeds
#
#   deploy/test_containers.sh             the full set (as root)
#   deploy/test_containers.sh --quick     jobs (20 of them), failover, disk-full
#   deploy/test_containers.sh rolling postgres    the scenarios named
#   deploy/test_containers.sh --check     exit 0 if podman can run here,
#                                         else print why and exit 1
# Builds the images first (deploy/build_image.sh; NIMBUS_SKIP_BUILD=1 uses
# the existing ones). Everything it starts is named nimbus-t-PID-* and
# removed on exit, even after a failure or a signal; the whole run is
# bounded by NIMBUS_TEST_LIMIT_S (1500 s). Where podman cannot run the test
# fails: it never reports SKIPPED.
set -euo pipefail
# shellcheck source=podman/env.sh
source "$(dirname "$0")/podman/env.sh"

all_scenarios="jobs failover rolling postgres disk-full"
scenarios=$all_scenarios jobs_count=50
case "${1:-}" in
  --quick) scenarios="jobs failover disk-full" jobs_count=20 ;;
  --check) why=$(podman_unusable); [ -z "$why" ] && exit 0; echo "$why"; exit 1 ;;
  "") ;;
  *)
    for s in "$@"; do
      case " $all_scenarios " in *" $s "*) ;; *) usage "$0"; exit 2 ;; esac
    done
    scenarios="$*" ;;
esac

say() { echo "test_containers: $*"; }
fail() { say "FAIL: $*"; exit 1; }
why=$(podman_unusable)
[ -z "$why" ] || fail "podman cannot run here: $why"

export NIMBUS_PREFIX=nimbus-t-$$
prefix=$NIMBUS_PREFIX
work=$(mktemp -d /tmp/nimbus-t-$$.XXXXXX)
export NIMBUS_LOG_DIR=$work/logs
mkdir -p "$NIMBUS_LOG_DIR" "$work/specs"
compose="$deploy_dir/compose.sh"

cleanup() {
  local rc=$?
  set +e
  trap - EXIT INT TERM
  if [ -n "${watchdog:-}" ]; then pkill -P "$watchdog" 2>/dev/null; kill "$watchdog" 2>/dev/null; fi
  if [ -n "${watcher:-}" ]; then kill "$watcher" 2>/dev/null; fi
  podman rm -f -t 0 "$prefix-cli" >/dev/null 2>&1 || true
  "$compose" down >/dev/null 2>&1 || true
  if [ "$rc" -ne 0 ]; then
    say "logs kept in $work/logs"
    tail -n 5 "$work"/logs/*.log 2>/dev/null || true
  else
    rm -rf "$work"
  fi
  exit "$rc"
}
trap cleanup EXIT
trap 'say "interrupted"; exit 130' INT TERM
limit=${NIMBUS_TEST_LIMIT_S:-1500}
(sleep "$limit" && say "FAIL: over the time limit of $limit s" && kill -TERM $$) 2>/dev/null &
watchdog=$!

# Free loopback ports for PostgreSQL and the two replicas.
free_port() {
  local p
  while :; do
    p=$((20000 + RANDOM % 20000))
    ss -Hltn "sport = :$p" | grep -q . || ss -Hltn "sport = :$((p + 1))" | grep -q . ||
      { echo "$p"; return; }
  done
}
export NIMBUS_PG_PORT NIMBUS_PORT_BASE
NIMBUS_PG_PORT=$(free_port)
NIMBUS_PORT_BASE=$(free_port)
export NIMBUS_RESULTS_TMPFS_MB=64
export NIMBUS_DB_PASSWORD=t-$RANDOM$RANDOM
# Short leases (failover after 4 s), two workers of one thread each, no
# free-space reserve (so a full volume fails a write, not a submit).
export NIMBUS_REPLICA_ARGS="--workers 2 --threads-per-job 1 --lease-ms 4000 --heartbeat-ms 500
  --min-free-disk-mib 0 --drain-ms 5000 --log-level info"
server() { echo "127.0.0.1:$((NIMBUS_PORT_BASE + $1 - 1))"; }
now() { date +%s.%N; }
since() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$(now)"; }

# Specs: the Sierpinski tetrahedron at sizes for short and long jobs, never
# answered from the result cache.
spec() {  # NAME RESOLUTION ITERATIONS
  python3 - "$repo_dir/examples/sierpinski_tetrahedron.json" "$work/specs/$1.json" "$2" "$3" <<'PY'
import json, sys
spec = json.load(open(sys.argv[1]))
spec["grid"]["resolution"] = [int(sys.argv[3])]
spec["chaos_game"]["iterations"] = sys.argv[4]
spec["no_cache"] = True
json.dump(spec, open(sys.argv[2], "w"))
PY
}
spec small 16 20000
spec medium 32 ${NIMBUS_TEST_MEDIUM_ITERATIONS:-2000000000}
spec long 32 ${NIMBUS_TEST_LONG_ITERATIONS:-6000000000}

if [ "${NIMBUS_SKIP_BUILD:-0}" != 1 ]; then
  start=$(now)
  "$deploy_dir/build_image.sh" >"$work/logs/build.log" 2>&1 ||
    { tail -20 "$work/logs/build.log"; fail "image build"; }
  say "images built in $(since "$start") s; $(grep 'MB (budget' "$work/logs/build.log")"
fi

start=$(now)
"$compose" up || fail "bring-up"
say "bring-up (PostgreSQL and two healthy replicas): $(since "$start") s"
# The CLI of the image, in a container of its own.
podman run -d --name "$prefix-cli" --network host --read-only --tmpfs /tmp \
  -v "$work/specs:/specs:ro" --entrypoint sleep "$NIMBUS_IMAGE" infinity >/dev/null

cli() { podman exec "$prefix-cli" nimbus "$@"; }
submit() { cli --server "$(server "$1")" submit "/specs/$2.json"; }
health() { cli --server "$(server "$1")" health --service nimbus.v1.NimbusService 2>/dev/null || true; }

# Every job's view (`nimbus get`), as one JSON list, from replica $1.
views() {
  local n=$1
  shift
  podman exec "$prefix-cli" sh -c 'server=$1; shift; echo "["; sep=""
    for id; do printf "%s" "$sep"; nimbus --server "$server" get "$id" || echo "{}"; sep=","; done
    echo "]"' sh "$(server "$n")" "$@"
}
# Waits (at most $1 s) until every job in $work/ids has ended, asking
# replica $2; leaves their views in $work/views.json.
await_ended() {
  local deadline=$(($(date +%s) + $1)) n=$2
  while :; do
    # shellcheck disable=SC2046
    views "$n" $(cat "$work/ids") >"$work/views.json" 2>/dev/null || true
    python3 - "$work/views.json" <<'PY' && return 0
import json, sys
try:
    views = json.load(open(sys.argv[1]))
except ValueError:
    sys.exit(1)
ended = {"JOB_STATE_SUCCEEDED", "JOB_STATE_FAILED", "JOB_STATE_CANCELLED"}
sys.exit(0 if views and all(v.get("state") in ended for v in views) else 1)
PY
    [ "$(date +%s)" -lt "$deadline" ] || fail "jobs did not end within $1 s"
    sleep 1
  done
}

# The logs of every replica container so far (kept ones and live ones).
collect_logs() {
  for n in 1 2; do
    podman logs "$prefix-r$n" >"$work/logs/live-r$n.log" 2>&1 || true
  done
}

# Every job in $work/ids SUCCEEDED with `attempts` $1 (or any when "any"),
# was started $2 times and ended exactly once in the replicas' logs; prints
# the distinct sha256s and how many replicas ran jobs.
check_jobs_once() {
  collect_logs
  python3 - "$work/views.json" "$work/logs" "$1" "$2" <<'PY'
import json, pathlib, re, sys
views = json.load(open(sys.argv[1]))
logs = [p.read_text() for p in pathlib.Path(sys.argv[2]).glob("*r[12].log")]
want_attempts, want_starts = sys.argv[3], sys.argv[4]
errors, shas, workers = [], set(), set()
starts_total = retried = 0
for v in views:
    jid = v.get("id", "?")
    if v.get("state") != "JOB_STATE_SUCCEEDED":
        errors.append(f"{jid}: {v.get('state')} {v.get('error', '')}")
        continue
    if want_attempts != "any" and v.get("attempts") != int(want_attempts):
        errors.append(f"{jid}: attempts {v.get('attempts')}")
    ends = sum(log.count(f"job={jid} event=end") for log in logs)
    starts = sum(log.count(f"job={jid} event=start") for log in logs)
    if ends != 1:
        errors.append(f"{jid}: {ends} end events")
    if want_starts != "any" and starts != int(want_starts):
        errors.append(f"{jid}: {starts} start events")
    starts_total += starts
    retried += v.get("attempts", 1) > 1
    shas.add(v["result"]["sha256"])
    for log in logs:
        m = re.search(rf"replica=(\S+) .*job={jid} event=end", log)
        if m:
            workers.add(m.group(1))
if errors:
    print("; ".join(errors[:5]))
    sys.exit(1)
print(f"{len(views)} jobs, {len(shas)} distinct sha256, ended on {len(workers)} replicas, "
      f"{starts_total} starts, {retried} with attempts > 1")
PY
}

# jobs: N small jobs alternately on both replicas.
scenario_jobs() {
  local count=${1:-50} start
  start=$(now)
  podman exec "$prefix-cli" sh -c 'for i in $(seq "$3"); do
      if [ $((i % 2)) = 1 ]; then s=$1; else s=$2; fi
      nimbus --server "$s" submit /specs/small.json || exit 1; done' \
    sh "$(server 1)" "$(server 2)" "$count" >"$work/ids" || fail "jobs: a submit failed"
  [ "$(sort -u "$work/ids" | wc -l)" -eq "$count" ] || fail "jobs: $count submits, not $count ids"
  await_ended 600 1
  local summary
  summary=$(check_jobs_once 1 1) || fail "jobs: $summary"
  case "$summary" in
    *" 1 distinct sha256, ended on 2 replicas,"*) ;;
    *) fail "jobs: $summary (want one sha256, both replicas)" ;;
  esac
  say "PASS jobs: $summary, in $(since "$start") s"
}

# Waits until job $1 runs with progress (asking replica $2); prints the
# replica number running it.
await_running() {
  local deadline=$(($(date +%s) + 120))
  while :; do
    views "$2" "$1" >"$work/views.json" 2>/dev/null || true
    python3 - "$work/views.json" "$prefix" <<'PY' && return 0
import json, sys
try:
    (v,) = json.load(open(sys.argv[1]))
except ValueError:
    sys.exit(1)
if v.get("state") != "JOB_STATE_RUNNING" or int(v.get("progress", {}).get("done", 0)) == 0:
    sys.exit(1)
worker = v.get("worker", "")
for n in (1, 2):
    if worker.startswith(f"{sys.argv[2]}-r{n}/"):
        print(n)
        sys.exit(0)
sys.exit(1)
PY
    [ "$(date +%s)" -lt "$deadline" ] || fail "job $1 never ran"
    sleep 0.2
  done
}

# failover: an undisturbed long job for the reference, then the same spec
# with its replica killed mid-run.
scenario_failover() {
  local ref job victim survivor kill_at start ref_s
  start=$(now)
  ref=$(submit 1 long)
  echo "$ref" >"$work/ids"
  await_ended 900 1
  check_jobs_once 1 1 >/dev/null || fail "failover: the reference job did not succeed once"
  ref_s=$(python3 -c "import json,sys; v=json.load(open(sys.argv[1]))[0]; print(v['result']['sha256'])" \
    "$work/views.json")
  say "failover: reference run $(since "$start") s, sha256 $ref_s"

  job=$(submit 2 long)
  victim=$(await_running "$job" 2) || fail "failover: job $job never ran"
  survivor=$((3 - victim))
  kill_at=$(date +%s.%3N)
  podman kill --signal KILL "$prefix-r$victim" >/dev/null
  echo "$job" >"$work/ids"
  await_ended 900 "$survivor"
  python3 - "$work/views.json" "$ref_s" <<'PY' || fail "failover: see above"
import json, sys
(v,) = json.load(open(sys.argv[1]))
ok = (v.get("state") == "JOB_STATE_SUCCEEDED" and v.get("attempts") == 2
      and v["result"]["sha256"] == sys.argv[2])
print(f"state {v.get('state')}, attempts {v.get('attempts')}, "
      f"sha256 {'equal to' if v.get('result', {}).get('sha256') == sys.argv[2] else 'DIFFERENT from'} the reference's")
sys.exit(0 if ok else 1)
PY
  # The killed replica's job restarted on the survivor: its start line's time.
  local restarted
  restarted=$(podman logs "$prefix-r$survivor" 2>&1 | grep "job=$job event=start" | tail -1 | cut -d' ' -f1)
  say "PASS failover: killed $prefix-r$victim; $prefix-r$survivor started attempt 2 after" \
    "$(python3 -c "import datetime,sys; t=datetime.datetime.fromisoformat(sys.argv[1]).replace(tzinfo=datetime.timezone.utc).timestamp(); print(f'{t - float(sys.argv[2]):.1f}')" "$restarted" "$kill_at") s (lease 4 s)"
  podman logs "$prefix-r$victim" >"$work/logs/killed-r$victim.log" 2>&1 || true
  podman rm -f "$prefix-r$victim" >/dev/null
  "$compose" start-replica "$victim" || fail "failover: restarting $prefix-r$victim"
}

# rolling: SIGTERM and a fresh container for each replica in turn, jobs running.
scenario_rolling() {
  local i start watched
  : >"$work/ids"
  for i in $(seq 8); do submit $((i % 2 + 1)) medium >>"$work/ids"; done
  watched=$(head -1 "$work/ids")
  await_running "$watched" 1 >/dev/null || fail "rolling: job $watched never ran"
  podman exec "$prefix-cli" nimbus --server "$(server 1)" watch "$watched" \
    >"$work/watch.out" 2>&1 &
  watcher=$!
  start=$(now)
  for i in 1 2; do
    "$compose" stop-replica "$i"
    "$compose" start-replica "$i" || fail "rolling: restarting $prefix-r$i"
  done
  local took
  took=$(since "$start")
  await_ended 900 2
  local summary
  summary=$(check_jobs_once any any) || fail "rolling: $summary"
  wait "$watcher" || fail "rolling: the watcher on $prefix-r1 ended with $? ($(tail -2 "$work/watch.out"))"
  watcher=
  say "PASS rolling: both replicas restarted in $took s; $summary; the watcher followed" \
    "$watched to its end ($(tail -1 "$work/watch.out"))"
}

# postgres: the database container stopped and started while jobs run.
scenario_postgres() {
  local i deadline stopped_at downtime_s recovered
  : >"$work/ids"
  for i in $(seq 6); do submit $((i % 2 + 1)) medium >>"$work/ids"; done
  await_running "$(head -1 "$work/ids")" 1 >/dev/null || fail "postgres: no job ran"
  stopped_at=$(now)
  podman stop -t 20 "$prefix-pg" >/dev/null
  deadline=$(($(date +%s) + 30))
  until [ "$(health 1)" = NOT_SERVING ] && [ "$(health 2)" = NOT_SERVING ]; do
    [ "$(date +%s)" -lt "$deadline" ] || fail "postgres: replicas still $(health 1)/$(health 2)"
    sleep 0.2
  done
  local not_serving_after
  not_serving_after=$(since "$stopped_at")
  # A submit while the store is down is refused, not lost.
  if submit 1 small >/dev/null 2>"$work/refused.txt"; then fail "postgres: a submit succeeded with no store"; fi
  sleep 5
  podman start "$prefix-pg" >/dev/null
  downtime_s=$(since "$stopped_at")
  recovered=$(now)
  deadline=$(($(date +%s) + 60))
  until [ "$(health 1)" = SERVING ] && [ "$(health 2)" = SERVING ]; do
    [ "$(date +%s)" -lt "$deadline" ] || fail "postgres: replicas did not recover"
    sleep 0.2
  done
  say "postgres: both NOT_SERVING $not_serving_after s after the stop; the store down" \
    "$downtime_s s; both SERVING $(since "$recovered") s after its start; a submit meanwhile:" \
    "$(tail -1 "$work/refused.txt")"
  await_ended 900 1
  local summary
  summary=$(check_jobs_once any any) || fail "postgres: $summary"
  say "PASS postgres: $summary"
}

# disk-full: the results volume filled by a file; a job's write fails.
scenario_disk_full() {
  local job
  podman exec "$prefix-r1" sh -c 'dd if=/dev/zero of=/results/filler bs=1M 2>/dev/null; sync' || true
  job=$(submit 2 medium)
  echo "$job" >"$work/ids"
  await_ended 600 1
  python3 - "$work/views.json" <<'PY' || fail "disk-full: see above"
import json, sys
(v,) = json.load(open(sys.argv[1]))
code = v.get("status", {}).get("code")
print(f"state {v.get('state')}, status code {code}, error: {v.get('error', '')[:120]}")
sys.exit(0 if v.get("state") == "JOB_STATE_FAILED" and code == 8 else 1)
PY
  [ "$(health 1)" = SERVING ] && [ "$(health 2)" = SERVING ] ||
    fail "disk-full: replicas not SERVING with the volume full"
  podman exec "$prefix-r1" rm -f /results/filler
  job=$(submit 1 small)
  echo "$job" >"$work/ids"
  await_ended 300 2
  check_jobs_once 1 1 >/dev/null || fail "disk-full: the job after freeing space did not succeed"
  say "PASS disk-full: RESOURCE_EXHAUSTED (code 8) with the volume full, replicas SERVING," \
    "the next job succeeded once space was freed"
}

for s in $scenarios; do
  "scenario_${s//-/_}" $([ "$s" = jobs ] && echo "$jobs_count")
done
say "PASSED ($scenarios)"

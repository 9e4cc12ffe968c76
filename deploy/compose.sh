#!/usr/bin/env bash
# Nimbus as a service on one machine, in containers: a PostgreSQL container
# and two nimbusd replicas on it, sharing one results volume. Host network,
# loopback addresses only. Images from deploy/build_image.sh.
#
#   deploy/compose.sh up | down | status
#   deploy/compose.sh stop-replica N | start-replica N   (N = 1 or 2)
#   deploy/compose.sh logs NAME                           (pg, r1, r2)
#
# Environment (the defaults suit a person trying Nimbus):
#   NIMBUS_PREFIX          names of containers and volumes   (nimbus)
#   NIMBUS_PORT_BASE       replica N listens on BASE+N-1     (50151)
#   NIMBUS_PG_PORT         PostgreSQL's port                 (55432)
#   NIMBUS_DB_PASSWORD     the nimbus role's password        (nimbus-dev)
#   NIMBUS_RESULTS_TMPFS_MB  results on a tmpfs of that size instead of disk
#   NIMBUS_REPLICA_ARGS    further nimbusd flags (e.g. "--lease-ms 5000")
#   NIMBUS_LOG_DIR         keep each container's log there when it is removed
# Then: nimbus --server 127.0.0.1:50151 submit examples/sierpinski_tetrahedron.json
set -euo pipefail
# shellcheck source=podman/env.sh
source "$(dirname "$0")/podman/env.sh"

prefix=${NIMBUS_PREFIX:-nimbus}
port_base=${NIMBUS_PORT_BASE:-50151}
pg_port=${NIMBUS_PG_PORT:-55432}
db_password=${NIMBUS_DB_PASSWORD:-nimbus-dev}
store_url="postgresql://nimbus:$db_password@127.0.0.1:$pg_port/nimbus"
health_service=nimbus.v1.NimbusService
log() { echo "compose: $*" >&2; }

replica_port() { echo $((port_base + $1 - 1)); }
now_ms() { date +%s%3N; }

# Waits up to $2 seconds for `podman healthcheck run $1` to pass.
await_healthy() {
  local deadline=$(($(date +%s) + $2))
  until podman healthcheck run "$1" >/dev/null 2>&1; do
    [ "$(date +%s)" -lt "$deadline" ] || { log "$1 not healthy after $2 s"; return 1; }
    sleep 0.2
  done
}

# The results volume: a podman volume, or with NIMBUS_RESULTS_TMPFS_MB a
# tmpfs of that size mounted on the host (podman's local volume driver takes
# no size here) and bind-mounted into the replicas.
tmpfs_dir=/run/nimbus-deploy/$prefix-results
results_mount() {
  if [ -n "${NIMBUS_RESULTS_TMPFS_MB:-}" ]; then echo "$tmpfs_dir"; else echo "$prefix-results"; fi
}

volumes() {
  podman volume exists "$prefix-pgdata" || podman volume create "$prefix-pgdata" >/dev/null
  if [ -n "${NIMBUS_RESULTS_TMPFS_MB:-}" ]; then
    if ! mountpoint -q "$tmpfs_dir"; then
      mkdir -p "$tmpfs_dir"
      mount -t tmpfs -o "size=${NIMBUS_RESULTS_TMPFS_MB}m,uid=10001,gid=10001,mode=0750" \
        tmpfs "$tmpfs_dir"
    fi
  else
    podman volume exists "$prefix-results" || podman volume create "$prefix-results" >/dev/null
  fi
}

start_postgres() {
  # SIGINT: PostgreSQL's fast shutdown (SIGTERM would wait for every client).
  podman run -d --name "$prefix-pg" --network host --read-only --stop-signal INT \
    --tmpfs /tmp:rw,size=16m \
    -v "$prefix-pgdata:/var/lib/postgresql/data" \
    -e "NIMBUS_DB_PASSWORD=$db_password" -e "PGPORT=$pg_port" \
    --health-cmd "/usr/lib/postgresql/15/bin/pg_isready -q -h 127.0.0.1 -p $pg_port" \
    --health-interval disable \
    "$NIMBUS_PG_IMAGE" >/dev/null
  await_healthy "$prefix-pg" 60
}

start_replica() {
  local n=$1 port
  port=$(replica_port "$n")
  podman volume exists "$prefix-data$n" || podman volume create "$prefix-data$n" >/dev/null
  # shellcheck disable=SC2086  # NIMBUS_REPLICA_ARGS is a list of flags
  podman run -d --name "$prefix-r$n" --network host --read-only \
    --tmpfs /tmp:rw,size=256m --stop-timeout 30 \
    -v "$prefix-data$n:/var/lib/nimbus" -v "$(results_mount):/results" \
    -e "NIMBUS_STORE_URL=$store_url" \
    --health-cmd "nimbus --server 127.0.0.1:$port health --service $health_service" \
    --health-interval disable \
    "$NIMBUS_IMAGE" --listen "127.0.0.1:$port" --data-dir /var/lib/nimbus \
    --results-dir /results --replica-id "$prefix-r$n" ${NIMBUS_REPLICA_ARGS:-} >/dev/null
  await_healthy "$prefix-r$n" 60
}

# SIGTERM (podman stop): nimbusd hands its running jobs back and drains.
# With NIMBUS_LOG_DIR set, the container's log is kept there first.
stop_replica() {
  podman stop -t 30 "$prefix-r$1" >/dev/null 2>&1 || true
  save_log "r$1"
  podman rm -f "$prefix-r$1" >/dev/null 2>&1 || true
}

up() {
  local why start
  why=$(podman_unusable)
  [ -z "$why" ] || { log "cannot run: $why"; exit 1; }
  for image in "$NIMBUS_IMAGE" "$NIMBUS_PG_IMAGE"; do
    podman image exists "$image" || { log "no image $image: run deploy/build_image.sh"; exit 1; }
  done
  start=$(now_ms)
  volumes
  start_postgres
  start_replica 1
  start_replica 2
  log "up in $(($(now_ms) - start)) ms: replicas on 127.0.0.1:$(replica_port 1) and" \
    "127.0.0.1:$(replica_port 2), PostgreSQL on 127.0.0.1:$pg_port"
}

save_log() {
  [ -n "${NIMBUS_LOG_DIR:-}" ] || return 0
  podman logs "$prefix-$1" >>"$NIMBUS_LOG_DIR/$prefix-$1.log" 2>&1 || true
}

down() {
  local name
  for name in r1 r2 pg; do
    save_log "$name"
    podman rm -f -t 10 "$prefix-$name" >/dev/null 2>&1 || true
  done
  for name in data1 data2 results pgdata; do
    podman volume rm -f "$prefix-$name" >/dev/null 2>&1 || true
  done
  if mountpoint -q "$tmpfs_dir"; then umount "$tmpfs_dir"; fi
  rmdir "$tmpfs_dir" 2>/dev/null || true
}

status() {
  local name state health
  for name in pg r1 r2; do
    state=$(podman inspect -f '{{.State.Status}}' "$prefix-$name" 2>/dev/null || echo absent)
    health=-
    if [ "$state" = running ]; then
      health=$(podman healthcheck run "$prefix-$name" >/dev/null 2>&1 && echo healthy || echo unhealthy)
    fi
    printf '%-22s %-10s %s\n' "$prefix-$name" "$state" "$health"
  done
}

case "${1:-}" in
  up) up ;;
  down) down ;;
  status) status ;;
  stop-replica) stop_replica "$2" ;;
  start-replica) start_replica "$2" ;;
  logs) podman logs "$prefix-$2" ;;
  *) usage "$0"; exit 2 ;;
esac

#!/usr/bin/env bash
# Builds the nimbusd image with podman and smoke-tests it: the server starts
# as its non-root user, answers the CLI, and runs a tiny job to the end.
# Where podman cannot run (not installed, no user namespaces, no network to
# pull the Debian base image) it prints why and exits 0 as SKIPPED.
#   deploy/smoke_test.sh            (from anywhere in the repository)
set -euo pipefail
cd "$(dirname "$0")/.."
skip() { echo "deploy/smoke_test.sh: SKIPPED: $*"; exit 0; }

command -v podman >/dev/null 2>&1 || skip "podman is not installed (apt-get install podman)"
podman info >/dev/null 2>&1 || skip "podman cannot run here: $(podman info 2>&1 | tail -1)"
podman image exists docker.io/library/debian:bookworm ||
  podman pull -q docker.io/library/debian:bookworm >/dev/null 2>&1 ||
  skip "cannot pull docker.io/library/debian:bookworm (offline?)"

image=localhost/nimbusd:smoke
podman build -q -f deploy/Containerfile -t "$image" . >/dev/null
name=nimbusd-smoke-$$
trap 'podman rm -f "$name" >/dev/null 2>&1 || true' EXIT
podman run -d --name "$name" "$image" >/dev/null

# The server runs as the image's unprivileged user.
user=$(podman exec "$name" id -u)
[ "$user" = 10001 ] || { echo "FAIL: nimbusd runs as uid $user, not 10001"; exit 1; }
for _ in $(seq 50); do
  podman exec "$name" nimbus --server 127.0.0.1:50051 jobs >/dev/null 2>&1 && break
  sleep 0.2
done
podman exec "$name" nimbus --server 127.0.0.1:50051 jobs >/dev/null

# A tiny chaos-game job through submit, watch and fetch.
podman cp examples/sierpinski_tetrahedron.json "$name":/tmp/spec.json
podman exec "$name" sh -c "sed -e 's/\\[256\\]/[16]/' -e 's/200000000/20000/' \
  /tmp/spec.json > /tmp/tiny.json"
id=$(podman exec "$name" nimbus --server 127.0.0.1:50051 submit /tmp/tiny.json)
podman exec "$name" nimbus --server 127.0.0.1:50051 watch "$id" >/dev/null
podman exec "$name" nimbus --server 127.0.0.1:50051 fetch "$id" -o /tmp/out.vdb
podman exec "$name" test -s /tmp/out.vdb
echo "deploy/smoke_test.sh: PASSED ($image, job $id)"

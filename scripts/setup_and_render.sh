#!/usr/bin/env bash
# The main job on a fresh machine: install, build, start nimbusd, render an
# example through the service and write a .vdb.
#   scripts/setup_and_render.sh [SPEC] [OUT.vdb]
set -euo pipefail
cd "$(dirname "$0")/.."
SPEC=${1:-examples/sierpinski_tetrahedron.json}
OUT=${2:-out/$(basename "${SPEC%.*}").vdb}
scripts/install_deps.sh
# The programs and the OpenVDB module they load; (linking the server also
# builds the PostgreSQL module). scripts/test.sh builds the rest.
scripts/build.sh nimbusd nimbus nimbus_vdb
mkdir -p "$(dirname "$OUT")" out/previews
PORT=${NIMBUS_PORT:-50051}
build/bin/nimbusd --listen "127.0.0.1:$PORT" --data-dir out/nimbus-data &
DAEMON=$!
trap 'kill $DAEMON 2>/dev/null; wait $DAEMON 2>/dev/null || true' EXIT
build/bin/nimbus --server "127.0.0.1:$PORT" render "$SPEC" -o "$OUT" --previews out/previews
echo "done: $OUT"

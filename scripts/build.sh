#!/usr/bin/env bash
# Configures and builds the release preset into build/ (binaries in build/bin).
#   scripts/build.sh            everything: programs, modules, tests, benchmarks
#   scripts/build.sh TARGET...  only those targets and what they need
set -euo pipefail
cd "$(dirname "$0")/.."
cmake --preset release >/dev/null
targets=()
for t in "$@"; do targets+=(--target "$t"); done
cmake --build --preset release -j "$(nproc)" "${targets[@]}"

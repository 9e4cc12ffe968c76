#!/usr/bin/env bash
# Installs the Debian packages Nimbus builds and runs with. Skips apt when
# everything is already present, so repeated runs are fast.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libopenvdb-dev libboost-iostreams-dev libtbb-dev libblosc-dev liblz4-dev
  libspdlog-dev libcli11-dev libsqlite3-dev libssl-dev libabsl-dev
  # The shared job store of several replicas (libpqxx), and the throwaway
  # server its tests start (initdb, pg_ctl).
  libpqxx-dev postgresql
  # The deploy/ manifest check (tests/deploy/validate_deploy.py), and the
  # container image and its test (deploy/build_image.sh, deploy/test_containers.sh).
  python3-yaml podman runc debootstrap
  libgtest-dev libgmock-dev libbenchmark-dev
  # Fractal fields: 16-bit PNG height maps; pictures (PNG, OpenEXR); libnoise
  # only for the benchmark's comparison (bench/fractal_field_bench.cc).
  libpng-dev libnoise-dev libopenexr-dev
  # SLEEF: vector sin, cos, atan2, exp, pow ... for the flame kernels.
  libsleef-dev
  # flam3-render: the flam3 agreement test and bench/compare_flam3.sh.
  flam3-utils
  # expat: reading flam3 genomes (nimbus import-flame).
  libexpat1-dev
  python3-openvdb libopenvdb-tools
  # The Python client (python/) and the Blender add-on test (dcc/blender/):
  # Debian's grpc and protobuf for /usr/bin/python3, and Blender 3.4, whose
  # Python is the system one.
  python3-grpcio python3-protobuf blender
  # The libFuzzer targets (tests/fuzz, scripts/fuzz.sh) build with clang.
  clang libclang-rt-14-dev ccache
  # The HTTP port (nimbusd --http): the JSON API, the console and /metrics;
  # promtool and a real Prometheus for its tests, chromium (driven by
  # playwright-core from npm, scripts/console_deps.sh) for the console's.
  libcpp-httplib-dev prometheus-cpp-dev prometheus chromium
)

# playwright-core for the console's browser test, pinned by its lock file.
install_npm() {
  local dir
  dir="$(cd "$(dirname "$0")/.." && pwd)/tests/browser"
  if command -v npm >/dev/null && [ ! -d "$dir/node_modules/playwright-core" ]; then
    (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error)
  fi
}

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#PACKAGES[@]} packages present"
  install_npm
  exit 0
fi
echo "install_deps: installing ${missing[*]}"
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
install_npm

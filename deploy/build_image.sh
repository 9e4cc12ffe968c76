#!/usr/bin/env bash
# Builds the nimbusd image from nothing but Debian's package archive:
#   1. a minimal bookworm root file system from `debootstrap --variant=minbase`,
#      kept as a tarball under $NIMBUS_DEPLOY_CACHE and named by the digest of
#      its package list (suite, mirror, architecture and the packages
#      debootstrap resolves), so it is made once and reused;
#   2. `podman import` of that tarball as localhost/nimbus-base:bookworm-DIGEST;
#   3. deploy/Containerfile built on it (build argument BASE), and a
#      PostgreSQL image (deploy/postgres/Containerfile) on the same base.
# Prints the image's size and fails when it exceeds the budget.
#
#   deploy/build_image.sh                 (as root, from anywhere in the repo)
# Environment:
#   NIMBUS_IMAGE            nimbusd image name      (localhost/nimbusd:dev)
#   NIMBUS_PG_IMAGE         PostgreSQL image name   (localhost/nimbus-postgres:dev)
#   NIMBUS_DEPLOY_CACHE     base tarball cache      (/var/cache/nimbus-deploy)
#   NIMBUS_DEBIAN_MIRROR    Debian mirror           (http://deb.debian.org/debian)
#   NIMBUS_IMAGE_BUDGET_MB  size budget of the nimbusd image (250)
#   NIMBUS_PREBUILT         a host build tree (e.g. build) whose bin/ and
#                           lib/nimbus/ go into the image instead of compiling
#                           in the build stage (same Debian release only);
#                           unset: compile, through ccache in a cache mount
#   NIMBUS_BUILD_PG=0       skip the PostgreSQL image
#   NIMBUS_NO_CACHE=1       ignore podman's layer cache (a build from scratch
#                           but for the base tarball and the ccache mount)
set -euo pipefail
# shellcheck source=podman/env.sh
source "$(dirname "$0")/podman/env.sh"
cd "$repo_dir"

mirror=${NIMBUS_DEBIAN_MIRROR:-http://deb.debian.org/debian}
budget_mb=${NIMBUS_IMAGE_BUDGET_MB:-250}
suite=bookworm
arch=$(dpkg --print-architecture)
log() { echo "build_image: $*" >&2; }

why=$(podman_unusable)
[ -z "$why" ] || { log "cannot build: $why"; exit 1; }
command -v debootstrap >/dev/null || { log "debootstrap is not installed"; exit 1; }

# The package list debootstrap resolves for a minbase root file system.
package_list() {
  local probe
  probe=$(mktemp -d)
  debootstrap --variant=minbase --arch="$arch" --print-debs "$suite" "$probe" "$mirror" |
    tr ' ' '\n' | sed '/^$/d' | sort
  rm -rf "$probe"
}

# Makes (or reuses) the base tarball and imports it; prints the image name.
base_image() {
  local list digest tarball image root
  list=$(package_list)
  digest=$(printf '%s\n' "$suite" "$mirror" "$arch" "$list" | sha256sum | cut -c1-16)
  tarball=$NIMBUS_DEPLOY_CACHE/bookworm-minbase-$digest.tar
  image=localhost/nimbus-base:bookworm-$digest
  if [ ! -s "$tarball" ]; then
    log "debootstrap $suite (minbase, $(wc -l <<<"$list") packages) -> $tarball"
    mkdir -p "$NIMBUS_DEPLOY_CACHE"
    root=$(mktemp -d "$NIMBUS_DEPLOY_CACHE/root.XXXXXX")
    trap 'rm -rf "$root"' EXIT
    debootstrap --variant=minbase --arch="$arch" "$suite" "$root" "$mirror" >&2
    # Updates and security fixes too, as in Debian's own images.
    cat >"$root/etc/apt/sources.list" <<SOURCES
deb $mirror $suite main
deb $mirror $suite-updates main
deb http://deb.debian.org/debian-security $suite-security main
SOURCES
    rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/*
    tar --numeric-owner -C "$root" -cf "$tarball.tmp" .
    mv "$tarball.tmp" "$tarball"
    rm -rf "$root"
    trap - EXIT
  else
    log "base tarball cached: $tarball"
  fi
  if ! podman image exists "$image"; then
    podman import -q "$tarball" "$image" >/dev/null
  fi
  echo "$image"
}

base=$(base_image)
log "base image $base"

cache_args=(--layers)
[ "${NIMBUS_NO_CACHE:-0}" = 1 ] && cache_args=(--no-cache)
prebuilt_args=()
if [ -n "${NIMBUS_PREBUILT:-}" ]; then
  prebuilt=$(cd "$NIMBUS_PREBUILT" && pwd)
  [ -x "$prebuilt/bin/nimbusd" ] || { log "no $prebuilt/bin/nimbusd"; exit 1; }
  prebuilt_args=(--volume "$prebuilt:/prebuilt:ro")
  # The layer cache knows nothing of the mounted programs: rebuild the stage.
  prebuilt_args+=(--build-arg "PREBUILT_ID=$(cat "$prebuilt/bin/nimbusd" \
    "$prebuilt/bin/nimbus" "$prebuilt"/lib/nimbus/*.so | sha256sum | cut -c1-16)")
fi
start=$(date +%s)
podman build --network host "${cache_args[@]}" --build-arg "BASE=$base" "${prebuilt_args[@]}" \
  -f deploy/Containerfile -t "$NIMBUS_IMAGE" .
log "nimbusd image $NIMBUS_IMAGE built in $(( $(date +%s) - start )) s"

if [ "${NIMBUS_BUILD_PG:-1}" != 0 ]; then
  podman build --network host "${cache_args[@]}" --build-arg "BASE=$base" \
    -f deploy/postgres/Containerfile -t "$NIMBUS_PG_IMAGE" deploy/postgres
  log "PostgreSQL image $NIMBUS_PG_IMAGE: $(podman image inspect -f '{{.Size}}' "$NIMBUS_PG_IMAGE" |
    awk '{printf "%.0f MB", $1/1e6}')"
fi

size=$(podman image inspect -f '{{.Size}}' "$NIMBUS_IMAGE")
size_mb=$(( (size + 999999) / 1000000 ))
echo "build_image: $NIMBUS_IMAGE is $size_mb MB (budget $budget_mb MB)"
[ "$size_mb" -le "$budget_mb" ] || { log "FAIL: image exceeds its budget"; exit 1; }

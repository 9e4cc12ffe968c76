# Sourced by the deploy/ scripts: podman settings and names shared by them.
# shellcheck shell=bash
deploy_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
repo_dir=$(dirname "$deploy_dir")
export CONTAINERS_CONF=${CONTAINERS_CONF:-$deploy_dir/podman/containers.conf}
# The image built by deploy/build_image.sh and run by compose.sh.
NIMBUS_IMAGE=${NIMBUS_IMAGE:-localhost/nimbusd:dev}
NIMBUS_PG_IMAGE=${NIMBUS_PG_IMAGE:-localhost/nimbus-postgres:dev}
# Where the debootstrap base tarballs are kept between runs.
NIMBUS_DEPLOY_CACHE=${NIMBUS_DEPLOY_CACHE:-/var/cache/nimbus-deploy}

# Why podman cannot run containers here, or nothing when it can.
podman_unusable() {
  command -v podman >/dev/null 2>&1 || { echo "podman is not installed"; return; }
  [ "$(id -u)" -eq 0 ] || { echo "the deploy scripts use rootful podman (run as root)"; return; }
  local out
  out=$(podman info 2>&1) || { echo "podman info failed: $(tail -1 <<<"$out")"; return; }
}

# Prints the comment block at the top of script $1 (its usage).
usage() { awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$1"; }

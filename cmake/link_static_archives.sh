#!/bin/sh
# A linker launcher (CMake's CXX_LINKER_LAUNCHER) for the shipped programs:
# runs the link command it is given with gRPC, Protobuf, Abseil, RE2,
# c-ares, upb and OpenSSL taken from Debian's static archives instead of
# their ~60 shared objects.
#
# Why: every `nimbus` command is a fresh process, and the dynamic loader's
# symbol lookups across those objects cost about 17 ms of each start, half
# of `nimbus --help`. Only executables can take the archives: Abseil's are
# built for executables (initial-exec TLS), so the shared modules
# (libnimbus_vdb.so, libnimbus_postgres.so) keep the shared libraries.
#
# All or nothing: if any of these libraries has no archive beside it, the
# command runs unchanged, since a static Abseil beside a shared gRPC (which
# loads the shared Abseil) would put two copies behind the same calls. The
# archives go in one link group, so their order does not matter.
set -eu

# Sets $archive to the archive that replaces link argument $1 (a path that
# may not exist: the first pass checks), or to nothing when $1 is not one of
# these libraries. A variable, not output: a command substitution forks a
# subshell per argument, two passes over ~90 arguments took about a second.
archive_for() {
  archive=
  case "$1" in
    */libabsl_*.so* | */libgrpc*.so* | */libgpr.so* | */libupb.so* | \
    */libaddress_sorting.so* | */libcares.so* | */libprotobuf.so* | \
    */libre2.so* | */libssl.so* | */libcrypto.so*)
      archive="${1%%.so*}.a"
      ;;
    -lre2)
      archive=/nonexistent/libre2.a  # none found: the first pass sees it missing
      for dir in /usr/lib/x86_64-linux-gnu /usr/lib /usr/local/lib; do
        if [ -f "$dir/libre2.a" ]; then
          archive="$dir/libre2.a"
          return
        fi
      done
      ;;
  esac
}

for arg in "$@"; do
  archive_for "$arg"
  if [ -n "$archive" ] && [ ! -f "$archive" ]; then
    exec "$@"  # one is missing: link against the shared libraries
  fi
done

first=1
grouped=
for arg in "$@"; do
  if [ "$first" = 1 ]; then set --; first=0; fi
  archive_for "$arg"
  if [ -n "$archive" ]; then
    [ -n "$grouped" ] || set -- "$@" -Wl,--start-group
    grouped=1
    arg="$archive"
  fi
  set -- "$@" "$arg"
done
[ -z "$grouped" ] || set -- "$@" -Wl,--end-group
exec "$@"

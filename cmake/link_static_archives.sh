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
# A library is swapped only where its archive sits beside it; the archives
# go in one link group, so their order does not matter.
set -eu

first=1
for arg in "$@"; do
  if [ "$first" = 1 ]; then set --; first=0; fi
  case "$arg" in
    */libabsl_*.so* | */libgrpc*.so* | */libgpr.so* | */libupb.so* | \
    */libaddress_sorting.so* | */libcares.so* | */libprotobuf.so* | \
    */libre2.so* | */libssl.so* | */libcrypto.so*)
      archive="${arg%%.so*}.a"
      if [ -f "$archive" ]; then
        [ "${grouped:-}" ] || set -- "$@" -Wl,--start-group
        grouped=1
        arg="$archive"
      fi
      ;;
    -lre2)
      for dir in /usr/lib/x86_64-linux-gnu /usr/lib /usr/local/lib; do
        if [ -f "$dir/libre2.a" ]; then
          [ "${grouped:-}" ] || set -- "$@" -Wl,--start-group
          grouped=1
          arg="$dir/libre2.a"
          break
        fi
      done
      ;;
  esac
  set -- "$@" "$arg"
done
[ -z "${grouped:-}" ] || set -- "$@" -Wl,--end-group
exec "$@"

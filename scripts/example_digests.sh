#!/usr/bin/env bash
# Renders examples with the programs in BIN_DIR, each in a fresh data dir
# (--no-cache), and prints the decoded-content digest of every file it
# wrote (build/bin/content_digest: voxels, topology, metadata and pixels
# read back through OpenVDB and libpng). Two builds that write the same
# content print the same lines, whatever their bytes.
#
#   scripts/example_digests.sh BIN_DIR OUT_DIR [EXAMPLE.json ...]
#     (default: every examples/*.json; DIGEST_TOOL overrides the digest
#      program, THREADS the engine threads, default 2)
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
bin="$(cd "$1" && pwd)"
out="$2"
shift 2
tool="${DIGEST_TOOL:-$here/build/bin/content_digest}"
threads="${THREADS:-2}"
examples=("$@")
[ ${#examples[@]} -gt 0 ] || examples=("$here"/examples/*.json)
mkdir -p "$out"
for spec in "${examples[@]}"; do
  name="$(basename "$spec" .json)"
  dir="$out/$name"
  rm -rf "$dir" "$out/data-$name"
  mkdir -p "$dir" "$out/data-$name"
  if [ "$name" = explore ]; then
    cmd=("$bin/nimbus" --data-dir "$out/data-$name" --threads "$threads" explore --no-cache
         "$spec" -o "$dir")
  else
    ext=vdb
    grep -q '"image_only": true' "$spec" && ext=png
    cmd=("$bin/nimbus" --data-dir "$out/data-$name" --threads "$threads" render --no-cache
         "$spec" -o "$dir/$name.$ext" --frames "$dir")
  fi
  if ! "${cmd[@]}" > "$out/$name.log" 2>&1; then
    echo "FAILED  $name (see $out/$name.log)"
    continue
  fi
  rm -rf "$out/data-$name"
  (cd "$out" && "$tool" "$name") | sed "s|^|$name  |" || echo "UNREADABLE  $name"
done

#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz, a clang build tree of its own)
# and runs each for SECONDS (default 30) on a scratch copy of its seed
# corpus, so runs never grow the repository. Prints executions and coverage
# per target; exits non-zero when any target finds a crash, leak, timeout
# or out-of-memory. See docs/fuzzing.md.
#   scripts/fuzz.sh [SECONDS]
# Environment: BUILD_DIR (default build-fuzz), FUZZ_TARGETS (default all),
# FUZZ_WORK (scratch dir, default a new temporary dir; kept on failure).
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH="${1:-30}"
BUILD_DIR="${BUILD_DIR:-build-fuzz}"
TARGETS="${FUZZ_TARGETS:-spec_fuzzer obj_fuzzer ply_fuzzer stl_fuzzer vdb_fuzzer}"
WORK="${FUZZ_WORK:-$(mktemp -d "${TMPDIR:-/tmp}/nimbus-fuzz.XXXXXX")}"

# -O1 and line tables only: ASan still reports file:line. It trims the build
# (the core compiled a second time) only a little: 6 min 59 s to 6 min 45 s
# on 2 cores, cold cache: little of its time goes to optimising.
# Only the named targets are built: the OpenVDB module, which only
# vdb_fuzzer links, is half of the tree's compile time (443 of 960 CPU s).
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_CXX_COMPILER=clang++ \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo -DNIMBUS_BUILD_FUZZERS=ON \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only -DNDEBUG" \
  -DNIMBUS_BUILD_TESTS=OFF -DNIMBUS_BUILD_BENCH=OFF >/dev/null
# shellcheck disable=SC2086 # one word per target
cmake --build "$BUILD_DIR" --target $TARGETS

# Per-target flags: the spec fuzzer gets the proto's names as a dictionary.
# OpenVDB's reader is not hardened (docs/fuzzing.md): vdb_fuzzer makes an
# allocation above 512 MiB a bad_alloc, as in the server's checker child, and
# OpenVDB's leaks on its error paths are not reported. Our own parsers get
# no such allowance.
flags_for() {
  case "$1" in
    spec_fuzzer) echo "-dict=tests/fuzz/spec.dict -max_len=8192" ;;
    vdb_fuzzer) echo "-max_len=65536 -rss_limit_mb=2048 -malloc_limit_mb=2048 -detect_leaks=0" ;;
    *) echo "-max_len=16384" ;;
  esac
}
asan_for() {
  case "$1" in
    vdb_fuzzer) echo "detect_leaks=0" ;;
    *) echo "${ASAN_OPTIONS:-}" ;;
  esac
}

failed=()
for t in $TARGETS; do
  mkdir -p "$WORK/$t/corpus" "$WORK/$t/artifacts"
  cp -r "tests/fuzz/corpus/$t/." "$WORK/$t/corpus/"
  log="$WORK/$t/fuzz.log"
  read -r -a flags <<<"$(flags_for "$t")"
  if ASAN_OPTIONS="$(asan_for "$t")" "$BUILD_DIR/bin/$t" "$WORK/$t/corpus" "${flags[@]}" \
      -max_total_time="$SECONDS_EACH" -timeout=30 -print_final_stats=1 \
      -artifact_prefix="$WORK/$t/artifacts/" >"$log" 2>&1; then
    status=ok
  else
    status=FAILED
    failed+=("$t")
  fi
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo "?")
  cov=$(grep -E '^#[0-9]+' "$log" | tail -1 | grep -oE 'cov: [0-9]+ ft: [0-9]+' ||
    echo "cov: ? ft: ?")
  printf '%-12s %-6s runs: %-10s %s\n' "$t" "$status" "$runs" "$cov"
  if [[ $status == FAILED ]]; then
    grep -E 'ERROR: |SUMMARY: |runtime error:|Test unit written' "$log" | head -5 | sed 's/^/    /'
  fi
done

if ((${#failed[@]})); then
  echo "fuzzing failed: ${failed[*]} (logs and crashing inputs in $WORK)" >&2
  exit 1
fi
[[ -n "${FUZZ_WORK:-}" ]] || rm -rf "$WORK"

#!/usr/bin/env bash
# shellcheck disable=SC2046,SC2013  # header values split into words on purpose
# Re-checks the faults of tests/faults/ (docs/testing.md, "Faults the suite
# is known to catch"): each patch is applied to a scratch git worktree of
# HEAD, its targets are built and every test it names must FAIL.
#
#   scripts/check_faults.sh [--list] [PATTERN]
#   scripts/check_faults.sh --check-patches BIN_DIR
#
# PATTERN (an extended regular expression) picks the patches whose file
# names match it. --list prints the patches and their headers, builds
# nothing. Before any patch, the named tests of the chosen patches run once
# on the unpatched scratch tree (the baseline): a test that fails there
# makes its fault count as not caught. One line per fault:
#   caught | MISSED: <tests that passed or skipped> | patch does not apply |
#   build failed | baseline fails: <tests> | unknown test: <names>
# with the seconds it took; the exit status is 1 if any fault is not caught.
#
# The scratch worktree and its build directory live in a temporary
# directory beside the repository (under ccache's base_dir, so the build
# reuses cached objects; CHECK_FAULTS_TMPDIR overrides the parent) and are
# removed on exit. The caller's tree is never written to. Patches are read
# from the caller's tests/faults/, so a patch not yet committed can be
# checked; the sources are HEAD's. CHECK_FAULTS_LOG_DIR=DIR keeps every
# test's output in DIR; CHECK_FAULTS_TEST_TIMEOUT (seconds, 600) bounds
# each test.
#
# --check-patches is the fast unit check (ctest label `faults`): every
# patch has its header and applies to this source tree (`git apply
# --check`), and every test it names is listed by one of its targets'
# gtest binaries in BIN_DIR.
#
# A patch is a `git diff` against main that begins with a header
# (git apply skips the lines before the first `diff --git`):
#   # fault: <what the change breaks>
#   # catches: <gtest names, space-separated; * matches as in --gtest_filter>
#   # targets: <cmake targets to build: the test binaries and what they run>
# e2e_tests, e2e_vdb_tests and http_tests start nimbusd and nimbus of the
# same build, so those two are built with them.
set -uo pipefail
# Header values are split into words on purpose, and a test name's * must
# reach gtest, not match files: no pathname expansion.
set -f

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FAULTS_DIR=$ROOT/tests/faults
TEST_TIMEOUT=${CHECK_FAULTS_TEST_TIMEOUT:-600}
LOG_DIR=${CHECK_FAULTS_LOG_DIR:-}

die() { echo "check_faults: $*" >&2; exit 2; }

# header PATCH KEY: the value of the `# KEY:` line of PATCH's header.
header() {
  sed -n "/^diff --git/q; s/^# $2:[[:space:]]*//p" "$1" | head -n 1
}

# gtest_binaries TARGETS...: the targets that are test executables.
gtest_binaries() {
  local t
  for t in "$@"; do [[ $t == *_tests ]] && echo "$t"; done
}

# with_servers TARGETS...: TARGETS, plus nimbusd and nimbus when a test
# binary among them starts the programs of its build.
with_servers() {
  local t extra=()
  for t in "$@"; do
    case $t in e2e_tests | e2e_vdb_tests | http_tests) extra=(nimbusd nimbus) ;; esac
  done
  printf '%s\n' "$@" "${extra[@]}" | awk 'NF && !seen[$0]++'
}

# list_tests BIN: the full names of BIN's tests (Suite.Name, params too).
list_tests() {
  "$1" --gtest_list_tests 2>/dev/null |
    awk '/^[^ ]/ {suite = $1} /^  / {print suite $1}'
}

# expand NAME LISTING: the tests of LISTING (a file) that NAME matches.
expand() {
  local name=$1 t
  while IFS= read -r t; do
    # shellcheck disable=SC2053  # NAME is a pattern on purpose
    [[ $t == $name ]] && echo "$t"
  done <"$2"
}

patches() {
  local p files
  set +f
  files=("$FAULTS_DIR"/*.patch)
  set -f
  for p in "${files[@]}"; do
    [[ -e $p ]] || continue
    [[ -z ${PATTERN:-} ]] || [[ $(basename "$p") =~ $PATTERN ]] || continue
    echo "$p"
  done
}

# check_header PATCH: complains (stdout) of a missing header line.
check_header() {
  local key
  for key in fault catches targets; do
    [[ -n $(header "$1" "$key") ]] || echo "$(basename "$1"): no '# $key:' line before the diff"
  done
  grep -q '^diff --git ' "$1" || echo "$(basename "$1"): no 'diff --git' in it"
}

check_patches() {
  local bin_dir=$1 p t name bad=0 listing
  [[ -d $bin_dir ]] || die "no directory $bin_dir"
  listing=$(mktemp -d) || die "mktemp failed"
  trap 'rm -rf "$listing"' EXIT
  local all
  all=$(patches)
  [[ -n $all ]] || { echo "no patches in $FAULTS_DIR"; exit 1; }
  for p in $all; do
    local problems
    problems=$(check_header "$p")
    if ! out=$(cd "$ROOT" && git apply --check "$p" 2>&1); then
      problems+=$'\n'"$(basename "$p"): does not apply to $ROOT: $out"
    fi
    local bins=()
    mapfile -t bins < <(gtest_binaries $(header "$p" targets))
    for t in $(header "$p" targets); do
      [[ -x $bin_dir/$t ]] || problems+=$'\n'"$(basename "$p"): target $t is not in $bin_dir"
    done
    for t in "${bins[@]}"; do
      [[ -s $listing/$t ]] || [[ ! -x $bin_dir/$t ]] || list_tests "$bin_dir/$t" >"$listing/$t"
    done
    for name in $(header "$p" catches); do
      local found=0
      for t in "${bins[@]}"; do
        [[ -s $listing/$t ]] && [[ -n $(expand "$name" "$listing/$t") ]] && found=1
      done
      ((found)) || problems+=$'\n'"$(basename "$p"): no test $name in $(header "$p" targets)"
    done
    problems=$(sed '/^$/d' <<<"$problems")
    if [[ -n $problems ]]; then
      echo "$problems"
      bad=1
    fi
  done
  ((bad)) && exit 1
  echo "$(wc -w <<<"$all") fault patches apply and name existing tests"
  exit 0
}

list_patches() {
  local p
  for p in $(patches); do
    echo "$(basename "$p" .patch): $(header "$p" fault)"
    echo "    catches: $(header "$p" catches)"
    echo "    targets: $(header "$p" targets)"
  done
  exit 0
}

cleanup() {
  if [[ -n ${SCRATCH:-} ]]; then
    git -C "$ROOT" worktree remove --force "$SCRATCH" >/dev/null 2>&1
  fi
  [[ -n ${TMP:-} ]] && rm -rf "$TMP"
  git -C "$ROOT" worktree prune >/dev/null 2>&1
}

# restore: the scratch tree back to HEAD (files a patch added removed; the
# ignored build directory kept).
restore() {
  git -C "$SCRATCH" checkout -q -- . && git -C "$SCRATCH" clean -fdq
}

# build TARGETS...: builds them in the scratch tree; the log in $TMP/build.log.
build() {
  cmake --build "$SCRATCH/build" --target "$@" >"$TMP/build.log" 2>&1
}

# run_tests PATCH LABEL: runs each named test of PATCH in a process of its own
# (as ctest does); prints "pass NAME", "fail NAME" or "skip NAME" (the
# test skipped itself, e.g. without PostgreSQL) per test, or "unknown NAME"
# for a name no binary lists. With CHECK_FAULTS_LOG_DIR set, each test's
# output is kept there as LABEL-TEST.log.
run_tests() {
  local p=$1 name t full found
  local bins=()
  mapfile -t bins < <(gtest_binaries $(header "$p" targets))
  for name in $(header "$p" catches); do
    found=0
    for t in "${bins[@]}"; do
      for full in $(expand "$name" "$TMP/list/$t"); do
        found=1
        if (cd "$SCRATCH/build/tests" &&
          timeout "$TEST_TIMEOUT" "$SCRATCH/build/bin/$t" --gtest_filter="$full" \
            >"$TMP/test.log" 2>&1) &&
          grep -q '^\[  PASSED  \] 1 test' "$TMP/test.log"; then
          echo "pass $full"
        elif grep -q '^\[  SKIPPED \] 1 test' "$TMP/test.log"; then
          echo "skip $full"
        else
          echo "fail $full"
        fi
        [[ -z ${LOG_DIR:-} ]] || cp "$TMP/test.log" "$LOG_DIR/$2-${full//\//_}.log"
      done
    done
    ((found)) || echo "unknown $name"
  done
}

main() {
  local list=0
  case ${1:-} in
    --check-patches) [[ $# -eq 2 ]] || die "usage: $0 --check-patches BIN_DIR"; check_patches "$2" ;;
    --list) list=1; shift ;;
    -h | --help) sed -n '3,/^set -uo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
  esac
  [[ $# -le 1 ]] || die "usage: $0 [--list] [PATTERN]"
  PATTERN=${1:-}
  ((list)) && list_patches
  local all
  all=$(patches)
  [[ -n $all ]] || die "no patch in $FAULTS_DIR matches '${PATTERN}'"

  if [[ -n $LOG_DIR ]]; then
    mkdir -p "$LOG_DIR" || die "cannot make $LOG_DIR"
    LOG_DIR=$(cd "$LOG_DIR" && pwd)
  fi
  local parent=${CHECK_FAULTS_TMPDIR:-$(dirname "$ROOT")}
  TMP=$(mktemp -d "$parent/.check-faults.XXXXXX") || die "cannot make a directory in $parent"
  trap cleanup EXIT
  trap 'exit 130' INT TERM
  SCRATCH=$TMP/src
  git -C "$ROOT" worktree add --detach "$SCRATCH" HEAD >/dev/null 2>&1 ||
    die "git worktree add $SCRATCH failed"
  mkdir -p "$TMP/list"
  echo "scratch tree $SCRATCH ($(git -C "$SCRATCH" rev-parse --short HEAD))"

  # Baseline: every named test passes with no fault in.
  local start=$SECONDS p targets=()
  mapfile -t targets < <(with_servers $(for p in $all; do header "$p" targets; done))
  (cd "$SCRATCH" && cmake --preset release >"$TMP/build.log" 2>&1) ||
    { cat "$TMP/build.log" >&2; die "cmake --preset release failed in the scratch tree"; }
  build "${targets[@]}" || { tail -n 30 "$TMP/build.log" >&2; die "the unpatched build failed"; }
  local t
  for t in $(gtest_binaries "${targets[@]}"); do
    list_tests "$SCRATCH/build/bin/$t" >"$TMP/list/$t"
  done
  local runs baseline_failed=()
  runs=$(for p in $all; do run_tests "$p" baseline; done | sort -u)
  mapfile -t baseline_failed < <(awk '$1 == "fail" || $1 == "skip" {print $2}' <<<"$runs")
  if ((${#baseline_failed[@]})); then
    echo "baseline: these tests fail or skip with no fault in: ${baseline_failed[*]}"
  else
    echo "baseline: every named test passes with no fault in ($((SECONDS - start)) s)"
  fi

  local missed=0 name result
  for p in $all; do
    start=$SECONDS
    name=$(basename "$p" .patch)
    restore
    if ! git -C "$SCRATCH" apply "$p" 2>"$TMP/apply.log"; then
      result="patch does not apply"
    else
      mapfile -t targets < <(with_servers $(header "$p" targets))
      if ! build "${targets[@]}"; then
        result="build failed"
        tail -n 20 "$TMP/build.log" | sed "s/^/  $name: /" >&2
      else
        local passed unknown still
        runs=$(run_tests "$p" "$name")
        passed=$(awk '$1 == "pass" || $1 == "skip" {print $2}' <<<"$runs" | xargs)
        unknown=$(awk '$1 == "unknown" {print $2}' <<<"$runs" | xargs)
        still=$(for t in $(awk '{print $2}' <<<"$runs"); do
          printf '%s\n' "${baseline_failed[@]}" | grep -qxF -- "$t" && echo "$t"
        done | xargs)
        if [[ -n $unknown ]]; then
          result="unknown test: $unknown"
        elif [[ -n $still ]]; then
          result="baseline fails: $still"
        elif [[ -n $passed ]]; then
          result="MISSED: $passed"
        else
          result="caught"
        fi
      fi
    fi
    restore
    [[ $result == caught ]] || missed=$((missed + 1))
    printf '%-40s %s (%d s)\n' "$name" "$result" $((SECONDS - start))
  done
  echo "$(wc -w <<<"$all") faults, $missed not caught"
  ((missed == 0))
}

main "$@"

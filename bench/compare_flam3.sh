#!/usr/bin/env bash
# Side-by-side timing of Nimbus and flam3-render (Debian's flam3-utils) on
# the same 2D genomes at 1024x1024 with the same number of samples:
#   - a Sierpinski triangle (three affine maps, no colour: Nimbus's fast path);
#   - a flame with six variations (swirl, spherical, julia, sinusoidal,
#     bubble, polar), colour by map with flam3's default colour speed.
# Both are whole processes timed from start to exit (Nimbus with its
# embedded server, so spec conversion, the walk and the VDB write count).
# Prints wall seconds, samples per second, peak memory and the ratio, and
# for Nimbus also the job's own time (start to end as the server records it:
# the walk, the finishing step and the write, without process start-up,
# which loads ~100 shared libraries, libopenvdb alone some 40-70 ms).
#
# Usage: bench/compare_flam3.sh [NIMBUS_BINARY]   (default build/bin/nimbus)
# Environment: THREADS (Nimbus threads per job, default 2), FLAM3_THREADS
# (flam3-render's nthreads, default 0 = all cores), REPEAT (runs per row,
# default 1; the fastest is kept).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
nimbus="${1:-$here/../build/bin/nimbus}"
threads="${THREADS:-2}"
flam3_threads="${FLAM3_THREADS:-0}"
repeat="${REPEAT:-1}"

if ! command -v flam3-render >/dev/null; then
  echo "compare_flam3: flam3-render is missing; install it with" >&2
  echo "  sudo apt-get install flam3-utils" >&2
  exit 2
fi
if [ ! -x "$nimbus" ]; then
  echo "compare_flam3: no Nimbus binary at $nimbus (build the 'nimbus' target)" >&2
  exit 2
fi

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# A grey ramp: the palette does not change the work, only the picture.
palette() {
  for i in $(seq 0 255); do echo "  <color index=\"$i\" rgb=\"$i $i $i\"/>"; done
}

# flam3 samples = quality * width * height at oversample 1, so quality 200
# is 200 * 1024^2 = 209715200 samples, the Nimbus spec's iteration count.
# Coefficients are flam3's "a d b e c f": x' = a x + b y + c, y' = d x + e y + f,
# the first two rows of the Nimbus matrices.
cat >"$work/sierpinski_2d.flam3" <<EOF
<flame name="sierpinski_2d" size="1024 1024" center="0.5 0.5" scale="853.333333" quality="200"
       oversample="1" filter="0" supersample="1" passes="1" temporal_samples="1"
       estimator_radius="0" gamma="1" brightness="4" vibrancy="1">
  <xform weight="1" color="0" linear="1" coefs="0.5 0 0 0.5 0 0"/>
  <xform weight="1" color="0.5" linear="1" coefs="0.5 0 0 0.5 0.5 0"/>
  <xform weight="1" color="1" linear="1" coefs="0.5 0 0 0.5 0.25 0.5"/>
$(palette)
</flame>
EOF
cat >"$work/flame6_2d.flam3" <<EOF
<flame name="flame6_2d" size="1024 1024" center="0 0" scale="256" quality="100"
       oversample="1" filter="0" supersample="1" passes="1" temporal_samples="1"
       estimator_radius="0" gamma="1" brightness="4" vibrancy="1">
  <xform weight="0.4" color="0.1" swirl="0.6" spherical="0.4" coefs="0.55 0.25 -0.25 0.55 0.3 0.1"/>
  <xform weight="0.35" color="0.5" julia="0.8" sinusoidal="0.2" coefs="0.7 -0.2 0.2 0.7 -0.4 0.5"/>
  <xform weight="0.25" color="0.9" bubble="0.5" polar="0.5" coefs="0.5 0 0 0.5 0 -0.3"/>
$(palette)
</flame>
EOF

# Runs a command REPEAT times, each with stdin from FILE (or nothing);
# prints "seconds peak_kb" of the fastest run. Usage: timed [-i FILE] CMD...
timed() {
  local best="" best_kb="" in=/dev/null
  if [ "$1" = "-i" ]; then in=$2; shift 2; fi
  for _ in $(seq 1 "$repeat"); do
    local t0 t1 kb
    t0=$(date +%s.%N)
    /usr/bin/time -f "%M" -o "$work/rss" "$@" <"$in" >"$work/log" 2>&1 || {
      echo "compare_flam3: failed: $*" >&2
      tail -5 "$work/log" >&2
      exit 1
    }
    t1=$(date +%s.%N)
    kb=$(tail -1 "$work/rss")
    cp "$work/log" "$work/last.log"
    local s
    s=$(echo "$t1 - $t0" | bc -l)
    if [ -z "$best" ] || [ "$(echo "$s < $best" | bc -l)" = 1 ]; then best=$s best_kb=$kb; fi
  done
  echo "$best $best_kb"
}

# Seconds from the job's start to its end, as the embedded server's store
# recorded them, for the job named in the last Nimbus run's output.
job_seconds() {
  local id
  id=$(grep -o 'job j-[0-9a-f]*' "$work/last.log" | head -1 | cut -d' ' -f2)
  "$nimbus" --data-dir "$work/data" get "$id" | /usr/bin/python3 -c '
import datetime, json, sys
j = json.load(sys.stdin)
t = lambda k: datetime.datetime.fromisoformat(j[k].replace("Z", "+00:00"))
print("%.3f" % (t("end_time") - t("start_time")).total_seconds())'
}

printf "%-20s %12s %10s %10s %10s %10s %10s %10s %8s %9s\n" genome samples flam3_s flam3_M/s \
  flam3_MB nimbus_s nimbus_M/s nimbus_MB speedup nimbus_job
# genome:nimbus spec:samples. The *_image specs draw the same genome as a
# 1024x1024 PNG (docs/images.md) instead of a 1024x1024x1 volume.
for g in sierpinski_2d:sierpinski_2d:209715200 sierpinski_2d:sierpinski_2d_image:209715200 \
  flame6_2d:flame6_2d:104857600 flame6_2d:flame6_2d_image:104857600; do
  name=${g%%:*} samples=${g##*:} spec=${g#*:}
  spec=${spec%%:*}
  out="$work/$spec.vdb"
  case "$spec" in *_image) out="$work/$spec.png" ;; esac
  read -r fs fkb < <(timed -i "$work/$name.flam3" env nthreads="$flam3_threads" verbose=0 \
    format=png out="$work/$name.png" flam3-render)
  read -r ns nkb < <(timed "$nimbus" --data-dir "$work/data" --threads "$threads" \
    render --no-cache "$here/flam3/$spec.json" -o "$out")
  js=$(job_seconds)
  printf "%-20s %12s %10.2f %10.1f %10.0f %10.2f %10.1f %10.0f %7.2fx %8.2fs\n" "$spec" "$samples" \
    "$fs" "$(echo "$samples / $fs / 1000000" | bc -l)" "$(echo "$fkb / 1024" | bc -l)" \
    "$ns" "$(echo "$samples / $ns / 1000000" | bc -l)" "$(echo "$nkb / 1024" | bc -l)" \
    "$(echo "$fs / $ns" | bc -l)" "$js"
done
echo "(whole processes; Nimbus on $threads threads, flam3-render nthreads=$flam3_threads;" \
  "speedup = flam3 time / Nimbus time; nimbus_job = the job's start to end in the server)"

#!/usr/bin/env bash
# Scaling and memory of `gsid denoise` on render sets tiled from a fixture (docs/ALGORITHM.md §5 targets):
#   - time per pixel at 1 MP and 4 MP (median of RUNS whole-process runs, all threads);
#   - 1 thread against 2 threads at 1 MP (runs alternate; medians);
#   - what two cores give at all: one 1-thread run alone against two independent 1-thread runs at once
#     (a shared VM can give less than 2×; no threading in gsid can beat that ceiling);
#   - peak resident memory (/usr/bin/time -v) at 4 MP, against the in-memory f32 size of the input buffers.
# Usage: scripts/scaling.sh [PIPELINE] [RUNS] [FIXTURE_SET]   (defaults: balanced 5 fixtures/mitsuba-cornell/spp4)
set -euo pipefail
pipeline=${1:-balanced}
runs=${2:-5}
src=${3:-fixtures/mitsuba-cornell/spp4}
cd "$(dirname "$0")/.."
cargo build --release --quiet --bin gsid --example tile_set
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
target/release/examples/tile_set "$src" "$work/1mp" 8
target/release/examples/tile_set "$src" "$work/4mp" 16

median() { sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
# Median wall seconds of RUNS runs of `gsid denoise SET` with extra arguments.
timed() {
  local set=$1; shift
  for _ in $(seq "$runs"); do
    local start end
    start=$(date +%s.%N)
    target/release/gsid denoise "$set" --pipeline "$pipeline" -o "$work/out.exr" --quiet "$@"
    end=$(date +%s.%N)
    echo "$end - $start" | bc -l
  done | median
}

# 1 against 2 threads: runs alternate, so a change in the machine's load (other tenants) falls on
# both medians alike rather than on whichever ran second.
threads_pair() {
  for _ in $(seq "$runs"); do
    for n in 1 2; do
      local start end
      start=$(date +%s.%N)
      target/release/gsid denoise "$work/1mp" --pipeline "$pipeline" -o "$work/out.exr" --quiet --threads "$n"
      end=$(date +%s.%N)
      echo "$n $(echo "$end - $start" | bc -l)"
    done
  done >"$work/pairs"
}

# The machine's own ceiling: a 1-thread run alone, then two 1-thread runs side by side (the slower
# of the two counts). Alternating again, so load changes fall on both.
ceiling_pair() {
  for _ in $(seq "$runs"); do
    local start end
    start=$(date +%s.%N)
    target/release/gsid denoise "$work/1mp" --pipeline "$pipeline" -o "$work/a.exr" --quiet --threads 1
    end=$(date +%s.%N)
    echo "alone $(echo "$end - $start" | bc -l)"
    start=$(date +%s.%N)
    target/release/gsid denoise "$work/1mp" --pipeline "$pipeline" -o "$work/a.exr" --quiet --threads 1 &
    target/release/gsid denoise "$work/1mp" --pipeline "$pipeline" -o "$work/b.exr" --quiet --threads 1
    wait
    end=$(date +%s.%N)
    echo "side $(echo "$end - $start" | bc -l)"
  done >"$work/ceiling"
}

t1=$(timed "$work/1mp")
t4=$(timed "$work/4mp")
threads_pair
t1_one=$(awk '$1 == 1 {print $2}' "$work/pairs" | median)
t1_two=$(awk '$1 == 2 {print $2}' "$work/pairs" | median)
printf 'pipeline %s, %s, %d cores, median of %d runs\n' "$pipeline" "$src" "$(nproc)" "$runs"
printf '  1 MP (1024x1024): %.3f s = %.1f ns/pixel\n' "$t1" "$(echo "$t1 * 1000000000 / 1048576" | bc -l)"
printf '  4 MP (2048x2048): %.3f s = %.1f ns/pixel (%.2fx the 1 MP time per pixel)\n' \
  "$t4" "$(echo "$t4 * 1000000000 / 4194304" | bc -l)" "$(echo "$t4 / 4 / $t1" | bc -l)"
printf '  1 MP, 1 thread %.3f s, 2 threads %.3f s: %.2fx\n' "$t1_one" "$t1_two" "$(echo "$t1_one / $t1_two" | bc -l)"
ceiling_pair
alone=$(awk '$1 == "alone" {print $2}' "$work/ceiling" | median)
side=$(awk '$1 == "side" {print $2}' "$work/ceiling" | median)
printf '  ceiling: 1-thread run alone %.3f s, two side by side %.3f s: two cores give %.2fx\n' \
  "$alone" "$side" "$(echo "2 * $alone / $side" | bc -l)"

# Input buffers in memory: every channel of every buffer as f32.
channels=$(for f in "$src"/*.exr; do
  case $(basename "$f") in color.exr|albedo.exr|normal.exr|material.exr) echo 3 ;; *) echo 1 ;; esac
done | paste -sd+ | bc)
input_mb=$(echo "2048 * 2048 * $channels * 4 / 1048576" | bc -l)
peak_kb=$(/usr/bin/time -v target/release/gsid denoise "$work/4mp" --pipeline "$pipeline" -o "$work/out.exr" --quiet 2>&1 \
  | awk -F': ' '/Maximum resident set size/ {print $2}')
printf '  peak memory at 4 MP: %.0f MB; input buffers (%d f32 channels): %.0f MB; ratio %.2f\n' \
  "$(echo "$peak_kb / 1024" | bc -l)" "$channels" "$input_mb" "$(echo "$peak_kb / 1024 / $input_mb" | bc -l)"

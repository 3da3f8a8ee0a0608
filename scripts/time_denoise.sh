#!/usr/bin/env bash
# Median wall time of `gsid denoise` over 5 runs on a 1024×1024 (1 MP) render set tiled from the fixture.
# Usage: scripts/time_denoise.sh [PIPELINE] [TILES]   (defaults: gsid 8 → 1 MP)
set -euo pipefail
pipeline=${1:-gsid}
tiles=${2:-8}
cd "$(dirname "$0")/.."
cargo build --release --quiet --bin gsid --example tile_set
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
target/release/examples/tile_set fixtures/mitsuba-cornell/spp4 "$work/set" "$tiles"
times=()
for _ in 1 2 3 4 5; do
  start=$(date +%s.%N)
  target/release/gsid denoise "$work/set" --pipeline "$pipeline" -o "$work/out.exr" --quiet
  end=$(date +%s.%N)
  times+=("$(echo "$end - $start" | bc -l)")
done
sorted=$(printf '%s\n' "${times[@]}" | sort -n)
median=$(echo "$sorted" | sed -n 3p)
mp=$(echo "($tiles * 128) ^ 2 / 1000000" | bc -l)
printf 'pipeline %s, %dx%d (%.2f MP), %d threads: runs %s s; median %.3f s = %.3f s/MP\n' \
  "$pipeline" $((tiles * 128)) $((tiles * 128)) "$mp" "$(nproc)" "$(echo $sorted | tr '\n' ' ')" "$median" "$(echo "$median / $mp" | bc -l)"

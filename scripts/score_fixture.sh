#!/usr/bin/env bash
# SSIM / PSNR / relMSE of the input and of named pipelines on every spp of a fixture.
# Usage: scripts/score_fixture.sh [FIXTURE_DIR] [PIPELINE...]   (defaults: fixtures/mitsuba-cornell sid gsid)
set -euo pipefail
cd "$(dirname "$0")/.."
fixture=${1:-fixtures/mitsuba-cornell}
shift || true
pipelines=("$@")
[ ${#pipelines[@]} -gt 0 ] || pipelines=(sid gsid)
cargo build --release --quiet --bin gsid
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for set in $(ls -d "$fixture"/spp*/ | sort -V); do
  spp=$(basename "$set")
  ref="$fixture/reference.exr"
  printf '%-8s %-10s %s\n' "$spp" input "$(target/release/gsid eval "$set/color.exr" --reference "$ref")"
  for p in "${pipelines[@]}"; do
    target/release/gsid denoise "$set" --pipeline "$p" -o "$out/$p.exr" --quiet
    printf '%-8s %-10s %s\n' "$spp" "$p" "$(target/release/gsid eval "$out/$p.exr" --reference "$ref")"
  done
done

#!/usr/bin/env bash
# The sweeps the presets are chosen from: `full` over walks × pyramid levels × window radius on every
# fixture at 4 spp, written to benches/results/sweeps/FIXTURE/, then the choice (scripts/choose_presets.py).
# Usage: scripts/sweep_presets.sh [REPEAT]   (default 5; run on an otherwise idle machine)
set -euo pipefail
repeat=${1:-5}
cd "$(dirname "$0")/.."
cargo build --release --quiet --bin gsid
for fixture in mitsuba-cornell cornell caustics textured detail; do
  target/release/gsid sweep "fixtures/$fixture/spp4" --pipeline full --quiet \
    --vary pyramid.gsid.walks=1,2,4,8,16,32 --vary pyramid.levels=1,2 --vary pyramid.gsid.window=2,3,4 --vary atrous.iterations=1,2 \
    --repeat "$repeat" --out "benches/results/sweeps/$fixture"
done
python3 scripts/choose_presets.py benches/results/sweeps/*/sweep.csv

#!/bin/sh
# Builds the fuzz targets, then runs each given target (default: all four) for SECONDS (default 600)
# one after the other, on one core each. Logs: fuzz/logs/TARGET.log and TARGET.worker.log.
# Seeds the corpora first if they are missing.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
seconds=${1:-600}
shift || true
targets=${*:-exr_reader pipeline_toml scene_toml pfm_reader}
[ -d "$here/corpus" ] || "$here/seed.sh"
mkdir -p "$here/logs"
cd "$here"
cargo +nightly fuzz build
for target in $targets; do
    # The built binary, not `cargo fuzz run`: a source edit during the runs must not trigger a rebuild.
    "target/x86_64-unknown-linux-gnu/release/$target" -artifact_prefix="artifacts/$target/" \
        -jobs=1 -workers=1 -max_total_time="$seconds" -print_final_stats=1 "corpus/$target" \
        > "logs/$target.log" 2>&1 || echo "$target: exit $? (see logs/$target.log)"
    # With -jobs, libFuzzer writes the worker's output to fuzz-0.log in the current folder.
    if [ -f fuzz-0.log ]; then mv fuzz-0.log "logs/$target.worker.log"; fi
done

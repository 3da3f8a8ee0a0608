#!/bin/sh
# Builds the fuzz targets, then runs each given target (default: all five) for SECONDS (default 600)
# one after the other, on one core each (several at once: JOBS=2). Logs: fuzz/logs/TARGET.log and TARGET.worker.log.
# Seeds the corpora first if they are missing.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
seconds=${1:-600}
shift || true
targets=${*:-exr_reader pipeline_toml scene_toml pfm_reader multilayer_passes}
[ -d "$here/corpus" ] || "$here/seed.sh"
mkdir -p "$here/logs"
cd "$here"
cargo +nightly fuzz build
# JOBS targets at a time (default 1); each runs on one core for SECONDS.
jobs=${JOBS:-1}
run_one() {
    target=$1
    # The built binary, not `cargo fuzz run`: a source edit during the runs must not trigger a rebuild.
    # Its own working folder: with -jobs, libFuzzer writes the worker's output to fuzz-0.log there.
    mkdir -p "work/$target"
    (cd "work/$target" && "$here/target/x86_64-unknown-linux-gnu/release/$target" \
        -artifact_prefix="$here/artifacts/$target/" -jobs=1 -workers=1 -max_total_time="$seconds" \
        -print_final_stats=1 "$here/corpus/$target" > "$here/logs/$target.log" 2>&1) \
        || echo "$target: exit $? (see logs/$target.log)"
    if [ -f "work/$target/fuzz-0.log" ]; then mv "work/$target/fuzz-0.log" "logs/$target.worker.log"; fi
}
running=0
for target in $targets; do
    mkdir -p "artifacts/$target"
    run_one "$target" &
    running=$((running + 1))
    if [ "$running" -ge "$jobs" ]; then
        wait
        running=0
    fi
done
wait

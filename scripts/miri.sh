#!/usr/bin/env bash
# Runs the Miri-sized walk kernel tests (tests/walk_miri.rs) under Miri, which checks every load of
# the reference, scalar and AVX2 kernels (the AVX2 kernel's raw-pointer loads above all) for
# out-of-bounds access and other undefined behaviour. The build enables the `avx2` target feature
# so that Miri reports AVX2 as available and emulates its intrinsics; without it the AVX2 case
# is skipped (the test says so on stderr).
# Too slow for CI: about 6 CPU-minutes of interpretation, 9 to 18 minutes of wall time on a
# loaded 2-core machine, plus about 4 minutes the first time to build the dependencies for Miri
# (cached in target/miri).
# Installs the nightly `miri` component (and `rust-src`, which it needs) if missing.
# Usage: scripts/miri.sh [extra `cargo test` arguments, e.g. a test name]
set -euo pipefail
cd "$(dirname "$0")/.."

if ! cargo +nightly miri --version >/dev/null 2>&1; then
  rustup +nightly component add miri rust-src
fi
cargo +nightly miri setup

export RUSTFLAGS="-C target-feature=+avx2"
# Tree Borrows: the kernels run on rayon, whose crossbeam-epoch breaks Stacked Borrows but not
# Tree Borrows (crossbeam-rs/crossbeam#545, #996). Permissive provenance: crossbeam-epoch casts
# integers to pointers, which would otherwise warn on every run. Ignore leaks: rayon's pool
# threads outlive the tests, which Miri otherwise fails at exit.
export MIRIFLAGS="-Zmiri-tree-borrows -Zmiri-permissive-provenance -Zmiri-ignore-leaks ${MIRIFLAGS:-}"
# Uncaptured, so that a skipped AVX2 case shows.
RUST_TEST_NOCAPTURE=1 cargo +nightly miri test --test walk_miri "$@"

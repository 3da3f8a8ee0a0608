#!/usr/bin/env bash
# Byte-identity check for refactorings: builds BASE (a commit, default HEAD) and the working tree, then
# runs both binaries on every fixture at 1 and 64 spp and compares what they write:
#   - every named pipeline's output EXR (cmp),
#   - `ablate` and a small `sweep` per fixture set (their CSV tables with the timing columns removed),
#   - `render` of every fixture scene at a small size and low spp (every buffer, cmp).
# Prints one line per comparison and a closing "N passed, N failed" line; exits 1 on any difference.
# Usage: scripts/compare_builds.sh [BASE_REV] [SPP...]     (defaults: HEAD, spp1 spp64)
#        BASE_BIN=path/to/gsid scripts/compare_builds.sh BASE_REV   (use a binary built from BASE_REV)
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
base_rev=${1:-HEAD}
shift || true
spps=("$@")
[ ${#spps[@]} -gt 0 ] || spps=(spp1 spp64)

work=$(mktemp -d)
trap 'git -C "$root" worktree remove --force "$work/base" >/dev/null 2>&1 || true; rm -rf "$work"' EXIT

if [ -n "${BASE_BIN:-}" ]; then
  # A binary already built from BASE_REV (saves a build; the caller vouches for its commit).
  old=$(realpath "$BASE_BIN")
else
  git worktree add --detach --quiet "$work/base" "$base_rev"
  echo "building base ($(git rev-parse --short "$base_rev")) ..." >&2
  CARGO_TARGET_DIR="$root/target/compare-base" cargo build --release --quiet --bin gsid \
    --manifest-path "$work/base/Cargo.toml"
  old="$root/target/compare-base/release/gsid"
fi
echo "building the working tree ..." >&2
cargo build --release --quiet --bin gsid
new="$root/target/release/gsid"

passed=0
failed=0
check() { # label file_a file_b
  if cmp -s "$2" "$3"; then
    passed=$((passed + 1))
  else
    failed=$((failed + 1))
    echo "DIFFERS: $1" >&2
  fi
}
# Drops the timing columns (headers seconds*, and `pareto`, which is judged on seconds) from a CSV table.
untimed() {
  python3 - "$1" <<'PY'
import csv, sys
rows = list(csv.reader(open(sys.argv[1], newline="")))
keep = [i for i, name in enumerate(rows[0]) if not name.startswith("seconds") and name != "pareto"]
for row in rows:
    print(",".join(row[i] for i in keep))
PY
}

pipelines=$("$new" pipelines | awk '{print $1}')
[ "$pipelines" = "$("$old" pipelines | awk '{print $1}')" ] || { echo "pipeline lists differ" >&2; exit 1; }

for fixture in fixtures/*/; do
  fixture=${fixture%/}
  for spp in "${spps[@]}"; do
    set_dir="$fixture/$spp"
    [ -d "$set_dir" ] || continue
    tag="$(basename "$fixture")-$spp"
    for p in $pipelines; do
      "$old" denoise "$set_dir" --pipeline "$p" --seed 0 -q -o "$work/old-$tag-$p.exr"
      "$new" denoise "$set_dir" --pipeline "$p" --seed 0 -q -o "$work/new-$tag-$p.exr"
      check "denoise $set_dir --pipeline $p" "$work/old-$tag-$p.exr" "$work/new-$tag-$p.exr"
    done
    for bin in old new; do
      b=$old; [ $bin = new ] && b=$new
      "$b" ablate "$set_dir" --pipeline full -q --out "$work/$bin-$tag-ablate.csv" >/dev/null
      untimed "$work/$bin-$tag-ablate.csv" >"$work/$bin-$tag-ablate.txt"
      "$b" sweep "$set_dir" --pipeline full -q --repeat 1 --vary pyramid.gsid.walks=1,4 \
        --vary atrous.iterations=1,2 --out "$work/$bin-$tag-sweep" >/dev/null
      untimed "$work/$bin-$tag-sweep/sweep.csv" >"$work/$bin-$tag-sweep.txt"
    done
    check "ablate $set_dir" "$work/old-$tag-ablate.txt" "$work/new-$tag-ablate.txt"
    check "sweep $set_dir" "$work/old-$tag-sweep.txt" "$work/new-$tag-sweep.txt"
  done
done

for scene in fixtures/scenes/*.toml; do
  name=$(basename "$scene" .toml)
  for bin in old new; do
    b=$old; [ $bin = new ] && b=$new
    "$b" render "$scene" --spp 1,2 --reference-spp 4 -q -o "$work/$bin-render-$name"
  done
  for f in $(cd "$work/old-render-$name" && find . -type f | sort); do
    check "render $scene $f" "$work/old-render-$name/$f" "$work/new-render-$name/$f"
  done
done

echo "compare_builds: base $(git rev-parse --short "$base_rev") against the working tree"
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]

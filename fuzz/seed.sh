#!/bin/sh
# Builds the seed corpora from the repository's own files (run from anywhere; writes fuzz/corpus/).
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
mkdir -p "$here/corpus/exr_reader" "$here/corpus/pipeline_toml" "$here/corpus/scene_toml"
# The small EXRs of the 1-spp sets (large files slow every execution down).
for f in "$root"/fixtures/*/spp1/*.exr; do
    if [ "$(wc -c < "$f")" -le 16384 ]; then
        cp "$f" "$here/corpus/exr_reader/$(basename "$(dirname "$(dirname "$f")")")-$(basename "$f")"
    fi
done
for f in "$root"/pipelines/*.toml; do
    name=$(basename "$f" .toml)
    cp "$f" "$here/corpus/pipeline_toml/$name.toml"
done
# A few with --set overrides after NUL bytes, the target's input format.
printf '%s\0gsid.walks=4\0gsid.weights.depth=0' "$(cat "$root/pipelines/gsid.toml")" > "$here/corpus/pipeline_toml/gsid-set"
printf '%s\0pyramid.levels=3\0pyramid.level1.gsid.sigma=0.5' "$(cat "$root/pipelines/full.toml")" > "$here/corpus/pipeline_toml/full-set"
for f in "$root"/fixtures/scenes/*.toml; do
    cp "$f" "$here/corpus/scene_toml/$(basename "$f")"
done
echo "seeded: $(ls "$here/corpus/exr_reader" | wc -l) EXR, $(ls "$here/corpus/pipeline_toml" | wc -l) pipeline, $(ls "$here/corpus/scene_toml" | wc -l) scene inputs"

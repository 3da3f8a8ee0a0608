#!/bin/sh
# Builds the seed corpora from the repository's own files (run from anywhere; writes fuzz/corpus/).
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
mkdir -p "$here/corpus/exr_reader" "$here/corpus/pipeline_toml" "$here/corpus/scene_toml" "$here/corpus/pfm_reader"
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
# Small hand-built PFMs (octal escapes: POSIX printf has no \x): RGB and grey, either byte order,
# a scale that is not 1, odd whitespace, a denormal, a NaN and -0.0 among the samples.
pfm=$here/corpus/pfm_reader
printf 'PF\n2 1\n-1.0\n\000\000\200\077\000\000\000\100\000\000\100\100\001\000\000\000\000\000\300\177\000\000\000\200' > "$pfm/rgb-le"
printf 'Pf\n1 2\n1.0\n\077\200\000\000\000\000\000\001' > "$pfm/grey-be"
printf 'Pf \t3\r\n1\n-2.5 \000\000\200\077\000\000\200\277\377\377\177\177' > "$pfm/grey-scaled"
printf 'PF\n1 1\n4\n\100\000\000\000\000\000\000\000\177\200\000\000' > "$pfm/rgb-be"
# Multilayer files for multilayer_passes, cropped with Python's OpenEXR (the venv of
# scripts/requirements-compare.txt, or any python3 that has it).
python=${PYTHON:-python3}
if "$python" -c "import OpenEXR, numpy" 2>/dev/null; then
    "$python" "$here/seed_multilayer.py" "$here/corpus/multilayer_passes"
else
    echo "multilayer_passes: no seeds (set PYTHON to a python3 with OpenEXR and numpy)" >&2
    mkdir -p "$here/corpus/multilayer_passes"
fi
echo "seeded: $(ls "$here/corpus/exr_reader" | wc -l) EXR, $(ls "$here/corpus/pipeline_toml" | wc -l) pipeline, $(ls "$here/corpus/scene_toml" | wc -l) scene, $(ls "$pfm" | wc -l) PFM inputs"

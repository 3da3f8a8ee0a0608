"""How the outlier clamp's flags fare against the reference: per fixture × spp, how many pixels a
pipeline's `outlier` stage flagged, how many of them the clamp brought closer to the reference (a
firefly) and how many it moved away (structure the test took for one: an emitter's rim, a texture's
glint, a highlight), and the relMSE summed over the flagged pixels before and after the clamp.

    python3 scripts/flag_audit.py [--fixtures cycles-glass,textured] [--spp 16,64] [--pipeline full]
    python3 scripts/flag_audit.py --keep /tmp/audit --print-pixels 5

It runs `gsid denoise SET -p PIPELINE --save-buffer outlier_light=…` (the light the clamp took, as
the pipeline's `outlier` stage names it: `outlier_light` in every preset) and compares the input, the
clamped input (input − light) and the reference, pixel by pixel, on linear HDR (relMSE as
`gsid eval`: (x − ref)² / (ref² + 0.01), mean over channels). What the later stages make of the
flagged pixels (the filters, the `spread` stage's bump and its highlights) is the comparison's
business (`scripts/compare_denoisers.py`); this reads the decision alone. `--print-pixels N` lists the
N flagged pixels the clamp hurt most, with their input, clamped value and reference.

Errors (a missing fixture, binary or package, a failed run) give one line on stderr and exit code 2.
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from gsidscore import (DEFAULT_FIXTURES, cases, fail, parse_spps, read_rgb, require_gsid,
                       scored_case)


def relmse(x, ref):
    """Per-pixel relMSE (mean over channels), as `gsid eval` scores it."""
    return ((x - ref) ** 2 / (ref ** 2 + 0.01)).mean(-1)


def audit(gsid, fx, spp, setdir, ref, workdir, pipeline, pixels):
    stem = workdir / f"{fx}-spp{spp}"
    inp, noisy, plain_ref = scored_case(setdir, ref, str(stem))
    out, light_path = Path(f"{stem}-{pipeline}.exr"), Path(f"{stem}-{pipeline}-light.exr")
    proc = subprocess.run([str(gsid), "denoise", str(inp), "-p", pipeline, "-o", str(out), "--quiet",
                           "--save-buffer", f"outlier_light={light_path}"], capture_output=True, text=True)
    if proc.returncode != 0:
        fail(f"gsid denoise {inp} -p {pipeline}: {proc.stderr.strip() or proc.stdout.strip()}")
    if not light_path.is_file():
        fail(f"{pipeline}: no buffer outlier_light written (does the pipeline clamp with light = \"outlier_light\"?)")
    light, noisy_rgb, reference = read_rgb(light_path), read_rgb(noisy), read_rgb(plain_ref)
    clamped = noisy_rgb - light
    flagged = (light > 0).any(-1)
    before, after = relmse(noisy_rgb, reference), relmse(clamped, reference)
    helped = flagged & (after < before)
    row = (fx, spp, int(flagged.sum()), 100.0 * flagged.mean(), int(helped.sum()),
           int((flagged & ~helped).sum()), float(before[flagged].sum()), float(after[flagged].sum()))
    print("| %s | %d | %d | %.2f %% | %d | %d | %.2f | %.2f |" % row, flush=True)
    lines = []
    if pixels:
        lum = lambda x: x.mean(-1)
        hurt = (after - before) * flagged
        ys, xs = (hurt > 0).nonzero()
        for y, x in sorted(zip(ys, xs), key=lambda p: -hurt[p])[:pixels]:
            lines.append(f"  {fx} {spp} spp ({x}, {y}): input {lum(noisy_rgb)[y, x]:.3f}, clamped "
                         f"{lum(clamped)[y, x]:.3f}, reference {lum(reference)[y, x]:.3f}")
    return lines


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fixtures", default=",".join(DEFAULT_FIXTURES), help="comma-separated fixture names")
    p.add_argument("--spp", default="1,4,16,64", help="comma-separated sample counts")
    p.add_argument("--pipeline", default="full", help="gsid pipeline (name or file)")
    p.add_argument("--keep", type=Path, default=None, help="keep the outputs and light buffers in this folder")
    p.add_argument("--print-pixels", type=int, default=0, help="list the N flagged pixels the clamp hurt most")
    p.add_argument("--no-build", action="store_true", help="do not run cargo build first")
    args = p.parse_args()
    try:
        import numpy  # noqa: F401
        import OpenEXR  # noqa: F401
    except ImportError as e:
        fail(f"missing Python package ({e}); run: pip install -r scripts/requirements-compare.txt")
    found = cases([f for f in args.fixtures.split(",") if f], parse_spps(args.spp))
    gsid = require_gsid(not args.no_build)
    with tempfile.TemporaryDirectory() as tmp:
        workdir = args.keep or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        print(f"`{args.pipeline}`'s outlier flags against the reference (relMSE summed over the flagged pixels)\n")
        print("| fixture | spp | flagged | share | clamp helped | clamp hurt | relMSE sum, input | relMSE sum, clamped |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- |")
        worst = []
        for fx, spp, setdir, ref in found:
            worst += audit(gsid, fx, spp, setdir, ref, workdir, args.pipeline, args.print_pixels)
        if worst:
            print("\nFlagged pixels the clamp moved furthest from the reference (luminance):")
            print("\n".join(worst))


if __name__ == "__main__":
    sys.exit(main())

"""Mean `gsid ablate` rows over fixtures, per sample count: what each stage and choice buys at every spp.

For every fixture × spp this runs `target/release/gsid ablate fixtures/<name>/spp<N> --pipeline P --out
rows.json` on the *whole* render set (so the noise rows can compare the image-only estimate with the
renderer's `variance.exr`/half buffers where the set has them; mitsuba-cornell has none, so its two rows
agree), or on a Blender multilayer fixture's file (`cycles-studio`, `cycles-glass`, `cycles-fog`, read
from ../shared/fixtures when it exists, scored against its reference's `Combined`), and prints, per spp, each variant's mean SSIM and mean relMSE over the fixtures and its mean
ΔSSIM to the pipeline as shipped. Seconds are left out (ablate times one run; see compare_denoisers).

    python3 scripts/ablate_summary.py                       # full, five fixtures, 1/4/16/64 spp
    python3 scripts/ablate_summary.py --fixtures cycles-fog --rows reliability
    python3 scripts/ablate_summary.py --pipeline balanced --spp 1,4 --rows "fixed σ,without walks"

Errors (a missing fixture or binary) give a one-line message and exit code 2.
"""

import argparse
import json
import os
import statistics
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor

from gsidscore import ALL_FIXTURES, cases, fail, parse_spps, require_gsid


def ablate(gsid, setdir, ref, pipeline, out):
    r = subprocess.run([gsid, "ablate", str(setdir), "--reference", str(ref), "--pipeline", pipeline, "--quiet",
                        "--threads", "1", "--out", out], capture_output=True, text=True)
    if r.returncode:
        fail(f"{setdir}: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else 'gsid ablate failed'}")
    with open(out) as f:
        return json.load(f)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pipeline", default="full")
    p.add_argument("--fixtures", default=",".join(ALL_FIXTURES))
    p.add_argument("--spp", default="1,4,16,64")
    p.add_argument("--rows", default="", help="comma-separated substrings: only the variants containing one")
    a = p.parse_args()
    gsid = str(require_gsid(False))
    fixtures, spps = a.fixtures.split(","), parse_spps(a.spp)
    found = {(fx, s): (setdir, ref) for fx, s, setdir, ref in cases(fixtures, spps)}
    cells = [(fx, s) for s in spps for fx in fixtures]
    tmp = tempfile.mkdtemp()
    with ThreadPoolExecutor(2) as ex:
        tables = list(ex.map(lambda c: ablate(gsid, *found[c], a.pipeline,
                                              os.path.join(tmp, f"{c[0]}-{c[1]}.json")), cells))
    wanted = [w for w in a.rows.split(",") if w]
    print(f"`gsid ablate --pipeline {a.pipeline}`, mean over {', '.join(fixtures)}: SSIM / relMSE (ΔSSIM)\n")
    print("| variant | " + " | ".join(f"{s} spp" for s in spps) + " |")
    print("| --- |" + " --- |" * len(spps))
    names = [row["variant"] for row in tables[0]]
    for name in names:
        if wanted and not any(w in name for w in wanted) and name != names[0]:
            continue
        cols = []
        for s in spps:
            rows = [t for (_, ss), t in zip(cells, tables) if ss == s]
            pick = [next(r for r in rs if r["variant"] == name) for rs in rows]
            base = [rs[0] for rs in rows]
            ssim = statistics.mean(r["ssim"] for r in pick)
            rel = statistics.mean(r["relmse"] for r in pick)
            d = ssim - statistics.mean(r["ssim"] for r in base)
            cols.append(f"{ssim:.4f} / {rel:.4f} ({d:+.4f})")
        print(f"| {name} | " + " | ".join(cols) + " |")


if __name__ == "__main__":
    main()

"""The oracle check of issue 13: would a hand-picked σ beat the noise-driven one? And deeper pyramids.

The presets take GSID's σ and the à-trous σ from the measured noise (docs/ALGORITHM.md §8:
σ = sigma · min(2, (level / noise_ref)^noise_power)). For every fixture × sample count this scores

  * `auto`: the pipeline (`--pipeline`, default `full`) as shipped;
  * `fixed`: the same pipeline with **fixed** σ, for every pair on the grid GSID sigma ∈ {0.1, 0.3, 1, 2}
    × à-trous sigma ∈ {0.1, 0.2, 0.4} (`--gsid-sigmas`, `--atrous-sigmas`). Fixed means
    `--set pyramid.gsid.sigma=S --set pyramid.gsid.noise_power=0 --set pyramid.gsid.local_noise=0
    --set atrous.sigma=A --set atrous.noise_power=0`: with power 0 the noise factor is 1 at any level,
    and with local_noise 0 every pixel's colour difference counts alike, so σ = sigma at every
    pyramid level, pixel and à-trous pass (`cargo test --release --test it noise::noise_power_zero`
    checks that this gives the same bits as the stages without a `noise` buffer; a preset's own
    `levelN = { gsid = { ... } }` override would win over `pyramid.gsid.*` at that level, and the
    shipped presets have none). Everything else
    stays as shipped and stays on: the outlier stage, the `noise` stages (the blend reads their
    estimate), the pyramid, and the final blend back to the input where the noise does not explain
    the change.

and prints per cell the auto SSIM, the best fixed SSIM and its (GSID σ, à-trous σ) pair; then per
sample count the mean auto SSIM over the fixtures, the mean of the per-cell best (an oracle that picks σ
per image from the reference, which no user can), their difference with PASS/FAIL against the issue's
bound (`--bound`, 0.005), and the single fixed pair with the best mean (what one hand-tuned preset per
sample count would score).

`--levels 2,3,4` runs the deeper-pyramid study instead (issue 13, item 6): the pipeline as shipped,
noise-driven σ included, with `--set pyramid.levels=N` for each N (every level runs the pyramid's whole
sub-list, its noise measured again at that level), and prints per sample count the mean SSIM and
relMSE for each N.

Inputs and scoring are those of `scripts/compare_denoisers.py` (shared in `scripts/gsidscore.py`):
colour + albedo + normal + depth only, linked into a temporary folder (so a fixture's `variance.exr`
or halves are not used; `cycles-studio`, when `--fixtures` names it, is read as its multilayer file),
scored by `gsid eval --json` against the fixture's reference (SSIM on the clipped sRGB view, relMSE on
linear HDR). Each denoise runs with `--threads 1` and the default seed, `--workers` (2) at a time, so a
run gives the same scores however it is scheduled.

Run from the repository root after `cargo build --release` (or drop `--no-build`; Python 3.11 with
`pip install -r scripts/requirements-compare.txt`):

    python3 scripts/oracle_sigma.py --no-build
    python3 scripts/oracle_sigma.py --no-build --levels 2,3,4
    python3 scripts/oracle_sigma.py --no-build --pipeline balanced --fixtures textured,detail --spp 64

Options: --fixtures a,b (default: the five of compare_denoisers; cycles-studio too if named), --spp
(default 1,4,16,64), --pipeline NAME, --gsid-key, --atrous-key (the stages whose σ the grid sets,
default `pyramid.gsid` and `atrous`), --levels N,M, --workers N, --bound X, --no-build, --json PATH
(every run and the summaries), --keep DIR (keep the outputs). Errors (a missing fixture, binary,
package, or a key the pipeline does not have) give one line on stderr and exit code 2.
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from itertools import product
from pathlib import Path

from gsidscore import (ALL_FIXTURES, ROOT, cases, fail, git_commit, gsid_eval, note, parse_spps, require_gsid,
                       scored_case)


def parse_floats(text, what):
    try:
        values = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        values = []
    if not values:
        fail(f"{what} {text!r}: expected comma-separated numbers such as 0.1,0.3")
    return values


def parse_args(argv):
    p = argparse.ArgumentParser(description="Oracle σ check and pyramid-depth study (see the file's docstring).")
    p.add_argument("--fixtures", default=",".join(ALL_FIXTURES), help="comma-separated fixture names")
    p.add_argument("--spp", default="1,4,16,64", help="comma-separated sample counts (folders spp<N>)")
    p.add_argument("--pipeline", default="full", help="gsid pipeline name or TOML file")
    p.add_argument("--gsid-sigmas", default="0.1,0.3,1,2", help="GSID σ grid")
    p.add_argument("--atrous-sigmas", default="0.1,0.2,0.4", help="à-trous σ grid")
    p.add_argument("--gsid-key", default="pyramid.gsid", help="--set prefix of the GSID stage")
    p.add_argument("--atrous-key", default="atrous", help="--set prefix of the à-trous stage")
    p.add_argument("--levels", help="comma-separated pyramid depths: run the depth study instead")
    p.add_argument("--levels-key", default="pyramid.levels", help="--set key of the pyramid depth")
    p.add_argument("--workers", type=int, default=2, help="denoises run at a time (each on 1 thread)")
    p.add_argument("--bound", type=float, default=0.005, help="largest allowed mean best − mean auto SSIM")
    p.add_argument("--no-build", action="store_true", help="do not run cargo build first")
    p.add_argument("--json", metavar="PATH", help="also write every run and the summaries as JSON")
    p.add_argument("--keep", metavar="DIR", help="keep the denoised images in DIR")
    args = p.parse_args(argv)
    if args.workers < 1:
        fail("--workers must be at least 1")
    return args


def variants(args):
    """(label, --set assignments) of every run per case."""
    if args.levels:
        try:
            levels = [int(s) for s in args.levels.split(",") if s.strip()]
        except ValueError:
            levels = []
        if not levels:
            fail(f"--levels {args.levels!r}: expected comma-separated integers such as 2,3,4")
        return [(f"levels={n}", [f"{args.levels_key}={n}"]) for n in levels]
    out = [("auto", [])]
    for g, a in product(parse_floats(args.gsid_sigmas, "--gsid-sigmas"),
                        parse_floats(args.atrous_sigmas, "--atrous-sigmas")):
        out.append((f"fixed {g:g}/{a:g}", [f"{args.gsid_key}.sigma={g}", f"{args.gsid_key}.noise_power=0",
                                            f"{args.gsid_key}.local_noise=0",
                                            f"{args.atrous_key}.sigma={a}", f"{args.atrous_key}.noise_power=0"]))
    return out


def denoise(gsid, gsid_input, pipeline, sets, out):
    cmd = [str(gsid), "denoise", str(gsid_input), "--pipeline", pipeline, "--threads", "1", "--quiet",
           "-o", str(out)]
    for s in sets:
        cmd += ["--set", s]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        fail(f"{' '.join(cmd)}: {proc.stderr.strip()}", proc.returncode)


def mean(rows, key):
    return statistics.mean(r[key] for r in rows)


def oracle_report(rows, spps, labels, bound):
    """Per-cell and per-spp tables of auto against the best fixed pair; the per-spp verdicts."""
    fixed = [lab for lab in labels if lab != "auto"]
    by = {(r["fixture"], r["spp"], r["variant"]): r for r in rows}
    cells, per_spp = [], []
    lines = ["| fixture | spp | input SSIM | auto SSIM | best fixed SSIM | best σ (GSID/à-trous) | best − auto |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for spp in spps:
        fixtures = list(dict.fromkeys(r["fixture"] for r in rows if r["spp"] == spp))
        at = []
        for fx in fixtures:
            auto = by[(fx, spp, "auto")]
            best = max((by[(fx, spp, lab)] for lab in fixed), key=lambda r: r["ssim"])
            cell = {"fixture": fx, "spp": spp, "input_ssim": by[(fx, spp, "input")]["ssim"],
                    "auto_ssim": auto["ssim"], "auto_relmse": auto["relmse"], "best_ssim": best["ssim"],
                    "best_relmse": best["relmse"], "best": best["variant"].removeprefix("fixed ")}
            at.append(cell)
            lines.append(f"| {fx} | {spp} | {cell['input_ssim']:.4f} | {cell['auto_ssim']:.4f} | "
                         f"{cell['best_ssim']:.4f} | {cell['best']} | {cell['best_ssim'] - cell['auto_ssim']:+.4f} |")
        cells += at
        pair = max(fixed, key=lambda lab: statistics.mean(by[(fx, spp, lab)]["ssim"] for fx in fixtures))
        auto_mean, best_mean = mean(at, "auto_ssim"), mean(at, "best_ssim")
        per_spp.append({"spp": spp, "fixtures": len(at), "mean_auto_ssim": auto_mean, "mean_best_ssim": best_mean,
                        "difference": best_mean - auto_mean, "pass": best_mean - auto_mean <= bound,
                        "mean_auto_relmse": mean(at, "auto_relmse"),
                        "best_single_pair": pair.removeprefix("fixed "),
                        "best_single_pair_ssim": statistics.mean(by[(fx, spp, pair)]["ssim"] for fx in fixtures)})
    lines += ["", f"Means over the fixtures (PASS: mean best − mean auto ≤ {bound}):", "",
              "| spp | fixtures | mean auto SSIM | mean per-cell best | best − auto | verdict | "
              "best single pair | its mean SSIM |",
              "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for s in per_spp:
        lines.append(f"| {s['spp']} | {s['fixtures']} | {s['mean_auto_ssim']:.4f} | {s['mean_best_ssim']:.4f} | "
                     f"{s['difference']:+.4f} | {'PASS' if s['pass'] else 'FAIL'} | {s['best_single_pair']} | "
                     f"{s['best_single_pair_ssim']:.4f} |")
    return lines, {"cells": cells, "per_spp": per_spp}


def levels_report(rows, spps, labels):
    """Per spp and depth: mean SSIM and relMSE over the fixtures, beside the input's."""
    lines = ["| spp | variant | fixtures | mean SSIM | mean relMSE |", "| --- | --- | --- | --- | --- |"]
    per_spp = []
    for spp in spps:
        for lab in ["input"] + labels:
            at = [r for r in rows if r["spp"] == spp and r["variant"] == lab]
            s = {"spp": spp, "variant": lab, "fixtures": len(at), "mean_ssim": mean(at, "ssim"),
                 "mean_relmse": mean(at, "relmse")}
            per_spp.append(s)
            lines.append(f"| {spp} | {lab} | {s['fixtures']} | {s['mean_ssim']:.4f} | {s['mean_relmse']:.5f} |")
    return lines, {"per_spp": per_spp}


def main(argv=None):
    args = parse_args(argv)
    spps = parse_spps(args.spp)
    found = cases([f.strip() for f in args.fixtures.split(",") if f.strip()], spps)
    runs = variants(args)
    try:
        import numpy  # noqa: F401
        import OpenEXR  # noqa: F401
    except ImportError as e:
        fail(f"missing Python package ({e}); run: pip install -r scripts/requirements-compare.txt")
    gsid = require_gsid(not args.no_build)

    tmp = tempfile.TemporaryDirectory(prefix="oracle_sigma.")
    outdir = Path(args.keep) if args.keep else Path(tmp.name)
    outdir.mkdir(parents=True, exist_ok=True)

    rows = []
    jobs = []
    for fx, spp, setdir, ref in found:
        stem = outdir / f"{fx}-spp{spp}"
        gsid_input, noisy, ref = scored_case(setdir, ref, stem)
        rows.append({"fixture": fx, "spp": spp, "variant": "input", "sets": [], "image": noisy, "ref": ref})
        for i, (label, sets) in enumerate(runs):
            out = Path(f"{stem}-{i:02d}.exr")
            rows.append({"fixture": fx, "spp": spp, "variant": label, "sets": sets, "image": out, "ref": ref})
            jobs.append((gsid_input, sets, out))
    # The first run checks the keys, so a misspelled one fails once rather than in every job.
    denoise(gsid, jobs[0][0], args.pipeline, runs[-1][1], outdir / "key-check.exr")
    note(f"{len(jobs)} denoises of {len(found)} cases, {args.workers} at a time ...")

    def job(j):
        denoise(gsid, j[0], args.pipeline, j[1], j[2])

    with ThreadPoolExecutor(args.workers) as pool:
        for done, _ in enumerate(pool.map(job, jobs), 1):
            if done % 20 == 0 or done == len(jobs):
                note(f"  {done}/{len(jobs)}")
    for r in rows:
        score = gsid_eval(gsid, r.pop("image"), r.pop("ref"))
        r.update(ssim=score["ssim"], psnr=score["psnr"], relmse=score["relmse"])

    labels = [label for label, _ in runs]
    if args.levels:
        lines, summary = levels_report(rows, spps, labels)
        title = f"Pyramid depth, `{args.pipeline}` with its noise-driven σ (`--set {args.levels_key}=N`):"
    else:
        lines, summary = oracle_report(rows, spps, labels, args.bound)
        title = (f"Oracle check, `{args.pipeline}` as shipped (auto) against fixed σ "
                 f"(`{args.gsid_key}.sigma`, `{args.atrous_key}.sigma`, both `noise_power=0`):")
    print(f"gsid {git_commit()}; colour + albedo + normal + depth; scores by `gsid eval` (SSIM on the clipped "
          f"sRGB view, relMSE on linear HDR).")
    print()
    print(title)
    print()
    print("\n".join(lines))
    if args.json:
        header = {"gsid_commit": git_commit(), "pipeline": args.pipeline, "spp": spps, "bound": args.bound,
                  "variants": [{"label": label, "sets": sets} for label, sets in runs]}
        Path(args.json).write_text(json.dumps({"header": header, "rows": rows, **summary}, indent=1) + "\n")
        note(f"wrote {args.json}")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())

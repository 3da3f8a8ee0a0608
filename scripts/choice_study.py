#!/usr/bin/env python3
"""Would a per-pixel choice among filter strengths pay (issue 41 item 2)? Three estimates of each candidate's error, measured.

The candidates are one pipeline (`full` unless `--pipeline`) at several strengths: `--set gsid.sigma=S`
and `--set atrous.sigma=0.2·S` for each S of `--strengths`, each run on the fixture's colour, albedo,
normal and depth (what `scripts/compare_denoisers.py` gives gsid; a Blender multilayer file's passes are
written to a folder first). Each candidate's error is estimated per pixel, relative as the table's
relMSE is ((f − c)² over f_base² + 0.01, channel mean), box-smoothed over `--window` pixels, and the
candidates are combined by it: `hard` takes the smallest estimate, `soft` weighs each by 1 / estimate².
Three estimates, each needing no reference:

  * `sure`: Stein's unbiased risk estimate, (f − c)² − v + 2 v ∂f/∂c, its divergence measured by running
    the candidate once more on c + ε σ b (b random ±1 per pixel and channel, ε = 0.1, σ² = v); v is
    gsid's own `noise` buffer (`--variance noise`), or the fixture's `sample_variance.exr` ÷ spp, the
    truth, on the folder fixtures that have it (`--variance truth`);
  * `halves`: where the fixture has `color_a`/`color_b` (two halves of the samples): each candidate run on
    each half, its error against the other half, (f(A) − B)² + (f(B) − A)²: the other half's noise is
    independent of the filter's and the same for every candidate, so it drops out of the comparison;
  * `masked`: each candidate run once more with a quarter of the pixels (even x, even y) replaced by
    the mean of their four diagonal neighbours; its output there does not depend on their noise, so
    (f − c)² there is the error plus the same v for every candidate (Noise2Self), smoothed over those
    pixels.

Also printed: each candidate alone, their plain mean (`ensemble`), and an `oracle` that takes, per
pixel, the candidate with the least true error over a 7×7 window (the reference's, for a bound).
Means of relMSE over the fixtures, per spp.

    python3 scripts/choice_study.py --methods sure,masked
    python3 scripts/choice_study.py --fixtures cornell,caustics,textured,detail --spp 4,16,64 --methods sure,halves --variance truth

Needs numpy, scipy and OpenEXR (scripts/requirements-compare.txt). Errors give one line and exit code 2.
"""

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gsidscore as gs  # noqa: E402

EPS = 0.1
METHODS = ("sure", "halves", "masked")


def relmse(np, out, ref):
    return float(np.mean((out - ref) ** 2 / (ref * ref + 0.01)))


def case_folder(work, fx, spp, source):
    """A folder of colour, albedo, normal, depth (and halves where the fixture has them) for one case."""
    d = work / f"{fx}-{spp}"
    (d / "set").mkdir(parents=True)
    if source.is_file():  # a Blender multilayer file
        for name, (layer, chans) in {**gs.LAYER_PASSES, "depth": ("Denoising Depth", "ZZZ")}.items():
            gs.write_rgb(d / "set" / f"{name}.exr", gs.read_pass(source, layer, chans))
    else:
        for name in gs.GSID_BUFFERS:
            if (source / f"{name}.exr").is_file():
                (d / "set" / f"{name}.exr").symlink_to((source / f"{name}.exr").resolve())
    return d


def variant(d, name, color):
    """`d`/`name`: the case's features with another colour."""
    v = d / name
    v.mkdir()
    for f in (d / "set").iterdir():
        if f.name != "color.exr":
            (v / f.name).symlink_to(f.resolve())
    gs.write_rgb(v / "color.exr", color)
    return v


def denoise(gsid, setdir, out, pipeline, strength, save_noise=None):
    cmd = [str(gsid), "denoise", str(setdir), "-p", pipeline, "-o", str(out), "--quiet",
           "--set", f"gsid.sigma={strength}", "--set", f"atrous.sigma={0.2 * strength}"]
    if save_noise:
        cmd += ["--save-buffer", f"noise={save_noise}"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        gs.fail(f"gsid denoise {setdir} failed: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
    return gs.read_rgb(out)


def study_case(gsid, args, d, fx, spp, source, ref, np, uniform_filter):
    strengths = args.strengths
    c = gs.read_rgb(d / "set" / "color.exr")
    r = gs.read_rgb(ref)
    outs = [denoise(gsid, d / "set", d / f"s{s}.exr", args.pipeline, s,
                    save_noise=d / "noise.exr" if s == 1.0 else None) for s in strengths]
    base = outs[strengths.index(1.0)]
    den = base * base + 0.01
    row = {f"strength {s:g}": relmse(np, o, r) for s, o in zip(strengths, outs)}
    stack = np.stack(outs)
    row["ensemble"] = relmse(np, stack.mean(0), r)
    true_err = np.stack([uniform_filter(((o - r) ** 2 / (r * r + 0.01)).mean(-1), 7, mode="nearest") for o in outs])
    row["oracle"] = relmse(np, np.take_along_axis(stack, true_err.argmin(0)[None, :, :, None], 0)[0], r)

    def combine(name, errors, counts=None):
        smooth = np.stack([uniform_filter(e, args.window, mode="nearest") for e in errors])
        if counts is not None:
            smooth = smooth / counts
        row[f"{name} hard"] = relmse(np, np.take_along_axis(stack, smooth.argmin(0)[None, :, :, None], 0)[0], r)
        w = 1.0 / np.maximum(smooth, 1e-12) ** 2
        w /= w.sum(0)
        row[f"{name} soft"] = relmse(np, (stack * w[..., None]).sum(0), r)

    if "sure" in args.methods:
        if args.variance == "truth":
            truth = source.parent / "sample_variance.exr" if source.is_dir() else None
            if truth is None or not truth.is_file():
                print(f"  {fx} {spp} spp: no sample_variance.exr, no `sure` row", file=sys.stderr)
                v = None
            else:
                v = gs.read_rgb(truth) / spp
        else:
            v = gs.read_rgb(d / "noise.exr")
        if v is not None:
            v = np.maximum(v, 0.0)
            sd = np.sqrt(v)
            b = np.random.default_rng(7).choice([-1.0, 1.0], size=c.shape).astype(np.float32)
            pert = variant(d, "perturbed", (c + EPS * sd * b).astype(np.float32))
            errors = []
            for s, f in zip(strengths, outs):
                fp = denoise(gsid, pert, d / f"s{s}-perturbed.exr", args.pipeline, s)
                with np.errstate(divide="ignore", invalid="ignore"):
                    div = np.where(sd > 0, b * (fp - f) / (EPS * sd), 0.0)
                errors.append((((f - c) ** 2 - v + 2 * v * div) / den).mean(-1))
            combine("sure", errors)
    if "halves" in args.methods and source.is_dir() and (source / "color_a.exr").is_file():
        a, bh = gs.read_rgb(source / "color_a.exr"), gs.read_rgb(source / "color_b.exr")
        sa, sb = variant(d, "half_a", a), variant(d, "half_b", bh)
        errors = []
        for s in strengths:
            fa = denoise(gsid, sa, d / f"s{s}-a.exr", args.pipeline, s)
            fb = denoise(gsid, sb, d / f"s{s}-b.exr", args.pipeline, s)
            errors.append((((fa - bh) ** 2 + (fb - a) ** 2) / 2 / den).mean(-1))
        combine("halves", errors)
    if "masked" in args.methods:
        h, w, _ = c.shape
        mask = np.zeros((h, w), bool)
        mask[0::2, 0::2] = True
        p = np.pad(c, ((1, 1), (1, 1), (0, 0)), mode="edge")
        diag = (p[:-2, :-2] + p[:-2, 2:] + p[2:, :-2] + p[2:, 2:]) / 4
        masked = variant(d, "masked", np.where(mask[..., None], diag, c).astype(np.float32))
        errors = []
        for s in strengths:
            fm = denoise(gsid, masked, d / f"s{s}-masked.exr", args.pipeline, s)
            errors.append(np.where(mask, ((fm - c) ** 2 / den).mean(-1), 0.0))
        combine("masked", errors, uniform_filter(mask.astype(float), args.window, mode="nearest"))
    return row


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fixtures", default=",".join(gs.DEFAULT_FIXTURES))
    p.add_argument("--spp", default="1,4,16,64")
    p.add_argument("--pipeline", default="full")
    p.add_argument("--strengths", default="0.5,1,2,4", help="multiples of gsid σ 1 and à-trous σ 0.2; must hold 1")
    p.add_argument("--methods", default="sure,halves,masked", help=f"any of {','.join(METHODS)}")
    p.add_argument("--variance", choices=("noise", "truth"), default="noise", help="v for `sure` (see above)")
    p.add_argument("--window", type=int, default=15, help="side of the box the error estimates are smoothed over")
    p.add_argument("--gsid", type=Path, default=None, help="gsid binary (default: $GSID_BIN or target/release)")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    try:
        args.strengths = [float(s) for s in args.strengths.split(",")]
    except ValueError:
        gs.fail(f"--strengths {args.strengths!r}: not a comma-separated list of numbers")
    if 1.0 not in args.strengths:
        gs.fail("--strengths must hold 1 (the pipeline as it is, whose output weighs the relative errors)")
    args.methods = [m for m in args.methods.split(",") if m]
    bad = [m for m in args.methods if m not in METHODS]
    if bad:
        gs.fail(f"--methods: unknown {', '.join(bad)} (known: {', '.join(METHODS)})")
    if args.window < 1:
        gs.fail(f"--window {args.window}: must be at least 1")
    try:
        import numpy as np
        from scipy.ndimage import uniform_filter
    except ImportError as e:
        gs.fail(f"missing Python package ({e}); run: pip install -r scripts/requirements-compare.txt")
    gsid = gs.gsid_binary(args.gsid)
    cases = gs.cases([f for f in args.fixtures.split(",") if f], gs.parse_spps(args.spp))
    work = Path(tempfile.mkdtemp(prefix="gsid-choice-"))
    rows = []
    try:
        for fx, spp, source, ref in cases:
            d = case_folder(work, fx, spp, Path(source))
            if Path(source).is_file():  # score against the reference's Combined, as written plain
                plain = d / "reference.exr"
                gs.write_rgb(plain, gs.read_pass(ref, *gs.LAYER_PASSES["color"]))
                ref = plain
            row = study_case(gsid, args, d, fx, spp, Path(source), ref, np, uniform_filter)
            rows.append({"fixture": fx, "spp": spp, **row})
            print(f"{fx} {spp} spp: " + ", ".join(f"{k} {v:.5f}" for k, v in row.items()), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"\nMean relMSE over the fixtures (pipeline {args.pipeline}, window {args.window}, sure's v: {args.variance}):")
    common = ("strength 1", "ensemble", "oracle")
    for spp in sorted({r["spp"] for r in rows}):
        at = [r for r in rows if r["spp"] == spp]
        keys = [k for k in at[0] if k not in ("fixture", "spp") and all(k in r for r in at)]
        print(f"  {spp} spp ({len(at)} fixtures): " + ", ".join(f"{k} {np.mean([r[k] for r in at]):.5f}" for k in keys))
        # A method only some fixtures allow (the halves) is compared on those alone.
        for m in args.methods:
            some = [r for r in at if f"{m} soft" in r]
            if some and len(some) < len(at):
                names = ", ".join(r["fixture"] for r in some)
                shown = list(common) + [f"{m} hard", f"{m} soft"]
                print(f"    on the {len(some)} with {m} ({names}): "
                      + ", ".join(f"{k} {np.mean([r[k] for r in some]):.5f}" for k in shown))
    if args.json:
        args.json.write_text(json.dumps({"pipeline": args.pipeline, "strengths": args.strengths,
                                         "window": args.window, "variance": args.variance,
                                         "gsid_commit": gs.git_commit(), "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""How right is gsid's noise estimate? Its `noise` buffer against the variance measured over a still shot's seeds.

Every strength in gsid follows the `noise` stage's estimate of each pixel's variance (docs/ALGORITHM.md §8),
and from the image alone it can only be judged against a truth: a locked-off shot rendered with several
seeds (`../shared/fixtures/cycles-static`: 8 seeds, `sppN/frame.####.exr`, Blender multilayer). Per pixel
the truth is the sample variance of the frames' `Combined` (ddof 1: an unbiased estimate of one frame's
pixel-mean variance, itself noisy with n − 1 degrees of freedom), channel mean. gsid denoises the first
frame alone (`gsid denoise FRAME -o … --save-buffer noise=…`, pipeline and `--set` as given) and its
estimate is read back, channel mean, at the input's exposure.

Printed per spp:
  * the median over pixels of estimate ÷ truth, and its 10/25/75/90 % quantiles. Even an exact estimate
    reads above 1 here: the truth's own χ² noise skews the ratio (for 8 seeds the median of 7/χ²₇ is
    1.10);
  * the same median over Blender's diffuse and glossy pixels apart (glossy: `GlossCol` + `TransCol`
    above half of `DiffCol` + `GlossCol` + `TransCol`, where the passes exist): where a reflection's
    structure is read as noise;
  * the pooled ratio Σ estimate ÷ Σ truth over each 16×16 tile, as a map (rows top to bottom): free of
    the skew, but the truth's rare bright paths (which the estimate leaves to the outlier stage on
    purpose) weigh in it.

With `--bound`, what a right estimate would buy: the first frame denoised again with a truth from the
other frames alone (their variance, ddof 1, independent of the frame's own noise) given as the
renderer's variance (`gsid denoise FRAME --variance FILE`), with gsid's own estimate given so (the
control: it passes through the renderer-variance path's smoothing), with that estimate scaled by each of
`--scales`, and with only its overestimates (above 2× the truth) or only its underestimates (below half)
replaced by the truth; each scored by `gsid eval` (relMSE, SSIM) against the shot's reference.

    python3 scripts/noise_truth.py ../shared/fixtures/cycles-static --spp 4,16,64
    python3 scripts/noise_truth.py ../shared/fixtures/cycles-static --spp 4,16,64 --bound
    python3 scripts/noise_truth.py SHOT --spp 64 --gsid OTHER_BUILD --set noise.source=image --json out.json

Needs numpy and OpenEXR (scripts/requirements-compare.txt). Errors give one line and exit code 2.
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gsidscore as gs  # noqa: E402

TILE = 16


def frames(shot, spp):
    found = sorted((shot / f"spp{spp}").glob("frame.*.exr"))
    if len(found) < 2:
        gs.fail(f"{shot / f'spp{spp}'}: needs at least two frame.####.exr of one still shot (has {len(found)})")
    return found


def glossy_mask(path, np):
    """Pixels whose glossy and transmitted colour outweigh the diffuse, or None without those passes."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        colours = []
        for name in ("DiffCol", "GlossCol", "TransCol"):
            names = [[k for k in ch if k.split(".")[-2:] == [name, c]] for c in gs.CHANNELS]
            if not all(len(n) == 1 for n in names):
                return None
            colours.append(sum(ch[n[0]].pixels.astype(np.float64) for n in names) / 3.0)
    diff, gloss, trans = colours
    total = diff + gloss + trans
    return (gloss + trans) > 0.5 * np.maximum(total, 1e-12)


def measure(gsid, shot, spp, pipeline, sets, np, scales=None):
    paths = frames(shot, spp)
    stack = np.stack([gs.read_pass(p, "Combined", "RGB") for p in paths])
    truth = stack.astype(np.float64).var(axis=0, ddof=1).mean(axis=2)
    with tempfile.TemporaryDirectory(prefix="noise_truth.") as tmp:
        out, noise = Path(tmp) / "out.exr", Path(tmp) / "noise.exr"
        cmd = [str(gsid), "denoise", str(paths[0]), "-p", pipeline, "-o", str(out), "--quiet",
               "--save-buffer", f"noise={noise}"]
        for s in sets:
            cmd += ["--set", s]
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            gs.fail(f"{' '.join(cmd)}: {run.stderr.strip()}")
        estimate = gs.read_rgb(noise).astype(np.float64).mean(axis=2)
    valid = truth > 0
    ratio = estimate[valid] / truth[valid]
    row = {"spp": spp, "frames": len(paths), "pixels": int(valid.sum()),
           "median": float(np.median(ratio)),
           "quantiles": {str(q): float(np.quantile(ratio, q)) for q in (0.1, 0.25, 0.75, 0.9)}}
    glossy = glossy_mask(paths[0], np)
    if glossy is not None:
        for name, m in (("diffuse", ~glossy), ("glossy", glossy)):
            sel = m & valid
            row[f"median_{name}"] = float(np.median(estimate[sel] / truth[sel])) if sel.any() else None
            row[f"share_{name}"] = float(sel.mean())
    if scales is not None:
        row["bound"] = bound_rows(gsid, paths, stack, pipeline, sets, scales, np)
    h, w = truth.shape
    row["tiles"] = [[float(estimate[y:y + TILE, x:x + TILE].sum() / max(truth[y:y + TILE, x:x + TILE].sum(), 1e-30))
                     for x in range(0, w, TILE)] for y in range(0, h, TILE)]
    return row


def reference_of(shot, frame):
    for ref in (shot / "reference" / frame.name, shot / "reference.exr"):
        if ref.is_file():
            return ref
    gs.fail(f"no reference for {frame} (looked for {shot / 'reference' / frame.name} and {shot / 'reference.exr'})")


def bound_rows(gsid, paths, stack, pipeline, sets, scales, np):
    """The first frame denoised with each variance `--bound` names, scored against the reference."""
    frame = paths[0]
    reference = reference_of(frame.parent.parent, frame)
    truth = stack[1:].astype(np.float64).var(axis=0, ddof=1)
    rows = {}
    with tempfile.TemporaryDirectory(prefix="noise_bound.") as tmp:
        tmp = Path(tmp)

        def scored(name, variance=None, save=False):
            out = tmp / f"{len(rows)}.exr"
            cmd = [str(gsid), "denoise", str(frame), "-p", pipeline, "-o", str(out), "--quiet"]
            for s in sets:
                cmd += ["--set", s]
            if variance is not None:
                path = tmp / f"{len(rows)}-variance.exr"
                gs.write_rgb(path, variance.astype(np.float32))
                cmd += ["--variance", str(path)]
            if save:
                cmd += ["--save-buffer", f"noise={tmp / 'estimate.exr'}"]
            run = subprocess.run(cmd, capture_output=True, text=True)
            if run.returncode != 0:
                gs.fail(f"{' '.join(cmd)}: {run.stderr.strip()}")
            score = gs.gsid_eval(gsid, out, reference)
            rows[name] = {"relmse": score["relmse"], "ssim": score["ssim"]}

        scored("image estimate", save=True)
        estimate = gs.read_rgb(tmp / "estimate.exr").astype(np.float64)
        scored("estimate as --variance", estimate)
        scored("truth as --variance", truth)
        for k in scales:
            scored(f"estimate × {k:g}", estimate * k)
        ratio = estimate.mean(axis=2) / np.maximum(truth.mean(axis=2), 1e-30)
        over, under = (ratio > 2.0)[..., None], (ratio < 0.5)[..., None]
        scored("overestimates → truth", np.where(over, truth, estimate))
        scored("underestimates → truth", np.where(under, truth, estimate))
    return rows


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("shot", type=Path, help="still shot folder with sppN/frame.####.exr (several seeds)")
    p.add_argument("--spp", default="4,16,64")
    p.add_argument("--pipeline", default="full")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="passed to gsid denoise")
    p.add_argument("--gsid", type=Path, default=None, help="gsid binary (default: $GSID_BIN or target/release)")
    p.add_argument("--json", type=Path)
    p.add_argument("--bound", action="store_true",
                   help="also denoise the first frame with the other frames' variance as the renderer's, "
                        "and with the estimate scaled or corrected by it (see above)")
    p.add_argument("--scales", default="0.7,0.5,0.35", help="scales of the estimate for --bound")
    args = p.parse_args()
    try:
        scales = [float(k) for k in args.scales.split(",")] if args.bound else None
    except ValueError:
        gs.fail(f"--scales {args.scales!r}: not a comma-separated list of numbers")
    try:
        import numpy as np
    except ImportError as e:
        gs.fail(f"missing Python package ({e}); run: pip install -r scripts/requirements-compare.txt")
    gsid = gs.gsid_binary(args.gsid)
    if not args.shot.is_dir():
        gs.fail(f"{args.shot}: not a folder")
    rows = []
    for spp in gs.parse_spps(args.spp):
        row = measure(gsid, args.shot, spp, args.pipeline, args.set, np, scales)
        rows.append(row)
        q = row["quantiles"]
        parts = [f"spp{spp}: estimate ÷ truth median {row['median']:.2f} "
                 f"(10/25/75/90 %: {q['0.1']:.2f} / {q['0.25']:.2f} / {q['0.75']:.2f} / {q['0.9']:.2f})"]
        if "median_glossy" in row:
            g = row["median_glossy"]
            parts.append(f"diffuse {row['median_diffuse']:.2f}, glossy {'—' if g is None else f'{g:.2f}'} "
                         f"({row['share_glossy'] * 100:.0f} % of pixels)")
        print("; ".join(parts))
        for name, r in row.get("bound", {}).items():
            print(f"  denoised with {name}: relMSE {r['relmse']:.5f}, SSIM {r['ssim']:.4f}")
        print(f"  pooled Σ estimate ÷ Σ truth per {TILE}×{TILE} tile:")
        for tiles in row["tiles"]:
            print("  " + " ".join(f"{t:5.2f}" for t in tiles))
    if args.json:
        args.json.write_text(json.dumps({"shot": str(args.shot), "pipeline": args.pipeline, "set": args.set,
                                         "gsid_commit": gs.git_commit(), "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()

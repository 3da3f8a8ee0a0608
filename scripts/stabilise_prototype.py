#!/usr/bin/env python3
"""Would stabilising the *output* of `--temporal` cut an animated shot's flicker? (issue 38, measured no)

Output stabilisation (as SVGF and TAA do): frame t's final image is a weighted mean of the denoised
frames t−R … t+R, each reprojected to t by the Blender `Vector` pass (chained frame by frame, nearest
pixel's offset, bilinear sample, as `src/temporal/motion.rs` tracks), frame t counting 1. A neighbour
counts by the agreement of its albedo, normal and depth with frame t's (full weight up to the merge's
tolerances: albedo 0.03 + 5 %, normal 0.1, depth 2 %; none from twice that) and, per variant, by its
colour against a residual-noise estimate:

  * `spread`: the spread of the feature-accepted denoised neighbours around frame t's output, pooled
    over 3×3 (full weight up to 1 σ, none from 2; `spread 2-4` from 2 to 4);
  * `local`: frame t's own 3×3 standard deviation (1 to 2 σ);
  * `clamp`: TAA's clamp of each neighbour into frame t's 3×3 mean ± 1 σ, then averaged;
  * `features only`: no colour test;
  * `oracle`: a neighbour counts where the *reference* at its tracked position agrees with frame t's
    reference within 2 %, 5 % or 20 % (no user has it: the most a colour test could pick);
  * `oracle on OIDN`: the 5 % oracle applied to OIDN's per-frame outputs.

For each `--spp`, the shot is denoised by `gsid` frame by frame and with `--temporal R`, OIDN runs per
frame (as `temporal_metrics.py` runs it), and every variant is scored as `temporal_metrics.py` scores:
mean SSIM (`gsid eval`), relMSE, temporal relMSE, relMSE in the motion mask, and the lowest per-frame
SSIM gain over gsid alone. Only for shots with a Blender `Vector` pass.

    scripts/stabilise_prototype.py ../shared/fixtures/cycles-anim --spp 4,16,64
"""

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gsidscore as gs  # noqa: E402
import temporal_metrics as tm  # noqa: E402


def vector_pass(frame):
    import OpenEXR

    with OpenEXR.File(str(frame), separate_channels=True) as f:
        ch = f.channels()
        picked = []
        for c in "XYZW":
            names = [k for k in ch if k.endswith(f"Vector.{c}")]
            if not names:
                gs.fail(f"{frame}: no Vector.{c} channel (the prototype needs Blender's motion pass)")
            picked.append(ch[names[0]].pixels)
    return np.stack(picked, -1).astype(np.float64)


def track(vectors, t, s):
    """Positions (x, y; rows down) of frame t's pixels in frame s; NaN where the chain leaves."""
    h, w = vectors[t].shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pos = np.stack([xs, ys], -1)
    step = -1 if s < t else 1
    j = t
    while j != s:
        xi = np.rint(np.nan_to_num(pos[..., 0], nan=-1)).astype(int)
        yi = np.rint(np.nan_to_num(pos[..., 1], nan=-1)).astype(int)
        ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        o = vectors[j][np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)]
        # Blender: previous at (x + X, y − Y), next at (x − Z, y + W) (docs/FORMATS.md).
        d = np.stack([o[..., 0], -o[..., 1]], -1) if step < 0 else np.stack([-o[..., 2], o[..., 3]], -1)
        pos = np.where(ok[..., None], pos + d, np.nan)
        j += step
    return pos


def bilinear(img, pos):
    h, w = img.shape[:2]
    x, y = pos[..., 0], pos[..., 1]
    valid = np.isfinite(x) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    x, y = np.where(valid, x, 0), np.where(valid, y, 0)
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    out = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
           + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)
    return out, valid


def box3(a):
    p = np.pad(a, ((1, 1), (1, 1)) + ((0, 0),) * (a.ndim - 2), mode="edge")
    h, w = a.shape[:2]
    return sum(p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0


def ramp(r, lo, hi):
    return np.clip((hi - r) / (hi - lo), 0, 1)


def neighbours(shot, outs, t, radius, oracle_tol=None):
    """Each neighbour's reprojected output and its feature (or oracle) weight."""
    n = len(outs)
    for s in range(max(0, t - radius), min(n, t + radius + 1)):
        if s == t:
            continue
        pos = track(shot["vec"], t, s)
        c, valid = bilinear(outs[s].astype(np.float64), pos)
        if oracle_tol is not None:
            r, _ = bilinear(shot["ref"][s].astype(np.float64), pos)
            rt = shot["ref"][t]
            yield c, (valid & (np.abs(r - rt).max(-1) <= oracle_tol * (np.abs(rt).max(-1) + 0.01))).astype(float)
            continue
        a, _ = bilinear(shot["alb"][s], pos)
        nr, _ = bilinear(shot["nrm"][s], pos)
        z, _ = bilinear(shot["dep"][s], pos)
        at, nt, zt = shot["alb"][t], shot["nrm"][t], shot["dep"][t]
        da = np.abs(a - at).max(-1) / (0.03 + 0.05 * at.max(-1))
        dn = np.linalg.norm(nr - nt, axis=-1) / 0.1
        dz = np.abs(z - zt)[..., 0] / (0.02 * np.abs(zt[..., 0]) + 1e-6)
        yield c, valid * ramp(np.maximum(np.maximum(da, dn), dz), 1, 2)


def stabilise(shot, outs, radius, sigma=None, lo=1.0, hi=2.0, clamp=False, oracle_tol=None):
    res = []
    for t in range(len(outs)):
        ot = outs[t].astype(np.float64)
        samples = list(neighbours(shot, outs, t, radius, oracle_tol))
        m = box3(ot)
        local = np.sqrt(np.maximum(box3(ot ** 2) - m ** 2, 0))
        if sigma == "spread":
            num = sum(wt * ((c - ot) ** 2).mean(-1) for c, wt in samples)
            den = sum(wt for _, wt in samples)
            sd = np.sqrt(box3(num[..., None])[..., 0] / np.maximum(box3(den[..., None])[..., 0], 1e-9) / 2)
        else:
            sd = local.mean(-1)
        acc, wsum = ot.copy(), np.ones(ot.shape[:2])
        for c, wt in samples:
            if clamp:
                c = np.clip(c, m - local, m + local)
            elif sigma is not None:
                wt = wt * ramp(np.sqrt(((c - ot) ** 2).mean(-1)) / np.maximum(sd, 1e-9), lo, hi)
            acc += wt[..., None] * c
            wsum += wt
        res.append((acc / wsum[..., None]).astype(np.float32))
    return res


def score(gsid, shot, outs, work):
    ssim = []
    for k, (o, r) in enumerate(zip(outs, shot["ref_paths"])):
        path = work / f"scored.{k}.exr"
        gs.write_rgb(path, o)
        ssim.append(gs.gsid_eval(gsid, path, r)["ssim"])
    refs = shot["ref"]
    return {"ssim": ssim, "relmse": float(np.mean([tm.relmse(o, r) for o, r in zip(outs, refs)])),
            "trelmse": tm.temporal_relmse(outs, refs),
            "mask": float(np.mean([tm.relmse(o, r, m) for o, r, m in zip(outs, refs, shot["masks"])]))}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("shot", type=Path)
    p.add_argument("--spp", default="4,16,64")
    p.add_argument("--radius", type=int, default=2, help="frames each side, of --temporal and of the stabilisation")
    p.add_argument("--pipeline", default="full")
    p.add_argument("--gsid", type=Path, default=None)
    args = p.parse_args(argv)
    gsid = args.gsid or Path(os.environ.get("CARGO_TARGET_DIR", gs.ROOT / "target")) / "release" / "gsid"
    if not gsid.is_file():
        gs.fail(f"no gsid binary at {gsid}")
    print(f"{args.shot.name}: pipeline {args.pipeline}, radius {args.radius}; load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="gsid-stabilise-") as tmp:
        for spp in gs.parse_spps(args.spp):
            folder = args.shot / f"spp{spp}"
            work = Path(tmp) / f"spp{spp}"
            work.mkdir()
            frames = tm.frames_of(folder)
            shot = {"ref": [gs.read_pass(tm.reference_of(args.shot, f), *gs.LAYER_PASSES["color"]) for f in frames],
                    "alb": [gs.read_pass(f, *gs.LAYER_PASSES["albedo"]).astype(np.float64) for f in frames],
                    "nrm": [gs.read_pass(f, *gs.LAYER_PASSES["normal"]).astype(np.float64) for f in frames],
                    "dep": [gs.read_pass(f, "Denoising Depth", "Z")[..., :1].astype(np.float64) for f in frames],
                    "vec": [vector_pass(f) for f in frames],
                    "masks": [tm.motion_mask(f) for f in frames]}
            shot["ref_paths"] = []
            for k, r in enumerate(shot["ref"]):
                shot["ref_paths"].append(work / f"ref.{k}.exr")
                gs.write_rgb(shot["ref_paths"][-1], r)
            common = ["--pipeline", args.pipeline]
            single = [tm.read_any_rgb(o) for o in tm.run_gsid(gsid, folder, work, "single", common, 1)[0]]
            temporal = [tm.read_any_rgb(o) for o in tm.run_gsid(
                gsid, folder, work, "temporal", common + ["--temporal", str(args.radius)], 1)[0]]
            oidn = [tm.read_any_rgb(o) for o in tm.run_oidn(folder, work)]
            r = args.radius
            rows = {"gsid": single, f"gsid --temporal {r}": temporal, "OIDN": oidn,
                    "spread 1-2": stabilise(shot, temporal, r, sigma="spread"),
                    "spread 2-4": stabilise(shot, temporal, r, sigma="spread", lo=2, hi=4),
                    "local 1-2": stabilise(shot, temporal, r, sigma="local"),
                    "clamp 1σ": stabilise(shot, temporal, r, clamp=True),
                    "features only": stabilise(shot, temporal, r),
                    "oracle 2 %": stabilise(shot, temporal, r, oracle_tol=0.02),
                    "oracle 5 %": stabilise(shot, temporal, r, oracle_tol=0.05),
                    "oracle 20 %": stabilise(shot, temporal, r, oracle_tol=0.2),
                    "oracle 5 % on OIDN": stabilise(shot, oidn, r, oracle_tol=0.05)}
            print(f"\n{spp} spp\n| method | SSIM | relMSE | tRelMSE | relMSE in motion mask | min SSIM gain vs gsid |")
            print("|---|---|---|---|---|---|")
            base = None
            for name, outs in rows.items():
                s = score(gsid, shot, outs, work)
                base = base or s["ssim"]
                gain = "" if name == "gsid" else f"{min(a - b for a, b in zip(s['ssim'], base)):+.4f}"
                print(f"| {name} | {np.mean(s['ssim']):.4f} | {s['relmse']:.5f} | {s['trelmse']:.5f} | "
                      f"{s['mask']:.5f} | {gain} |", flush=True)


if __name__ == "__main__":
    main()

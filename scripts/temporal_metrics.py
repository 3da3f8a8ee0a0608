#!/usr/bin/env python3
"""Temporal scores of a shot: gsid frame by frame, gsid `--temporal R`, and OIDN frame by frame.

For a shot folder laid out like `../shared/fixtures/cycles-static` or `cycles-anim` (`sppN/frame.####.exr`
multilayer EXRs, and `reference.exr` for every frame or `reference/frame.####.exr` per frame), at each
`--spp`, prints per method: mean per-frame SSIM and relMSE (`gsid eval --json`, ALGORITHM.md §5), the
lowest per-frame SSIM gain over gsid alone, the temporal relMSE as the fixtures' READMEs define it
(mean over t of mean(((o_t - o_{t-1}) - (r_t - r_{t-1}))^2 / ((r_t^2 + r_{t-1}^2)/2 + 0.01))), and, when the
frames carry a Blender `Vector` pass, the relMSE inside a motion mask (pixels whose motion differs from the
frame's median motion by more than half a pixel, and a border as wide as the largest motion: the moving
objects and the frame's moving edges), plus the median seconds per frame of each gsid run.

    scripts/temporal_metrics.py ../shared/fixtures/cycles-static --spp 4,16,64 --radius 2
    scripts/temporal_metrics.py ../shared/fixtures/cycles-anim --spp 4,16,64 --radius 2 --json out.json

OIDN is run through `pyoidn` as `scripts/compare_denoisers.py` runs it (RT filter, hdr, `Combined` +
`Denoising Albedo` + `Denoising Normal`). Needs numpy, OpenEXR and pyoidn (requirements-compare.txt).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gsidscore as gs  # noqa: E402
from compare_denoisers import oidn_filter  # noqa: E402  (one OIDN setup for every comparison)


def frames_of(folder):
    found = sorted(folder.glob("frame.*.exr"))
    if not found:
        gs.fail(f"no frame.####.exr in {folder}")
    return found


def reference_of(shot, frame):
    per_frame = shot / "reference" / frame.name
    if per_frame.is_file():
        return per_frame
    one = shot / "reference.exr"
    if one.is_file():
        return one
    gs.fail(f"no reference for {frame} (looked for {per_frame} and {one})")


def read_any_rgb(path):
    """R, G, B of an EXR whether plain or layered (`*.R`), HxWx3 float32."""
    import numpy as np
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        picked = []
        for c in gs.CHANNELS:
            names = [k for k in ch if k == c] or [k for k in ch if k.endswith(f"Combined.{c}")] \
                or [k for k in ch if k.split(".")[-1] == c]
            if not names:
                gs.fail(f"{path}: no channel {c}")
            picked.append(ch[names[0]].pixels)
        return np.ascontiguousarray(np.stack(picked, axis=-1), dtype=np.float32)


def motion_mask(frame):
    """Pixels that move unlike the frame's typical motion, and the border new content enters by."""
    import numpy as np
    import OpenEXR

    with OpenEXR.File(str(frame), separate_channels=True) as f:
        ch = f.channels()
        names = {c: [k for k in ch if k.endswith(f"Vector.{c}")] for c in "XYZW"}
        if not all(names.values()):
            return None
        v = {c: ch[n[0]].pixels for c, n in names.items()}
    back = np.hypot(v["X"], v["Y"])
    fore = np.hypot(v["Z"], v["W"])
    mask = np.zeros(back.shape, bool)
    for m in (back, fore):
        if m.max() > 0:
            mask |= np.abs(m - np.median(m)) > 0.5
    edge = int(np.ceil(max(back.max(), fore.max()))) + 1
    mask[:edge, :] = mask[-edge:, :] = True
    mask[:, :edge] = mask[:, -edge:] = True
    return mask


def relmse(out, ref, mask=None):
    import numpy as np

    e = (out - ref) ** 2 / (ref ** 2 + 0.01)
    return float(e[mask].mean() if mask is not None else e.mean())


def temporal_relmse(outs, refs):
    import numpy as np

    vals = []
    for t in range(1, len(outs)):
        d = (outs[t] - outs[t - 1]) - (refs[t] - refs[t - 1])
        vals.append(float(np.mean(d ** 2 / ((refs[t] ** 2 + refs[t - 1] ** 2) / 2 + 0.01))))
    return float(np.mean(vals))


def run_gsid(gsid, folder, work, name, extra, runs):
    out = work / f"{name}.####.exr"
    cmd = [str(gsid), "denoise", str(folder / "frame.####.exr"), "-o", str(out), "-q"] + extra
    times = []
    for _ in range(runs):
        for old in work.glob(f"{name}.*.exr"):
            old.unlink()
        start = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        times.append(time.perf_counter() - start)
        if proc.returncode != 0:
            gs.fail(f"{' '.join(cmd)}: {proc.stderr.strip()}", proc.returncode)
    times.sort()
    return [work / f"{name}.{f.name.split('.')[1]}.exr" for f in frames_of(folder)], times[len(times) // 2], cmd


def run_oidn(folder, work):
    import numpy as np
    import pyoidn

    device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
    device.commit()
    outs = []
    for frame in frames_of(folder):
        color = np.ascontiguousarray(np.maximum(np.nan_to_num(gs.read_pass(frame, *gs.LAYER_PASSES["color"])), 0))
        albedo = gs.read_pass(frame, *gs.LAYER_PASSES["albedo"])
        normal = gs.read_pass(frame, *gs.LAYER_PASSES["normal"])
        output = np.zeros_like(color)
        flt = oidn_filter(device, color, albedo, normal, output)
        flt.execute()
        flt.release()
        path = work / f"oidn.{frame.name.split('.')[1]}.exr"
        gs.write_rgb(path, output)
        outs.append(path)
    return outs


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("shot", type=Path, help="shot folder with sppN/frame.####.exr")
    p.add_argument("--spp", default="4,16,64")
    p.add_argument("--radius", type=int, default=2)
    p.add_argument("--pipeline", default="full")
    p.add_argument("--runs", type=int, default=1, help="runs of each gsid command; the median time is kept")
    p.add_argument("--gsid", type=Path, default=None, help="gsid binary (default: $CARGO_TARGET_DIR or target/release)")
    p.add_argument("--no-oidn", action="store_true")
    p.add_argument("--json", type=Path)
    p.add_argument("--keep", type=Path, default=None,
                   help="keep every output (inputs, references, gsid, gsid --temporal, OIDN) in this folder")
    args = p.parse_args(argv)
    target = Path(os.environ.get("CARGO_TARGET_DIR", gs.ROOT / "target"))
    gsid = args.gsid or target / "release" / "gsid"
    if not gsid.is_file():
        gs.fail(f"no gsid binary at {gsid}")
    load = os.getloadavg()
    results = {"shot": str(args.shot), "radius": args.radius, "pipeline": args.pipeline,
               "load_average_start": load, "spp": {}}
    mask_note = False
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="gsid-temporal-") as scratch:
        tmp = scratch if args.keep is None else args.keep
        for spp in gs.parse_spps(args.spp):
            folder = args.shot / f"spp{spp}"
            work = Path(tmp) / f"spp{spp}"
            work.mkdir(exist_ok=True)
            frames = frames_of(folder)
            refs_path = [reference_of(args.shot, f) for f in frames]
            refs = [gs.read_pass(r, *gs.LAYER_PASSES["color"]) for r in refs_path]
            plain_refs = []
            for k, r in enumerate(refs):
                path = work / f"ref.{k}.exr"
                gs.write_rgb(path, r)
                plain_refs.append(path)
            masks = [motion_mask(f) for f in frames]
            inputs = []
            for k, f in enumerate(frames):
                path = work / f"input.{k}.exr"
                gs.write_rgb(path, gs.read_pass(f, *gs.LAYER_PASSES["color"]))
                inputs.append(path)
            methods = {"input": (inputs, None)}
            common = ["--pipeline", args.pipeline]
            single, t1, _ = run_gsid(gsid, folder, work, "single", common, args.runs)
            methods["gsid"] = (single, t1 / len(frames))
            temporal, t2, cmd = run_gsid(gsid, folder, work, "temporal",
                                         common + ["--temporal", str(args.radius)], args.runs)
            methods[f"gsid --temporal {args.radius}"] = (temporal, t2 / len(frames))
            if not args.no_oidn:
                methods["OIDN"] = (run_oidn(folder, work), None)
            rows = {}
            single_ssim = None
            for name, (paths, secs) in methods.items():
                scores = [gs.gsid_eval(gsid, o, r) for o, r in zip(paths, plain_refs)]
                ssim = [s["ssim"] for s in scores]
                outs = [read_any_rgb(o) for o in paths]
                row = {
                    "ssim": sum(ssim) / len(ssim),
                    "relmse": sum(s["relmse"] for s in scores) / len(scores),
                    "ssim_per_frame": ssim,
                    "trelmse": temporal_relmse(outs, refs),
                    "seconds_per_frame": secs,
                }
                if all(m is not None for m in masks):
                    mask_note = True
                    row["relmse_motion_mask"] = sum(relmse(o, r, m) for o, r, m in zip(outs, refs, masks)) / len(outs)
                if name == "gsid":
                    single_ssim = ssim
                if single_ssim is not None and name != "gsid":
                    row["min_ssim_gain_over_gsid"] = min(a - b for a, b in zip(ssim, single_ssim))
                rows[name] = row
            results["spp"][spp] = rows
    results["load_average_end"] = os.getloadavg()
    print(f"{args.shot.name}: pipeline {args.pipeline}, radius {args.radius}; load average "
          f"{results['load_average_start'][0]:.2f} at start, {results['load_average_end'][0]:.2f} at end")
    head = "| spp | method | SSIM | relMSE | tRelMSE | min SSIM gain vs gsid |"
    if mask_note:
        head += " relMSE in motion mask |"
    head += " s/frame |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for spp, rows in results["spp"].items():
        for name, r in rows.items():
            gain = r.get("min_ssim_gain_over_gsid")
            cells = [str(spp), name, f"{r['ssim']:.4f}", f"{r['relmse']:.4f}", f"{r['trelmse']:.4f}",
                     "" if gain is None else f"{gain:+.4f}"]
            if mask_note:
                cells.append(f"{r['relmse_motion_mask']:.4f}")
            cells.append("" if r["seconds_per_frame"] is None else f"{r['seconds_per_frame']:.3f}")
            print("| " + " | ".join(cells) + " |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

"""Compare gsid with Intel Open Image Denoise and BM3D on the same fixtures, scored the same way.

In one run, for every chosen fixture and sample count (render set fixtures/<name>/spp<N>/), this
denoises the noisy colour with

  * Intel Open Image Denoise (PyPI `pyoidn`, which ships OIDN's CPU library): the `RT` filter, hdr=true,
    colour + albedo + normal (first-hit auxiliary buffers, as OIDN recommends), CPU device, default
    quality (high) and cleanAux=false (our albedo/normal are averaged over the same few samples, so
    they carry some noise of their own);
  * BM3D (PyPI `bm3d`, `bm3d.bm3d_rgb`), a Gaussian-noise denoiser, on a display-range view of the
    colour (see "BM3D" below);
  * gsid's named pipelines (`--pipelines`, default `fast balanced quality full`; a name that
    `gsid pipelines` does not list is skipped with a note), on colour + albedo + normal + depth only,
    the buffers most renderers write (a temporary folder links just those four files, so a
    `variance.exr` or material/shadow buffer in the fixture is not used); with `--noise-buffers`
    each pipeline also runs with `variance.exr`, `color_a.exr` and `color_b.exr` added where the set
    has them (rows labelled `NAME`+var),

and scores every output, plus the noisy input, with the repository's own metric
(`target/release/gsid eval IMAGE.exr --reference REF.exr --json`: SSIM on the clipped sRGB view,
relMSE on linear HDR, docs/ALGORITHM.md §5), so all methods are judged by identical code. OIDN and BM3D
outputs are written as float32 EXR to a temporary folder first. The result is a markdown table on
stdout (progress goes to stderr), then a summary table: mean SSIM and mean relMSE over the fixtures
per sample count and method, with each method's gap to OIDN (ΔSSIM, relMSE ratio); `--json PATH`
also writes every row and the run's header as JSON.

The Blender Cycles multilayer renders `cycles-studio`, `cycles-glass` and `cycles-fog` are read from
../shared/fixtures/NAME/spp<N>.exr when that folder exists, else from fixtures/NAME/ (only cycles-studio's
spp4 is bundled). gsid reads the multilayer file directly;
OIDN gets its `Combined`, `Denoising Albedo` and `Denoising Normal` passes, extracted here, and the
noisy input and the reference are scored by their `Combined`.

Install and run, from the repository root (Python 3.11):

    pip install -r scripts/requirements-compare.txt && python3 scripts/compare_denoisers.py
    python3 scripts/compare_denoisers.py --fixtures mitsuba-cornell --spp 1,4,16,64 --pipelines sid gsid full

Options: --fixtures a,b (default: mitsuba-cornell,cornell,caustics,textured,detail and the Blender
renders cycles-studio,cycles-glass,cycles-fog), --spp 1,4 (default 1,4,16,64), --pipelines NAME..., --noise-buffers, --runs N (timed
runs of OIDN and gsid, default 5), --bm3d-runs N (default 1; 0 or --no-bm3d skips BM3D),
--bm3d-curve srgb|reinhard, --no-build, --json PATH, --keep DIR (keep the outputs).

What "seconds" means for each method, and why:

  * OIDN: the median of --runs executions of the already committed filter (oidnExecuteFilter only).
    The device and the filter are created, given their images and committed beforehand, as a renderer
    that denoises every frame keeps them. This is the figure OIDN is usually quoted by, and it is the
    best case for OIDN. The column "process s" also gives the whole-process cost of a one-shot
    denoise (a fresh `python3` that imports pyoidn, reads the three EXRs, creates device and filter,
    runs once and writes the EXR; median of --runs) for a like-for-like comparison with gsid's figure.
  * BM3D: the bm3d_rgb call only (median of --bm3d-runs, default 1, because it takes seconds); the
    tone curve, the noise estimate and EXR I/O are left out. BM3D is a reference point for quality,
    not a fast method.
  * gsid: the wall time of the whole `gsid denoise SETDIR --pipeline NAME -o OUT.exr --quiet`
    process, reading six EXRs and writing one included (median of --runs). That is how a user or a
    render farm calls it, and gsid has no library entry point that keeps state between frames.
    It therefore slightly flatters OIDN's "seconds" relative to gsid's; compare "process s" too.

OIDN and gsid both use every core by default; the header prints the core count, the CPU model and
the load average, because this machine is shared and a busy neighbour slows every figure.

BM3D: BM3D assumes additive white Gaussian noise of known σ on an image in a fixed range, and path
tracing gives neither (the noise is signal dependent and heavy tailed, and the colour is HDR). It is
run on the display view the metric scores, clip to [0, 1] then the sRGB transfer curve (default
`--bm3d-curve srgb`), and the result is sent back through the inverse curve to linear. So anything
brighter than 1 (the light itself) comes back as 1, which costs relMSE at the light but nothing in
SSIM, whose view clips there anyway. `--bm3d-curve reinhard` (x/(1+x), inverted as y/(1-y), keeps
HDR) is the alternative; on mitsuba-cornell, caustics and textured at 4 spp it gave lower SSIM
(0.54/0.55/0.56 against 0.60/0.61/0.66 with sRGB) and higher relMSE, which is why sRGB is the
default. σ is estimated from the noisy image alone, never from the reference: scikit-image's
wavelet (median absolute deviation) estimator `estimate_sigma` on the tone-mapped image, per
channel, averaged. Being a robust estimator, it tracks the bulk of the noise and ignores the
fireflies (on mitsuba-cornell at 4 spp it gives 0.045 where the standard deviation of
(noisy − reference) in the same view is 0.070), so BM3D leaves the bright outliers largely in place.

Errors: a missing fixture, sample count, reference, gsid binary or Python package gives a one-line
message on stderr and exit code 2.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gsidscore import (DEFAULT_FIXTURES, GSID_BUFFERS, LAYER_PASSES, NOISE_BUFFERS, ROOT, fail, gsid_eval,
                       gsid_pipelines, git_commit, linked_set, note, parse_spps, read_pass, read_rgb,
                       require_gsid, scored_case, write_rgb)
from gsidscore import cases as fixture_cases
from user_metrics import albedo_noise_correlation, brightness_percent, dark_dot_count, firefly_count

DEFAULT_PIPELINES = ["fast", "balanced", "quality", "full"]


# ---------------------------------------------------------------------------- inputs

def sanitize_color(color):
    """NaN/Inf/negative colour to 0, as gsid does before denoising (the fixtures have none)."""
    import numpy as np

    color = np.nan_to_num(color, nan=0.0, posinf=0.0, neginf=0.0)
    return np.ascontiguousarray(np.maximum(color, 0.0), dtype=np.float32)


# ---------------------------------------------------------------------------- OIDN

def oidn_filter(device, color, albedo, normal, output):
    """An RT filter with hdr=true on colour + albedo + normal, committed and ready to execute."""
    import pyoidn

    flt = pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)
    flt.set_image(pyoidn.OIDN_IMAGE_COLOR, color, pyoidn.OIDN_FORMAT_FLOAT3)
    flt.set_image(pyoidn.OIDN_IMAGE_ALBEDO, albedo, pyoidn.OIDN_FORMAT_FLOAT3)
    flt.set_image(pyoidn.OIDN_IMAGE_NORMAL, normal, pyoidn.OIDN_FORMAT_FLOAT3)
    flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, output, pyoidn.OIDN_FORMAT_FLOAT3)
    # set_bool, not set_value: pyoidn's set_value sends a bool through set_int.
    flt.set_bool("hdr", True)
    flt.commit()
    return flt


def oidn_check(device, what):
    err = device.get_error()
    if err is not None:
        fail(f"OIDN {what}: {err}", 1)


def load_set(setdir):
    """Colour, albedo and normal of a render set folder, or of a Blender multilayer file."""
    setdir = Path(setdir)
    if setdir.is_file():
        color, albedo, normal = (read_pass(setdir, *LAYER_PASSES[b]) for b in ("color", "albedo", "normal"))
    else:
        color, albedo, normal = (read_rgb(setdir / f"{b}.exr") for b in ("color", "albedo", "normal"))
    return sanitize_color(color), albedo, normal


def oidn_denoise(device, setdir, out_path, runs):
    """Denoise with a committed filter; returns the median seconds of `runs` executions."""
    import numpy as np

    color, albedo, normal = load_set(setdir)
    output = np.zeros_like(color)
    flt = oidn_filter(device, color, albedo, normal, output)
    oidn_check(device, f"filter setup for {setdir}")
    times = []
    try:
        for _ in range(runs):
            start = time.perf_counter()
            flt.execute()
            times.append(time.perf_counter() - start)
        oidn_check(device, f"filter execution on {setdir}")
    finally:
        flt.release()
    write_rgb(out_path, output)
    return statistics.median(times), times


def oidn_once(setdir, out_path):
    """One-shot denoise in this process (run as a subprocess to time the whole process)."""
    import numpy as np
    import pyoidn

    device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
    device.commit()
    color, albedo, normal = load_set(Path(setdir))
    output = np.zeros_like(color)
    flt = oidn_filter(device, color, albedo, normal, output)
    flt.execute()
    oidn_check(device, f"one-shot denoise of {setdir}")
    flt.release()
    device.release()
    write_rgb(out_path, output)


# ---------------------------------------------------------------------------- BM3D

def srgb(x):
    import numpy as np

    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_inverse(y):
    import numpy as np

    y = np.clip(y, 0.0, 1.0)
    return np.where(y <= 0.04045, y / 12.92, np.power((y + 0.055) / 1.055, 2.4))


def reinhard(x):
    return x / (1.0 + x)


def reinhard_inverse(y):
    import numpy as np

    y = np.clip(y, 0.0, 0.999)  # 0.999 ↔ 999 in linear, far above any fixture's light
    return y / (1.0 - y)


CURVES = {"srgb": (srgb, srgb_inverse), "reinhard": (reinhard, reinhard_inverse)}


def bm3d_denoise(setdir, out_path, runs, curve):
    """BM3D on the tone-mapped colour; returns (median seconds of the bm3d_rgb call, σ, times)."""
    import bm3d
    import numpy as np
    from skimage.restoration import estimate_sigma

    forward, inverse = CURVES[curve]
    noisy = forward(load_set(setdir)[0].astype(np.float64))
    sigma = float(np.mean(estimate_sigma(noisy, channel_axis=-1, average_sigmas=False)))
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        denoised = bm3d.bm3d_rgb(noisy, sigma)
        times.append(time.perf_counter() - start)
    write_rgb(out_path, inverse(denoised))
    return statistics.median(times), sigma, times


# ---------------------------------------------------------------------------- gsid

def gsid_denoise(gsid, setdir, pipeline, out_path, runs):
    times = []
    for _ in range(runs):
        cmd = [str(gsid), "denoise", str(setdir), "--pipeline", pipeline, "-o", str(out_path), "--quiet"]
        start = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        times.append(time.perf_counter() - start)
        if proc.returncode != 0:
            fail(f"{' '.join(cmd)}: {proc.stderr.strip()}", proc.returncode)
    return statistics.median(times), times


# ---------------------------------------------------------------------------- run

def cpu_model():
    """The CPU's model name and its widest vector ISA (OIDN's CPU kernels depend on it)."""
    model, flags = None, set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and model is None:
                model = line.split(":", 1)[1].strip()
            elif line.startswith("flags") and not flags:
                flags = set(line.split(":", 1)[1].split())
    except OSError:
        pass
    if model is None:
        import platform

        model = platform.processor() or "unknown CPU"
    isa = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else None
    return f"{model} ({isa})" if isa else model


def parse_args(argv):
    p = argparse.ArgumentParser(description="Compare gsid with Open Image Denoise and BM3D (see the file's docstring).")
    p.add_argument("--fixtures", default=",".join(DEFAULT_FIXTURES), help="comma-separated fixture names, or folders as gsid render writes them (a name with a slash)")
    p.add_argument("--spp", default="1,4,16,64", help="comma-separated sample counts (folders spp<N>)")
    p.add_argument("--pipelines", nargs="+", default=DEFAULT_PIPELINES, help="gsid pipeline names")
    p.add_argument("--runs", type=int, default=5, help="timed runs of OIDN and gsid (median)")
    p.add_argument("--bm3d-runs", type=int, default=1, help="timed runs of BM3D (median; 0 skips it)")
    p.add_argument("--no-bm3d", action="store_true", help="skip BM3D (same as --bm3d-runs 0)")
    p.add_argument("--noise-buffers", action="store_true",
                   help="also run gsid with variance/color_a/color_b where the set has them (rows NAME+var)")
    p.add_argument("--bm3d-curve", choices=sorted(CURVES), default="srgb", help="tone curve BM3D runs under")
    p.add_argument("--no-build", action="store_true", help="do not run cargo build first")
    p.add_argument("--json", metavar="PATH", help="also write the rows as JSON")
    p.add_argument("--keep", metavar="DIR", help="keep the denoised images in DIR")
    p.add_argument("--oidn-once", nargs=2, metavar=("SETDIR", "OUT"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.runs < 1 or args.bm3d_runs < 0:
        fail("--runs must be at least 1 and --bm3d-runs at least 0")
    if args.no_bm3d:
        args.bm3d_runs = 0
    return args


def summary(rows, spps):
    """Means over the fixtures per spp and method, and each method's gap to OIDN."""
    lines = ["| spp | method | fixtures | SSIM | PSNR | relMSE | ΔSSIM to OIDN | ΔPSNR | relMSE / OIDN's "
             "| brightness | fireflies (sum) | dark dots (sum) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for spp in spps:
        at = [r for r in rows if r["spp"] == spp]
        methods = list(dict.fromkeys(r["method"] for r in at))
        means = {}
        for m in methods:
            rs = [r for r in at if r["method"] == m]
            means[m] = (len(rs), *(statistics.mean(r[k] for r in rs) for k in ("ssim", "psnr", "relmse",
                                                                                 "brightness_pct")),
                        sum(r["fireflies"] for r in rs), sum(r.get("dark_dots", 0) for r in rs))
        oidn = next((means[m] for m in methods if m.startswith("OIDN")), None)
        for m in methods:
            n, ssim, psnr, relmse, bright, flies, dots = means[m]
            if oidn and not m.startswith("OIDN") and n == oidn[0]:
                gap = f"{ssim - oidn[1]:+.4f} | {psnr - oidn[2]:+.2f} | {relmse / oidn[3]:.2f}×"
            else:
                gap = "— | — | —"
            lines.append(f"| {spp} | {m} | {n} | {ssim:.4f} | {psnr:.2f} | {relmse:.5f} | {gap} | {bright:+.1f} % "
                         f"| {flies} | {dots} |")
    return lines


def main(argv=None):
    args = parse_args(argv)
    if args.oidn_once:
        oidn_once(*args.oidn_once)
        return 0

    # Check every input before any slow work.
    spps = parse_spps(args.spp)
    fixtures = [f.strip() for f in args.fixtures.split(",") if f.strip()]
    cases = fixture_cases(fixtures, spps)
    try:
        import numpy as np
        import OpenEXR  # noqa: F401
        if args.bm3d_runs:
            import bm3d  # noqa: F401
        import pyoidn
        import skimage  # noqa: F401
    except ImportError as e:
        fail(f"missing Python package ({e}); run: pip install -r scripts/requirements-compare.txt")

    gsid = require_gsid(not args.no_build)

    available = gsid_pipelines(gsid)
    pipelines = [p for p in args.pipelines if p in available]
    skipped = [p for p in args.pipelines if p not in available]
    for p in skipped:
        note(f"note: gsid has no pipeline {p!r} (gsid pipelines lists: {', '.join(available)}); skipped")

    device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
    device.commit()
    oidn_check(device, "CPU device creation")
    oidn_version = device.get_int("version")
    oidn_threads = device.get_int("numThreads")
    load_start = os.getloadavg()

    from importlib.metadata import version as pkg_version

    header = {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "load_average_start": [round(x, 2) for x in load_start],
        "oidn": f"{oidn_version // 10000}.{oidn_version // 100 % 100}.{oidn_version % 100}",
        "oidn_threads": oidn_threads,
        "pyoidn": pkg_version("pyoidn"),
        "bm3d": pkg_version("bm3d") if args.bm3d_runs else None,
        "numpy": np.__version__,
        "python": sys.version.split()[0],
        "gsid_commit": git_commit(),
        "runs": args.runs,
        "bm3d_runs": args.bm3d_runs,
        "bm3d_curve": args.bm3d_curve,
        "pipelines_run": pipelines,
        "pipelines_skipped": skipped,
    }

    rows = []
    tmp = tempfile.TemporaryDirectory(prefix="compare_denoisers.")
    outdir = Path(args.keep) if args.keep else Path(tmp.name)
    outdir.mkdir(parents=True, exist_ok=True)

    references = {}  # each reference read once, not once a method

    def add(fx, spp, method, image, ref, seconds=None, process=None, albedos=None, **extra):
        score = gsid_eval(gsid, image, ref)
        if ref not in references:
            references[ref] = read_rgb(ref)
        out_rgb, ref_rgb = read_rgb(image), references[ref]
        corr = albedo_noise_correlation(out_rgb, ref_rgb, *albedos) if albedos else None
        row = {"fixture": fx, "spp": spp, "method": method, "ssim": score["ssim"], "psnr": score["psnr"],
               "relmse": score["relmse"], "brightness_pct": brightness_percent(out_rgb, ref_rgb),
               "fireflies": firefly_count(out_rgb, ref_rgb), "dark_dots": dark_dot_count(out_rgb, ref_rgb),
               "albedo_noise_corr": corr,
               "seconds": seconds, "process_seconds": process, **extra}
        rows.append(row)
        secs = "" if seconds is None else f" {seconds:.3f} s"
        note(f"  {fx} spp{spp} {method}: SSIM {row['ssim']:.4f} PSNR {row['psnr']:.2f} relMSE {row['relmse']:.5f} "
             f"bright {row['brightness_pct']:+.1f}% fireflies {row['fireflies']} dark dots {row['dark_dots']}{secs}")

    for fx, spp, setdir, ref in cases:
        note(f"{fx} spp{spp}:")
        stem = outdir / f"{fx}-spp{spp}"
        albedos = None
        if setdir.is_file():
            albedos = (read_pass(setdir, *LAYER_PASSES["albedo"]), read_pass(ref, *LAYER_PASSES["albedo"]))
        gsid_input, noisy, ref = scored_case(setdir, ref, stem)
        inputs = {"": gsid_input}
        if args.noise_buffers and setdir.is_dir() and any((setdir / f"{b}.exr").is_file() for b in NOISE_BUFFERS):
            inputs["+var"] = linked_set(setdir, GSID_BUFFERS + NOISE_BUFFERS, Path(f"{stem}-set-var"))
        add(fx, spp, "input (noisy)", noisy, ref, albedos=albedos)

        out = Path(f"{stem}-oidn.exr")
        secs, times = oidn_denoise(device, setdir, out, args.runs)
        ptimes = []
        for _ in range(args.runs):
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--oidn-once", str(setdir),
                                   f"{stem}-oidn-process.exr"], capture_output=True, text=True, cwd=ROOT)
            ptimes.append(time.perf_counter() - start)
            if proc.returncode != 0:
                fail(f"one-shot OIDN process on {setdir}: {proc.stderr.strip()}", 1)
        add(fx, spp, "OIDN (RT, hdr, albedo+normal)", out, ref, secs, statistics.median(ptimes), albedos=albedos,
            times=times, process_times=ptimes)

        if args.bm3d_runs:
            out = Path(f"{stem}-bm3d.exr")
            secs, sigma, times = bm3d_denoise(setdir, out, args.bm3d_runs, args.bm3d_curve)
            add(fx, spp, f"BM3D ({args.bm3d_curve})", out, ref, secs, albedos=albedos, times=times, sigma=sigma)

        for p in pipelines:
            for suffix, gsid_input in inputs.items():
                out = Path(f"{stem}-gsid-{p}{suffix}.exr")
                secs, times = gsid_denoise(gsid, gsid_input, p, out, args.runs)
                add(fx, spp, f"gsid `{p}`{suffix}", out, ref, secs, secs, albedos=albedos, times=times)

    device.release()
    header["load_average_end"] = [round(x, 2) for x in os.getloadavg()]

    def fmt(x, spec):
        return "—" if x is None else format(x, spec)

    print(f"{header['cpu']}, {header['cores']} cores; load average {header['load_average_start'][0]:.2f} "
          f"at start, {header['load_average_end'][0]:.2f} at end. OIDN {header['oidn']} (pyoidn "
          f"{header['pyoidn']}, {oidn_threads} threads), bm3d {header['bm3d'] or 'not run'}, "
          f"gsid {header['gsid_commit']}.")
    if skipped:
        print(f"Skipped gsid pipelines (not listed by `gsid pipelines`): {', '.join(skipped)}.")
    print()
    print("| fixture | spp | method | SSIM | PSNR | relMSE | brightness³ | fireflies³ | dark dots³ "
          "| albedo-noise corr.³ | seconds¹ | process s² |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['fixture']} | {r['spp']} | {r['method']} | {r['ssim']:.4f} | {r['psnr']:.2f} | "
              f"{r['relmse']:.5f} | {r['brightness_pct']:+.1f} % | {r['fireflies']} | {r['dark_dots']} | "
              f"{fmt(r['albedo_noise_corr'], '+.3f')} | {fmt(r['seconds'], '.3f')} | "
              f"{fmt(r['process_seconds'], '.2f')} |")
    print()
    print()
    print("Means over the fixtures (gsid on colour + albedo + normal + depth; `+var` adds the noise buffers):")
    print()
    print("\n".join(summary(rows, spps)))
    print()
    bm3d_note = f" BM3D: the bm3d_rgb call only, median of {args.bm3d_runs}." if args.bm3d_runs else ""
    print(f"¹ OIDN: oidnExecuteFilter only, device and filter created and committed beforehand, median of "
          f"{args.runs}.{bm3d_note} gsid: wall time of the whole "
          f"`gsid denoise SET --pipeline NAME -o OUT.exr --quiet` process (EXR reading and writing included), "
          f"median of {args.runs}.")
    print(f"² Whole process of a one-shot denoise, median of {args.runs}: for OIDN a fresh python3 that imports "
          f"pyoidn, reads color/albedo/normal, creates device and filter, runs once and writes the EXR; for gsid "
          f"the same figure as ¹. Scores: `gsid eval --json` against fixtures/NAME/reference.exr (SSIM on the "
          f"clipped sRGB view, relMSE on linear HDR)."
          + " ³ scripts/user_metrics.py: mean luminance against the reference's; pixels above 4× a smooth "
          "reference; pixels below a quarter of a bright (at least the median), smooth reference; "
          "correlation of the output's error with the albedo's noise (multilayer fixtures)."
          + (f" BM3D: σ̂ estimated from the noisy image (skimage estimate_sigma, channel mean) under the "
             f"{args.bm3d_curve} curve (its σ̂ is in the JSON)." if args.bm3d_runs else ""))

    if args.json:
        Path(args.json).write_text(json.dumps({"header": header, "rows": rows}, indent=1) + "\n")
        note(f"wrote {args.json}")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())

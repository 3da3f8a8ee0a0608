"""Speed of gsid's `balanced` and `full` against Intel Open Image Denoise on one 1024×1024 render at 4 spp.

Issue 13 asks for `balanced` no slower than OIDN's CPU filter and `full` at most 2.5× it, side by side in
one run, median of 5. This script:

  1. renders the set once (cached in `--cache`, default target/speed-set): fixtures/textured/scene.toml
     with width and height set to 1024, `gsid render SCENE -o DIR --spp 4 --reference-spp 0`; a cached set
     is reused when its scene file is unchanged;
  2. times, in one run and on the same colour + albedo + normal (+ depth for gsid) buffers:
       * OIDN (pyoidn; the RT filter, hdr, albedo + normal, CPU device, set up exactly as
         scripts/compare_denoisers.py does): "filter" is oidnExecuteFilter alone on a committed filter,
         "process" a fresh python3 that imports pyoidn, reads the EXRs, denoises once and writes the EXR;
       * gsid `balanced` and `full`: the whole `gsid denoise SET --pipeline NAME -o OUT.exr --quiet --json`
         process, default threads, on a folder that links only color/albedo/normal/depth ("process"),
         and within it the pipeline alone ("filter": its `seconds.pipeline`, without starting the process
         and reading and writing the EXRs), the counterpart of OIDN's "filter";
     each the median of `--runs` (default 5), in rounds: one OIDN filter execution and one run of every
     gsid pipeline and binary per round, so all see the same drift of a shared machine's load;
  3. prints a markdown table with every time's ratio to OIDN's filter and to OIDN's process time, and
     for gsid's rows the median of each round's ratio to that round's OIDN filter time (the machine's
     drift between rounds cancels in it), under a header with the CPU, core count and the load average
     at start and end (a shared machine slows every figure).

Usage (from the repository root, after `cargo build --release`):

    python3 scripts/speed_vs_oidn.py [--runs 5] [--cache target/speed-set] [--gsid target/release/gsid ...]
        [--pipelines balanced full] [--json PATH]

`--gsid A B` times several builds (e.g. an older commit's binary and this tree's) in the same run, so
before and after see the same load; their runs alternate, and rows name the binary.
Errors (missing binary, packages, failed render or denoise) print one line and exit with code 2.
"""

import argparse
import filecmp
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_denoisers as cd  # noqa: E402  (the same OIDN setup, EXR I/O and machine header)

ROOT = cd.ROOT
fail = cd.fail  # gsidscore's: one line naming this script, exit 2
SCENE = ROOT / "fixtures" / "textured" / "scene.toml"
SIZE = 1024
SPP = 4


def sized_scene(into):
    """fixtures/textured/scene.toml with its [render] width and height set to SIZE."""
    lines, in_render = [], False
    for line in SCENE.read_text().splitlines():
        stripped = line.strip()
        if stripped.startswith("["):
            in_render = stripped == "[render]"
        key = stripped.split("=", 1)[0].strip()
        if in_render and key in ("width", "height"):
            line = f"{key} = {SIZE}"
        lines.append(line)
    into.write_text("\n".join(lines) + "\n")


def render_set(gsid, cache):
    """The cached render set folder (rendered when missing or when the scene changed)."""
    cache.mkdir(parents=True, exist_ok=True)
    scene = cache / "scene.toml"
    fresh = cache / "scene.new.toml"
    sized_scene(fresh)
    setdir = cache / "render" / f"spp{SPP}"
    if scene.is_file() and filecmp.cmp(scene, fresh, shallow=False) and (setdir / "color.exr").is_file():
        fresh.unlink()
        return setdir
    shutil.rmtree(cache / "render", ignore_errors=True)
    fresh.replace(scene)
    cd.note(f"rendering {SIZE}×{SIZE} at {SPP} spp into {cache / 'render'} (once) ...")
    cmd = [str(gsid), "render", str(scene), "-o", str(cache / "render"), "--spp", str(SPP),
           "--reference-spp", "0", "--quiet"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        scene.unlink(missing_ok=True)
        fail(f"{' '.join(cmd)}: {proc.stderr.strip()}")
    return setdir


def oidn_process(setdir, out, runs):
    """Median wall time of a fresh python3 doing one whole OIDN denoise (compare_denoisers --oidn-once)."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "compare_denoisers.py"), "--oidn-once",
                               str(setdir), str(out)], capture_output=True, text=True, cwd=ROOT)
        times.append(time.perf_counter() - start)
        if proc.returncode != 0:
            fail(f"one-shot OIDN process on {setdir}: {proc.stderr.strip()}")
    return statistics.median(times), times


def gsid_run(gsid, setdir, pipeline, out_path):
    """One `gsid denoise` process: its wall time, and its pipeline's own time from its --json report."""
    cmd = [str(gsid), "denoise", str(setdir), "--pipeline", pipeline, "-o", str(out_path), "--quiet", "--json"]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        fail(f"{' '.join(cmd)}: {proc.stderr.strip()}", proc.returncode)
    try:
        return wall, float(json.loads(proc.stdout)["seconds"]["pipeline"])
    except (ValueError, KeyError, TypeError) as e:
        fail(f"{' '.join(cmd)}: no seconds.pipeline in its --json report ({e})")


def interleaved(device, setdir, linked, binaries, pipelines, tmp, runs):
    """`runs` rounds of one OIDN filter execution and one run of every gsid pipeline and binary, in
    turn: on a shared machine the load drifts within a run, and rounds make every method see the same
    drift (timing OIDN's runs first and gsid's after moved their ratio by ±0.2). Returns OIDN's times,
    and gsid's process and pipeline times per (pipeline, binary)."""
    import numpy as np

    color, albedo, normal = cd.load_set(setdir)
    output = np.zeros_like(color)
    flt = cd.oidn_filter(device, color, albedo, normal, output)
    cd.oidn_check(device, f"filter setup for {setdir}")
    oidn_times, gsid_times = [], {(name, g): [] for name in pipelines for g in binaries}
    filter_times = {key: [] for key in gsid_times}
    try:
        for r in range(runs):
            cd.note(f"round {r + 1} of {runs}: OIDN filter, then gsid {' '.join(pipelines)} ...")
            start = time.perf_counter()
            flt.execute()
            oidn_times.append(time.perf_counter() - start)
            cd.oidn_check(device, f"filter execution on {setdir}")
            for name in pipelines:
                for g in binaries:
                    wall, filtering = gsid_run(g, linked, name, tmp / f"{name}.exr")
                    gsid_times[(name, g)].append(wall)
                    filter_times[(name, g)].append(filtering)
    finally:
        flt.release()
    cd.write_rgb(tmp / "oidn.exr", output)
    return oidn_times, gsid_times, filter_times


def per_round_ratio(times, oidn_times):
    """The median over rounds of a gsid time over the same round's OIDN filter time: a round's two
    runs are seconds apart, so the machine's drift between rounds (the ratio of medians moved from
    1.02× to 1.25× between two runs of the same binaries) cancels in each quotient."""
    return statistics.median(t / o for t, o in zip(times, oidn_times))


def main(argv=None):
    p = argparse.ArgumentParser(description="gsid balanced/full against OIDN at 1024×1024, 4 spp (see the docstring).")
    p.add_argument("--runs", type=int, default=5, help="timed runs of each method (median)")
    p.add_argument("--cache", default=str(ROOT / "target" / "speed-set"), help="folder of the cached render set")
    p.add_argument("--gsid", nargs="+", default=[str(ROOT / "target" / "release" / "gsid")],
                   help="gsid binaries to time (the first also renders the set)")
    p.add_argument("--pipelines", nargs="+", default=["balanced", "full"], help="gsid pipelines to time")
    p.add_argument("--json", metavar="PATH", help="also write the header and times as JSON")
    args = p.parse_args(argv)
    if args.runs < 1:
        fail("--runs must be at least 1")
    binaries = [Path(g).resolve() for g in args.gsid]
    for gsid in binaries:
        if not (gsid.is_file() and os.access(gsid, os.X_OK)):
            fail(f"no gsid binary at {gsid}: run cargo build --release (or pass --gsid)")
    gsid = binaries[0]
    try:
        import numpy as np  # noqa: F401
        import OpenEXR  # noqa: F401
        import pyoidn
    except ImportError as e:
        fail(f"missing Python package ({e}); run: pip install -r scripts/requirements-compare.txt")

    setdir = render_set(gsid, Path(args.cache).resolve())
    for buf in cd.GSID_BUFFERS:
        if not (setdir / f"{buf}.exr").is_file():
            fail(f"render set {setdir}: no {buf}.exr")

    device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
    device.commit()
    cd.oidn_check(device, "CPU device creation")
    oidn_version = device.get_int("version")
    header = {
        "cpu": cd.cpu_model(),
        "cores": os.cpu_count(),
        "load_average_start": [round(x, 2) for x in os.getloadavg()],
        "oidn": f"{oidn_version // 10000}.{oidn_version // 100 % 100}.{oidn_version % 100}",
        "oidn_threads": device.get_int("numThreads"),
        "gsid_binaries": [str(g) for g in binaries],
        "gsid_commit": cd.git_commit(),
        "runs": args.runs,
        "set": str(setdir),
        "size": [SIZE, SIZE],
        "spp": SPP,
    }

    rows = {}
    with tempfile.TemporaryDirectory(prefix="speed_vs_oidn.") as tmp:
        tmp = Path(tmp)
        linked = cd.linked_set(setdir, cd.GSID_BUFFERS, tmp / "set")
        oidn_times, gsid_times, filter_times = interleaved(device, setdir, linked, binaries, args.pipelines, tmp,
                                                           args.runs)
        device.release()
        rows["OIDN filter (execute only)"] = (statistics.median(oidn_times), oidn_times)
        cd.note("OIDN process ...")
        rows["OIDN process (one-shot python3)"] = oidn_process(setdir, tmp / "oidn-process.exr", args.runs)
        for name in args.pipelines:
            for g in binaries:
                label = f" {g}" if len(binaries) > 1 else ""
                times = gsid_times[(name, g)]
                rows[f"gsid `{name}` (process){label}"] = (statistics.median(times), times)
                times = filter_times[(name, g)]
                rows[f"gsid `{name}` (filter: pipeline only){label}"] = (statistics.median(times), times)
    header["load_average_end"] = [round(x, 2) for x in os.getloadavg()]

    filt = rows["OIDN filter (execute only)"][0]
    proc = rows["OIDN process (one-shot python3)"][0]
    oidn_rounds = rows["OIDN filter (execute only)"][1]
    per_round = {m: per_round_ratio(times, oidn_rounds) for m, (_, times) in rows.items() if m.startswith("gsid")}
    print(f"{header['cpu']}, {header['cores']} cores; load average {header['load_average_start'][0]:.2f} at start, "
          f"{header['load_average_end'][0]:.2f} at end. OIDN {header['oidn']} ({header['oidn_threads']} threads), "
          f"gsid {', '.join(map(str, binaries))} (tree at {header['gsid_commit']}). {SIZE}×{SIZE}, {SPP} spp, {setdir}; "
          f"median of {args.runs}.")
    print()
    print("| method | median s | runs (s) | ÷ OIDN filter | ÷ OIDN filter, per round | ÷ OIDN process |")
    print("| --- | --- | --- | --- | --- | --- |")
    for method, (median, times) in rows.items():
        runs = " ".join(f"{t:.2f}" for t in times)
        rounds = f"{per_round[method]:.2f}×" if method in per_round else "—"
        print(f"| {method} | {median:.3f} | {runs} | {median / filt:.2f}× | {rounds} | {median / proc:.2f}× |")
    if args.json:
        out = {"header": header,
               "rows": {m: {"median": t[0], "times": t[1], "per_round_ratio": per_round.get(m)}
                        for m, t in rows.items()}}
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
        cd.note(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

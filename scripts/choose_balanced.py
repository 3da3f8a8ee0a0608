"""Re-chooses `balanced` among cheaper settings of its own stages, by quality at every spp and by
time on the render the speed bound is about.

For every setting of GRID (keys `gsid denoise --set` takes, applied to `balanced`):
  * quality: mean SSIM over the five fixtures at 1, 4, 16 and 64 spp, gsid reading colour + albedo +
    normal + depth only (as `compare_denoisers.py` runs it), scored by `gsid eval`; and SSIM on
    `cycles-studio` (Blender's own multilayer files), the one render from a renderer we did not write;
  * time: a 1024×1024 render of `textured` at 4 spp (`speed_vs_oidn.py`'s set, rendered once into
    its cache), whole `gsid denoise` process on every core, median of --runs rounds; each round
    runs every setting once, in a new shuffled order, so load that drifts during the run reaches
    all alike. Settings are ranked by CPU seconds (user + system of the process), which other
    load on a shared machine disturbs less than wall time; both are printed.
`quality` is scored the same way. The choice: the fastest setting whose SSIM is within LOSS of
`quality`'s at every spp, on the five fixtures' mean and on `cycles-studio` (docs/RESULTS.md "Presets": the
rule was the five fixtures at 4 spp only before the stages took their strength from the noise; at
1 spp and on the Blender render the cheaper settings lose most).

    python3 scripts/choose_balanced.py [--runs 5] [--no-build]

Needs the packages of scripts/requirements-compare.txt (the Blender passes are split with them).
"""

import argparse
import concurrent.futures
import itertools
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gsidscore import (ALL_FIXTURES, GSID_BUFFERS, ROOT, fail, gsid_eval, linked_set, note, require_gsid,
                       scored_case)
from gsidscore import cases as fixture_cases

sys.path.insert(0, str(Path(__file__).resolve().parent))
import speed_vs_oidn  # noqa: E402  (its cached 1024² render set)

SPPS = [1, 4, 16, 64]
BLENDER = "cycles-studio"
GROUPS = ("five fixtures", BLENDER)
LOSS = 0.01
GRID = {
    "pyramid.gsid.walks": ["2", "3", "4"],
    "pyramid.gsid.p_min": ["1e-6", "1e-4"],
    "regress.radius": ["5", "6"],
    "prefilter.estimate": ["directional", "trimmed"],
}


def settings():
    keys = list(GRID)
    return [tuple(zip(keys, values)) for values in itertools.product(*GRID.values())]


def label(setting):
    return " ".join(f"{k.split('.')[-1]}={v}" for k, v in setting)


def denoise(gsid, setdir, pipeline, setting, out, threads=None):
    """Runs one denoise; returns its (wall, CPU) seconds."""
    cmd = [str(gsid), "denoise", str(setdir), "--pipeline", pipeline, "-o", str(out), "--quiet"]
    cmd += [a for k, v in setting for a in ("--set", f"{k}={v}")]
    if threads:
        cmd += ["--threads", str(threads)]
    # CPU time is the change in this process's finished children: the run's own only when it is the
    # one child running (the timing rounds; the quality runs go two at a time and ignore it).
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        fail(f"{' '.join(cmd)}: {proc.stderr.strip()}", proc.returncode)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def quality(gsid, cases, pipeline, setting, tmp, jobs):
    """SSIM per (group, spp): the five fixtures' mean, and `cycles-studio`'s."""
    def one(case):
        fx, spp, setdir, ref = case
        out = tmp / f"{fx}-spp{spp}-out.exr"
        denoise(gsid, setdir, pipeline, setting, out, threads=1)
        return (BLENDER if fx == BLENDER else GROUPS[0], spp), gsid_eval(gsid, out, ref)["ssim"]

    with concurrent.futures.ThreadPoolExecutor(jobs) as pool:
        scores = list(pool.map(one, cases))
    return {key: statistics.mean(s for k, s in scores if k == key) for key in dict(scores)}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=5, help="timed rounds (median)")
    p.add_argument("--jobs", type=int, default=2, help="scoring processes at once (one thread each)")
    p.add_argument("--no-build", action="store_true", help="use target/release/gsid as it is")
    args = p.parse_args(argv)
    gsid = require_gsid(not args.no_build)
    with tempfile.TemporaryDirectory(prefix="choose_balanced.") as tmp:
        tmp = Path(tmp)
        cases = []
        for fx, spp, setdir, ref in fixture_cases(ALL_FIXTURES + [BLENDER], SPPS):
            gsid_input, _, plain_ref = scored_case(setdir, ref, tmp / f"{fx}-spp{spp}")
            cases.append((fx, spp, gsid_input, plain_ref))
        note("scoring quality and every setting of balanced ...")
        best = quality(gsid, cases, "quality", (), tmp, args.jobs)
        rows = {s: quality(gsid, cases, "balanced", s, tmp, args.jobs) for s in settings()}
        rendered = speed_vs_oidn.render_set(gsid, ROOT / "target" / "speed-set")
        speed_set = linked_set(rendered, GSID_BUFFERS, tmp / "speed-set")
        note(f"timing on {speed_set} ({args.runs} rounds) ...")
        times = {s: [] for s in rows}
        order, shuffle = list(rows), random.Random(0)
        for _ in range(args.runs):
            shuffle.shuffle(order)
            for s in order:
                times[s].append(denoise(gsid, speed_set, "balanced", s, tmp / "speed.exr"))
    wall = {s: statistics.median(w for w, _ in t) for s, t in times.items()}
    cpu = {s: statistics.median(c for _, c in t) for s, t in times.items()}
    ranked = sorted(rows, key=cpu.get)
    keys = [(g, spp) for g in GROUPS for spp in SPPS]
    print("quality: " + " / ".join(f"{best[k]:.4f}" for k in keys) + f" (SSIM: five fixtures' mean, then {BLENDER}, at {SPPS} spp)")
    heads = [f"{spp} spp" + (f" ({BLENDER})" if g == BLENDER else "") for g, spp in keys]
    print("| setting | " + " | ".join(heads) + " | CPU s | wall s | within |")
    print("| --- | " + " | ".join("---" for _ in keys) + " | --- | --- | --- |")
    ok = {s: all(rows[s][k] >= best[k] - LOSS for k in keys) for s in ranked}
    for s in ranked:
        cells = " | ".join(f"{rows[s][k]:.4f}" for k in keys)
        print(f"| {label(s)} | {cells} | {cpu[s]:.3f} | {wall[s]:.3f} | {'yes' if ok[s] else 'no'} |")
    chosen = [s for s in ranked if ok[s]]
    if not chosen:
        fail("no setting is within the loss of quality at every spp", 1)
    c = chosen[0]
    print(f"\nbalanced: {label(c)} ({cpu[c]:.3f} CPU s, {wall[c]:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

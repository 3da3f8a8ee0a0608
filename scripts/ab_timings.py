"""Per-stage times of two gsid builds on one render set, their runs alternated so both see the same
drift of a shared machine's load: the A/B a speed claim of a change needs.

Usage (from the repository root):

    python3 scripts/ab_timings.py OLD_BIN NEW_BIN SET [--pipeline balanced] [--runs 7] [--threads N]

Runs `BIN denoise SET --pipeline P -o TMP.exr --quiet --json` alternately, `--runs` times each, and
prints per stage (and level) the fastest and the median seconds of each build and their ratio, then the
pipeline's and the whole process's, with the load average at start and end.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time


def run(binary, setdir, pipeline, threads, out):
    cmd = [binary, "denoise", setdir, "--pipeline", pipeline, "-o", out, "--quiet", "--json"]
    if threads:
        cmd += ["--threads", str(threads)]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"ab_timings: {' '.join(cmd)}: {proc.stderr.strip()}")
    report = json.loads(proc.stdout)
    times = {"process": wall, "pipeline": report["seconds"]["pipeline"]}
    for st in report["stages"]:
        key = f"{st['id']} (level {st['level']})"
        times[key] = times.get(key, 0.0) + st["seconds"]
    return times


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old")
    p.add_argument("new")
    p.add_argument("set")
    p.add_argument("--pipeline", default="balanced")
    p.add_argument("--runs", type=int, default=7)
    p.add_argument("--threads", type=int)
    a = p.parse_args()
    load0 = os.getloadavg()
    samples = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "o.exr")
        for _ in range(a.runs):
            for name, binary in (("old", a.old), ("new", a.new)):
                samples[name].append(run(binary, a.set, a.pipeline, a.threads, out))
    load1 = os.getloadavg()
    print(f"pipeline {a.pipeline}, {a.runs} runs each, alternated; load {load0[0]:.2f} -> {load1[0]:.2f}")
    print("| stage | old fastest | new fastest | new/old | old median | new median | new/old |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    keys = [k for k in samples["old"][0] if k not in ("process", "pipeline")] + ["pipeline", "process"]
    for k in keys:
        old = [s[k] for s in samples["old"] if k in s]
        new = [s[k] for s in samples["new"] if k in s]
        if not old or not new:
            continue
        fo, fn = min(old), min(new)
        mo, mn = statistics.median(old), statistics.median(new)
        print(f"| {k} | {fo:.4f} | {fn:.4f} | {fn / fo:.3f} | {mo:.4f} | {mn:.4f} | {mn / mo:.3f} |")


if __name__ == "__main__":
    main()

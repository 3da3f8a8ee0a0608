"""Choose the fast / balanced / quality presets from `gsid sweep` CSVs, one per fixture.

Every fixture was swept over the same settings (same labels). Each setting gets its mean seconds
and mean SSIM over the fixtures; it is *near the front* when its mean SSIM is within TOLERANCE of
the best mean SSIM any setting reaches in no more mean time (0 on the Pareto front of the means).
Only settings near that front are candidates. (Requiring nearness on every fixture separately was
tried first: the cheapest settings differ by less than the run-to-run timing noise, so the
candidate set changed from run to run and once collapsed to a single setting.) The worst gap to
any single fixture's front is printed too.

  quality  = the candidate with the highest mean SSIM;
  balanced = the fastest candidate whose mean SSIM is within BALANCED_LOSS of quality's;
  fast     = the fastest candidate whose mean SSIM is within FAST_LOSS of quality's.

Standard library only. Run from the repository root after the sweeps (docs/RESULTS.md "Presets"):

    python3 scripts/choose_presets.py sweeps/*/sweep.csv
"""

import csv
import statistics
import sys

TOLERANCE = 0.002
BALANCED_LOSS = 0.01
FAST_LOSS = 0.03


def load(path):
    with open(path, newline="") as f:
        return {row["label"]: (float(row["seconds"]), float(row["ssim"])) for row in csv.DictReader(f)}


def gap_to_front(rows, label):
    seconds, ssim = rows[label]
    best = max(s for t, s in rows.values() if t <= seconds)
    return best - ssim


def main(paths):
    if not paths:
        sys.exit("usage: choose_presets.py SWEEP.csv ...")
    sweeps = {p: load(p) for p in paths}
    labels = set.intersection(*(set(r) for r in sweeps.values()))
    table = []
    for label in labels:
        gaps = [gap_to_front(r, label) for r in sweeps.values()]
        table.append(
            {
                "label": label,
                "ssim": statistics.mean(r[label][1] for r in sweeps.values()),
                "seconds": statistics.mean(r[label][0] for r in sweeps.values()),
                "worst_gap": max(gaps),
            }
        )
    table.sort(key=lambda r: r["seconds"])
    means = {r["label"]: (r["seconds"], r["ssim"]) for r in table}
    for r in table:
        r["gap"] = gap_to_front(means, r["label"])
    candidates = [r for r in table if r["gap"] <= TOLERANCE]
    quality = max(candidates, key=lambda r: r["ssim"])
    pick = lambda loss: next(r for r in candidates if r["ssim"] >= quality["ssim"] - loss)
    chosen = {"fast": pick(FAST_LOSS), "balanced": pick(BALANCED_LOSS), "quality": quality}

    print(f"{len(paths)} fixtures, {len(table)} settings; near the front = within {TOLERANCE} SSIM of the front of the means\n")
    print("| setting | mean seconds | mean SSIM | gap to the front of the means | worst gap to one fixture's front | preset |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in table:
        names = ", ".join(n for n, c in chosen.items() if c is r)
        print(f"| {r['label']} | {r['seconds']:.3f} | {r['ssim']:.4f} | {r['gap']:.4f} | {r['worst_gap']:.4f} | {names} |")


if __name__ == "__main__":
    main(sys.argv[1:])

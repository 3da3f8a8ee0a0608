#!/usr/bin/env python3
"""gsid against Open Image Denoise on scene kinds no comparison fixture has, held out from tuning.

The scenes are `fixtures/scenes/unseen/*.toml` (depth of field, a glossy room, a room lit only by
bounced light, an outdoor sky and sun).
Each is rendered once by `gsid render` at 1 / 4 / 16 / 64 spp with a 4096-spp reference into
`target/unseen/NAME/` (again only when its scene file changed), then scored by
`scripts/compare_denoisers.py` with every other argument passed on (`--scenes dof,glossy` picks some):

    python3 scripts/unseen_scenes.py --no-build --runs 1 --no-bm3d --pipelines full balanced

No gsid setting may be chosen on these scenes: they measure how the defaults carry to renders the
project was not tuned on (docs/results/unseen.md).
"""

import filecmp
import shutil
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gsidscore import ROOT, fail, note, require_gsid  # noqa: E402

SCENES = ROOT / "fixtures" / "scenes" / "unseen"
OUT = ROOT / "target" / "unseen"
SPP = "1,4,16,64"
REFERENCE_SPP = "4096"


def rendered(gsid, scene):
    """The render folder of `scene`, rendered first unless it holds this scene file's render."""
    out = OUT / scene.stem
    kept = out / "scene.toml"
    if kept.is_file() and filecmp.cmp(kept, scene, shallow=False) and (out / "reference.exr").is_file():
        return out
    # Rendered beside it and renamed when complete, so an interrupted render leaves no folder that
    # looks finished.
    partial = OUT / f"{scene.stem}.partial"
    for old in (out, partial):
        if old.exists():
            shutil.rmtree(old)
    note(f"rendering {scene.name} at {SPP} spp, reference {REFERENCE_SPP} spp (a minute or two) ...")
    proc = subprocess.run([str(gsid), "render", str(scene), "-o", str(partial), "--spp", SPP,
                           "--reference-spp", REFERENCE_SPP, "--quiet"])
    if proc.returncode != 0:
        shutil.rmtree(partial, ignore_errors=True)
        fail(f"gsid render {scene} failed (exit {proc.returncode})", 1)
    partial.rename(out)
    return out


def main(argv):
    scenes = sorted(SCENES.glob("*.toml"))
    if not scenes:
        fail(f"no scene files in {SCENES}")
    if any(a == "--fixtures" or a.startswith("--fixtures=") for a in argv):
        fail("--fixtures: this script compares the held-out scenes; pick some with --scenes NAME,NAME")
    for i, a in enumerate(argv):
        if a == "--scenes" or a.startswith("--scenes="):
            value = a.split("=", 1)[1] if "=" in a else (argv[i + 1] if i + 1 < len(argv) else "")
            names = [n for n in value.split(",") if n]
            known = {s.stem: s for s in scenes}
            unknown = [n for n in names if n not in known]
            if not names or unknown:
                fail(f"--scenes {value!r}: no such scene {unknown or value!r} (known: {', '.join(known)})")
            scenes = [known[n] for n in names]
            argv = argv[:i] + argv[i + (1 if "=" in a else 2):]
            break
    gsid = require_gsid("--no-build" not in argv)
    folders = [rendered(gsid, s) for s in scenes]
    rest = [a for a in argv if a != "--no-build"] + ["--no-build"]
    cmd = [sys.executable, str(ROOT / "scripts" / "compare_denoisers.py"),
           "--fixtures", ",".join(str(f) for f in folders)] + rest
    return subprocess.run(cmd).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""What the scoring scripts share: the fixtures, EXR I/O, and running and scoring gsid.

`scripts/compare_denoisers.py` and `scripts/oracle_sigma.py` import this, so both give gsid the same
buffers (colour + albedo + normal + depth, linked into a temporary folder; a Blender multilayer file
as it is) and score with the same code (`gsid eval --json`, docs/ALGORITHM.md §5). Errors print one
line prefixed with the running script's name and exit with code 2.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# GSID_BIN=path scores another build (an older binary kept for a before/after table), as the tests do.
GSID = Path(os.environ["GSID_BIN"]) if os.environ.get("GSID_BIN") else ROOT / "target" / "release" / "gsid"
ALL_FIXTURES = ["mitsuba-cornell", "cornell", "caustics", "textured", "detail"]
MULTILAYER_FIXTURES = ["cycles-studio", "cycles-glass", "cycles-fog"]
# What compare_denoisers.py runs by default: every folder fixture and the Blender renders.
DEFAULT_FIXTURES = ALL_FIXTURES + MULTILAYER_FIXTURES
# What gsid is given by default: what most renderers write and what OIDN's comparison gets.
GSID_BUFFERS = ("color", "albedo", "normal", "depth")
NOISE_BUFFERS = ("variance", "color_a", "color_b")
# Blender passes OIDN reads from a multilayer file, with their channels.
LAYER_PASSES = {"color": ("Combined", "RGB"), "albedo": ("Denoising Albedo", "RGB"),
                "normal": ("Denoising Normal", "XYZ")}
CHANNELS = ("R", "G", "B")


def fail(message, code=2):
    print(f"{Path(sys.argv[0]).stem}: error: {message}", file=sys.stderr)
    sys.exit(code)


def note(message):
    print(message, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------- EXR I/O

def read_rgb(path):
    """An EXR's R, G, B channels as a contiguous float32 HxWx3 array (row 0 = top row)."""
    import numpy as np
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        missing = [c for c in CHANNELS if c not in ch]
        if missing:
            fail(f"{path}: no channel {','.join(missing)} (has {','.join(sorted(ch))})")
        return np.ascontiguousarray(np.stack([ch[c].pixels for c in CHANNELS], axis=-1), dtype=np.float32)


def read_pass(path, name, channels):
    """One pass of a Blender multilayer EXR (`ViewLayer.<name>.<channel>`) as HxWx3 float32."""
    import numpy as np
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        picked = []
        for c in channels:
            full = [k for k in ch if k.split(".")[-2:] == [name, c]]
            if len(full) != 1:
                fail(f"{path}: no single channel {name}.{c} (has {', '.join(sorted(ch))})")
            picked.append(ch[full[0]].pixels)
        return np.ascontiguousarray(np.stack(picked, axis=-1), dtype=np.float32)


def write_rgb(path, image):
    """Write HxWx3 as a float32, zip-compressed RGB EXR."""
    import numpy as np
    import OpenEXR

    image = np.asarray(image, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate(CHANNELS)}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


# ---------------------------------------------------------------------------- fixtures

def parse_spps(text):
    """`1,4,16` as [1, 4, 16], or a one-line error."""
    try:
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        fail(f"--spp {text!r}: expected comma-separated integers such as 1,4,16")


def multilayer_case(fx, spp):
    """The multilayer file of `fx` at `spp` spp and its reference: the shared copy if present."""
    for fdir in (ROOT.parent / "shared" / "fixtures" / fx, ROOT / "fixtures" / fx):
        if fdir.is_dir():
            path, ref = fdir / f"spp{spp}.exr", fdir / "reference.exr"
            if not path.is_file():
                fail(f"fixture {fx!r} at {spp} spp: no {path}")
            if not ref.is_file():
                fail(f"fixture {fx!r}: no reference {ref}")
            return path, ref
    fail(f"fixture {fx!r}: no folder {ROOT / 'fixtures' / fx}")


def cases(fixtures, spps):
    """(fixture, spp, render set folder or multilayer file, reference) for each fixture × spp,
    every file checked to exist before any slow work."""
    found = []
    for fx in fixtures:
        if fx in MULTILAYER_FIXTURES:
            for spp in spps:
                path, ref = multilayer_case(fx, spp)
                found.append((fx, spp, path, ref))
            continue
        # A name with a slash is a folder as `gsid render` writes it (reference.exr, spp<N>/),
        # named in the tables by its last part.
        fdir = Path(fx) if "/" in fx else ROOT / "fixtures" / fx
        if not fdir.is_dir():
            fail(f"fixture {fx!r}: no folder {fdir} (known: {', '.join(ALL_FIXTURES + MULTILAYER_FIXTURES)})")
        ref = fdir / "reference.exr"
        if not ref.is_file():
            fail(f"fixture {fx!r}: no reference {ref}")
        for spp in spps:
            setdir = fdir / f"spp{spp}"
            for buf in ("color", "albedo", "normal"):
                if not (setdir / f"{buf}.exr").is_file():
                    fail(f"fixture {fx!r} at {spp} spp: no {setdir / (buf + '.exr')}")
            found.append((fdir.name, spp, setdir, ref))
    return found


def linked_set(setdir, names, into):
    """A folder `into` with links to just the buffers `names` of `setdir` that exist: what gsid sees."""
    into.mkdir(parents=True, exist_ok=True)
    for b in names:
        src = setdir / f"{b}.exr"
        link = into / src.name
        if src.is_file() and not link.is_symlink():
            link.symlink_to(src.resolve())
    return into


def scored_case(setdir, ref, stem):
    """(gsid's input, the noisy colour to score, the reference to score against) for one case:
    a render set's colour + albedo + normal + depth linked into `stem`-set, or a multilayer file as
    it is, scored by its `Combined` pass (written next to `stem`, since `gsid eval` reads plain RGB)."""
    if setdir.is_file():
        noisy, plain_ref = Path(f"{stem}-input.exr"), Path(f"{stem}-reference.exr")
        write_rgb(noisy, read_pass(setdir, *LAYER_PASSES["color"]))
        write_rgb(plain_ref, read_pass(ref, *LAYER_PASSES["color"]))
        return setdir, noisy, plain_ref
    return linked_set(setdir, GSID_BUFFERS, Path(f"{stem}-set")), setdir / "color.exr", ref


# ---------------------------------------------------------------------------- gsid

def require_gsid(build):
    """The release binary, built first when `build` (a one-line error when it cannot be had)."""
    if build:
        note("building gsid (cargo build --release --quiet --bin gsid) ...")
        try:
            proc = subprocess.run(["cargo", "build", "--release", "--quiet", "--bin", "gsid"], cwd=ROOT)
        except FileNotFoundError:
            fail("cargo not found: install Rust, or build target/release/gsid and pass --no-build")
        if proc.returncode != 0:
            fail("cargo build --release --bin gsid failed (see above)", 1)
    if not (GSID.is_file() and os.access(GSID, os.X_OK)):
        fail(f"no gsid binary at {GSID}: run cargo build --release --bin gsid (or drop --no-build)")
    return GSID


def gsid_binary(given=None):
    """The gsid binary a script's `--gsid` names, else $GSID_BIN or target/release/gsid; a one-line
    error when it is not a file."""
    gsid = Path(given) if given else GSID
    if not gsid.is_file():
        fail(f"no gsid binary at {gsid} (cargo build --release, or --gsid PATH)")
    return gsid


def gsid_eval(gsid, image, reference):
    proc = subprocess.run([str(gsid), "eval", str(image), "--reference", str(reference), "--json"],
                          capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        fail(f"gsid eval {image}: {proc.stderr.strip() or proc.stdout.strip()}", proc.returncode)
    return json.loads(proc.stdout)


def gsid_pipelines(gsid):
    proc = subprocess.run([str(gsid), "pipelines"], capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        fail(f"gsid pipelines: {proc.stderr.strip()}", 1)
    return [line.split()[0] for line in proc.stdout.splitlines() if line.strip()]


def git_commit():
    proc = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    return proc.stdout.strip() if proc.returncode == 0 else "unknown"

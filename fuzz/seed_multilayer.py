"""Seeds for the `multilayer_passes` target: Blender multilayer EXRs cropped to a few pixels (every
channel kept), written single-part and multi-part, ZIP and uncompressed, each behind every map byte.
Needs Python's OpenEXR (scripts/requirements-compare.txt); run by seed.sh."""
import itertools, pathlib, sys
import numpy as np, OpenEXR

root = pathlib.Path(__file__).resolve().parent.parent
out = pathlib.Path(sys.argv[1])
out.mkdir(parents=True, exist_ok=True)
sources = sorted((root / "fixtures").glob("cycles-*/spp4/frame.0001.exr")) + [root / "fixtures/cycles-studio/spp4.exr"]
for src in sources:
    with OpenEXR.File(str(src), separate_channels=True) as f:
        channels = {k: np.ascontiguousarray(v.pixels[10:15, 12:18]) for k, v in f.channels().items()}
    name = src.parent.parent.name if src.parent.name == "spp4" else src.parent.name
    for compression, tag in ((OpenEXR.ZIP_COMPRESSION, "zip"), (OpenEXR.NO_COMPRESSION, "none")):
        header = {"compression": compression, "type": OpenEXR.scanlineimage}
        path = out / f"{name}-{tag}.exr"
        with OpenEXR.File(header, channels) as f:
            f.write(str(path))
    # Multi-part: one part per view-layer pass, as some writers store them.
    groups = {}
    for k, v in channels.items():
        groups.setdefault(k.rsplit(".", 1)[0] if "." in k else "", {})[k] = v
    parts = [OpenEXR.Part({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, ch, name=layer or "rgba")
             for layer, ch in itertools.islice(groups.items(), 6)]
    with OpenEXR.File(parts) as f:
        f.write(str(out / f"{name}-parts.exr"))
# Each file behind every map byte (the target's first byte).
for path in sorted(out.glob("*.exr")):
    data = path.read_bytes()
    for choice in range(4):
        (out / f"{path.stem}-map{choice}").write_bytes(bytes([choice]) + data)
    path.unlink()
print(f"seeded {len(list(out.iterdir()))} multilayer inputs")

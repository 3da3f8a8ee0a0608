"""Reference image-quality metrics computed with scikit-image, for gsid's Rust tests.

Computes SSIM, PSNR (on the LDR view: clamp to [0,1], then sRGB transfer curve)
and relMSE (on linear HDR values) for the mitsuba-cornell fixtures against their
reference, plus a few seeded synthetic LDR image pairs (pixel data inlined) that
exercise SSIM border handling and odd image sizes.

Rerun from the repository root:

    pip install -r scripts/requirements-metrics.txt
    python3 scripts/skimage_metrics.py > tests/data/skimage_metrics.json
"""

import json
import sys

import numpy as np
import OpenEXR
import skimage
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

FIXTURE_DIR = "fixtures/mitsuba-cornell"
REFERENCE = f"{FIXTURE_DIR}/reference.exr"
SPPS = [1, 4, 16, 64]

# (name, seed, height, width, noise standard deviation).
# With gaussian_weights=True and sigma=1.5 skimage uses an 11x11 window, so no
# side may be smaller than 11 (11x11 leaves a single valid window position).
SYNTHETIC = [
    ("synthetic-16x16", 1, 16, 16, 0.05),
    ("synthetic-13x21", 2, 13, 21, 0.10),
    ("synthetic-11x11", 3, 11, 11, 0.20),
    ("synthetic-40x11", 4, 40, 11, 0.02),
]


def read_exr_rgb(path):
    """Read an EXR's R, G, B channels as float64, shape HxWx3, row 0 = top row."""
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        return np.stack([ch[c].pixels for c in ("R", "G", "B")], axis=-1).astype(np.float64)


def to_ldr(x):
    """The project's scoring view: clamp to [0,1], then the sRGB transfer curve."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def ssim(img, ref):
    return float(structural_similarity(
        img, ref, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
        data_range=1.0, channel_axis=2))


def psnr(img, ref):
    return float(peak_signal_noise_ratio(ref, img, data_range=1.0))


def relmse(img, ref):
    return float(np.mean((img - ref) ** 2 / (ref ** 2 + 0.01)))


def fixture_cases():
    ref = read_exr_rgb(REFERENCE)
    ref_ldr = to_ldr(ref)
    cases = []
    for spp in SPPS:
        path = f"{FIXTURE_DIR}/spp{spp}/color.exr"
        img = read_exr_rgb(path)
        img_ldr = to_ldr(img)
        cases.append({
            "name": f"mitsuba-cornell/spp{spp}",
            "image": path,
            "reference": REFERENCE,
            "ssim": ssim(img_ldr, ref_ldr),
            "psnr": psnr(img_ldr, ref_ldr),
            "relmse": relmse(img, ref),
        })
    return cases


def synthetic_cases():
    cases = []
    for name, seed, h, w, noise in SYNTHETIC:
        rng = np.random.default_rng(seed)
        a = rng.random((h, w, 3))
        b = np.clip(a + rng.normal(0.0, noise, size=a.shape), 0.0, 1.0)
        # Round first so the JSON holds exactly the values that were scored.
        a = np.round(a, 6)
        b = np.round(b, 6)
        cases.append({
            "name": name,
            "seed": seed,
            "noise_sigma": noise,
            "height": h,
            "width": w,
            "channels": 3,
            "a": [float(v) for v in a.ravel()],  # row-major HxWxC
            "b": [float(v) for v in b.ravel()],
            "ssim": ssim(a, b),
            "psnr": psnr(b, a),  # a is the reference
        })
    return cases


def main():
    out = {
        "generator": f"scikit-image {skimage.__version__} (numpy {np.__version__}), "
                     "scripts/skimage_metrics.py",
        "fixtures": fixture_cases(),
        "synthetic": synthetic_cases(),
    }
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()

"""Where gsid's SSIM gap to Open Image Denoise lies: near feature edges, on colour structure the features
do not show, or on flat surfaces.

Reads the outputs `scripts/compare_denoisers.py --keep DIR` leaves (`FIXTURE-sppN-oidn.exr` and
`FIXTURE-sppN-gsid-PIPELINE.exr`) and, for every fixture × spp, splits the mean SSIM difference
(OIDN − gsid) by the pixel regions of the per-pixel SSIM map it comes from (SSIM on the clipped sRGB view,
docs/ALGORITHM.md §5: the same map `gsid eval` averages, from scikit-image):

  * feature edge: within 2 pixels of a step of the fixture's 64 spp albedo (> 0.05 in a channel) or
    normal (> 0.1), i.e. where a filter's neighbourhood on the pixel's own surface is one-sided;
  * colour structure: within 2 pixels of a step of the reference (> 0.08 in the sRGB view) that is not
    a feature edge (reflections, shadows, caustics);
  * flat: the rest.

Each region's figure is its share of the whole image's mean difference, so the three add up to the total
(and to the difference of the two SSIM scores). The region's share of the frame is printed in brackets.

    python3 scripts/compare_denoisers.py --no-build --runs 1 --no-bm3d --pipelines full --keep /tmp/cmp
    python3 scripts/gap_by_region.py /tmp/cmp --pipeline full

Errors (a missing folder, output or package) give one line on stderr and exit code 2.
"""

import argparse
from pathlib import Path

from gsidscore import ALL_FIXTURES, ROOT, fail, parse_spps, read_rgb


def srgb(x):
    import numpy as np

    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


# scikit-image averages the map without a border of half its 11×11 Gaussian window (σ 1.5, truncated
# at 3.5σ): so do the sums here, so they add up to the difference of the two scores.
BORDER = 5


def ssim_map(image, reference):
    """The per-pixel SSIM map (mean over channels) of the protocol `gsid eval` implements, without the
    border the score leaves out."""
    from skimage.metrics import structural_similarity

    _, full = structural_similarity(srgb(image), srgb(reference), channel_axis=2, data_range=1.0,
                                    full=True, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False)
    return full.mean(axis=2)[BORDER:-BORDER, BORDER:-BORDER]


def steps(image, threshold):
    """Pixels beside a step larger than `threshold` in any channel, to their right or below."""
    import numpy as np

    out = np.zeros(image.shape[:2], bool)
    dx = np.abs(np.diff(image, axis=1)).max(-1) > threshold
    dy = np.abs(np.diff(image, axis=0)).max(-1) > threshold
    out[:, :-1] |= dx
    out[:, 1:] |= dx
    out[:-1] |= dy
    out[1:] |= dy
    return out


def regions(fixture):
    """(feature edge, colour structure, flat) masks of a folder fixture."""
    from scipy.ndimage import maximum_filter

    fdir = ROOT / "fixtures" / fixture
    albedo, normal = read_rgb(fdir / "spp64" / "albedo.exr"), read_rgb(fdir / "spp64" / "normal.exr")
    reference = read_rgb(fdir / "reference.exr")
    edge = maximum_filter(steps(albedo, 0.05) | steps(normal, 0.1), 5)
    structure = maximum_filter(steps(srgb(reference), 0.08), 5) & ~edge
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    return reference, edge[inner], structure[inner], (~edge & ~structure)[inner]


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("keep", type=Path, help="the --keep folder of a compare_denoisers.py run")
    p.add_argument("--pipeline", default="full")
    p.add_argument("--fixtures", default=",".join(ALL_FIXTURES))
    p.add_argument("--spp", default="1,4,16,64")
    a = p.parse_args()
    try:
        import numpy  # noqa: F401
        import scipy  # noqa: F401
        import skimage  # noqa: F401
    except ImportError as e:
        fail(f"{e.name} is not installed: pip install -r scripts/requirements-compare.txt")
    if not a.keep.is_dir():
        fail(f"{a.keep}: no such folder (the --keep folder of scripts/compare_denoisers.py)")
    print(f"SSIM of OIDN − gsid `{a.pipeline}` by region (share of the frame in brackets)\n")
    print("| fixture | spp | total | feature edge | colour structure | flat |")
    print("| --- | --- | --- | --- | --- | --- |")
    for fx in a.fixtures.split(","):
        if fx not in ALL_FIXTURES:
            fail(f"fixture {fx!r}: only the folder fixtures have the 64 spp features this needs "
                 f"({', '.join(ALL_FIXTURES)})")
        reference, *masks = regions(fx)
        for spp in parse_spps(a.spp):
            paths = [a.keep / f"{fx}-spp{spp}-oidn.exr", a.keep / f"{fx}-spp{spp}-gsid-{a.pipeline}.exr"]
            for path in paths:
                if not path.is_file():
                    fail(f"{path}: missing (run compare_denoisers.py with --keep and this pipeline)")
            oidn, ours = (ssim_map(read_rgb(path), reference) for path in paths)
            diff = oidn - ours
            parts = [f"{diff[m].sum() / diff.size:+.4f} ({m.mean():.2f})" for m in masks]
            print(f"| {fx} | {spp} | {diff.mean():+.4f} | " + " | ".join(parts) + " |")


if __name__ == "__main__":
    main()

"""What a user sees beside SSIM/PSNR/relMSE: lost or added light, surviving fireflies, copied feature noise.

`scripts/compare_denoisers.py` adds these to every row. All are computed on linear HDR luminance
(Rec. 709 weights) against the reference:

  * brightness: mean(output) / mean(reference) − 1, in %: a clamp that throws fireflies' energy away
    shows here as a negative figure.
  * fireflies: output pixels brighter than 4× the reference (and than 4 × 0.01, so a black pixel is not
    counted for any light at all) where the reference is smooth (its 3×3 neighbourhood within ±25 % of
    the pixel): a speck on a flat wall or floor, not a highlight the reference has.
  * dark dots: output pixels darker than a quarter of the reference where the reference is bright (at
    or above the image's median luminance, so a shadow or a dark texel does not count) and smooth (as
    for fireflies): a speck on a lit wall or floor whose one sample returned almost nothing (scattered
    in fog, a shadow ray blocked) and that the denoiser kept.
  * albedo-noise correlation (only when the noisy and the reference albedo are given): the Spearman (rank)
    correlation of the output's error with the albedo's noise (noisy − reference albedo luminance) over
    the pixels: a denoiser that takes the albedo's noise for texture copies it into its output. Ranks, not
    Pearson, because a handful of HDR pixels (the light, a caustic) would otherwise decide the figure.
"""

LUMA = (0.2126, 0.7152, 0.0722)


def luminance(rgb):
    return rgb[..., 0] * LUMA[0] + rgb[..., 1] * LUMA[1] + rgb[..., 2] * LUMA[2]


def brightness_percent(output, reference):
    import numpy as np

    ref = float(np.mean(luminance(reference), dtype=np.float64))
    out = float(np.mean(luminance(output), dtype=np.float64))
    return 100.0 * (out / ref - 1.0) if ref > 0 else 0.0


def smooth_mask(ref_lum, tolerance=0.25):
    """Pixels whose 3×3 neighbourhood (edge-replicated) stays within ±tolerance of the pixel."""
    import numpy as np

    padded = np.pad(ref_lum, 1, mode="edge")
    h, w = ref_lum.shape
    lo = np.full_like(ref_lum, np.inf)
    hi = np.full_like(ref_lum, -np.inf)
    for dy in range(3):
        for dx in range(3):
            win = padded[dy:dy + h, dx:dx + w]
            lo = np.minimum(lo, win)
            hi = np.maximum(hi, win)
    return (hi <= ref_lum * (1 + tolerance)) & (lo >= ref_lum * (1 - tolerance))


def firefly_count(output, reference, factor=4.0, floor=0.01):
    import numpy as np

    ref = luminance(reference)
    out = luminance(output)
    return int(np.count_nonzero((out > factor * np.maximum(ref, floor)) & smooth_mask(ref)))


def dark_dot_count(output, reference, factor=0.25):
    import numpy as np

    ref = luminance(reference)
    out = luminance(output)
    bright = ref >= np.median(ref)
    return int(np.count_nonzero((out < factor * ref) & bright & smooth_mask(ref)))


def albedo_noise_correlation(output, reference, albedo, albedo_reference):
    import numpy as np

    from scipy.stats import spearmanr

    err = (luminance(output) - luminance(reference)).ravel().astype(np.float64)
    noise = (luminance(albedo) - luminance(albedo_reference)).ravel().astype(np.float64)
    if err.std() == 0 or noise.std() == 0:
        return 0.0
    return float(spearmanr(err, noise)[0])

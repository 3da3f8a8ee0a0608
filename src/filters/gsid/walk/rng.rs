//! The random numbers of the walks (and the renderer's seeds): SplitMix64 streams keyed by
//! (seed, level, pixel, walk), so no number depends on scheduling.

/// SplitMix64's increment (the golden ratio in 64 bits).
pub(crate) const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// SplitMix64's step: add [`GAMMA`], then its finaliser, which spreads nearby integers over the
/// whole 64-bit range.
pub fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(GAMMA);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The key of one start pixel: depends only on (seed, level, pixel), never on scheduling.
#[inline]
pub fn pixel_key(seed: u64, level: u32, pixel: usize) -> u64 {
    splitmix(splitmix(splitmix(seed) ^ level as u64) ^ pixel as u64)
}

/// The key of walk `walk` from a start pixel. Every walk has its own stream, so walks may be
/// interleaved (or run in any order) without changing which numbers each one draws.
#[inline]
pub fn walk_key(pixel_key: u64, walk: u32) -> u64 {
    splitmix(pixel_key ^ walk as u64)
}

/// The uniform in [0, 1) that step `step` of the walk `key` draws: SplitMix64's output number
/// `step` of the stream seeded with `key`, cut to 24 bits (the precision of the f32 sums it meets).
#[inline]
pub fn uniform(key: u64, step: u32) -> f32 {
    (splitmix(key.wrapping_add((step as u64).wrapping_mul(GAMMA))) >> 40) as f32
        * (1.0 / 16_777_216.0)
}

//! Per-pixel feature vectors and the pixel difference d(i, j) of docs/ALGORITHM.md §2.
//!
//! Each pixel's features are packed into one 16-float (64-byte) record with the weights already
//! folded in, so the hot loop computes d(i, j) from two cache lines and no configuration:
//!
//! | lanes | content                  | scaling                      | enters d as          |
//! |-------|--------------------------|------------------------------|----------------------|
//! | 0..3  | tone-mapped colour T(c)  | × W1                         | Euclidean norm       |
//! | 3..6  | albedo                   | × W2                         | Euclidean norm       |
//! | 6..9  | unit normal              | × √W3 / 2                    | squared norm         |
//! | 9..12 | diffuse/refl./refr.      | × W4, W5, W6                 | sum of abs diffs     |
//! | 12    | shadow                   | × W7                         | abs diff             |
//! | 13    | depth (unscaled)         | W8 applied in `distance`     | relative abs diff    |
//!
//! The normal term uses ‖n_i − n_j‖²/4, which equals (1 − n_i·n_j)/2 for unit normals and also
//! behaves for "unknown" (zero) normals: two unknowns are equal, unknown vs known differs by 1/4.
//!
//! `weights`: the eight weights, the buffer each needs, and the tone curve; `records`: the records
//! ([`Features`]) and how buffers become them ([`Recipe`]); `planes`: bands of records as padded
//! planes ([`FeaturePlanes`]); `distance`: d itself, between two records or along runs of planes.

mod distance;
mod planes;
mod records;
mod weights;

pub use distance::{distance, distance_row, DEPTH_EPS, FEATURE_LANES, USED_LANES};
pub use planes::FeaturePlanes;
pub use records::{Features, Recipe};
pub use weights::{Tone, Weights};

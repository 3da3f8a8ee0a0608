//! The SIMD and numeric helpers the filters share: fast exponentials and logarithms, the run-time
//! choice of SIMD kernel, padded planes, trimmed means and window bit masks.

pub mod fastmath;
pub(crate) mod padded;
pub mod simd;
pub(crate) mod trim;
pub(crate) mod window_bits;

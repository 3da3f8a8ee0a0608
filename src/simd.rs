//! Which instruction set the hot loops use, chosen at run time, so one binary serves every x86-64
//! CPU. Every kernel runs the same IEEE operations in the same order, so the choice never changes
//! a result bit.

/// Which implementation of a hot loop runs. All give the same bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Portable Rust, lane by lane.
    Scalar,
    /// One step's 8 neighbours in one 256-bit register (x86-64 with AVX2).
    Avx2,
}

impl Kernel {
    /// The fastest kernel this CPU runs, detected at run time so one binary serves old CPUs too.
    pub fn detect() -> Kernel {
        if Kernel::Avx2.is_available() {
            Kernel::Avx2
        } else {
            Kernel::Scalar
        }
    }

    /// This kernel if the CPU runs it, else the portable one (same result).
    pub fn or_portable(self) -> Kernel {
        if self.is_available() {
            self
        } else {
            Kernel::Scalar
        }
    }

    pub fn is_available(self) -> bool {
        match self {
            Kernel::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(not(target_arch = "x86_64"))]
            Kernel::Avx2 => false,
        }
    }
}

/// Calls the row function `f(args…)` compiled for `kernel`: the same code, so the same bits, with
/// AVX2 lanes where the CPU has them. `f` must be `#[inline(always)]` and return nothing, so
/// its loops are compiled inside the AVX2 copy.
macro_rules! row_kernel {
    ($kernel:expr, $f:ident($($arg:ident: $ty:ty),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        if $kernel.or_portable() == $crate::simd::Kernel::Avx2 {
            #[target_feature(enable = "avx2")]
            fn avx2($($arg: $ty),*) {
                $f($($arg),*)
            }
            // SAFETY: `or_portable` gives Avx2 only when the CPU reports AVX2.
            unsafe { avx2($($arg),*) }
        } else {
            $f($($arg),*)
        }
        #[cfg(not(target_arch = "x86_64"))]
        $f($($arg),*)
    }};
}
pub(crate) use row_kernel;

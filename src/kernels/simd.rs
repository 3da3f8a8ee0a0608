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
    /// The AVX2 kernels, and 512-bit copies of the row loops that run faster in them (the fit's
    /// window sums, the à-trous taps; x86-64 with AVX-512 F, VL, BW and DQ). The loops that do not
    /// gain keep their AVX2 copies: wider registers made the prefilter slower.
    Avx512,
}

impl Kernel {
    /// Every kernel, portable first.
    pub const ALL: [Kernel; 3] = [Kernel::Scalar, Kernel::Avx2, Kernel::Avx512];

    /// The fastest kernel this CPU runs, detected at run time so one binary serves old CPUs too.
    pub fn detect() -> Kernel {
        Kernel::Avx512.or_portable()
    }

    /// This kernel if the CPU runs it, else the fastest narrower one it runs (same result).
    pub fn or_portable(self) -> Kernel {
        match self {
            Kernel::Avx512 if !self.is_available() => Kernel::Avx2.or_portable(),
            Kernel::Avx2 if !self.is_available() => Kernel::Scalar,
            k => k,
        }
    }

    /// Whether the AVX2 kernels run (with AVX2 or AVX-512 on a CPU that has AVX2). One test of
    /// the CPU: row kernels ask it once per row.
    pub fn avx2(self) -> bool {
        self != Kernel::Scalar && Kernel::Avx2.is_available()
    }

    pub fn is_available(self) -> bool {
        match self {
            Kernel::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => {
                static AVX512: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
                *AVX512.get_or_init(|| {
                    std::arch::is_x86_feature_detected!("avx2")
                        && std::arch::is_x86_feature_detected!("avx512f")
                        && std::arch::is_x86_feature_detected!("avx512vl")
                        && std::arch::is_x86_feature_detected!("avx512bw")
                        && std::arch::is_x86_feature_detected!("avx512dq")
                })
            }
            #[cfg(not(target_arch = "x86_64"))]
            Kernel::Avx2 | Kernel::Avx512 => false,
        }
    }
}

/// Calls the row function `f(args…)` compiled for `kernel`: the same code, so the same bits, with
/// AVX2 lanes where the CPU has them. `f` must be `#[inline(always)]` and return nothing, so
/// its loops are compiled inside the AVX2 copy. `row_kernel!(wide kernel, f(…))` adds a copy
/// compiled for AVX-512, which [`Kernel::Avx512`] runs; only loops measured faster in it opt in.
macro_rules! row_kernel {
    ($kernel:expr, $f:ident($($arg:ident: $ty:ty),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        if $kernel.avx2() {
            #[target_feature(enable = "avx2")]
            fn avx2($($arg: $ty),*) {
                $f($($arg),*)
            }
            // SAFETY: `avx2` holds only when the CPU reports AVX2.
            unsafe { avx2($($arg),*) }
        } else {
            $f($($arg),*)
        }
        #[cfg(not(target_arch = "x86_64"))]
        $f($($arg),*)
    }};
    (wide $kernel:expr, $f:ident($($arg:ident: $ty:ty),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        if $kernel.or_portable() == $crate::kernels::simd::Kernel::Avx512 {
            #[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw,avx512dq")]
            fn avx512($($arg: $ty),*) {
                $f($($arg),*)
            }
            // SAFETY: `or_portable` gives Avx512 only when the CPU reports all four extensions.
            unsafe { avx512($($arg),*) }
        } else {
            $crate::kernels::simd::row_kernel!($kernel, $f($($arg: $ty),*))
        }
        #[cfg(not(target_arch = "x86_64"))]
        $f($($arg),*)
    }};
}
pub(crate) use row_kernel;

//! Runtime CPU-feature dispatch for element-wise kernels.
//!
//! The build stays portable (no `target-cpu`), but element-wise loops (activations, Adam, SAC's
//! tanh-Gaussian head) are compiled twice: once for the baseline and once with AVX2+FMA, chosen
//! at run time. faer already dispatches its GEMM kernels the same way. Both versions compute the
//! same IEEE operations in the same order per element, so results do not depend on the path
//! taken (FMA contraction is never applied implicitly by rustc; kernels that want FMAs write
//! `mul_add`, see [`crate::math`]).

/// Call `kernel(args..)` through an AVX2+FMA-compiled copy when the CPU has it.
///
/// `kernel` must be `#[inline(always)]` (and so must everything it calls): code that is not
/// inlined into the `#[target_feature]` copy is compiled for the baseline.
#[macro_export]
macro_rules! simd_dispatch {
    ($kernel:path [$($arg:expr),* $(,)?]) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2,fma")]
            unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
                f()
            }
            if $crate::simd::has_avx2() {
                // SAFETY: the CPU supports AVX2 and FMA (checked above).
                unsafe { avx2(|| $kernel($($arg),*)) }
            } else {
                $kernel($($arg),*)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            $kernel($($arg),*)
        }
    }};
}

/// In-crate shorthand: `dispatch!(kernel(args..))`.
macro_rules! dispatch {
    ($kernel:ident($($arg:expr),* $(,)?)) => {
        $crate::simd_dispatch!($kernel[$($arg),*])
    };
}
pub(crate) use dispatch;

/// Whether the CPU has AVX2 and FMA (cached by std).
#[cfg(target_arch = "x86_64")]
#[inline]
pub fn has_avx2() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

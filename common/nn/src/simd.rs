//! Runtime CPU-feature dispatch for element-wise kernels.
//!
//! The build stays portable (no `target-cpu`), but element-wise loops (activations, Adam, SAC's
//! tanh-Gaussian head) are compiled three times: for the baseline, with AVX2+FMA, and with
//! AVX-512F (16 lanes instead of 8: twice the multiply-adds of an `exp` polynomial per
//! instruction), chosen at run time. faer already dispatches its GEMM kernels the same way. Every
//! version computes the same IEEE operations in the same order per element, so results do not
//! depend on the path taken (FMA contraction is never applied implicitly by rustc; kernels that
//! want FMAs write `mul_add`, see [`crate::math`]; sums across elements are never reordered).
//!
//! [`cap_simd_level`] lowers the widest level the dispatch may take, process-wide: benchmarks
//! time the same work on each level in one process, and tests compare the levels' bits.

use std::sync::atomic::{AtomicU8, Ordering};

/// An instruction-set level of the element-wise kernels, narrowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SimdLevel {
    /// x86-64's baseline (SSE2), or the target's own on other architectures.
    Baseline = 0,
    /// AVX2 with FMA.
    Avx2 = 1,
    /// AVX-512F (with AVX2 and FMA).
    Avx512 = 2,
}

impl SimdLevel {
    /// Every level, narrowest first.
    pub const ALL: [SimdLevel; 3] = [SimdLevel::Baseline, SimdLevel::Avx2, SimdLevel::Avx512];

    /// The name a command line uses: `baseline`, `avx2`, `avx512`.
    pub fn name(self) -> &'static str {
        match self {
            SimdLevel::Baseline => "baseline",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the level.
    pub fn supported(self) -> bool {
        match self {
            SimdLevel::Baseline => true,
            SimdLevel::Avx2 => has_avx2(),
            SimdLevel::Avx512 => has_avx512(),
        }
    }

    /// The widest level this CPU supports.
    pub fn best_supported() -> SimdLevel {
        widest_supported_up_to(SimdLevel::Avx512)
    }
}

impl std::str::FromStr for SimdLevel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        SimdLevel::ALL
            .into_iter()
            .find(|l| l.name() == s)
            .ok_or_else(|| format!("unknown SIMD level `{s}`: expected baseline, avx2 or avx512"))
    }
}

/// The widest level the dispatch may take (`SimdLevel as u8`); the widest by default.
static CAP: AtomicU8 = AtomicU8::new(SimdLevel::Avx512 as u8);

/// The level stored as `level as u8`.
fn level_of(v: u8) -> SimdLevel {
    SimdLevel::ALL[usize::from(v).min(SimdLevel::ALL.len() - 1)]
}

/// Let the element-wise kernels of this process use at most `level` from now on (results stay
/// the same bits; only speed changes). Returns the previous cap.
pub fn cap_simd_level(level: SimdLevel) -> SimdLevel {
    level_of(CAP.swap(level as u8, Ordering::Relaxed))
}

/// The level the dispatch takes now: the widest the CPU supports, at most the cap.
#[inline]
pub fn simd_level() -> SimdLevel {
    widest_supported_up_to(level_of(CAP.load(Ordering::Relaxed)))
}

/// Whether faer's GEMMs take its x86 kernels here, which decides whether a run's bits equal
/// other machines'. faer takes them on x86-64 CPUs with AVX2 and FMA (its AVX2 or AVX-512
/// kernels give the same bits, and their depth blocking is fixed, whatever the caches); the
/// element-wise kernels give the same bits on every level. So a run is the same bits on every
/// x86-64 CPU with AVX2 and FMA (`tests/tests/cross_cpu.rs` runs MBPO on CPUs that QEMU
/// emulates). Elsewhere -- x86-64 CPUs without FMA (most from before 2013, some low-power ones
/// since), AArch64 and every other architecture -- faer falls back to the `gemm` crate's
/// kernels, which sum in another order, pick their depth blocking from the L1 cache's size and
/// allocate their packing buffers on every product but the smallest: other bits than x86-64
/// with FMA (a Nehalem and AArch64 under QEMU, results/measurements.md, 2026-11-29, commits
/// f7834bc and 4cb2acf; AArch64 again by `tools/compare_aarch64.sh`), and possibly other bits
/// between such CPUs whose L1 caches differ.
pub fn faer_x86_gemm_kernels() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The widest level at most `cap` that this CPU supports.
#[inline]
fn widest_supported_up_to(cap: SimdLevel) -> SimdLevel {
    if cap >= SimdLevel::Avx512 && has_avx512() {
        SimdLevel::Avx512
    } else if cap >= SimdLevel::Avx2 && has_avx2() {
        SimdLevel::Avx2
    } else {
        SimdLevel::Baseline
    }
}

/// Call `kernel(args..)` through the copy compiled for [`simd_level`]: AVX-512F, AVX2+FMA or
/// the baseline.
///
/// `kernel` must be `#[inline(always)]` (and so must everything it calls): code that is not
/// inlined into the `#[target_feature]` copy is compiled for the baseline.
#[macro_export]
macro_rules! simd_dispatch {
    ($kernel:path [$($arg:expr),* $(,)?]) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx512f,avx2,fma")]
            unsafe fn avx512<R>(f: impl FnOnce() -> R) -> R {
                f()
            }
            #[target_feature(enable = "avx2,fma")]
            unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
                f()
            }
            match $crate::simd::simd_level() {
                // SAFETY: `simd_level` returns a level only on a CPU that supports it.
                $crate::simd::SimdLevel::Avx512 => unsafe { avx512(|| $kernel($($arg),*)) },
                // SAFETY: as above.
                $crate::simd::SimdLevel::Avx2 => unsafe { avx2(|| $kernel($($arg),*)) },
                $crate::simd::SimdLevel::Baseline => $kernel($($arg),*),
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

/// Whether the CPU has AVX-512F besides AVX2 and FMA (cached by std).
#[inline]
fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f") && has_avx2()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU has AVX2 and FMA (cached by std).
#[inline]
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Activation, Adam, AdamConfig, WeightDecay};

    /// The bits of everything the crate's element-wise kernels write for fixed inputs, at the
    /// level the dispatch takes now: every activation's forward, fused bias forward, backward
    /// and fused backward with bias gradient, and three Adam steps with both kinds of decay.
    /// Widths leave tails in every vector width (16 + 8 + 4 + 3 lanes).
    fn kernel_bits() -> Vec<u32> {
        let (rows, width) = (3, 16 + 8 + 4 + 3);
        let wave = |n: usize, f: f32, a: f32| -> Vec<f32> {
            (0..n).map(|i| (i as f32 * f).sin() * a).collect()
        };
        let mut out = Vec::new();
        let mut keep = |v: &[f32]| out.extend(v.iter().map(|x| x.to_bits()));
        for act in [
            Activation::Identity,
            Activation::Relu,
            Activation::Silu,
            Activation::Tanh,
        ] {
            let (z0, bias, g) = (
                wave(rows * width, 0.77, 6.0),
                wave(width, 0.31, 0.5),
                wave(rows * width, 0.13, 1.0),
            );
            let mut a = vec![0.0; rows * width];
            act.forward(&z0, &mut a);
            keep(&a);
            let mut z = z0.clone();
            act.bias_forward(&mut z, &bias, &mut a);
            keep(&z);
            keep(&a);
            let mut dz = vec![0.0; rows * width];
            act.backward(&z, &a, &g, &mut dz);
            keep(&dz);
            let mut db = vec![0.0; width];
            act.backward_bias_grad(&z, &a, &g, &mut dz, &mut db);
            keep(&dz);
            keep(&db);
        }
        let n = 2 * width;
        let mut adam = Adam::new(n, AdamConfig::with_lr(0.01));
        adam.set_decay(3..9, WeightDecay::L2(0.3));
        adam.set_decay(14..20, WeightDecay::Decoupled(0.2));
        let mut p = wave(n, 0.3, 1.0);
        for step in 0..3 {
            adam.step(&mut p, &wave(n, 0.7 + step as f32, 1.0));
        }
        keep(&p);
        out
    }

    /// The same bits on every level this CPU has: what a run computes must not depend on the
    /// CPU it lands on. (Other tests running meanwhile only change speed while the cap is low.)
    #[test]
    fn every_simd_level_gives_the_same_bits() {
        let levels: Vec<SimdLevel> = SimdLevel::ALL
            .into_iter()
            .filter(|l| l.supported())
            .collect();
        let bits: Vec<Vec<u32>> = levels
            .iter()
            .map(|&level| {
                cap_simd_level(level);
                assert_eq!(simd_level(), level, "the cap is what the dispatch takes");
                kernel_bits()
            })
            .collect();
        cap_simd_level(SimdLevel::Avx512);
        for (level, b) in levels.iter().zip(&bits) {
            assert!(*b == bits[0], "{} differs from the baseline", level.name());
        }
    }

    #[test]
    fn levels_parse_from_their_names_and_refuse_others() {
        for level in SimdLevel::ALL {
            assert_eq!(level.name().parse::<SimdLevel>(), Ok(level));
        }
        let err = "sse4".parse::<SimdLevel>().unwrap_err();
        assert!(err.contains("sse4") && err.contains("avx512"), "{err}");
    }
}

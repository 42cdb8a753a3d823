//! Subnormal floats flushed to zero while the numerics run.
//!
//! Why: x86 handles a subnormal operand or result (|x| < 1.2e-38 for f32) in microcode, about
//! a hundred times slower than a normal one. A SAC agent makes them as it trains: gradients of
//! saturated units square to subnormal second moments in Adam. On Hopper-v5 after 20k updates
//! one update took 6.8 ms with them and 4.9 ms with them flushed (`mbpo bench breakdown`;
//! results/measurements.md, "Where an MBPO run's time goes", 2026-11-26, commit cab65f9).
//! TensorFlow, in which the MBPO paper's code runs, sets the same two flags for its kernels.
//!
//! The rule, in one place: every job of a [`crate::WorkerPool`] runs flushed (workers from
//! their start, the caller's share under a guard), and the entry points whose work may run
//! on a pool hold a [`FlushSubnormals`] for the whole call: training (`Sac::update`, the
//! ensemble's `train`), inference (`Sac::td_targets`, the ensemble's sampled and Gaussian
//! predictions) and acting (`ActorPolicy`, and `Sac::act`, which must equal it). So a result
//! never depends on the thread count or on which thread a caller runs on.

/// While alive, the calling thread flushes subnormal results to zero (FTZ) and reads
/// subnormal inputs as zero (DAZ); dropping it restores the thread's previous mode.
#[must_use = "the mode lasts only while the guard lives"]
pub struct FlushSubnormals {
    #[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
    saved: mode::Register,
}

/// x86-64: MXCSR, the SSE/AVX control register.
#[cfg(target_arch = "x86_64")]
mod mode {
    pub type Register = u32;

    /// MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6).
    pub const FLUSH: Register = 0x8040;

    pub fn read() -> Register {
        let mut csr = 0u32;
        // SAFETY: stmxcsr stores the 32-bit MXCSR register into the given location.
        unsafe {
            core::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack, preserves_flags))
        };
        csr
    }

    pub fn write(csr: Register) {
        // SAFETY: ldmxcsr loads MXCSR; only the FTZ/DAZ bits differ from a value read from it.
        unsafe {
            core::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly, preserves_flags))
        };
    }
}

/// AArch64: FPCR, the floating-point control register. Its FZ bit does what x86's FTZ and DAZ
/// do together (subnormal inputs read as zero, subnormal results written as zero), so the
/// numerics treat tiny values as on x86, as TensorFlow does on both. (AArch64 decides that a
/// result is subnormal before rounding, x86 after: they differ only for a result that rounds up
/// to the smallest normal float. Runs on AArch64 differ from x86-64's anyway, in their GEMMs:
/// `mbpo_nn::simd::faer_x86_gemm_kernels`.)
#[cfg(target_arch = "aarch64")]
mod mode {
    pub type Register = u64;

    /// FPCR's flush-to-zero bit (FZ, bit 24).
    pub const FLUSH: Register = 1 << 24;

    pub fn read() -> Register {
        let fpcr: u64;
        // SAFETY: mrs reads FPCR, which user code may read.
        unsafe {
            core::arch::asm!("mrs {}, fpcr", out(reg) fpcr, options(nomem, nostack, preserves_flags))
        };
        fpcr
    }

    pub fn write(fpcr: Register) {
        // SAFETY: msr writes FPCR, which user code may write; only FZ differs from a value read
        // from it.
        unsafe {
            core::arch::asm!("msr fpcr, {}", in(reg) fpcr, options(nostack, preserves_flags))
        };
    }
}

impl FlushSubnormals {
    /// Flush subnormals on this thread until the guard is dropped.
    pub fn new() -> Self {
        #[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
        {
            let saved = mode::read();
            mode::write(saved | mode::FLUSH);
            Self { saved }
        }
        #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
        Self {}
    }

    /// Flush subnormals on this thread from now on (a worker thread that only runs numerics).
    pub fn for_this_thread() {
        std::mem::forget(Self::new());
    }
}

impl Default for FlushSubnormals {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for FlushSubnormals {
    fn drop(&mut self) {
        #[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
        mode::write(self.saved);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The smallest normal f32 halved: a subnormal result.
    fn halve_smallest_normal() -> f32 {
        std::hint::black_box(f32::MIN_POSITIVE) * std::hint::black_box(0.5)
    }

    #[test]
    fn subnormals_are_flushed_only_while_the_guard_lives() {
        assert!(halve_smallest_normal() > 0.0, "subnormal kept by default");
        {
            let _flush = FlushSubnormals::new();
            if cfg!(any(target_arch = "x86_64", target_arch = "aarch64")) {
                assert_eq!(halve_smallest_normal(), 0.0);
                // DAZ: a subnormal input reads as zero.
                let tiny = std::hint::black_box(f32::from_bits(1));
                assert_eq!(tiny * std::hint::black_box(2.0f32), 0.0);
            }
        }
        assert!(halve_smallest_normal() > 0.0, "mode restored on drop");
    }
}

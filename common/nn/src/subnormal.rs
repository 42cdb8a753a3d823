//! Subnormal floats flushed to zero while the numerics run.
//!
//! Why: x86 handles a subnormal operand or result (|x| < 1.2e-38 for f32) in microcode, about
//! a hundred times slower than a normal one. A SAC agent makes them as it trains: gradients of
//! saturated units square to subnormal second moments in Adam. On Hopper-v5 after 20k updates
//! one update took 6.8 ms with them and 4.9 ms with them flushed (`mbpo bench breakdown`,
//! results/measurements.md, session 16).
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
    #[cfg(target_arch = "x86_64")]
    saved: u32,
}

#[cfg(target_arch = "x86_64")]
mod mxcsr {
    /// MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6).
    pub const FTZ_DAZ: u32 = 0x8040;

    pub fn read() -> u32 {
        let mut csr = 0u32;
        // SAFETY: stmxcsr stores the 32-bit MXCSR register into the given location.
        unsafe {
            core::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack, preserves_flags))
        };
        csr
    }

    pub fn write(csr: u32) {
        // SAFETY: ldmxcsr loads MXCSR; only the FTZ/DAZ bits differ from a value read from it.
        unsafe {
            core::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly, preserves_flags))
        };
    }
}

impl FlushSubnormals {
    /// Flush subnormals on this thread until the guard is dropped.
    pub fn new() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let saved = mxcsr::read();
            mxcsr::write(saved | mxcsr::FTZ_DAZ);
            Self { saved }
        }
        #[cfg(not(target_arch = "x86_64"))]
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
        #[cfg(target_arch = "x86_64")]
        mxcsr::write(self.saved);
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
            if cfg!(target_arch = "x86_64") {
                assert_eq!(halve_smallest_normal(), 0.0);
                // DAZ: a subnormal input reads as zero.
                let tiny = std::hint::black_box(f32::from_bits(1));
                assert_eq!(tiny * std::hint::black_box(2.0f32), 0.0);
            }
        }
        assert!(halve_smallest_normal() > 0.0, "mode restored on drop");
    }
}

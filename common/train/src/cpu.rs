//! What this CPU means for a run's results, logged once by every process that computes
//! (`mbpo train`, `mbpo bench`, each service of `mbpo run` on every host): runs are the same bits
//! on every x86-64 CPU with AVX2 and FMA, and differ in rounding on one without FMA
//! ([`mbpo_nn::simd::same_bits_as_fma_x86`]).

use std::sync::Once;

use mbpo_nn::simd::{same_bits_as_fma_x86, simd_level};

/// Logs the kernels this process takes, and warns when its results cannot equal those of other
/// machines (a lockstep run across such hosts, or a run repeated on another machine). Once per
/// process.
pub fn log_cpu_kernels() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let level = simd_level().name();
        match same_bits_as_fma_x86() {
            Some(true) => tracing::info!(
                "CPU kernels: {level}, GEMMs with FMA (the same bits on every x86-64 CPU with AVX2 and FMA)"
            ),
            Some(false) => tracing::warn!(
                "CPU without AVX2 and FMA: GEMMs multiply, then add, so results differ in rounding from \
                 runs on CPUs with AVX2 and FMA; compare runs made on one kind of CPU, and run a \
                 multi-host lockstep check on hosts of one kind"
            ),
            None => tracing::info!(
                "CPU kernels: {level} (bits compared across CPUs on x86-64 only)"
            ),
        }
    });
}

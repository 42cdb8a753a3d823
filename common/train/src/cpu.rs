//! What this CPU means for a run's results, logged once by every process that computes
//! (`mbpo train`, `mbpo bench`, each service of `mbpo run` on every host): runs are the same bits
//! on every x86-64 CPU with AVX2 and FMA, and other bits elsewhere
//! ([`mbpo_nn::simd::faer_x86_gemm_kernels`] says why). On an x86-64 CPU without AVX2 and FMA
//! it also warns about speed: the baseline copy of the element-wise kernels makes each
//! `mul_add` a library call (a correctly rounded fused multiply-add, so that every level gives
//! the same bits; software where the CPU has no FMA) and runs one lane at a time.

use std::sync::Once;

use mbpo_nn::simd::{faer_x86_gemm_kernels, simd_level};

/// Logs the kernels this process takes, and warns when its results cannot equal those of
/// x86-64 machines with AVX2 and FMA (a lockstep run across such hosts, or a run repeated on
/// another machine). Once per process.
pub fn log_cpu_kernels() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let level = simd_level().name();
        if faer_x86_gemm_kernels() {
            tracing::info!(
                "CPU kernels: {level}, GEMMs with FMA (the same bits on every x86-64 CPU with AVX2 and FMA)"
            );
        } else {
            tracing::warn!(
                "CPU kernels: {level} on {}, without faer's x86 GEMM kernels (they need x86-64 with \
                 AVX2 and FMA): the fallback GEMMs round differently, so results differ from runs on \
                 x86-64 CPUs with AVX2 and FMA (and may between CPUs with other L1 caches); compare \
                 runs made on one kind of CPU, and run a multi-host lockstep check on hosts of one kind",
                std::env::consts::ARCH
            );
            // On x86-64 this branch is a CPU without AVX2 and FMA: the element-wise kernels'
            // baseline level.
            if cfg!(target_arch = "x86_64") {
                tracing::warn!(
                    "CPU kernels: without AVX2 and FMA every multiply-add of the element-wise \
                     kernels (activations, Adam, the model's Gaussian head) is a library call, \
                     one lane at a time: model training runs tens of times slower than on a CPU \
                     with AVX2 and FMA (one model epoch over 10k transitions: 44 s at this level \
                     against 0.9 s with AVX2 on the same CPU, results/measurements.md session \
                     42; slower still where the call is software)"
                );
            }
        }
    });
}

//! Micro-benchmarks whose figures other benchmarks are compared with.

use crate::gemm::{gemm, Op};
use std::time::{Duration, Instant};

/// Single-thread f32 GEMM throughput for `C[m x n] = A[m x k] B[k x n]`, in GFLOP/s (2·m·k·n
/// flops per call), measured over at least `min_time` after a warm-up. Returns the best of
/// five timed rounds: the machine's attainable peak for that shape, i.e. a roofline.
pub fn gemm_gflops(m: usize, k: usize, n: usize, min_time: Duration) -> f64 {
    gemm_gflops_with(m, k, n, Op::N, Op::N, min_time)
}

/// [`gemm_gflops`] for `C = A' B'` with the operands stored transposed as `op_a` / `op_b` say,
/// as a backward pass multiplies them (`X^T dZ` for a weight gradient, `dZ W^T` for the
/// input's).
pub fn gemm_gflops_with(
    m: usize,
    k: usize,
    n: usize,
    op_a: Op,
    op_b: Op,
    min_time: Duration,
) -> f64 {
    let a: Vec<f32> = (0..m * k).map(|i| ((i % 17) as f32 - 8.0) * 0.01).collect();
    let b: Vec<f32> = (0..k * n).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect();
    let mut c = vec![0.0f32; m * n];
    let best = best_rate(2.0 * (m * k * n) as f64, min_time, || {
        gemm(&mut c, &a, op_a, &b, op_b, m, k, n, false)
    });
    std::hint::black_box(&c);
    best
}

/// [`gemm_gflops`] for the bf16 product on AMX (`crate::gemm::bf16`, the weights packed once as
/// a planner packs them, the rows converted in every call); `None` where AMX is not available.
pub fn gemm_bf16_gflops(m: usize, k: usize, n: usize, min_time: Duration) -> Option<f64> {
    use crate::gemm::bf16::{available, gemm_bf16, Bf16Scratch, PackedBf16};
    if !available() {
        return None;
    }
    let a: Vec<f32> = (0..m * k).map(|i| ((i % 17) as f32 - 8.0) * 0.01).collect();
    let b: Vec<f32> = (0..k * n).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect();
    let mut packed = PackedBf16::new(k, n);
    packed.pack(&b);
    let (mut scratch, mut c) = (Bf16Scratch::new(m, k, n), vec![0.0f32; m * n]);
    let best = best_rate(2.0 * (m * k * n) as f64, min_time, || {
        gemm_bf16(&mut c, &a, m, &packed, &mut scratch)
    });
    std::hint::black_box(&c);
    Some(best)
}

/// GFLOP/s of `call` (`flops` each): ten untimed calls, then the best of five rounds of
/// `min_time / 5`.
fn best_rate(flops: f64, min_time: Duration, mut call: impl FnMut()) -> f64 {
    for _ in 0..10 {
        call();
    }
    let round = min_time / 5;
    let mut best = 0.0f64;
    for _ in 0..5 {
        let start = Instant::now();
        let mut calls = 0u64;
        while start.elapsed() < round {
            for _ in 0..8 {
                call();
            }
            calls += 8;
        }
        let secs = start.elapsed().as_secs_f64();
        best = best.max(flops * calls as f64 / secs / 1e9);
    }
    best
}

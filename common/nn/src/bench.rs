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
    let flops = 2.0 * (m * k * n) as f64;
    for _ in 0..10 {
        gemm(&mut c, &a, op_a, &b, op_b, m, k, n, false);
    }
    let round = min_time / 5;
    let mut best = 0.0f64;
    for _ in 0..5 {
        let start = Instant::now();
        let mut calls = 0u64;
        while start.elapsed() < round {
            for _ in 0..8 {
                gemm(&mut c, &a, op_a, &b, op_b, m, k, n, false);
            }
            calls += 8;
        }
        let secs = start.elapsed().as_secs_f64();
        best = best.max(flops * calls as f64 / secs / 1e9);
    }
    std::hint::black_box(&c);
    best
}

//! Row-major GEMM on faer.
//!
//! All matrices in this crate are row-major `[f32]` slices: a batch is `rows x features`, a
//! weight matrix is `in x out`, so a dense layer is `Y = X W + b`. faer views a row-major slice
//! as the transpose of a column-major one at no cost, so transposed operands (`X^T dY`,
//! `dY W^T`) are free views, never copies.
//!
//! Products whose output width is not a multiple of 16 (the dynamics model's 200-wide layers)
//! and whose `B` is used as stored (forward passes and weight gradients) run, on AVX-512 CPUs,
//! through `ragged`, a kernel that gives faer's results bit for bit without faer's slow
//! 8-row tail; the environment variable `MBPO_GEMM_FAER=1` sends them back to
//! faer, for measuring one against the other.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

pub mod bf16;
#[cfg(target_arch = "x86_64")]
mod ragged;

/// Whether an operand is used as stored or transposed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op {
    /// Use the matrix as stored.
    N,
    /// Use its transpose.
    T,
}

/// `C = A' B'` (or `C += A' B'` when `accumulate`), where `A'` is `m x k` and `B'` is `k x n`
/// after applying `op_a` / `op_b` to the stored row-major matrices.
///
/// `a` holds `m x k` (or `k x m` when transposed), `b` holds `k x n` (or `n x k`), `c` holds `m x n`.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn gemm(
    c: &mut [f32],
    a: &[f32],
    op_a: Op,
    b: &[f32],
    op_b: Op,
    m: usize,
    k: usize,
    n: usize,
    accumulate: bool,
) {
    if k == 1 {
        // An outer product (the backward pass through a scalar-output layer, e.g. a critic's
        // Q head): faer takes its generic rank-update path for it, which cost 1.5 % of a SAC
        // update; this loop is a fraction of that. Each element is one product, as in faer.
        return outer(&mut c[..m * n], &a[..m], &b[..n], accumulate);
    }
    // Only with `B` as stored: `Bᵀ`'s rows are `B`'s columns, strided, and packing them costs
    // more than faer loses on its tail (`dZ Wᵀ` for a 200 x 200 layer: faer 162-166 GFLOP/s,
    // faer plus the kernel on a packed tail 157, the kernel on a packed whole 144).
    #[cfg(target_arch = "x86_64")]
    if !accumulate && op_b == Op::N && n >= 96 && !n.is_multiple_of(16) && use_ragged() {
        let (a, (rs_a, cs_a)) = (&a[..m * k], strides(op_a, m, k));
        // SAFETY: `use_ragged` checked the CPU for AVX-512F.
        return unsafe { ragged::gemm(c, n, a, rs_a, cs_a, b, n, m, k, n) };
    }
    let c = MatMut::from_row_major_slice_mut(&mut c[..m * n], m, n);
    let accum = if accumulate {
        Accum::Add
    } else {
        Accum::Replace
    };
    let (a, b) = (operand(a, op_a, m, k), operand(b, op_b, k, n));
    matmul(c, accum, a, b, 1.0f32, Par::Seq);
}

/// Whether a product of a shape seen before allocates nothing: with faer's x86 kernels
/// ([`crate::simd::faer_x86_gemm_kernels`]). faer's fallback, the `gemm` crate, allocates its
/// packing buffers on every product but the smallest, so the no-allocation tests of the hot
/// loops hold only here (measured under QEMU for AArch64: `tools/compare_aarch64.sh`).
pub fn allocation_free() -> bool {
    crate::simd::faer_x86_gemm_kernels()
}

/// The stored row-major matrix `x` as the `rows x cols` operand `op` makes of it.
fn operand(x: &[f32], op: Op, rows: usize, cols: usize) -> MatRef<'_, f32> {
    match op {
        Op::N => MatRef::from_row_major_slice(&x[..rows * cols], rows, cols),
        Op::T => MatRef::from_row_major_slice(&x[..rows * cols], cols, rows).transpose(),
    }
}

/// `(row stride, column stride)` of the `rows x cols` operand `op` makes of a row-major matrix.
#[cfg(target_arch = "x86_64")]
fn strides(op: Op, rows: usize, cols: usize) -> (usize, usize) {
    match op {
        Op::N => (cols, 1),
        Op::T => (1, rows),
    }
}

/// Whether ragged widths go through [`ragged`]: on AVX-512 CPUs unless `MBPO_GEMM_FAER` is set
/// (read once per process).
#[cfg(target_arch = "x86_64")]
fn use_ragged() -> bool {
    static USE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *USE.get_or_init(|| ragged::available() && std::env::var_os("MBPO_GEMM_FAER").is_none())
}

/// `C = a bᵀ` (or `C += a bᵀ`) for vectors a (m) and b (n): both layouts of a `m x 1` or
/// `1 x n` operand are the same contiguous vector.
fn outer(c: &mut [f32], a: &[f32], b: &[f32], accumulate: bool) {
    crate::simd::dispatch!(outer_kernel(c, a, b, accumulate))
}

#[inline(always)]
fn outer_kernel(c: &mut [f32], a: &[f32], b: &[f32], accumulate: bool) {
    for (row, &ai) in c.chunks_exact_mut(b.len()).zip(a) {
        if accumulate {
            row.iter_mut().zip(b).for_each(|(c, &bj)| *c += ai * bj);
        } else {
            row.iter_mut().zip(b).for_each(|(c, &bj)| *c = ai * bj);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Vec<f32> {
        let mut c = vec![0.0; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| a[i * k + p] * b[p * n + j]).sum();
            }
        }
        c
    }

    fn transpose(x: &[f32], r: usize, c: usize) -> Vec<f32> {
        let mut t = vec![0.0; r * c];
        for i in 0..r {
            for j in 0..c {
                t[j * r + i] = x[i * c + j];
            }
        }
        t
    }

    #[test]
    fn all_transpose_combinations_match_naive_product() {
        for (m, k, n) in [(5, 7, 3), (6, 1, 4)] {
            check_shape(m, k, n);
        }
    }

    /// Widths that are not a multiple of 16 take [`ragged`] (on AVX-512 CPUs) for every
    /// orientation; the products must be faer's, bit for bit, so that no result depends on
    /// the CPU the run happens to be on. One to three rows included: an epoch's last minibatch,
    /// halved for a member cut across two threads, can have a single row, and for one row faer
    /// sums a product with `Bᵀ` in another order than with `B` as stored (Hopper's 2-thread run
    /// changed at 26k for that when 8383275 stopped splitting `Bᵀ` products between faer and
    /// this kernel; results/measurements.md, "The 2-thread parting at 26k is 8383275",
    /// 2026-11-29, commit f7834bc).
    #[test]
    fn ragged_widths_give_faers_bits_in_every_orientation() {
        for (m, k, n) in [
            (128, 200, 200),
            (37, 50, 104),
            (256, 14, 200),
            (9, 300, 99),
            (1, 200, 200),
            (2, 14, 200),
            (3, 200, 104),
        ] {
            let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
            let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.11).cos()).collect();
            for op_a in [Op::N, Op::T] {
                for op_b in [Op::N, Op::T] {
                    let mut got = vec![f32::NAN; m * n];
                    gemm(&mut got, &a, op_a, &b, op_b, m, k, n, false);
                    let mut want = vec![0.0; m * n];
                    let c = MatMut::from_row_major_slice_mut(&mut want, m, n);
                    let (a, b) = (operand(&a, op_a, m, k), operand(&b, op_b, k, n));
                    matmul(c, Accum::Replace, a, b, 1.0f32, Par::Seq);
                    let same = got
                        .iter()
                        .zip(&want)
                        .all(|(x, y)| x.to_bits() == y.to_bits());
                    assert!(same, "{m}x{k}x{n} {op_a:?}{op_b:?}");
                }
            }
        }
    }

    fn check_shape(m: usize, k: usize, n: usize) {
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.11).cos()).collect();
        let want = naive(&a, &b, m, k, n);
        let at = transpose(&a, m, k);
        let bt = transpose(&b, k, n);
        for (aa, oa) in [(&a, Op::N), (&at, Op::T)] {
            for (bb, ob) in [(&b, Op::N), (&bt, Op::T)] {
                let mut c = vec![1.0; m * n];
                gemm(&mut c, aa, oa, bb, ob, m, k, n, false);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - y).abs() < 1e-5, "{oa:?}{ob:?}");
                }
                gemm(&mut c, aa, oa, bb, ob, m, k, n, true);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - 2.0 * y).abs() < 1e-5, "accumulate {oa:?}{ob:?}");
                }
            }
        }
    }
}
